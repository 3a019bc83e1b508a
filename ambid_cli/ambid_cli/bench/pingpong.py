"""Bare rclpy ping-pong: the lock-step loop with nothing but the messages.

What the plant and controller do per sample, minus the work: the pinger
(the plant's role) publishes a 52-byte ``ambid_msgs/Sample`` payload,
the ponger (the controller's role) answers each with the same bytes; raw
subscriptions, QoS ``qos.LOOP``, bytes published the nodes' way
(:func:`ambid_nodes.raw_publish.raw_publisher`), EventsExecutor, composed in
one process or as two processes, exactly as :mod:`ambid_nodes.running` runs the
real nodes. One message in flight: the pinger sends the next ping when the
pong is in.
Its rate is the practical limit of the loop on this machine.

As a process: ``python -m ambid_cli.bench.pingpong ping|pong --ros-args -p samples:=N``;
the pinger prints ``AMBID_SUMMARY {json}`` when done, the ponger runs until SIGINT.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import rclpy
from rclpy.node import Node
from rclpy.task import Future

from ambid_msgs.msg import Sample
from ambid_nodes import qos
from ambid_nodes.node_main import SUMMARY_PREFIX, run_single, spin_until_done
from ambid_nodes.parameters import declare, refuse_unknown
from ambid_nodes.raw_publish import raw_publisher

NAMESPACE = "/ambid_bench"
# the size of a 4-channel Sample in CDR (sample_codec's layout): header, index, count, padding, 4 float64
PAYLOAD = b"\x00\x01\x00\x00" + bytes(48)


class Pinger(Node):
    """Publishes ``ping``, waits for ``pong``, ``samples`` times; times the loop from the first ping."""

    def __init__(self, **kwargs) -> None:
        super().__init__("pinger", **kwargs)
        self.n_samples = declare(self, "samples", 10_000, "round trips to time", 1, 10**9)
        refuse_unknown(self)
        self.pub = self.create_publisher(Sample, "ping", qos.LOOP)
        self.publish = raw_publisher(self.pub)
        self.sub = self.create_subscription(Sample, "pong", self.on_pong, qos.LOOP, raw=True)
        self.k = 0
        self.started = None
        self.finished = Future()  # completes with the summary
        self.start_timer = self.create_timer(0.05, self.try_start)

    def try_start(self) -> None:
        # as the plant: start once both directions are matched
        if self.pub.get_subscription_count() < 1 or self.sub.get_publisher_count() < 1:
            return
        self.start_timer.cancel()
        self.started = time.perf_counter()
        self.publish(PAYLOAD)

    def on_pong(self, data: bytes) -> None:
        self.k += 1
        if self.k < self.n_samples:
            self.publish(PAYLOAD)
            return
        wall = time.perf_counter() - self.started
        self.finished.set_result({"samples": self.k, "wall_s": wall, "samples_per_wall_s": self.k / wall,
                                  "state": "done"})


class Ponger(Node):
    """Answers every ``ping`` with the same bytes on ``pong``."""

    def __init__(self, **kwargs) -> None:
        super().__init__("ponger", **kwargs)
        refuse_unknown(self)
        self.pub = self.create_publisher(Sample, "pong", qos.LOOP)
        self.publish = raw_publisher(self.pub)
        self.create_subscription(Sample, "ping", self.on_ping, qos.LOOP, raw=True)

    def on_ping(self, data: bytes) -> None:
        self.publish(data)


def run_pingpong_composed(n_samples: int, domain_id: int) -> dict:
    """Pinger and ponger as two nodes of one process on one EventsExecutor (as ``graph.run_composed``).

    Returns:
        dict with ``samples``, ``wall_s``, ``samples_per_wall_s`` (round trips per wall second)
        and ``cpu_s`` (this process's CPU time over the run, all threads).
    """
    from rclpy.experimental import EventsExecutor
    from rclpy.parameter import Parameter

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    executor = EventsExecutor(context=context)
    nodes = []
    try:
        ping = Pinger(namespace=NAMESPACE, context=context,
                      parameter_overrides=[Parameter("samples", value=int(n_samples))])
        nodes += [ping, Ponger(namespace=NAMESPACE, context=context)]
        for n in nodes:
            executor.add_node(n)
        cpu0 = time.process_time()
        spin_until_done(executor, ping.finished, context)
        if not ping.finished.done():
            raise RuntimeError("ping-pong interrupted")
        return {**ping.finished.result(), "cpu_s": time.process_time() - cpu0, "layout": "composed"}
    finally:
        executor.shutdown()
        for n in nodes:
            n.destroy_node()
        rclpy.shutdown(context=context)


def run_pingpong_processes(n_samples: int, domain_id: int, timeout_s: float = 300.0) -> dict:
    """Pinger and ponger as separate processes on one DDS domain (as ``graph.run_processes``)."""
    from ambid_nodes.supervisor import stop_processes

    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
    base = [sys.executable, "-m", "ambid_cli.bench.pingpong"]
    ros = ["--ros-args", "-r", f"__ns:={NAMESPACE}"]
    procs = []
    try:
        procs.append(subprocess.Popen([*base, "pong", *ros], env=env, start_new_session=True))
        ping = subprocess.Popen([*base, "ping", *ros, "-p", f"samples:={int(n_samples)}"], env=env,
                                stdout=subprocess.PIPE, text=True, start_new_session=True)
        procs.append(ping)
        try:
            out, _ = ping.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"ping-pong processes took over {timeout_s:g} s") from None
        for line in out.splitlines():
            if line.startswith(SUMMARY_PREFIX):
                return {**json.loads(line[len(SUMMARY_PREFIX):]), "layout": "processes"}
        raise RuntimeError(f"pinger exited with code {ping.returncode} without a summary")
    finally:
        stop_processes(procs)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    roles = {"ping": Pinger, "pong": Ponger}
    if not argv or argv[0] not in roles:
        print("usage: python -m ambid_cli.bench.pingpong ping|pong [--ros-args ...]", file=sys.stderr)
        return 2
    return run_single(roles[argv[0]], [sys.argv[0], *argv[1:]])


if __name__ == "__main__":
    sys.exit(main())
