"""The loop message pump (ambid_nodes._loop_pump), on a real rclpy context and DDS.

Two echo nodes: ``a`` answers each ``pong`` k with ``ping`` k + lead, ``b``
each ``ping`` k with ``pong`` k, both through a compiled kernel. With lead 2
and pings 0 and 1 sent first, two messages are in flight, as with the
pipelined controller. The kernel refuses a message whose index is not its k,
and returns ECHO_SPECIAL every ``every`` samples, which the node's Python
handler must finish.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
import rclpy
from ambid_nodes.loop_call import BoundKernel
from ambid_nodes.loop_kernels import (LOOP_COUNT, LOOP_DONE, LOOP_GATE, LOOP_K, LOOP_KERNEL, LOOP_LIMIT,
                                      LOOP_NO_LIMIT, LOOP_OUT, N_LOOP, pointer)
from ambid_nodes.loop_pump import BUDGET, NOT_RUN, LoopEntry, Pump, pump_of
from ambid_nodes.sample_codec import decode_sample

from ambid_msgs.msg import Sample
from ambid_nodes import qos

ECHO_STEP = N_LOOP  # the answer's index is the message's + step
ECHO_EVERY = N_LOOP + 1  # ECHO_SPECIAL where k % every == 0 (0: never)
ECHO_SPECIAL = 2


@numba.cfunc(LOOP_KERNEL)
def echo_kernel(data, size, k, c):
    if size != 52:
        return 0
    index = 0
    for i in range(8):  # the Sample's int64 index, little-endian after the 4-byte CDR header
        index |= np.int64(data[4 + i]) << (8 * i)
    if index != k:
        return 0
    out = numba.carray(pointer(c[LOOP_OUT], np.uint8), c[LOOP_OUT + 1])
    for i in range(52):
        out[i] = data[i]
    answer = index + c[ECHO_STEP]
    for i in range(8):
        out[4 + i] = (answer >> (8 * i)) & 0xFF
    if c[ECHO_EVERY] > 0 and k % c[ECHO_EVERY] == 0:
        return ECHO_SPECIAL
    return LOOP_DONE


class EchoNode:
    """A node whose ``inp`` messages the pump answers on ``out``; Python finishes the rest."""

    def __init__(self, ros, name: str, inp: str, out: str, step: int, every: int = 0) -> None:
        self.node = ros.add(rclpy.create_node(name, context=ros.context))
        self.pub = self.node.create_publisher(Sample, out, qos.LOOP)
        self.kernel = BoundKernel(echo_kernel, N_LOOP + 2)
        self.out = np.zeros(52, dtype=np.uint8)
        self.kernel.bind(LOOP_OUT, self.out, np.uint8)
        self.kernel.set(LOOP_GATE, 1)
        self.kernel.set(LOOP_LIMIT, LOOP_NO_LIMIT)
        self.kernel.set(ECHO_STEP, step)
        self.kernel.set(ECHO_EVERY, every)
        self.handled: list[tuple[int, int]] = []  # (index in the message, code)
        self.loop = LoopEntry(self.node, Sample, inp, qos.LOOP, self.pub, self.kernel, self.on_rest)

    def word(self, w: int) -> int:
        return int(self.kernel.context[w])

    def on_rest(self, data: bytes, code: int) -> None:
        index = decode_sample(data, 4, "test")[0]
        self.handled.append((index, code))
        if code == ECHO_SPECIAL:  # the kernel answered; publishing and counting are ours
            self.kernel.context[LOOP_K] += 1
            self.pub.publish(Sample(index=index + self.word(ECHO_STEP), values=[0.0] * 4))


def echo_pair(ros, every: int = 0, lead: int = 1) -> tuple[EchoNode, EchoNode]:
    a = EchoNode(ros, "a", "pong", "ping", lead, every)
    b = EchoNode(ros, "b", "ping", "pong", 0, every)
    ros.matched(a.pub, b.pub)
    return a, b


@pytest.mark.parametrize("lead", [1, 2])
def test_the_pump_answers_in_compiled_code_and_lets_the_executor_serve_the_rest(ros, lead):
    a, b = echo_pair(ros, every=100, lead=lead)
    seen: list[int] = []  # another subscriber of a loop topic in the process sees every message, in order
    spy = ros.add(rclpy.create_node("spy", context=ros.context))
    spy.create_subscription(Sample, "pong", lambda m: seen.append(m.index), qos.LOOP)
    ticks: list[int] = []  # and the executor serves timers meanwhile
    spy.create_timer(0.001, lambda: ticks.append(a.word(LOOP_K)))
    ros.matched((b.pub, 2))
    n = 6000
    a.kernel.set(LOOP_LIMIT, n)  # a stops at pong n: the Python path gets it
    for i in range(lead):  # lead messages in flight
        a.pub.publish(Sample(index=i, values=[0.0] * 4))
    assert ros.spin_until(lambda: (n, NOT_RUN) in a.handled, 60), (a.word(LOOP_K), b.word(LOOP_K))
    assert a.word(LOOP_K) == n and b.word(LOOP_K) == n + lead  # every index once, k up by 1 per message
    # the special samples went to Python with the kernel's code, and only those
    assert [i for i, c in b.handled] == list(range(0, n + lead, 100))
    assert all(c == ECHO_SPECIAL for _, c in b.handled)
    # the rest the pump answered and counted itself
    assert b.word(LOOP_COUNT) == b.word(LOOP_K) - len(b.handled)
    assert ros.spin_until(lambda: len(seen) == n + lead, 10), (len(seen), n + lead)
    assert seen == list(range(n + lead))
    # composed, the pump took the messages itself, holding what waited every BUDGET messages
    pump = pump_of(ros.context)
    assert pump.taken > 0.9 * 2 * n
    assert pump.holds >= 2 * n // (BUDGET + lead) - 2
    assert len({k for k in ticks if 0 < k < n}) > 2  # timers ran while the loop ran


def test_foreign_messages_on_a_loop_topic_go_to_python_while_the_loop_runs(ros):
    """Messages the executor hands over between the pump's runs start runs of their own: the refused
    ones go to Python, the loop goes on, timers keep their turn. (That these runs send no kicks of
    their own, which would pile up events without bound, test_fuzz's loop test shows: it stalls.)"""
    a, b = echo_pair(ros)
    intruder = ros.add(rclpy.create_node("intruder", context=ros.context))
    pub = intruder.create_publisher(Sample, "ping", qos.LOOP)
    sent: list[int] = []

    def intrude() -> None:  # a few stray pings (an index b never waits for) every millisecond
        for _ in range(3):
            sent.append(1)
            pub.publish(Sample(index=10**9, values=[0.0] * 4))

    timer = intruder.create_timer(0.001, intrude)
    ros.matched(pub)
    n = 20000
    a.kernel.set(LOOP_LIMIT, n)
    a.pub.publish(Sample(index=0, values=[0.0] * 4))
    assert ros.spin_until(lambda: (n, NOT_RUN) in a.handled, 120), (a.word(LOOP_K), len(sent))
    timer.cancel()
    assert len(sent) > 30  # the intruder's timer had its turns while the loop ran
    assert ros.spin_until(lambda: len(b.handled) == len(sent), 10), (len(b.handled), len(sent))
    assert set(b.handled) == {(10**9, 0)}  # each refused by the kernel, handed to Python
    assert b.word(LOOP_K) == n + 1 and pump_of(ros.context).taken > n


def test_a_closed_gate_and_a_refused_message_go_to_python(ros):
    a, b = echo_pair(ros)
    b.kernel.set(LOOP_GATE, 0)
    a.pub.publish(Sample(index=0, values=[0.0] * 4))
    assert ros.spin_until(lambda: len(b.handled) == 1, 10)
    assert b.handled == [(0, NOT_RUN)] and b.word(LOOP_K) == 0 and b.word(LOOP_COUNT) == 0
    b.kernel.set(LOOP_GATE, 1)
    a.pub.publish(Sample(index=5, values=[0.0] * 4))  # not b's k: the kernel refuses it
    assert ros.spin_until(lambda: len(b.handled) == 2, 10)
    assert b.handled[1] == (5, 0) and b.word(LOOP_K) == 0


def test_a_closed_entry_leaves_the_pump(ros):
    a, b = echo_pair(ros)
    pump = pump_of(ros.context)
    assert pump.entries == 2
    b.loop.close()
    b.loop.close()  # idempotent
    assert pump.entries == 1 and not b.loop.entry.open
    a.pub.publish(Sample(index=0, values=[0.0] * 4))
    ros.spin_until(lambda: False, 0.3)
    assert b.handled == [] and b.word(LOOP_K) == 0  # its subscription is gone with it
    assert ros.spin_until(lambda: a.pub.get_subscription_count() == 0, 5)


def test_pump_arguments_are_checked():
    with pytest.raises(ValueError, match="budget"):
        Pump(-1)
    pump = Pump(4)
    ctx = np.zeros(N_LOOP, dtype=np.int64)
    with pytest.raises(ValueError, match="address is 0"):
        pump.add(0, 1, 1, ctx, print, 1, b"")
    with pytest.raises(ValueError, match="address is 0"):
        pump.add(1, 1, 1, ctx, print, 0, b"")
    with pytest.raises(ValueError, match="int64 buffer of at least 6 words"):
        pump.add(1, 1, 1, np.zeros(N_LOOP, dtype=np.float64), print, 1, b"")
    with pytest.raises(ValueError, match="int64 buffer of at least 6 words"):
        pump.add(1, 1, 1, np.zeros(3, dtype=np.int64), print, 1, b"")
    with pytest.raises(TypeError, match="callable"):
        pump.add(1, 1, 1, ctx, None, 1, b"")
    with pytest.raises((ValueError, BufferError)):
        pump.add(1, 1, 1, np.zeros(2 * N_LOOP, dtype=np.int64)[::2], print, 1, b"")  # not contiguous
    assert pump.entries == 0
