"""The loop nodes' compiled subscription callback (ambid_nodes._loop_callback), on a real rclpy context and DDS.

Two echo nodes: ``a`` answers each ``pong`` k with ``ping`` k + 1, ``b`` each
``ping`` k with ``pong`` k, both through a compiled kernel. The kernel refuses
a message whose index is not its k, and returns ECHO_SPECIAL every ``every``
samples, which the node's Python handler must finish.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
import rclpy
from ambid_msgs.msg import Sample

from ambid_nodes import qos
from ambid_nodes.loop_call import BoundKernel
from ambid_nodes.loop_callback import NOT_RUN, KernelCallback, LoopCallback
from ambid_nodes.loop_kernels import (LOOP_COUNT, LOOP_DONE, LOOP_GATE, LOOP_K, LOOP_KERNEL, LOOP_LIMIT,
                                      LOOP_NO_LIMIT, LOOP_OUT, N_LOOP, _pointer)
from ambid_nodes.sample_codec import decode_sample

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
    out = numba.carray(_pointer(c[LOOP_OUT], np.uint8), c[LOOP_OUT + 1])
    for i in range(52):
        out[i] = data[i]
    answer = index + c[ECHO_STEP]
    for i in range(8):
        out[4 + i] = (answer >> (8 * i)) & 0xFF
    if c[ECHO_EVERY] > 0 and k % c[ECHO_EVERY] == 0:
        return ECHO_SPECIAL
    return LOOP_DONE


class EchoNode:
    """A node whose ``inp`` messages its compiled callback answers on ``out``; Python finishes the rest."""

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
        self.loop = KernelCallback(self.node, Sample, inp, qos.LOOP, self.pub, self.kernel, self.on_rest)

    def word(self, w: int) -> int:
        return int(self.kernel.context[w])

    def on_rest(self, data: bytes, code: int) -> None:
        index = decode_sample(data, 4, "test")[0]
        self.handled.append((index, code))
        if code == ECHO_SPECIAL:  # the kernel answered; publishing and counting are ours
            self.kernel.context[LOOP_K] += 1
            self.pub.publish(Sample(index=index + self.word(ECHO_STEP), values=[0.0] * 4))


def echo_pair(ros, every: int = 0) -> tuple[EchoNode, EchoNode]:
    a = EchoNode(ros, "a", "pong", "ping", 1, every)
    b = EchoNode(ros, "b", "ping", "pong", 0, every)
    assert ros.spin_until(lambda: a.pub.get_subscription_count() >= 1 and b.pub.get_subscription_count() >= 1, 10)
    return a, b


def test_the_callback_answers_in_compiled_code_and_hands_the_rest_to_python(ros):
    a, b = echo_pair(ros, every=100)
    seen: list[int] = []  # another subscriber of a loop topic sees every answer, in order
    spy = ros.add(rclpy.create_node("spy", context=ros.context))
    spy.create_subscription(Sample, "pong", lambda m: seen.append(m.index), qos.LOOP)
    assert ros.spin_until(lambda: b.pub.get_subscription_count() == 2, 10)
    n = 2000
    a.kernel.set(LOOP_LIMIT, n)  # a stops at pong n: the Python path gets it
    a.pub.publish(Sample(index=0, values=[0.0] * 4))  # ping 0
    assert ros.spin_until(lambda: (n, NOT_RUN) in a.handled, 60), (a.word(LOOP_K), b.word(LOOP_K))
    assert a.word(LOOP_K) == n and b.word(LOOP_K) == n + 1  # every index once: k went up once per message
    # the special samples went to Python with the kernel's code, and only those
    assert [i for i, c in b.handled] == list(range(0, n + 1, 100))
    assert all(c == ECHO_SPECIAL for _, c in b.handled)
    # the rest were answered in compiled code and counted there
    assert b.word(LOOP_COUNT) == b.word(LOOP_K) - len(b.handled)
    assert ros.spin_until(lambda: len(seen) == n + 1, 10)
    assert seen == list(range(n + 1))


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


def test_closed_every_message_goes_to_python(ros):
    a, b = echo_pair(ros)
    b.loop.close()
    b.loop.close()  # idempotent
    a.pub.publish(Sample(index=0, values=[0.0] * 4))
    assert ros.spin_until(lambda: len(b.handled) == 1, 10)
    assert b.handled == [(0, NOT_RUN)] and b.word(LOOP_K) == 0


def test_callback_arguments_are_checked():
    ctx = np.zeros(N_LOOP, dtype=np.int64)
    with pytest.raises(ValueError, match="address is 0"):
        LoopCallback(0, 1, ctx, print)
    with pytest.raises(ValueError, match="int64 buffer of at least 6 words"):
        LoopCallback(1, 1, np.zeros(N_LOOP, dtype=np.float64), print)
    with pytest.raises(ValueError, match="int64 buffer of at least 6 words"):
        LoopCallback(1, 1, np.zeros(3, dtype=np.int64), print)
    with pytest.raises(TypeError, match="callable"):
        LoopCallback(1, 1, ctx, None)
    with pytest.raises((ValueError, BufferError)):
        LoopCallback(1, 1, np.zeros(2 * N_LOOP, dtype=np.int64)[::2], print)  # not contiguous
    seen = []
    closed = LoopCallback(1, 1, ctx, lambda data, code: seen.append((bytes(data), code)))
    closed(b"abc")  # gate closed: the handler gets it, the addresses are never used
    assert seen == [(b"abc", NOT_RUN)]
    with pytest.raises(TypeError, match="one positional argument"):
        closed()
