"""The C reference target behind the real hardware bridge, over loopback, protocol version 3 with the rig's key:
`ambid identify --hardware` records a session and identifies the C target's plant as accurately as the simulated
rig at the same noise; under forged, replayed and old datagrams from a man on the rig network
(tests/nodes/udp_relay.py) it gives the same FRF, to the bit. `ambid graph --hardware` levitating the rotor
against the C target, paced on absolute deadlines, is test_commission's last step (with the controller tune
wrote): the graph run both tests had was the same, once each."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from ambid.background import wait
from ambid.excitation.spec import DesignSpec
from ambid.hardware import bridge_protocol as bp
from ambid.hardware.link_key import LinkKey, write_key_file
from ambid.hardware.target_model import rig_target_model, write_target_model
from ambid.plant.rig import make_rig

from ambid_nodes.running.plan import SessionConfig, session_samples
from udp_port import free_port
from udp_relay import Relay

ROOT = Path(__file__).resolve().parents[2]
BIN = ROOT / "ros_ws" / "install" / "target_c" / "ambp_udp_target"
SMALL = ["--resolution", "10", "--periods", "2", "--realisations", "1", "--transient-periods", "1", "--no-progress"]


@pytest.fixture(scope="module")
def key_file(tmp_path_factory) -> Path:
    """The rig's key, for the bridge (--key-file) and the target (--key-file) alike."""
    path = tmp_path_factory.mktemp("key") / "rig.key"
    write_key_file(path)
    return path


def start_target(model: Path, key: Path, *args: str, relay: bool = False):
    """The C target with the rig's key: (process, the address the bridge names as its target, the bridge's local
    port[, the relay between them: both ends name it as their peer])."""
    assert BIN.is_file(), f"{BIN} is missing: run './launch_scripts/ambid setup' (it compiles the C target)"
    tp, lp = free_port(), free_port()
    r = Relay(("127.0.0.1", lp), ("127.0.0.1", tp)) if relay else None
    peer = f"127.0.0.1:{r.address[1]}" if r else f"127.0.0.1:{lp}"
    proc = subprocess.Popen([str(BIN), "--model", str(model), "--bind", f"127.0.0.1:{tp}", "--bridge", peer,
                             "--linger", "0.3", "--key-file", str(key), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    target = peer if r else f"127.0.0.1:{tp}"
    return (proc, target, lp, r) if relay else (proc, target, lp)


def session_total(rig=None) -> int:
    """The samples of an identify session of SMALL on ``rig`` (default the default rig)."""
    rig = make_rig() if rig is None else rig
    fs = 1 / rig.dt
    spec = DesignSpec(resolution_hz=10, n_periods=2, n_realisations=1, n_transient_periods=1)
    return session_samples(SessionConfig(experiment=spec).design(fs, inputs=rig.layout.inputs), fs)[1]


def identify_on_target(model: Path, key: Path, out: Path, rig=None, *extra: str, strike=None) -> tuple[int, dict]:
    """``ambid identify --hardware --key-file`` (SMALL, ``extra`` arguments) against the C target running
    ``model``, free-running while it waits for the excitation (deterministic and fast), through a relay that
    records the session; ``strike(relay)`` arms it as a forger. Both ends must finish as planned; returns the
    session's samples and the relay's recording."""
    total = session_total(rig)
    # --bridge-timeout 5: identify's composed process can stall for more than the default 0.5 s on a loaded
    # machine (seen: the first FRF estimate), and a free-running target would land; a silent bridge is
    # test_target_c_socket's drill
    proc, target, local, relay = start_target(model, key, "--pace", "0", "--hold-for-excitation", "--samples",
                                              str(total), "--seed", "7", "--bridge-timeout", "5", relay=True)
    if strike is not None:
        strike(relay)
    try:
        hw = cli("identify", "--hardware", target, "--local-port", str(local), "--key-file", str(key),
                 "--true-model", str(model), "--out", str(out), *extra, *SMALL)
        s = target_summary(proc)
    finally:
        proc.kill()
        relay.close()
    assert hw.returncode == 0, hw.stdout + hw.stderr
    # the report, written by a process of its own after the headline, finished (the folder is whole)
    assert wait(out / "report" / "status.json")["state"] == "done"
    assert s["state"] == "done" and s["samples"] == total and s["late_excitation_samples"] == 0, s
    recording = {"to_target": list(relay.to_target), "to_bridge": list(relay.to_bridge), "target": s,
                 "stdout": hw.stdout + hw.stderr}
    return total, recording


def target_summary(proc: subprocess.Popen) -> dict:
    out, err = proc.communicate(timeout=30)
    line = next((ln for ln in out.splitlines() if ln.startswith("RT_TARGET_SUMMARY ")), None)
    assert line, err
    return json.loads(line.split(" ", 1)[1])


def cli(*args: str) -> subprocess.CompletedProcess:
    """``ambid ARGS`` on a ROS domain of its own (localhost only): no other test's or user's session hears it."""
    from domain_ids import next_domain_id

    env = dict(os.environ, ROS_DOMAIN_ID=str(next_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.run([sys.executable, "-m", "ambid_cli.cli", *args], capture_output=True, text=True,
                          timeout=240, cwd=ROOT, env=env)


@pytest.fixture(scope="module")
def c_identify(tmp_path_factory, key_file) -> dict:
    """One ``ambid identify --hardware`` of the C target with the rig's key, its traffic recorded by the relay."""
    d = tmp_path_factory.mktemp("c_identify")
    model = d / "rig.txt"
    write_target_model(model, rig_target_model())
    total, recording = identify_on_target(model, key_file, d / "hw")
    return {"dir": d, "model": model, "total": total, "out": d / "hw", "recording": recording}


def test_identify_hardware_gives_the_c_target_the_accuracy_of_the_simulated_rig(tmp_path, c_identify, key_file):
    model = c_identify["model"]
    sim = cli("identify", "--out", str(tmp_path / "sim"), "--linear-magnets", "--no-report", *SMALL)
    assert sim.returncode == 0, sim.stdout + sim.stderr
    total = c_identify["total"]
    a = json.loads((tmp_path / "sim" / "summary.json").read_text())
    b = json.loads((c_identify["out"] / "summary.json").read_text())
    assert b["layout"].startswith("hardware bridge") and b["frf_error"]["reference"] == "the given plant model"
    ea, eb = a["frf_error"], b["frf_error"]
    print(f"FRF error, simulated rig: median {100 * ea['median']:.2f} %, worst {100 * ea['worst']:.2f} %; "
          f"C target: median {100 * eb['median']:.2f} %, worst {100 * eb['worst']:.2f} %")
    # the same accuracy at the same noise: the median over ~100 lines within 25 %, the worst line within 1.6x
    assert 0.8 < eb["median"] / ea["median"] < 1.25
    assert 1 / 1.6 < eb["worst"] / ea["worst"] < 1.6
    assert b["max_mode_freq_error"] < 0.01 and b["modes_vs_true"]
    # the Python target serves the simulated rig itself (same seed): over the same bridge path the figures
    # are the simulated session's to the last bit, so the C target's differ by its noise realisation only
    tp, lp = free_port(), free_port()
    py_target = subprocess.Popen([sys.executable, "-m", "ambid.hardware.rt_target", "--bind", f"127.0.0.1:{tp}",
                                  "--bridge", f"127.0.0.1:{lp}", "--pace", "0", "--hold-for-excitation",
                                  "--samples", str(total), "--seed", "1", "--linger", "0.3", "--key-file",
                                  str(key_file), "--bridge-timeout", "5"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT / "ambid_core")
    try:
        py = cli("identify", "--hardware", f"127.0.0.1:{tp}", "--local-port", str(lp), "--true-model", str(model),
                 "--key-file", str(key_file), "--out", str(tmp_path / "py"), "--no-report", *SMALL)
        py_target.communicate(timeout=30)
    finally:
        py_target.kill()
    assert py.returncode == 0, py.stdout + py.stderr
    ep = json.loads((tmp_path / "py" / "summary.json").read_text())["frf_error"]
    assert ep["median"] == ea["median"] and ep["worst"] == ea["worst"]
    # recorded as any session: every sample's measurement, read back by the offline FRF above
    assert Path(b["recording"]["path"]).is_file() and b["recording"]["complete"]
    assert b["state"] == "done" and b["simulated_time_s"] == total / (1 / make_rig().dt)
    assert np.isfinite(b["noise"]["relative_frf_noise_std"])


def test_the_c_target_runs_the_five_axis_model_over_the_bridge(tmp_path, key_file):
    """rigs/five_axis.yaml's model in the C target: the protocol (version 3, like 2) carries its five axes (y, u,
    ic, r of a_x b_x a_y b_y z); the graph levitates on all five and identify measures the 5 x 5 FRF of the model
    the target runs."""
    rig_file = ROOT / "rigs" / "five_axis.yaml"
    from ambid.plant.rig import load_rig

    rig = load_rig(rig_file)
    model = tmp_path / "five.txt"
    write_target_model(model, rig_target_model(rig))
    assert "axes 5 a_x b_x a_y b_y z" in model.read_text()
    # paced on absolute deadlines as on a rig, at a quarter of real time: a loaded 2-core machine keeps up with
    # it, so a lost sample is the bridge's fault, not the test machine's (real time is a bench figure)
    proc, target, local = start_target(model, key_file, "--pace", "4")
    try:
        p = cli("graph", "--hardware", target, "--local-port", str(local), "--rig", str(rig_file),
                "--key-file", str(key_file), "--sim-seconds", "0.5")
        s = target_summary(proc)
    finally:
        proc.kill()
    assert p.returncode == 0, p.stdout + p.stderr
    assert "rotor levitated" in p.stdout and "lost 0 samples in 0 gaps" in p.stdout, p.stdout
    assert s["state"] == "done" and s["samples"] >= 5000 and s["rx_rejected_by_reason"]["content"] == 0
    # identify over the bridge: the 5 x 5 FRF against the model the target runs
    identify_on_target(model, key_file, tmp_path / "hw", rig, "--rig", str(rig_file))
    b = json.loads((tmp_path / "hw" / "summary.json").read_text())
    assert b["inputs"] == list(rig.layout.inputs) and b["outputs"] == list(rig.layout.outputs)
    print(f"five-axis C target: FRF error median {100 * b['frf_error']['median']:.2f} %, worst "
          f"{100 * b['frf_error']['worst']:.2f} %, modes {[round(m['freq_hz'], 1) for m in b['fit']['modes']]}")
    assert b["frf_error"]["median"] < 0.05 and b["max_mode_freq_error"] < 0.01


def _forge(d: bytes, tag: bytes) -> bytes:
    body = d[:-20] + tag
    return body + struct.pack("<I", zlib.crc32(body))


def test_identify_hardware_under_forged_and_replayed_traffic_gives_the_same_frf_to_the_bit(tmp_path, c_identify,
                                                                                            key_file):
    """The session of ``c_identify`` again, while a man on the rig network forges datagrams to both ends (right
    address and CRC, a zero tag or another key's), replays the whole earlier session to both, and sends this
    session's own datagrams again with old sequence numbers: the same FRF as without him, to the bit."""
    import ambid

    old = c_identify["recording"]
    evil = LinkKey(b"\x3c" * 32)
    sent = {"to_bridge": 0, "to_target": 0, "struck": False}

    def strike(relay: Relay) -> None:
        def tap(direction: str, d: bytes) -> None:
            if sent["struck"] or d[5] != bp.Kind.MEASUREMENT or len(relay.to_bridge) < 400:
                return
            sent["struck"] = True
            session = d[16:24]  # read off the wire, as anyone on the network can
            first = int.from_bytes(d[24:32], "little") + 2000
            fakes = {"to_target": [bp.Command(9, 99, bp.CommandCode.STOP),
                                   bp.Excitation(999, first, np.full((40, 4), 2.5))],
                     "to_bridge": [bp.Heartbeat(10**6, bp.TargetState.DONE, sample_rate_hz=10_000, axes=4),
                                   bp.Measurement(10**6, first, np.zeros((10, 16)), np.zeros(10, np.uint8))]}
            for way, msgs in fakes.items():
                sender = bp.Sender.BRIDGE if way == "to_target" else bp.Sender.TARGET
                for m in msgs:
                    sealed = bp.pack_datagram(m, 3, seal=bp.Seal(evil, sender, session))
                    for fake in (_forge(sealed, bytes(16)), _forge(sealed, os.urandom(16)), sealed):
                        relay.inject(way, fake)
                        sent[way] += 1
                for old_d in old[way]:  # the earlier session, whole
                    relay.inject(way, old_d)
            meas = [x for x in relay.to_bridge if x[5] == bp.Kind.MEASUREMENT]
            relay.inject("to_bridge", meas[0])   # this session's own, older than the replay window
            relay.inject("to_bridge", meas[-1])  # and one accepted just before
        relay.taps.append(tap)

    total, rec = identify_on_target(c_identify["model"], key_file, tmp_path / "hw", strike=strike)
    assert sent["struck"] and total == c_identify["total"]
    refused = {k: v for k, v in rec["target"]["rx_rejected_by_reason"].items() if v}
    assert refused == {"auth": sent["to_target"], "session": len(old["to_target"])}, refused
    clean, attacked = (ambid.estimate_frf(d / "session.mcap") for d in (c_identify["out"], tmp_path / "hw"))
    assert np.array_equal(attacked.freq_hz, clean.freq_hz)
    assert np.array_equal(attacked.frf, clean.frf)  # the same FRF, to the bit
    a, b = (json.loads((d / "summary.json").read_text()) for d in (c_identify["out"], tmp_path / "hw"))
    assert a["frf_error"] == b["frf_error"] and a["modes_vs_true"] == b["modes_vs_true"]
    # the key is nowhere but in its file: not in the recording, the summary, the report, the output
    secret_hex = key_file.read_text().split()[-1]
    for f in [p for p in (tmp_path / "hw").rglob("*") if p.is_file()]:
        data = f.read_bytes()
        assert bytes.fromhex(secret_hex) not in data and secret_hex.encode() not in data, f
    assert secret_hex not in rec["stdout"] and rec["target"]["key_fingerprint"] in rec["stdout"]
    # the recorded session's events name the bridge's refusals and the target's, by reason
    from ambid.recording.reader import iter_decoded

    events = [e for _, e in iter_decoded(tmp_path / "hw" / "session.mcap", "/amb/events")]
    codes = {e.code for e in events}
    assert {"forged_datagram", "foreign_session_datagram", "replayed_datagram", "duplicate_datagram",
            "target_refused"} <= codes, codes
    said = " ".join(e.text for e in events if e.code == "target_refused")
    assert "auth " in said and "session " in said
    # the bridge's own "finished" (the excitation generator's says so too, in words, and may be recorded first)
    final = json.loads(next(e.text for e in events if e.code == "finished" and e.node.endswith("hardware_bridge")))
    assert final["malformed_by_reason"] == {"auth": sent["to_bridge"], "session": len(old["to_bridge"]),
                                            "replay": 1}, final["malformed_by_reason"]
    assert final["duplicates"] == 1 and final["target_refused_by_reason"]["auth"] == sent["to_target"]
    print(f"identify under attack: target refused {refused}; bridge got {len(old['to_bridge'])} replayed and "
          f"{sent['to_bridge']} forged datagrams, {len(rec['to_bridge'])} genuine; FRF identical to the bit")
