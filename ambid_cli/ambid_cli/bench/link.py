"""What the authenticated link (protocol version 3) costs the C reference target, beside version 2.

Two measurements, each for version 2 (before authentication) and version 3 (after):

* the protocol's cost per datagram: ``ambp_bench`` (ambid_core/target_c/ambp_bench.c) encodes the target's
  MEASUREMENT datagram and decodes the bridge's EXCITATION datagram many times and reports the thread's CPU
  time per datagram (sealing and checking the tag included in version 3);
* the target at 10 kHz in real time: ``ambp_udp_target --pace 1`` under the real ``hardware_bridge`` (the
  graph of ``ambid graph --hardware``), its own account of overruns (more than 10 ms behind), late samples
  (started more than one period after their deadline) and its worst lateness.
"""

from __future__ import annotations

import json
import socket
import subprocess
import time
from pathlib import Path

TARGET_C_DIR = Path(__file__).resolve().parents[3] / "ros_ws" / "install" / "target_c"


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


def real_time_run(work: Path, version: int, seconds: float) -> dict:
    """The C target at 10 kHz (``--pace 1``) for ``seconds`` under the hardware bridge, at protocol ``version``
    (3: with a fresh key file); the target's RT_TARGET_SUMMARY and the bridge's figures."""
    from ambid.hardware.link_key import write_key_file
    from ambid.hardware.target_model import rig_target_model, write_target_model
    from ambid.plant.rig import make_rig

    from ambid_nodes.graph import GraphConfig, run_hardware

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
    proc = subprocess.Popen([str(TARGET_C_DIR / "ambp_udp_target"), "--model", str(model), "--bind",
                             f"127.0.0.1:{port}", "--bridge", f"127.0.0.1:{local}", "--pace", "1", "--linger", "0.3",
                             *target_link], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        bridge = run_hardware(GraphConfig(sim_seconds=seconds, plant=link, rig=make_rig()), f"127.0.0.1:{port}", local)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    line = next((ln for ln in out.splitlines() if ln.startswith("RT_TARGET_SUMMARY ")), None)
    if line is None:
        raise RuntimeError(f"the C target gave no summary: {err.strip()}")
    return {"target": json.loads(line.split(" ", 1)[1]), "bridge": {k: bridge[k] for k in (
        "samples_published", "missing_samples", "datagrams_malformed", "authenticated", "protocol_version")}}


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port
