"""Crash safety: truncated files, a writer killed with SIGKILL, a full disk."""

import errno
import os
import signal
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from ambid.recording import (IncompleteSessionError, SessionWriteError, SessionWriter, iter_decoded, iter_messages,
                           scan_session)
from mcap.reader import make_reader

AMBID_CORE = Path(__file__).resolve().parents[2] / "ambid_core"
STEP_NS = 1_000_000


@pytest.fixture(autouse=True)
def ament_prefix(monkeypatch):
    monkeypatch.setenv("AMENT_PREFIX_PATH", sys.prefix)


def payload(i):
    # std_msgs/String CDR: encapsulation, length incl. NUL, text, NUL.
    text = f"message {i:08d}".encode()
    return b"\x00\x01\x00\x00" + struct.pack("<I", len(text) + 1) + text + b"\x00"


def check_prefix(messages):
    """The messages must be 0, 1, 2, ... exactly as written, none altered."""
    for k, m in enumerate(messages):
        assert m.log_time_ns == k * STEP_NS and m.data == payload(k), f"message {k} corrupted"


def test_truncated_files_give_every_complete_chunk(tmp_path):
    path = tmp_path / "full.mcap"
    with SessionWriter(path, chunk_size_bytes=1024) as w:
        w.add_topic("/count", "std_msgs/msg/String")
        for i in range(400):
            w.write("/count", payload(i), i * STEP_NS)
    data = path.read_bytes()
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) > 10
    # Cut inside chunk records, inside message indexes, inside a record header.
    cuts = [chunks[3].chunk_start_offset + 5, chunks[5].chunk_start_offset + chunks[5].chunk_length // 2,
            chunks[8].chunk_start_offset + chunks[8].chunk_length + 3, chunks[-1].chunk_start_offset]
    for cut in cuts:
        short = tmp_path / f"cut{cut}.mcap"
        short.write_bytes(data[:cut])
        # Messages of chunks whose record ends before the cut (log times are i * STEP_NS).
        expected = sum((c.message_end_time - c.message_start_time) // STEP_NS + 1
                       for c in chunks if c.chunk_start_offset + c.chunk_length <= cut)
        scan = scan_session(short)
        assert not scan.complete and scan.problem and scan.message_count == expected
        got = list(iter_messages(short, recover=True))
        assert len(got) == expected
        check_prefix(got)
        assert scan.valid_bytes <= cut
    with pytest.raises(ValueError, match="not an MCAP file"):
        (tmp_path / "junk.mcap").write_bytes(b"hello world, not mcap")
        scan_session(tmp_path / "junk.mcap")
    (tmp_path / "empty.mcap").write_bytes(b"")
    assert scan_session(tmp_path / "empty.mcap").message_count == 0


CHILD = textwrap.dedent(
    """
    import struct, sys, time
    from ambid.recording import SessionWriter

    def payload(i):
        text = f"message {i:08d}".encode()
        return b"\\x00\\x01\\x00\\x00" + struct.pack("<I", len(text) + 1) + text + b"\\x00"

    w = SessionWriter(sys.argv[1], chunk_size_bytes=2048)
    w.add_topic("/count", "std_msgs/msg/String")
    w.write_session_facts({"rig": "killed"})
    chunks = 0
    for i in range(2_000_000):  # bounded, in case the parent dies
        w.write("/count", payload(i), i * 1_000_000)
        if w.chunk_count != chunks:
            chunks = w.chunk_count
            print(chunks, w.flushed_message_count, flush=True)
    time.sleep(60)
    """
)


def test_sigkilled_writer_loses_at_most_its_open_chunk(tmp_path):
    path = tmp_path / "killed.mcap"
    env = dict(os.environ, PYTHONPATH=str(AMBID_CORE), AMENT_PREFIX_PATH=sys.prefix)
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, env=env, text=True)
    try:
        flushed = chunks = 0
        for line in proc.stdout:
            chunks, flushed = map(int, line.split())
            if chunks >= 8:
                break
        proc.send_signal(signal.SIGKILL)  # the child keeps writing until here
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL and chunks >= 8 and flushed > 0

    scan = scan_session(path)
    assert not scan.complete
    assert scan.message_count >= flushed
    assert scan.metadata["ambid.session"]["rig"] == "killed"
    got = list(iter_messages(path, recover=True))
    assert len(got) == scan.message_count
    check_prefix(got)
    decoded = [obj.data for _, obj in iter_decoded(path, recover=True)]
    assert decoded[:3] == ["message 00000000", "message 00000001", "message 00000002"]
    with pytest.raises(IncompleteSessionError):
        list(iter_messages(path))


class FullDisk:
    """Binary file that accepts `budget` bytes, writes the part that fits, then raises ENOSPC."""

    def __init__(self, path, budget):
        self._f = open(path, "wb")
        self._budget = budget
        self.name = str(path)

    def write(self, b):
        room = self._budget - self._f.tell()
        if len(b) > room:
            self._f.write(bytes(b[: max(room, 0)]))
            self._f.flush()
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self._f.write(b)

    def tell(self):
        return self._f.tell()

    def flush(self):
        self._f.flush()

    def close(self):
        self._f.close()


def test_full_disk_raises_clear_error_and_leaves_a_recoverable_file(tmp_path):
    path = tmp_path / "full_disk.mcap"
    sink = FullDisk(path, budget=20_000)
    w = SessionWriter(sink, chunk_size_bytes=1024)
    w.add_topic("/count", "std_msgs/msg/String")
    flushed_before = 0
    with pytest.raises(SessionWriteError) as info:
        for i in range(100_000):
            flushed_before = w.flushed_message_count
            w.write("/count", payload(i), i * STEP_NS)
    err = info.value
    assert err.errno == errno.ENOSPC and isinstance(err, OSError)
    assert str(path) in str(err) and "disk full" in str(err) and "recover=True" in str(err)
    with pytest.raises(SessionWriteError):  # the writer stays failed
        w.write("/count", payload(0), 0)
    w.close()  # only releases; must not raise again
    sink.close()
    assert path.stat().st_size == 20_000

    scan = scan_session(path)
    assert not scan.complete and scan.message_count >= flushed_before > 0
    got = list(iter_messages(path, recover=True))
    assert len(got) == scan.message_count
    check_prefix(got)
