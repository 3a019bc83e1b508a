"""Issue 38's drills on both targets (the C example program and the Python target), over real loopback
sockets, the test playing the bridge with the protocol module: a forger who sends from the bridge's own
address with right CRCs but no key or a wrong one, a replay of a whole recorded session, and datagrams of the
right session with sequences from the past. Every one is refused and counted by its reason at the target
(summary and heartbeat), the session runs as commanded, and its samples are those of the same session
without the attack, bit for bit. Key files: written 0600 by write_key_file, refused by both targets when
others may read them or they hold no key, one line and exit code 2; the key never shows in their output."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from ambid.hardware import bridge_protocol as bp
from ambid.hardware.link_key import LinkKey, read_key_file, write_key_file
from ambid.hardware.link_session import WINDOW
from ambid.hardware.target_model import rig_target_model, write_target_model

sys.path.insert(0, str(Path(__file__).resolve().parent))
from link_testbench import LinkBridge, target_command  # noqa: E402

N, CHUNK = 3000, 40
IMPLS = ["c", "python"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("link")
    key = write_key_file(d / "rig.key")
    write_target_model(d / "rig.txt", rig_target_model())
    secret = bytes.fromhex((d / "rig.key").read_text().split()[-1])
    return {"dir": d, "key_file": d / "rig.key", "key": key, "model": d / "rig.txt", "secret": secret}


def forge(d: bytes, tag: bytes) -> bytes:
    """A sealed datagram with its tag replaced and its CRC made right again: what a forger without the key
    can send (header and payload its own choice, the tag a guess)."""
    body = d[:-20] + tag
    return body + struct.pack("<I", zlib.crc32(body))


def run_session(impl: str, files: dict, attack: list[bytes] | None = None) -> tuple[LinkBridge, dict, np.ndarray]:
    """One deterministic session (free-running, held for its excitation): experiment [0, N) of seeded noise,
    START, run to DONE. ``attack`` (datagrams of an earlier session, replayed) arms the forger: it strikes
    before the experiment is announced, between the excitation chunks and while the clock runs."""
    b = LinkBridge(files["key"], 3, 4)
    args = ("--pace", "0", "--hold-for-excitation", "--samples", str(N), "--seed", "3", "--linger", "0.2",
            "--bridge-timeout", "10", "--protocol-version", "3", "--key-file", str(files["key_file"]))
    if impl == "c":
        b.start(impl, *args, model=files["model"])
    else:  # the Python target's code in a thread: no second interpreter to start
        b.start_thread(*args)
    r = np.random.default_rng(38).uniform(-0.3, 0.3, (N, 4))
    evil = LinkKey(b"\x5a" * 32)
    forged = 0

    def strike(code: int) -> int:
        """Forgeries of a command and of excitation: no key (a zero tag, a random one), another key, and
        version 2 (no tag at all); each with the session's id, the sender's next sequence, a right CRC."""
        session = b.link.session
        cmd = bp.Command(b.link.seq[bp.Kind.COMMAND], 900 + code, code)
        exc = bp.Excitation(b.link.seq[bp.Kind.EXCITATION], 0, np.full((CHUNK, 4), 2.5))  # 2.5 A: a kick
        sent = 0
        for msg in (cmd, exc):
            good_form = bp.pack_datagram(msg, 3, seal=bp.Seal(evil, bp.Sender.BRIDGE, session))
            for d in (forge(good_form, bytes(16)), forge(good_form, os.urandom(16)), good_form):
                b.raw(d)
                sent += 1
            b.raw(bp.pack_datagram(msg, 2))  # version 2: refused for its version, never obeyed
        return sent

    if attack:
        forged += strike(bp.CommandCode.SAFE_STATE)
        for d in attack:  # the whole recorded session again, from the bridge's address
            b.raw(d)
    assert b.command(1, bp.CommandCode.EXPERIMENT, 0, N, 1).result == bp.AckResult.OK
    chunks = []
    for first in range(0, N, CHUNK):
        chunks.append(b.send(bp.Excitation(0, first, r[first:first + CHUNK])))
        if attack and first == 40 * CHUNK:
            forged += strike(bp.CommandCode.STOP)
    if attack:
        assert len(chunks) > WINDOW + 2
        b.raw(chunks[0])   # this session's own datagram, its sequence older than the window: replay
        b.raw(chunks[-2])  # one within the window, accepted before: duplicate
    assert b.command(2, bp.CommandCode.START).result == bp.AckResult.OK
    if attack:
        forged += strike(bp.CommandCode.SAFE_STATE)
    code, summary, err = b.finish()
    assert code == 0 and summary["state"] == "done" and summary["samples"] == N, (summary, err)
    rows, flags, first = b.rows()
    assert first == 0 and len(rows) == N
    rows = np.column_stack([rows, flags])  # the sample flags (the Python rig lifts off its backup bearings) too
    assert not b.refused, b.refused  # the bridge's end refused nothing of the genuine target
    summary["forged"] = forged
    summary["stderr"] = err
    return b, summary, rows


@pytest.mark.parametrize("impl", IMPLS)
def test_forged_replayed_and_old_datagrams_are_refused_by_reason_and_change_no_sample(impl, files):
    clean, s0, rows0 = run_session(impl, files)
    assert s0["authenticated"] is True and s0["key_fingerprint"] == files["key"].fingerprint
    refused0 = {k: v for k, v in s0["rx_rejected_by_reason"].items() if v}
    assert refused0 == {}, refused0
    attacked, s1, rows1 = run_session(impl, files, attack=clean.sent)
    assert np.array_equal(rows1, rows0)  # y, u, ic, r of every sample, bit for bit: the attack changed nothing
    assert np.abs(rows0[:, 12:16]).max() < 0.31  # the forged 2.5 A excitation never reached r
    assert s1["session"] != s0["session"] and len(s1["session"]) == 16
    got = {k: v for k, v in s1["rx_rejected_by_reason"].items() if v}
    # per strike: 2 datagrams (command, excitation) x (zero tag, random tag, another key) refused for their
    # tag, 2 version-2 ones for their version; the recording's every datagram for its session; one replay and
    # one duplicate of this session's own excitation
    assert got == {"auth": 3 * 6, "version": 3 * 2, "session": len(clean.sent), "replay": 1, "duplicate": 1}, got
    assert s1["forged"] == 3 * 6
    hb = attacked.hbs[-1][1]  # the target's last heartbeat tells the bridge the same, by reason
    assert (hb.refused_auth, hb.refused_session, hb.refused_replay, hb.duplicates) == (18, len(clean.sent), 1, 1)
    assert hb.rx_rejected == sum(got.values())
    secret_hex = files["secret"].hex()
    for text in (s0["stderr"], s1["stderr"], str(s1)):
        assert secret_hex not in text
    if impl == "c":
        assert f"authenticated with the key of fingerprint {files['key'].fingerprint}" in s0["stderr"]
    print(f"{impl} target drill: refused {got}, {N} samples identical to the clean run's")


@pytest.mark.parametrize("impl", IMPLS)
def test_version_2_runs_only_when_both_ends_ask_and_says_it_is_unauthenticated(impl, files):
    b = LinkBridge(None, 2, 4)
    try:
        b.start(impl, "--pace", "0", "--samples", "200", "--linger", "0.2", "--protocol-version", "2",
                model=files["model"])
        assert b.command(1, bp.CommandCode.START).result == bp.AckResult.OK
        code, s, err = b.finish()
    finally:
        b.kill()
    assert code == 0 and s["state"] == "done" and s["authenticated"] is False
    assert "the link is unauthenticated (protocol version 2)" in err
    # a version-3 bridge's HELLO at a version-2 target: refused for its version, the target never starts
    b3 = LinkBridge(files["key"], 3, 4)
    try:
        args = ("--pace", "0", "--samples", "200", "--linger", "0.2", "--protocol-version", "2")
        if impl == "c":
            b3.start(impl, *args, model=files["model"], handshake=False)
        else:
            b3.start_thread(*args, handshake=False)
        b3.wait_for(lambda: b3.refused["version"] >= 1, 20, "the version-2 target's heartbeat")  # refused too
        for _ in range(3):
            b3.raw(b3.link.hello())
        b3.pump(0.1)
        if impl == "c":
            b3.proc.terminate()
        else:
            b3.thread_target.stop.set()
        code, s, err = b3.finish()
    finally:
        b3.kill()
    assert not b3.link.established and s["state"] == "idle" and s["rx_rejected_by_reason"]["version"] == 3


def _run_target(impl: str, files: dict, capsys, *args: str) -> subprocess.CompletedProcess:
    """A target that refuses its options: the C program, or the Python target's main() in this process (the
    same checks, no interpreter to start; it returns before it binds a socket)."""
    version = [] if "--protocol-version" in args else ["--protocol-version", "3"]
    argv = ["--bind", "127.0.0.1:0", "--bridge", "127.0.0.1:9", *version, *args]
    if impl == "c":
        return subprocess.run([*target_command(impl, files["model"]), *argv], capture_output=True, text=True,
                              timeout=30, cwd=files["dir"])
    from ambid.hardware import rt_target

    capsys.readouterr()
    code = rt_target.main(argv)
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(argv, code, out, err)


@pytest.mark.parametrize("impl", IMPLS)
def test_bad_key_files_are_refused_with_one_line(impl, files, capsys):
    d = files["dir"]
    (d / "open.key").write_text(files["key_file"].read_text())
    os.chmod(d / "open.key", 0o644)
    cases = {
        "open.key": "may be read by group or others (mode 0644)",
        "missing.key": "does not exist",
        "empty.key": "is empty",
        "short.key": "a key of 8 bytes",
        "odd.key": "not an even number of hex digits",
        "two.key": "holds 2 lines besides comments",
        "comments.key": "holds no key",
        "binary.key": "not text",
    }
    texts = {"empty.key": "", "short.key": "00" * 8, "odd.key": "abc", "two.key": "00" * 32 + "\n" + "11" * 32,
             "comments.key": "# nothing\n\n", "binary.key": "\x00\xff" * 20}
    for name, text in texts.items():
        p = d / name
        p.unlink(missing_ok=True)
        p.write_bytes(text.encode("latin-1"))
        os.chmod(p, 0o600)
    for name, words in cases.items():
        r = _run_target(impl, files, capsys, "--key-file", str(d / name))
        assert r.returncode == 2 and words in r.stderr and len(r.stderr.strip().splitlines()) == 1, (name, r.stderr)
        assert "Traceback" not in r.stderr and "RT_TARGET_LISTENING" not in r.stdout
    r = _run_target(impl, files, capsys, "--key-file", str(d))
    assert r.returncode == 2 and "is a folder" in r.stderr
    r = _run_target(impl, files, capsys)  # version 3 without a key
    assert r.returncode == 2 and "--key-file" in r.stderr and "--protocol-version 2" in r.stderr
    r = _run_target(impl, files, capsys, "--protocol-version", "2", "--key-file", str(files["key_file"]))
    assert r.returncode == 2 and "unauthenticated" in r.stderr


def test_key_files_are_written_private_and_show_only_their_fingerprint(files, tmp_path):
    p = tmp_path / "new.key"
    key = write_key_file(p)
    assert os.stat(p).st_mode & 0o777 == 0o600
    assert read_key_file(p).fingerprint == key.fingerprint != files["key"].fingerprint
    text = p.read_text()
    secret = bytes.fromhex(text.split()[-1])
    assert len(secret) == 32 and f"fingerprint {key.fingerprint}" in text
    assert secret.hex() not in repr(key) + str(key) and key.fingerprint in repr(key)
    with pytest.raises(ValueError, match="exists"):
        write_key_file(p)
    import pickle
    with pytest.raises(TypeError, match="not pickled"):
        pickle.dumps(key)


def test_keygen_writes_a_private_key_file_and_says_its_fingerprint_only(tmp_path, capsys):
    from ambid_cli import cli

    out = tmp_path / "rig.key"
    assert cli.main(["keygen", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    key = read_key_file(out)
    assert os.stat(out).st_mode & 0o777 == 0o600
    assert f"fingerprint {key.fingerprint}" in printed and out.read_text().split()[-1] not in printed
    assert cli.main(["keygen", "--out", str(out)]) == 2  # never over an existing key
    assert "exists" in capsys.readouterr().err
