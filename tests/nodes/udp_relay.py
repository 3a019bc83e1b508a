"""A man on the rig network for the link drills (shared test helper): a UDP relay between the hardware bridge
and the real-time target that forwards every datagram both ways, keeps a recording of them, and sends
datagrams of its own to either end. Each end is configured with the relay's address as its peer's, so what the
relay injects arrives from the right source address: the forger who spoofs the peer's address, which
address filtering alone cannot stop.
"""

from __future__ import annotations

import socket
import threading
import time


class Relay:
    """Forwards between ``bridge`` and ``target`` (host, port); ``address`` is what both ends name as their peer.

    Attributes:
        to_target, to_bridge: every datagram forwarded, in order (a recording of the session).
    """

    def __init__(self, bridge: tuple[str, int], target: tuple[str, int]) -> None:
        self.bridge, self.target = bridge, target
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 * 1024 * 1024)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.address = self.sock.getsockname()
        self.to_target: list[bytes] = []
        self.to_bridge: list[bytes] = []
        self.taps: list = []  # callables (direction, datagram) run on every forwarded datagram, in the relay thread
        self._stop = threading.Event()
        self._lock = threading.RLock()  # a tap may inject from inside the relay's thread
        self._thread = threading.Thread(target=self._run, name="udp_relay", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                time.sleep(0.001)  # an ICMP error reported on the socket (a peer not up yet)
                continue
            if addr == self.bridge:
                direction, peer, log = "to_target", self.target, self.to_target
            elif addr == self.target:
                direction, peer, log = "to_bridge", self.bridge, self.to_bridge
            else:
                continue
            with self._lock:
                log.append(data)
                self._send(data, peer)
                for tap in self.taps:
                    tap(direction, data)

    def _send(self, data: bytes, peer) -> None:
        try:
            self.sock.sendto(data, peer)
        except OSError:
            pass  # the peer is not listening (yet): UDP

    def inject(self, direction: str, datagram: bytes) -> None:
        """Send ``datagram`` to the target (``to_target``) or the bridge (``to_bridge``) from the relay's address."""
        with self._lock:
            self._send(datagram, self.target if direction == "to_target" else self.bridge)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()
