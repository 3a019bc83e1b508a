"""The bridge's end of the link, played by a test against a real target process (the C example program or
``python -m ambid.hardware.rt_target``) over a real loopback socket: the protocol module's LinkEnd, every
datagram sent kept (a recording to replay), everything received kept, refusals counted by reason.

Datagrams a test sends with :meth:`LinkBridge.raw` leave from the bridge's own socket, so the target sees
them come from the right source address: a forger on the rig network who spoofs the bridge's address.
"""

from __future__ import annotations

import collections
import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
from ambid.hardware import bridge_protocol as bp
from ambid.hardware.link_session import LinkEnd

ROOT = Path(__file__).resolve().parents[2]
C_TARGET = ROOT / "ros_ws" / "install" / "target_c" / "ambp_udp_target"


def target_command(impl: str, model: Path | None = None) -> list[str]:
    """The start of a target's command line: ``impl`` "c" (needs the model file) or "python"."""
    if impl == "c":
        assert C_TARGET.is_file(), f"{C_TARGET} is missing: run './launch_scripts/ambid setup' (it compiles it)"
        return [str(C_TARGET), "--model", str(model)]
    return [sys.executable, "-m", "ambid.hardware.rt_target"]


class LinkBridge:
    """One socket, one LinkEnd of the bridge's role; what the target sends is kept by kind."""

    def __init__(self, key=None, version: int = bp.PROTOCOL_VERSION, n_axes: int | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)  # a free-running target's burst
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.02)
        self.addr = self.sock.getsockname()
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        self.target = s.getsockname()
        s.close()
        self.link = LinkEnd(bp.Sender.BRIDGE, version, key, n_axes)
        self.sent: list[bytes] = []  # every datagram this bridge sent, in order: a recording of its session
        self.meas: list[bp.Measurement] = []
        self.hbs: list[tuple[float, bp.Heartbeat]] = []
        self.acks: list[bp.Ack] = []
        self.refused: collections.Counter = collections.Counter()
        self.proc: subprocess.Popen | None = None

    def start(self, impl: str, *args: str, model: Path | None = None, handshake: bool = True) -> subprocess.Popen:
        """Start the target bound to this bridge; with ``handshake``, wait until its first heartbeat is heard
        (version 3: the session agreed)."""
        self.proc = subprocess.Popen([*target_command(impl, model), "--bind", f"{self.target[0]}:{self.target[1]}",
                                      "--bridge", f"{self.addr[0]}:{self.addr[1]}", *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     cwd=ROOT / "ambid_core")
        if handshake:
            self.handshake()
        return self.proc

    def start_thread(self, *args: str, handshake: bool = True) -> None:
        """The Python target in a thread of this process (the same code as ``python -m ambid.hardware.rt_target``
        ARGS after its options are parsed, without a second interpreter's start-up)."""
        from ambid.hardware.rt_target import Target, parse_args

        self.thread_target = Target(parse_args(["--bind", f"{self.target[0]}:{self.target[1]}",
                                                "--bridge", f"{self.addr[0]}:{self.addr[1]}", *args]))
        self.thread_result: dict = {}
        self.thread = threading.Thread(target=lambda: self.thread_result.update(self.thread_target.run()),
                                       daemon=True)
        self.thread.start()
        if handshake:
            self.handshake()

    def handshake(self, timeout: float = 30) -> None:
        end = time.monotonic() + timeout
        next_hello = 0.0
        while not self.hbs:
            assert time.monotonic() < end, "the target did not answer the handshake"
            assert self.proc is None or self.proc.poll() is None, f"the target exited: {self.proc.communicate()}"
            if self.link.authenticated and not self.link.established and time.monotonic() >= next_hello:
                self.raw(self.link.hello(), keep=True)
                if self.link.pending is not None:  # confirm the session the target proposed
                    self.send(bp.Heartbeat(0, bp.TargetState.RUNNING, axes=4))
                next_hello = time.monotonic() + 0.05
            self.pump()
        assert self.link.established

    def send(self, msg) -> bytes:
        """Pack (next sequence of its kind, sealed) and send ``msg``; returns the datagram."""
        d = self.link.pack(msg)
        self.raw(d, keep=True)
        return d

    def raw(self, datagram: bytes, keep: bool = False) -> None:
        """Send bytes as they are, from the bridge's address."""
        if keep:
            self.sent.append(datagram)
        self.sock.sendto(datagram, self.target)

    def pump(self, seconds: float = 0.0) -> None:
        """Take what arrives for ``seconds`` (at least one receive, waiting up to 20 ms)."""
        end = time.monotonic() + seconds
        while True:
            try:
                data, _ = self.sock.recvfrom(2048)
            except TimeoutError:
                data = None
            if data is not None:
                try:
                    msg = self.link.receive(data)
                except bp.ProtocolError as exc:
                    self.refused[exc.reason] += 1
                    msg = None
                if isinstance(msg, bp.Measurement):
                    self.meas.append(msg)
                elif isinstance(msg, bp.Heartbeat):
                    self.hbs.append((time.monotonic(), msg))
                elif isinstance(msg, bp.Ack):
                    self.acks.append(msg)
            if time.monotonic() >= end:
                return

    def wait_for(self, pred, timeout: float, what: str) -> None:
        end = time.monotonic() + timeout
        while not pred():
            assert time.monotonic() < end, f"timed out waiting for {what}"
            self.pump()

    def command(self, cid: int, code: int, *args: int) -> bp.Ack:
        n = len(self.acks)
        self.send(bp.Command(0, cid, code, *args))
        self.wait_for(lambda: len(self.acks) > n, 5, f"the ACK of command {cid}")
        return self.acks[n]

    def finish(self, timeout: float = 30) -> tuple[int, dict, str]:
        """Pump until the target exits; (exit code, its RT_TARGET_SUMMARY, its stderr)."""
        end = time.monotonic() + timeout
        if self.proc is None:  # the target in a thread
            while self.thread.is_alive():
                assert time.monotonic() < end, "the target did not end"
                self.pump()
            self.pump(0.05)
            self.sock.close()
            s = self.thread_result
            return (0 if s["state"] == "done" else 1), s, ""
        while self.proc.poll() is None:
            assert time.monotonic() < end, "the target did not exit"
            self.pump()
        self.pump(0.05)
        out, err = self.proc.communicate()
        self.sock.close()
        line = next((ln for ln in out.splitlines() if ln.startswith("RT_TARGET_SUMMARY ")), None)
        assert line, out + err
        return self.proc.returncode, json.loads(line.split(" ", 1)[1]), err

    def rows(self) -> tuple[np.ndarray, np.ndarray, int]:
        """Rows and flags by sample index, from the measurement datagrams, and the first index."""
        ms = sorted(self.meas, key=lambda m: m.first_index)
        assert all(a.end_index == b.first_index for a, b in zip(ms, ms[1:])), "measurement is not contiguous"
        return np.concatenate([m.data for m in ms]), np.concatenate([m.sample_flags for m in ms]), ms[0].first_index

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()
        if getattr(self, "thread", None) is not None:
            self.thread_target.stop.set()
            self.thread.join(5)
        self.sock.close()
