"""The C example target (ambp_udp_target) over a real loopback socket, this test playing the bridge with the
Python protocol module (version 3, the rig's key; tests/core/link_testbench.py): sample-exact injection of excitation that arrives reordered, duplicated, lost,
corrupted, truncated or from a stranger; late excitation in real time; a silent bridge; idempotent commands;
and bad options and model files refused with one line and exit code 2.

The plant and controller the target runs are checked against a simulation of the same matrices written here
(numpy, sensor noise off), so every row the C target sends is verified, not only its protocol.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from ambid.hardware import bridge_protocol as bp
from ambid.hardware.link_key import write_key_file
from ambid.hardware.target_model import TargetModel, rig_target_model, write_target_model

sys.path.insert(0, str(Path(__file__).resolve().parent))
from link_testbench import C_TARGET as BIN, LinkBridge  # noqa: E402


@pytest.fixture(scope="module")
def model_files(tmp_path_factory):
    assert BIN.is_file(), f"{BIN} is missing: run './launch_scripts/ambid setup' (it compiles the C target)"
    d = tmp_path_factory.mktemp("target_c")
    m = rig_target_model()
    quiet = TargetModel(m.plant, m.controller, m.current_limit_a, m.controller_limit_a, np.zeros(4))
    write_target_model(d / "quiet.txt", quiet)
    write_target_model(d / "rig.txt", m)
    key = write_key_file(d / "rig.key")
    return {"quiet": d / "quiet.txt", "rig": d / "rig.txt", "model": quiet, "dir": d, "key": key,
            "key_args": ["--protocol-version", "3", "--key-file", str(d / "rig.key")]}


def simulate(m: TargetModel, r: np.ndarray) -> np.ndarray:
    """(n, 16) rows y, u, ic, r of the loop the C target runs, without noise, for r (n, 4)."""
    p, c = m.plant, m.controller
    x, xc = np.zeros(p.n_states), np.zeros(c.n_states)
    out = np.zeros((len(r), 16))
    for k in range(len(r)):
        y = p.c @ x
        ic = np.clip(c.c @ xc + c.d @ y, -m.controller_limit_a, m.controller_limit_a)
        xc = c.a @ xc + c.b @ y
        u = ic + r[k]
        x = p.a @ x + p.b @ np.clip(u, -m.current_limit_a, m.current_limit_a)
        out[k] = np.concatenate([y, u, ic, r[k]])
    return out


class Bridge(LinkBridge):
    """The test's bridge: version 3 with the rig's key, the C target started with the same key."""

    def __init__(self, files: dict) -> None:
        super().__init__(files["key"], 3, 4)
        self.files = files

    def start(self, model: Path, *args: str):
        return super().start("c", *args, *self.files["key_args"], model=model)

    def finish(self, timeout: float = 20) -> tuple[int, dict]:
        code, summary, _ = super().finish(timeout)
        return code, summary


@pytest.fixture
def bridge(model_files):
    b = Bridge(model_files)
    yield b
    b.kill()


def test_excitation_reordered_duplicated_lost_and_malformed_is_applied_sample_exact(bridge, model_files):
    n, start, length = 400, 100, 200
    r_exc = np.random.default_rng(4).uniform(-0.3, 0.3, (length, 4))
    bridge.start(model_files["quiet"], "--pace", "0", "--hold-for-excitation", "--samples", str(n),
                 "--linger", "0.2", "--bridge-timeout", "10")
    assert bridge.hbs[0][1].state == bp.TargetState.IDLE and bridge.hbs[0][1].sample_rate_hz == 10_000
    # a version-1 START is refused as such (this target speaks version 3): the target stays idle
    bridge.raw(bp.pack_datagram(bp.Command(0, 99, bp.CommandCode.START), version=1))
    ack = bridge.command(1, bp.CommandCode.EXPERIMENT, start, length, 1)
    assert ack.result == bp.AckResult.OK and ack.state == bp.TargetState.IDLE
    # the same command id again with other arguments: answered as the first time, not run again
    again = bridge.command(1, bp.CommandCode.EXPERIMENT, 0, 5, 1)
    assert again.result == bp.AckResult.OK and again.command_id == 1
    assert bridge.command(2, 77).result == bp.AckResult.BAD_ARGUMENT
    chunks = {f: bp.Excitation(0, f, r_exc[f - start:f - start + 40]) for f in range(start, start + length, 40)}
    lost = start + 80
    for f in (260, 140, 100, 140, 220):  # reordered, one duplicated, the chunk at `lost` missing
        bridge.send(chunks[f])
    good = bytearray(bridge.link.pack(bp.Excitation(0, lost, chunks[lost].data)))
    good[100] ^= 0x10
    bridge.raw(bytes(good))  # corrupted: CRC
    bridge.raw(bridge.link.pack(chunks[lost])[:15])  # truncated below header + CRC: length
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger.sendto(bridge.link.pack(chunks[lost]), bridge.target)  # right bytes, wrong sender: foreign
    stranger.close()
    assert bridge.command(3, bp.CommandCode.START).result == bp.AckResult.OK
    # the target holds at the first missing sample and asks for it in its heartbeat
    bridge.wait_for(lambda: bridge.hbs[-1][1].sample_index == lost and bridge.hbs[-1][1].excitation_next == lost,
                    10, f"the target to hold at sample {lost}")
    bridge.send(chunks[lost])
    code, s = bridge.finish()
    assert code == 0 and s["state"] == "done" and s["samples"] == n
    assert s["rx_rejected_by_reason"] == {"oversized": 0, "length": 1, "magic": 0, "version": 1, "crc": 1, "kind": 0,
                                          "content": 0, "foreign": 1, "auth": 0, "direction": 0, "session": 0,
                                          "replay": 0, "duplicate": 0}
    assert s["late_excitation_samples"] == 0
    rows, flags, first = bridge.rows()
    assert first == 0 and len(rows) == n and not flags.any()
    r = np.zeros((n, 4))
    r[start:start + length] = r_exc
    assert np.array_equal(rows[:, 12:], r)  # every excitation sample at exactly its index, nothing else
    assert np.array_equal(rows[:, 4:8], rows[:, 8:12] + r)  # u = ic + r
    expected = simulate(model_files["model"], r)
    scale = np.abs(expected).max(axis=0) + 1e-30
    assert np.all(np.abs(rows - expected) <= 1e-9 * scale)
    assert np.abs(rows[:, :4]).max() > 1e-7  # the excitation moved the rotor: the check above is not of zeros
    hb = bridge.hbs[-1][1]
    assert hb.state == bp.TargetState.DONE and not hb.clock_running and hb.sent_end == n
    # sequence numbers per kind, +1 per datagram: what lets the bridge count losses
    assert sorted(m.sequence for m in bridge.meas) == list(range(n // 10)) == list(range(hb.next_measurement_sequence))
    assert [h.sequence for _, h in bridge.hbs] == list(range(len(bridge.hbs)))
    assert [a.sequence for a in bridge.acks] == list(range(len(bridge.acks)))
    assert hb.rx_rejected == 4 and hb.excitation_next == bp.NO_INDEX and not bridge.refused


def test_real_time_run_applies_r_zero_where_excitation_is_late_and_says_so(bridge, model_files):
    n, start, length, gap = 3000, 1000, 1000, (1520, 1600)  # two 40-sample chunks never sent
    r_exc = np.random.default_rng(5).uniform(-0.2, 0.2, (length, 4))
    bridge.start(model_files["rig"], "--pace", "1", "--samples", str(n), "--linger", "0.2", "--seed", "3")
    assert bridge.command(1, bp.CommandCode.EXPERIMENT, start, length, 1).result == bp.AckResult.OK
    for f in range(start, start + length, 40):
        if not gap[0] <= f < gap[1]:
            bridge.send(bp.Excitation(0, f, r_exc[f - start:f - start + 40]))
    assert bridge.command(2, bp.CommandCode.START).result == bp.AckResult.OK
    t_next = 0.0
    while bridge.proc.poll() is None:  # heartbeats as the bridge sends them
        if time.monotonic() > t_next:
            bridge.send(bp.Heartbeat(0, bp.TargetState.RUNNING))
            t_next = time.monotonic() + 0.05
        bridge.pump()
    code, s = bridge.finish()
    assert code == 0 and s["state"] == "done"
    rows, flags, first = bridge.rows()
    late = (flags & bp.FLAG_EXCITATION_LATE) != 0
    assert np.flatnonzero(late).tolist() == list(range(*gap))  # exactly the samples without excitation
    assert s["late_excitation_samples"] == gap[1] - gap[0] == bridge.hbs[-1][1].late_excitation_samples
    r = np.zeros((n, 4))
    r[start:start + length] = r_exc
    r[gap[0]:gap[1]] = 0.0
    assert np.array_equal(rows[:, 12:], r)
    assert np.abs(rows[:, :4]).max() < 20e-6  # levitated: far inside the backup clearance
    print(f"C target real time: {s['samples_per_wall_s']:.0f} samples/s achieved of "
          f"{s['commanded_samples_per_s']:.0f} commanded, {s['late_samples']} late samples "
          f"(max {s['max_late_us']:.0f} us), {s['overruns']} overruns")
    assert s["samples_per_wall_s"] == pytest.approx(10_000, rel=0.2)


def test_silent_bridge_sends_the_target_to_its_safe_state(bridge, model_files):
    timeout = 0.15
    bridge.start(model_files["rig"], "--pace", "1", "--bridge-timeout", str(timeout), "--safe-seconds", "0.01",
                 "--linger", "0.2", "--float32", "--block", "21")  # the most samples float32 datagrams carry
    assert bridge.command(1, bp.CommandCode.START).result == bp.AckResult.OK
    end = time.monotonic() + 0.3
    while time.monotonic() < end:
        bridge.send(bp.Heartbeat(0, bp.TargetState.RUNNING))
        last_sent = time.monotonic()
        bridge.pump(0.02)
    bridge.wait_for(lambda: bridge.hbs[-1][1].state == bp.TargetState.SAFE, 5, "the safe state")
    t_safe, hb = next((t, h) for t, h in bridge.hbs if h.state == bp.TargetState.SAFE)
    assert hb.safe_reason == bp.SafeReason.BRIDGE_SILENT
    assert timeout < t_safe - last_sent < timeout + 0.1
    code, s = bridge.finish()
    assert code == 1 and s["state"] == "safe" and s["safe_reason"] == "bridge_silent"
    rows, flags, first = bridge.rows()
    safe = (flags & bp.FLAG_SAFE_STATE) != 0
    assert safe.sum() == 100 and safe[-100:].all()  # 0.01 s of landing at zero current, then the clock stops
    assert not rows[safe, 4:].any() and rows[~safe, 8:12].any()
    assert bridge.hbs[-1][1].state == bp.TargetState.SAFE and not bridge.hbs[-1][1].clock_running
    assert {len(m.data) for m in bridge.meas[:-1]} == {21} and rows.dtype == float
    assert np.array_equal(rows, rows.astype(np.float32).astype(float))  # float32 on the wire


def _write(path: Path, text: str | bytes) -> Path:
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def _bad_models(d: Path, good: str) -> dict[str, tuple[Path, str]]:
    """name -> (model file, words the refusal must contain)."""
    lines = good.splitlines(keepends=True)
    d_idx = next(i for i, ln in enumerate(lines) if ln.startswith("plant_D"))
    nonzero_d = "".join(lines[:d_idx + 1]) + "1 0 0 0\n" + "".join(lines[d_idx + 2:])
    return {
        "missing": (d / "no_such.txt", "No such file"),
        "folder": (d, "is a directory"),
        "empty": (_write(d / "empty.txt", ""), "is empty"),
        "random": (_write(d / "random.txt", np.random.default_rng(0).bytes(3000)), "not"),
        "truncated": (_write(d / "truncated.txt", good[:len(good) // 2]), "truncated"),
        "unrelated": (_write(d / "unrelated.txt", "a: 1\nb: [2, 3]\n"), "not an ambid target model"),
        "version": (_write(d / "version.txt", good.replace("ambid_target_model 2", "ambid_target_model 3")),
                    "format version 3"),
        "nan": (_write(d / "nan.txt", good.replace("dt 0.0001", "dt nan")), "dt"),
        "word": (_write(d / "word.txt", good.replace("plant_B", "plant_X")), "expected 'plant_B'"),
        "dt": (_write(d / "dt.txt", good.replace("dt 0.0001", "dt 0.00013")), "whole number of hertz"),
        "plant_d": (_write(d / "d.txt", nonzero_d), "plant_D must be zero"),
        "trailing": (_write(d / "trailing.txt", good + "1 2 3\n"), "after 'end'"),
    }


def test_bad_model_files_get_one_line_and_exit_code_2(model_files):
    d = model_files["dir"] / "bad"
    d.mkdir()
    for name, (path, words) in _bad_models(d, model_files["quiet"].read_text()).items():
        p = subprocess.run([str(BIN), "--model", str(path), "--bind", "127.0.0.1:0", *model_files["key_args"]],
                           capture_output=True, text=True, timeout=10)
        assert p.returncode == 2, (name, p.stderr)
        assert p.stdout == "" and len(p.stderr.splitlines()) == 1, (name, p.stderr)
        assert p.stderr.startswith("ambp_udp_target: ") and words in p.stderr, (name, p.stderr)


@pytest.mark.parametrize("args, words", [
    ([], "--model FILE is required"),
    (["--model", "{m}", "--pace", "-1"], "--pace"),
    (["--model", "{m}", "--pace", "fast"], "--pace"),
    (["--model", "{m}", "--block", "11"], "at most 10 samples"),
    (["--model", "{m}", "--bind", "nonsense"], "--bind"),
    (["--model", "{m}", "--bridge", "127.0.0.1:70000"], "--bridge"),
    (["--model", "{m}", "--seed"], "needs a value"),
    (["--model", "{m}", "--bogus", "1"], "unknown option '--bogus'"),
    (["--model", "{m}", "--hold-for-excitation"], "needs --pace 0"),
    (["--model", "{m}", "stray"], "unexpected argument"),
    (["--model", "{m}", "--pace", "0", "--priority", "50"], "needs --pace > 0"),
    (["--model", "{m}", "--priority", "0"], "--priority"),
])
def test_bad_options_get_one_line_and_exit_code_2(model_files, args, words):
    args = model_files["key_args"] + [a.format(m=model_files["quiet"]) for a in args]
    p = subprocess.run([str(BIN), *args], capture_output=True, text=True, timeout=10)
    assert p.returncode == 2 and p.stdout == "" and len(p.stderr.splitlines()) == 1, p.stderr
    assert words in p.stderr, p.stderr
