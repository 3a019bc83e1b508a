"""What the authenticated link (protocol version 3) costs the C reference target and the Python side, beside
version 2.

The measurements, each for version 2 (before authentication) and version 3 (after):

* the protocol's cost per datagram: ``ambp_bench`` (ambid_core/target_c/ambp_bench.c) encodes the target's
  MEASUREMENT datagram and decodes the bridge's EXCITATION datagram many times and reports the thread's CPU
  time per datagram (sealing and checking the tag included in version 3);
* the same datagrams packed and opened by the Python module the bridge runs (:func:`python_datagram_costs`);
* the target at 10 kHz in real time: ``ambp_udp_target --pace 1`` under the real ``hardware_bridge`` (the
  graph of ``ambid graph --hardware``), at real-time priority where permitted (``--priority 80``, as a rig
  runs it), its own account of overruns (more than 10 ms behind), late samples (started more than one
  period after their deadline) and its worst lateness.
"""

from __future__ import annotations

import json
import socket
import subprocess
import time
from pathlib import Path

TARGET_C_DIR = Path(__file__).resolve().parents[3] / "ros_ws" / "install" / "target_c"
RT_PRIORITY = 80  # SCHED_FIFO priority of the 10 kHz runs, where permitted (ambp_udp_target --priority)


def datagram_costs(axes: int = 4, repeats: int = 20000) -> dict:
    """``ambp_bench``'s figures: {"v2": {...}, "v3": {...}} with encode_measurement_ns, decode_excitation_ns and
    the datagrams' sizes."""
    binary = TARGET_C_DIR / "ambp_bench"
    if not binary.is_file():
        raise RuntimeError(f"{binary} is missing: run './launch_scripts/ambid setup' (it compiles the C target)")
    p = subprocess.run([str(binary), "--axes", str(axes), "--repeats", str(repeats)], capture_output=True,
                       text=True, timeout=300)
    line = next((ln for ln in p.stdout.splitlines() if ln.startswith("AMBP_BENCH ")), None)
    if p.returncode != 0 or line is None:
        raise RuntimeError(f"ambp_bench failed ({p.returncode}): {p.stderr.strip()}")
    return json.loads(line.split(" ", 1)[1])


def python_datagram_costs(axes: int = 4, repeats: int = 20000) -> dict:
    """The Python side's cost per datagram (:mod:`ambid.hardware.bridge_protocol`, as ``hardware_bridge`` and the
    Python target run it), the datagrams ``ambp_bench`` times: the target's MEASUREMENT (10 samples) packed and
    the bridge's EXCITATION (40 samples) opened, sealing and checking the tag included in version 3; this
    thread's CPU time per datagram, the fastest of 5 rounds. Returns {"v2": {...}, "v3": {...}} with the keys
    of :func:`datagram_costs`.
    """
    import numpy as np
    from ambid.hardware import bridge_protocol as bp
    from ambid.hardware.link_key import LinkKey

    key, session = LinkKey(bytes(range(32))), bytes(range(8))
    meas = bp.Measurement(1, 0, 1e-6 * np.arange(10 * 4 * axes, dtype=float).reshape(10, 4 * axes),
                          np.zeros(10, np.uint8))
    exc = bp.Excitation(1, 0, 0.01 * (np.arange(40 * axes) % 7).reshape(40, axes))
    datagrams, best = {}, {}
    for version in (2, 3):
        target = bp.Seal(key, bp.Sender.TARGET, session) if version >= 3 else None
        bridge = bp.Seal(key, bp.Sender.BRIDGE, session) if version >= 3 else None
        exc_d = bp.pack_datagram(exc, version, seal=bridge)
        assert bp.unpack_datagram(exc_d, version, axes, key if version >= 3 else None) is not None
        datagrams[version] = (target, exc_d, len(bp.pack_datagram(meas, version, seal=target)))
        best[version] = [float("inf"), float("inf")]
    # rounds of the two versions in turn, the fastest round of each: a shared machine's other processes only
    # ever add to a round's time
    rounds = 5
    n = max(1, repeats // rounds)
    for _ in range(rounds):
        for version, (target, exc_d, _) in datagrams.items():
            opener = key if version >= 3 else None
            t0 = time.thread_time_ns()
            for _ in range(n):
                bp.pack_datagram(meas, version, seal=target)
            t1 = time.thread_time_ns()
            for _ in range(n):
                bp.open_datagram(exc_d, version, axes, opener)
            t2 = time.thread_time_ns()
            best[version] = [min(best[version][0], (t1 - t0) / n), min(best[version][1], (t2 - t1) / n)]
    return {f"v{v}": {"measurement_bytes": m_len, "excitation_bytes": len(exc_d),
                      "encode_measurement_ns": best[v][0], "decode_excitation_ns": best[v][1]}
            for v, (_, exc_d, m_len) in datagrams.items()}


def real_time_run(work: Path, version: int, seconds: float) -> dict:
    """The C target at 10 kHz (``--pace 1``) for ``seconds`` under the hardware bridge, at protocol ``version``
    (3: with a fresh key file); the target's RT_TARGET_SUMMARY and the bridge's figures."""
    from ambid.hardware.link_key import write_key_file
    from ambid.hardware.target_model import rig_target_model, write_target_model
    from ambid.plant.rig import make_rig

    from ambid_nodes.running.plan import SessionConfig, plan_session
    from ambid_nodes.running.run import run_session

    work.mkdir(parents=True, exist_ok=True)
    model = work / "rig_model.txt"
    if not model.is_file():
        write_target_model(model, rig_target_model())
    link = {"protocol_version": version}
    target_link = ["--protocol-version", str(version)]
    if version >= 3:
        key = work / f"rig_{time.monotonic_ns()}.key"
        write_key_file(key)
        link["key_file"] = str(key)
        target_link += ["--key-file", str(key)]
    port, local = _free_udp_port(), _free_udp_port()
    # as a rig runs it: at real-time priority (SCHED_FIFO, locked memory) where this account may, else as a
    # plain process, which a shared machine's scheduler delays by milliseconds whatever the protocol costs
    for priority in (["--priority", str(RT_PRIORITY)], []):
        proc = subprocess.Popen([str(TARGET_C_DIR / "ambp_udp_target"), "--model", str(model), "--bind",
                                 f"127.0.0.1:{port}", "--bridge", f"127.0.0.1:{local}", "--pace", "1", "--linger",
                                 "0.3", *target_link, *priority], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        if proc.stdout.readline().startswith("RT_TARGET_LISTENING"):  # else it refused (exit code 2), at once
            break
        proc.communicate()
    if proc.poll() is not None:
        raise RuntimeError(f"the C target did not start: {proc.communicate()[1].strip()}")
    try:
        cfg = SessionConfig(loop_seconds=seconds, hardware=f"127.0.0.1:{port}", local_port=local, progress=False,
                            **link)
        bridge = run_session(cfg, plan_session(cfg, make_rig()))
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    line = next((ln for ln in out.splitlines() if ln.startswith("RT_TARGET_SUMMARY ")), None)
    if line is None:
        raise RuntimeError(f"the C target gave no summary: {err.strip()}")
    return {"target": json.loads(line.split(" ", 1)[1]), "priority": RT_PRIORITY if priority else 0,
            "bridge": {k: bridge[k] for k in ("samples_published", "missing_samples", "datagrams_malformed",
                                              "authenticated", "protocol_version")}}


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port
