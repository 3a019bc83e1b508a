"""Converting between ambid_msgs messages and numpy / core objects, with validation."""

from __future__ import annotations

import math

import numpy as np
from ambid_msgs.msg import SampleBlock
from ambid_msgs.msg import StateSpace as StateSpaceMsg
from builtin_interfaces.msg import Time

from ambid.statespace import StateSpace


class BadMessage(ValueError):
    """A received message is malformed; ``args[0]`` says what is wrong, ``index`` is its
    sample index when that could still be read (else None)."""

    def __init__(self, text: str, index: int | None = None) -> None:
        super().__init__(text)
        self.index = index


def time_msg(seconds: float) -> Time:
    ns = int(round(seconds * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def check_values(values, n_expected: int, what: str) -> list[float]:
    """The values of a Sample as floats, or BadMessage for a wrong count or NaN/Inf."""
    if len(values) != n_expected:
        raise BadMessage(f"{what}: {len(values)} values, expected {n_expected}")
    out = list(values)
    # a sum is finite only if every term is (one C-level pass instead of a Python loop)
    if not math.isfinite(math.fsum(out)):
        raise BadMessage(f"{what}: non-finite value in {out}")
    return out


def statespace_to_msg(ss: StateSpace) -> StateSpaceMsg:
    return StateSpaceMsg(
        sample_period=float(ss.dt), n_states=ss.n_states, n_inputs=ss.n_inputs, n_outputs=ss.n_outputs,
        a=ss.a.ravel().tolist(), b=ss.b.ravel().tolist(), c=ss.c.ravel().tolist(), d=ss.d.ravel().tolist(),
        input_names=list(ss.input_names), input_units=list(ss.input_units),
        output_names=list(ss.output_names), output_units=list(ss.output_units))


def statespace_from_msg(msg: StateSpaceMsg) -> StateSpace:
    n, m, p = msg.n_states, msg.n_inputs, msg.n_outputs
    sizes = {"a": n * n, "b": n * m, "c": p * n, "d": p * m}
    for key, size in sizes.items():
        if len(getattr(msg, key)) != size:
            raise BadMessage(f"StateSpace: {key} has {len(getattr(msg, key))} entries, expected {size} "
                             f"for n_states={n}, n_inputs={m}, n_outputs={p}")
    try:
        return StateSpace(np.reshape(msg.a, (n, n)), np.reshape(msg.b, (n, m)), np.reshape(msg.c, (p, n)),
                          np.reshape(msg.d, (p, m)), msg.sample_period, tuple(msg.input_names),
                          tuple(msg.output_names), tuple(msg.input_units), tuple(msg.output_units))
    except ValueError as exc:
        raise BadMessage(str(exc)) from None


def block_msg(first_index: int, dt: float, names, units, data: np.ndarray, sample_flags: np.ndarray | None = None,
              flags: int = 0, experiment_id: str = "") -> SampleBlock:
    """A SampleBlock of ``data`` (n_samples, n_channels)."""
    data = np.ascontiguousarray(data, dtype=float)
    msg = SampleBlock(stamp=time_msg(first_index * dt), experiment_id=experiment_id, first_index=int(first_index),
                      sample_period=float(dt), n_samples=data.shape[0], channel_names=list(names),
                      channel_units=list(units), flags=int(flags))
    msg.data = data.ravel()  # rclpy takes a float64 array without a per-element copy loop
    if sample_flags is not None:
        msg.sample_flags = np.asarray(sample_flags, dtype=np.uint8)
        msg.flags = int(flags) | int(np.bitwise_or.reduce(sample_flags)) if len(sample_flags) else int(flags)
    return msg


def block_data(msg: SampleBlock, expected_names=None) -> np.ndarray:
    """The data of a SampleBlock as (n_samples, n_channels), or BadMessage naming the problem."""
    n_ch = len(msg.channel_names)
    if n_ch == 0:
        raise BadMessage("SampleBlock: no channel names")
    if expected_names is not None and list(msg.channel_names) != list(expected_names):
        raise BadMessage(f"SampleBlock: channels {list(msg.channel_names)}, expected {list(expected_names)}")
    if msg.channel_units and len(msg.channel_units) != n_ch:
        raise BadMessage(f"SampleBlock: {len(msg.channel_units)} units for {n_ch} channels")
    if len(msg.data) != msg.n_samples * n_ch:
        raise BadMessage(f"SampleBlock: {len(msg.data)} values, expected n_samples x channels = "
                         f"{msg.n_samples} x {n_ch}")
    if len(msg.sample_flags) not in (0, msg.n_samples):
        raise BadMessage(f"SampleBlock: {len(msg.sample_flags)} sample flags for {msg.n_samples} samples")
    if not msg.sample_period > 0 or not math.isfinite(msg.sample_period):
        raise BadMessage(f"SampleBlock: sample_period {msg.sample_period!r} must be > 0")
    data = np.asarray(msg.data, dtype=float).reshape(msg.n_samples, n_ch)
    if not np.all(np.isfinite(data)):
        raise BadMessage("SampleBlock: data contains NaN or Inf")
    return data
