"""Converting between ambid_msgs messages and numpy / core objects, with validation.

Light to import (no scipy: the recorder uses the checks and starts in a second).
"""

from __future__ import annotations

import array
import bisect
import json
import math
from collections.abc import Callable, Sequence

import numpy as np
from ambid.recording.blocks import MAX_SAMPLE_INDEX
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message

from ambid_msgs.msg import SampleBlock, SessionStatus
from ambid_msgs.msg import StateSpace as StateSpaceMsg
from ambid_nodes.cdr_check import cdr_problem


class BadMessage(ValueError):
    """A received message is malformed; ``args[0]`` says what is wrong, ``index`` is its
    sample index when that could still be read (else None)."""

    def __init__(self, text: str, index: int | None = None) -> None:
        super().__init__(text)
        self.index = index




#: sample rates a message may name [Hz]: far around the rigs' 1 kHz - 100 kHz
MIN_SAMPLE_RATE_HZ, MAX_SAMPLE_RATE_HZ = 1.0, 1e7


def decode_message(data: bytes, msg_type, what: str):
    """The ``msg_type`` message serialized in ``data`` (CDR), or BadMessage.

    A typed rclpy subscription drops a message that fails to deserialize without
    telling the node; subscribing raw and decoding here lets the node count it.
    The bytes are walked first (:func:`ambid_nodes.cdr_check.cdr_problem`): rosidl's
    deserializer writes some of its refusals to stderr, unattributed.
    """
    problem = cdr_problem(data, msg_type)
    if problem is not None:
        raise BadMessage(f"{what}: {len(data)} bytes that do not decode as {msg_type.__name__} ({problem})")
    try:
        return deserialize_message(data, msg_type)
    except Exception as exc:  # noqa: BLE001 - rclpy raises RMWError and others for undecodable bytes
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise BadMessage(f"{what}: {len(data)} bytes that do not decode as {msg_type.__name__} ({first})") from None


def check_index(first_index: int, n_samples: int, what: str) -> None:
    """BadMessage if samples [first_index, first_index + n_samples) leave [0, MAX_SAMPLE_INDEX]."""
    if first_index + n_samples > MAX_SAMPLE_INDEX:
        raise BadMessage(f"{what}: sample index {first_index} (+{n_samples}) is out of range "
                         f"(at most {MAX_SAMPLE_INDEX})", None)


def all_finite(values) -> bool:
    """True if every value is finite (no NaN, no Inf); fast for the short lists of the loop."""
    try:
        # a sum is finite only if every term is (one C-level pass instead of a Python loop)
        return math.isfinite(math.fsum(values))
    except (OverflowError, ValueError):  # 1e308 + 1e308 overflows; fsum raises on inf + -inf
        return all(map(math.isfinite, values))


def sec_nanosec(seconds: float) -> tuple[int, int]:
    """builtin_interfaces/Time's (sec, nanosec) of a time in seconds, rounded to the nanosecond."""
    ns = int(round(seconds * 1e9))
    return ns // 1_000_000_000, ns % 1_000_000_000


def time_msg(seconds: float) -> Time:
    sec, nanosec = sec_nanosec(seconds)
    return Time(sec=sec, nanosec=nanosec)


def check_values(values, n_expected: int, what: str) -> list[float]:
    """The values of a Sample as floats, or BadMessage for a wrong count or NaN/Inf."""
    if len(values) != n_expected:
        raise BadMessage(f"{what}: {len(values)} values, expected {n_expected}")
    out = list(values)
    if not all_finite(out):
        raise BadMessage(f"{what}: non-finite value in {out}")
    return out


def statespace_to_msg(ss) -> StateSpaceMsg:
    """The StateSpace message of an ``ambid.statespace.StateSpace``."""
    return StateSpaceMsg(
        sample_period=float(ss.dt), n_states=ss.n_states, n_inputs=ss.n_inputs, n_outputs=ss.n_outputs,
        a=ss.a.ravel().tolist(), b=ss.b.ravel().tolist(), c=ss.c.ravel().tolist(), d=ss.d.ravel().tolist(),
        input_names=list(ss.input_names), input_units=list(ss.input_units),
        output_names=list(ss.output_names), output_units=list(ss.output_units))


def check_statespace_msg(msg: StateSpaceMsg) -> None:
    """BadMessage unless the matrices' sizes agree with n_states, n_inputs, n_outputs, the names with
    the inputs and outputs, and every number is finite."""
    n, m, p = msg.n_states, msg.n_inputs, msg.n_outputs
    sizes = {"a": n * n, "b": n * m, "c": p * n, "d": p * m}
    for key, size in sizes.items():
        if len(getattr(msg, key)) != size:
            raise BadMessage(f"StateSpace: {key} has {len(getattr(msg, key))} entries, expected {size} "
                             f"for n_states={n}, n_inputs={m}, n_outputs={p}")
        if size and not all_finite(getattr(msg, key)):
            raise BadMessage(f"StateSpace: {key} contains NaN or Inf")
    for key, size in (("input_names", m), ("input_units", m), ("output_names", p), ("output_units", p)):
        if len(getattr(msg, key)) not in (0, size):
            raise BadMessage(f"StateSpace: {len(getattr(msg, key))} {key} for {size}")
    if not (math.isfinite(msg.sample_period) and msg.sample_period >= 0):
        raise BadMessage(f"StateSpace: sample_period {msg.sample_period!r} must be >= 0 and finite")


def statespace_from_msg(msg: StateSpaceMsg):
    """The ``ambid.statespace.StateSpace`` of a message, or BadMessage."""
    from ambid.statespace import StateSpace  # scipy: imported where a model is built, not with this module

    check_statespace_msg(msg)
    n, m, p = msg.n_states, msg.n_inputs, msg.n_outputs
    try:
        return StateSpace(np.reshape(msg.a, (n, n)), np.reshape(msg.b, (n, m)), np.reshape(msg.c, (p, n)),
                          np.reshape(msg.d, (p, m)), msg.sample_period, tuple(msg.input_names),
                          tuple(msg.output_names), tuple(msg.input_units), tuple(msg.output_units))
    except ValueError as exc:
        raise BadMessage(str(exc)) from None


def json_text(value) -> str:
    """``json.dumps(value)``, without its ~4 us of set-up for the plain ints and finite floats that
    make up most status figures (a status goes out per measurement block)."""
    t = type(value)
    if t is int or (t is float and math.isfinite(value)):
        return repr(value)  # what json.dumps writes for these
    return json.dumps(value)


def status_msg(stamp: Time, node: str, state: int, sample_index: int, progress: float, received: int,
               rejected: int, text: str, figures: dict) -> SessionStatus:
    """A node's SessionStatus: its counters, a one-line text and ``figures`` as keys with JSON values."""
    return SessionStatus(stamp=stamp, node=node, state=state, sample_index=sample_index, progress=progress,
                         messages_received=received, messages_rejected=rejected, text=text, keys=list(figures),
                         values=[json_text(v) for v in figures.values()])


def float_array(values) -> array.array:
    """``values`` as the array.array('d') a float64[] message field stores.

    Assigning a numpy array checks every element in Python (16 ms for a 1000 x 16 block);
    an array.array is taken as it is.
    """
    out = array.array("d")
    out.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return out


def block_msg(first_index: int, dt: float, names, units, data: np.ndarray, sample_flags: np.ndarray | None = None,
              flags: int = 0, experiment_id: str = "") -> SampleBlock:
    """A SampleBlock of ``data`` (n_samples, n_channels)."""
    data = np.ascontiguousarray(data, dtype=float)
    msg = SampleBlock(stamp=time_msg(first_index * dt), experiment_id=experiment_id, first_index=int(first_index),
                      sample_period=float(dt), n_samples=data.shape[0], channel_names=list(names),
                      channel_units=list(units), flags=int(flags))
    msg.data = float_array(data)
    if sample_flags is not None:
        flags_arr = array.array("B")
        flags_arr.frombytes(np.ascontiguousarray(sample_flags, dtype=np.uint8).tobytes())
        msg.sample_flags = flags_arr
        msg.flags = int(flags) | int(np.bitwise_or.reduce(sample_flags)) if len(sample_flags) else int(flags)
    return msg


def block_data(msg: SampleBlock, expected_names=None) -> np.ndarray:
    """The data of a SampleBlock as (n_samples, n_channels), or BadMessage naming the problem."""
    n_ch = len(msg.channel_names)
    if n_ch == 0:
        raise BadMessage("SampleBlock: no channel names")
    if msg.n_samples == 0:
        raise BadMessage("SampleBlock: no samples (n_samples = 0)")
    check_index(msg.first_index, msg.n_samples, "SampleBlock")
    if expected_names is not None and list(msg.channel_names) != list(expected_names):
        raise BadMessage(f"SampleBlock: channels {list(msg.channel_names)}, expected {list(expected_names)}")
    if msg.channel_units and len(msg.channel_units) != n_ch:
        raise BadMessage(f"SampleBlock: {len(msg.channel_units)} units for {n_ch} channels")
    if len(msg.data) != msg.n_samples * n_ch:
        raise BadMessage(f"SampleBlock: {len(msg.data)} values, expected n_samples x channels = "
                         f"{msg.n_samples} x {n_ch}")
    if len(msg.sample_flags) not in (0, msg.n_samples):
        raise BadMessage(f"SampleBlock: {len(msg.sample_flags)} sample flags for {msg.n_samples} samples")
    if not 1 / MAX_SAMPLE_RATE_HZ <= msg.sample_period <= 1 / MIN_SAMPLE_RATE_HZ:
        raise BadMessage(f"SampleBlock: sample_period {msg.sample_period!r} s is outside "
                         f"[{1 / MAX_SAMPLE_RATE_HZ:g}, {1 / MIN_SAMPLE_RATE_HZ:g}] s")
    data = np.asarray(msg.data, dtype=float).reshape(msg.n_samples, n_ch)
    if not np.all(np.isfinite(data)):
        raise BadMessage("SampleBlock: data contains NaN or Inf")
    return data


def _finite_positive(value: float) -> bool:
    return math.isfinite(value) and value > 0


def check_plant_description(msg) -> None:
    """BadMessage unless a PlantDescription's arrays agree in size and its numbers are usable."""
    n_y, n_i = len(msg.displacement_names), len(msg.current_names)
    if not 1 / MAX_SAMPLE_RATE_HZ <= msg.sample_period <= 1 / MIN_SAMPLE_RATE_HZ:
        raise BadMessage(f"plant/description: sample_period {msg.sample_period!r} s is outside "
                         f"[{1 / MAX_SAMPLE_RATE_HZ:g}, {1 / MIN_SAMPLE_RATE_HZ:g}] s")
    if n_y == 0 or n_i == 0 or "" in msg.displacement_names or "" in msg.current_names:
        raise BadMessage(f"plant/description: {n_y} displacement and {n_i} current names; both must be "
                         "non-empty lists of non-empty names")
    if len(set(msg.displacement_names)) != n_y or len(set(msg.current_names)) != n_i:
        raise BadMessage("plant/description: repeated channel names")
    for field, n in (("bias_current", n_i), ("current_limit", n_i)):
        values = getattr(msg, field)
        if len(values) != n:
            raise BadMessage(f"plant/description: {len(values)} {field} values for {n} currents")
        if not all(_finite_positive(v) or (field == "bias_current" and v == 0) for v in values):
            raise BadMessage(f"plant/description: {field} {list(values)} must be finite and > 0")
    if not all(_finite_positive(v) for v in msg.backup_clearance):
        raise BadMessage(f"plant/description: backup_clearance {list(msg.backup_clearance)} must be finite and > 0")
    try:
        check_statespace_msg(msg.analytical_model)
    except BadMessage as exc:
        raise BadMessage(f"plant/description: analytical_model: {exc}") from None


def check_controller_description(msg) -> None:
    """BadMessage unless a ControllerDescription holds a discrete model of consistent sizes."""
    try:
        check_statespace_msg(msg.model)
    except BadMessage as exc:
        raise BadMessage(f"controller/description: model: {exc}") from None
    if not msg.model.sample_period > 0:
        raise BadMessage("controller/description: the model must be discrete (sample_period > 0)")
    n_out = msg.model.n_outputs
    if len(msg.current_limit) not in (0, n_out) or not all(_finite_positive(v) for v in msg.current_limit):
        raise BadMessage(f"controller/description: {len(msg.current_limit)} current limits for "
                         f"{n_out} outputs; each finite and > 0")


def check_design(msg, sample_period: float | None = None) -> None:
    """BadMessage unless an ExcitationDesign message is self-consistent (and at the plant's rate).

    Checks the id, the sample range, the sample rate (equal to ``1 / sample_period``
    when given) and that every per-input array has one entry per input.
    """
    if not msg.experiment_id:
        raise BadMessage("excitation/design: empty experiment_id")
    where = f"excitation/design {msg.experiment_id[:40]!r}"
    check_index(msg.start_index, msg.total_samples, where)
    if not MIN_SAMPLE_RATE_HZ <= msg.sample_rate <= MAX_SAMPLE_RATE_HZ:
        raise BadMessage(f"{where}: sample_rate {msg.sample_rate!r} Hz is outside [{MIN_SAMPLE_RATE_HZ:g}, "
                         f"{MAX_SAMPLE_RATE_HZ:g}] Hz")
    if sample_period is not None and abs(msg.sample_rate * sample_period - 1.0) > 1e-9:
        raise BadMessage(f"{where}: designed at {msg.sample_rate:g} Hz, the plant runs at {1 / sample_period:g} Hz")
    n_u = len(msg.input_names)
    if "" in msg.input_names or len(set(msg.input_names)) != n_u:
        raise BadMessage(f"{where}: input_names {list(msg.input_names)[:8]} must be distinct, non-empty names")
    for field in ("rms", "peak", "crest_factor"):
        values = getattr(msg, field)
        if len(values) not in (0, n_u):
            raise BadMessage(f"{where}: {len(values)} {field} values for {n_u} inputs")
        if not all(math.isfinite(v) and v >= 0 for v in values):
            raise BadMessage(f"{where}: {field} must be finite and >= 0")
    if not math.isfinite(msg.measurement_time):
        raise BadMessage(f"{where}: measurement_time {msg.measurement_time!r} is not finite")
    half = msg.samples_per_period // 2
    for field in ("excited_lines", "detection_lines_odd", "detection_lines_even"):
        values = getattr(msg, field)
        if len(values) and max(values) > half:
            raise BadMessage(f"{where}: {field} up to bin {max(values)}, beyond samples_per_period / 2 = {half}")


def check_excitation_block(msg: SampleBlock, names: Sequence[str], dt: float, now: int, horizon: int,
                           held_starts: Sequence[int], held_length: Callable[[int], int], who: str,
                           passed: int | None = None) -> np.ndarray:
    """The data (n, channels) [A] of an excitation block its receiver (the plant, or the bridge for its
    target) can hold, or BadMessage naming what is wrong.

    Checks the channels, values and sample period, that the block ends after ``passed`` (when given:
    the receiver cannot apply anything at or before it), that it lies within ``horizon`` samples of
    ``now``, and that it does not repeat or overlap a block already held (``held_starts`` sorted,
    ``held_length(start)`` the length of the held block at ``start``).
    """
    try:
        data = block_data(msg, names)
    except BadMessage as exc:
        raise BadMessage(f"excitation: {exc}") from None
    if abs(msg.sample_period - dt) > 1e-9 * dt:
        raise BadMessage(f"excitation: sample period {msg.sample_period!r} s, the {who}'s is {dt} s")
    first, end = msg.first_index, msg.first_index + len(data)
    if passed is not None and end <= passed:
        raise BadMessage(f"excitation block at sample {first} arrived after the {who} passed it "
                         f"(now {passed}); publish excitation further ahead")
    if end > now + horizon:
        raise BadMessage(f"excitation: samples [{first}, {end}) lie beyond the {who}'s horizon of {horizon} "
                         f"samples ahead of sample {now} (parameter excitation_horizon)")
    i = bisect.bisect_left(held_starts, end)  # held blocks are disjoint: only the one before end may overlap
    if i > 0:
        f = held_starts[i - 1]
        f_end = f + held_length(f)
        if first < f_end:
            raise BadMessage(f"excitation: samples [{first}, {end}) repeat or overlap the block [{f}, {f_end}) "
                             "already held")
    return data
