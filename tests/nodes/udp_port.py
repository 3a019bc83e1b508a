"""A free UDP port on the loopback for the bridge tests (shared test helper)."""

import socket


def free_port() -> int:
    """A port number that no socket on 127.0.0.1 holds right now (the OS picks it)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port
