"""``ambid bench``: throughput, real-time factor, offline rates and memory of the toolkit.

- :mod:`.pingpong`: bare rclpy ping-pong, the practical limit of the lock-step loop.
- :mod:`.loop`: plant + controller loop beside the ping-pong, interleaved.
- :mod:`.identify`: a full ``identify`` session's real-time factor.
- :mod:`.offline`: FRF of a session beside a bare MCAP read; the 4x4 fit.
- :mod:`.memory`: peak memory of a session and of one six times longer.
"""
