"""The C protocol core (ambid_core/target_c/ambp.c) against the Python reference module: golden datagrams
byte-identical both ways, and the same refusal reason for every malformed datagram. The core is loaded
with ctypes from the shared library `ambid setup` builds."""

from __future__ import annotations

import ctypes
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from ambid.hardware import bridge_protocol as bp

ROOT = Path(__file__).resolve().parents[2]
LIB = ROOT / "ros_ws" / "install" / "target_c" / "libambp.so"
REASONS = ["ok", "oversized", "length", "magic", "version", "crc", "kind", "content", "foreign"]


class Message(ctypes.Structure):
    """ambp_message of ambp.h, field by field."""

    _fields_ = [("kind", ctypes.c_uint8), ("value_bytes", ctypes.c_uint8), ("axes", ctypes.c_uint8),
                ("n_samples", ctypes.c_uint16),
                ("sequence", ctypes.c_uint32), ("first_index", ctypes.c_uint64),
                ("state", ctypes.c_uint8), ("safe_reason", ctypes.c_uint8), ("clock_running", ctypes.c_uint8),
                ("reserved0", ctypes.c_uint8), ("sample_rate_hz", ctypes.c_uint32),
                ("sample_index", ctypes.c_uint64), ("sent_end", ctypes.c_uint64),
                ("excitation_next", ctypes.c_uint64), ("next_measurement_sequence", ctypes.c_uint32),
                ("rx_datagrams", ctypes.c_uint32), ("rx_rejected", ctypes.c_uint32),
                ("late_excitation_samples", ctypes.c_uint32), ("overruns", ctypes.c_uint32),
                ("command_id", ctypes.c_uint32), ("code", ctypes.c_uint8), ("result", ctypes.c_uint8),
                ("reserved1", ctypes.c_uint8), ("reserved2", ctypes.c_uint8), ("arg0", ctypes.c_uint64),
                ("arg1", ctypes.c_uint64), ("arg2", ctypes.c_uint32), ("reserved3", ctypes.c_uint32),
                ("data", ctypes.c_double * 359), ("sample_flags", ctypes.c_uint8 * 84)]


@pytest.fixture(scope="module")
def lib():
    assert LIB.is_file(), f"{LIB} is missing: run './launch_scripts/ambid setup' (it compiles the C target)"
    so = ctypes.CDLL(str(LIB))
    so.ambp_encode.restype = ctypes.c_size_t
    so.ambp_encode.argtypes = [ctypes.POINTER(Message), ctypes.c_uint8, ctypes.c_char_p, ctypes.c_size_t]
    so.ambp_decode.restype = ctypes.c_int
    so.ambp_decode.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint8, ctypes.POINTER(Message)]
    so.ambp_crc32.restype = ctypes.c_uint32
    so.ambp_crc32.argtypes = [ctypes.c_char_p, ctypes.c_size_t]
    return so


def c_encode(lib, m: Message, version: int = bp.PROTOCOL_VERSION) -> bytes:
    buf = ctypes.create_string_buffer(2048)
    n = lib.ambp_encode(ctypes.byref(m), version, buf, len(buf))
    return buf.raw[:n]


def c_decode(lib, d: bytes, version: int = bp.PROTOCOL_VERSION) -> tuple[str, Message]:
    m = Message()
    return REASONS[lib.ambp_decode(d, len(d), version, ctypes.byref(m))], m


def to_c(msg, value_bytes: int = 8) -> Message:
    """The C struct of a Python message, filled from its fields (not from its bytes)."""
    m = Message()
    m.sequence = msg.sequence
    if isinstance(msg, (bp.Measurement, bp.Excitation)):
        m.kind = bp.Kind.MEASUREMENT if isinstance(msg, bp.Measurement) else bp.Kind.EXCITATION
        m.value_bytes, m.n_samples, m.first_index, m.axes = value_bytes, len(msg.data), msg.first_index, msg.n_axes
        flat = np.ravel(msg.data)
        m.data[:len(flat)] = flat.tolist()
        if isinstance(msg, bp.Measurement):
            m.sample_flags[:len(msg.sample_flags)] = [int(f) for f in msg.sample_flags]
    elif isinstance(msg, bp.Heartbeat):
        m.kind = bp.Kind.HEARTBEAT
        for f in ("state", "safe_reason", "clock_running", "sample_rate_hz", "sample_index", "sent_end",
                  "excitation_next", "next_measurement_sequence", "rx_datagrams", "rx_rejected",
                  "late_excitation_samples", "overruns", "axes"):
            setattr(m, f, int(getattr(msg, f)))
    elif isinstance(msg, bp.Command):
        m.kind = bp.Kind.COMMAND
        m.command_id, m.code, m.arg0, m.arg1, m.arg2 = msg.command_id, msg.code, msg.arg0, msg.arg1, msg.arg2
    else:
        m.kind = bp.Kind.ACK
        m.command_id, m.code, m.result, m.state, m.sample_index = (msg.command_id, msg.code, msg.result, msg.state,
                                                                   msg.sample_index)
    return m


def from_c(m: Message):
    """The Python message of a decoded C struct."""
    k = m.kind
    if k in (bp.Kind.MEASUREMENT, bp.Kind.EXCITATION):
        nch = 4 * m.axes if k == bp.Kind.MEASUREMENT else m.axes
        data = np.array(m.data[:m.n_samples * nch]).reshape(m.n_samples, nch)
        if k == bp.Kind.EXCITATION:
            return bp.Excitation(m.sequence, m.first_index, data)
        return bp.Measurement(m.sequence, m.first_index, data, np.array(m.sample_flags[:m.n_samples], np.uint8))
    if k == bp.Kind.HEARTBEAT:
        return bp.Heartbeat(m.sequence, m.state, m.safe_reason, bool(m.clock_running), m.sample_rate_hz,
                            m.sample_index, m.sent_end, m.excitation_next, m.next_measurement_sequence,
                            m.rx_datagrams, m.rx_rejected, m.late_excitation_samples, m.overruns, m.axes)
    if k == bp.Kind.COMMAND:
        return bp.Command(m.sequence, m.command_id, m.code, m.arg0, m.arg1, m.arg2)
    return bp.Ack(m.sequence, m.command_id, m.code, m.result, m.state, m.sample_index)


def _golden():
    rng = np.random.default_rng(17)
    big = rng.standard_normal((11, 16)) * np.logspace(-9, 3, 16)  # metres to amperes, every exponent
    big[0, :3] = [5e-324, -0.0, np.finfo(float).max]  # subnormal, negative zero, the largest double
    return [
        (bp.Measurement(2**32 - 1, 2**64 - 2, big, rng.integers(0, 256, 11).astype(np.uint8)), 8),
        (bp.Measurement(7, 1234, rng.standard_normal((22, 16)) * 1e-5, rng.integers(0, 32, 22).astype(np.uint8)), 4),
        (bp.Measurement(0, 0, rng.standard_normal((1, 16)), np.array([8], np.uint8)), 8),
        (bp.Excitation(3, 2**40, rng.standard_normal((44, 4))), 8),
        (bp.Excitation(4, 5, rng.standard_normal((89, 4)) * 0.3), 4),
        # the five-axis machine (y, u, ic, r of a_x b_x a_y b_y z) and a one-axis rig
        (bp.Measurement(8, 99, rng.standard_normal((8, 20)) * 1e-5, rng.integers(0, 32, 8).astype(np.uint8)), 8),
        (bp.Measurement(9, 5, rng.standard_normal((84, 4)), rng.integers(0, 32, 84).astype(np.uint8)), 4),
        (bp.Excitation(10, 7, rng.standard_normal((35, 5))), 8),
        (bp.Excitation(11, 8, rng.standard_normal((359, 1))), 4),
        (bp.Heartbeat(5, bp.TargetState.RUNNING, axes=5), 8),
        (bp.Heartbeat(2**32 - 1, bp.TargetState.SAFE, bp.SafeReason.BRIDGE_SILENT, True, 10_000, 123_456, 123_450,
                      bp.NO_INDEX, 77, 5, 1, 2, 3), 8),
        (bp.Heartbeat(0, bp.TargetState.IDLE), 8),
        (bp.Command(0, 42, bp.CommandCode.EXPERIMENT, 5000, 80_000, 3), 8),
        (bp.Command(9, 2**32 - 1, 255, 2**64 - 1, 2**64 - 1, 2**32 - 1), 8),
        (bp.Ack(9, 42, bp.CommandCode.EXPERIMENT, bp.AckResult.REFUSED, bp.TargetState.DONE, 99), 8),
    ]


@pytest.mark.parametrize("msg,value_bytes", _golden(), ids=lambda x: type(x).__name__ if not isinstance(x, int)
                         else f"f{8 * x}")
def test_golden_datagrams_are_byte_identical_both_ways(lib, msg, value_bytes):
    py = bp.pack_datagram(msg, value_bytes=value_bytes)
    c = c_encode(lib, to_c(msg, value_bytes))
    assert c == py  # C encodes the fields to Python's bytes
    reason, m = c_decode(lib, py)  # C decodes Python's bytes to the same fields ...
    assert reason == "ok"
    back = from_c(m)
    expect = bp.unpack_datagram(py)  # (float32 values compared after Python's own rounding)
    for name in expect.__dataclass_fields__:
        a, b = getattr(back, name), getattr(expect, name)
        assert (np.array_equal(a, b) if isinstance(b, np.ndarray) else a == b), name
    assert c_encode(lib, m) == py  # ... and re-encodes them to the same bytes
    assert bp.unpack_datagram(c_encode(lib, m)) is not None
    assert lib.ambp_crc32(py[:-4], len(py) - 4) == zlib.crc32(py[:-4])


def _reframe(payload: bytes, kind: int, payload_len: int | None = None, version: int = bp.PROTOCOL_VERSION,
             magic=b"AMBP") -> bytes:
    head = struct.pack("<4sBBHIHH", magic, version, kind, 0, 0, len(payload) if payload_len is None else payload_len,
                       0)
    return head + payload + struct.pack("<I", zlib.crc32(head + payload))


def _axes(block_payload: bytes, axes: int) -> bytes:
    """A block payload whose axes field says ``axes`` (its channel count unchanged)."""
    p = bytearray(block_payload)
    p[12:14] = struct.pack("<H", axes)
    return bytes(p)


def _malformed() -> list[bytes]:
    rng = np.random.default_rng(3)
    meas = bp.pack_datagram(bp.Measurement(1, 10, rng.standard_normal((3, 16)), np.zeros(3, np.uint8)))
    exc = bp.pack_datagram(bp.Excitation(1, 10, rng.standard_normal((5, 4))))
    hb = bp.pack_datagram(bp.Heartbeat(1, 1))
    cmd = bp.pack_datagram(bp.Command(1, 1, 1))
    out = [meas + bytes(1472 - len(meas) + 1), bytes(19), b"", meas[:-1], exc[:20]]
    out += [meas[:i] for i in range(0, len(meas), 97)]  # truncations
    for bit in range(len(hb) * 8):  # every single-bit error
        bad = bytearray(hb)
        bad[bit // 8] ^= 1 << (bit % 8)
        out.append(bytes(bad))
    pm, pe = meas[16:-4], exc[16:-4]
    nan = bytearray(pe)
    nan[16 + 8 * 7:16 + 8 * 8] = struct.pack("<d", float("inf"))
    zero = bytearray(pe[:16])
    zero[8:10] = b"\x00\x00"
    vb = bytearray(pe)
    vb[14] = 2
    out += [
        _reframe(pm, bp.Kind.MEASUREMENT, len(pm) + 1), _reframe(pm[:-1], bp.Kind.MEASUREMENT),
        _reframe(pm, bp.Kind.EXCITATION), _reframe(pe, bp.Kind.MEASUREMENT), _reframe(bytes(nan), bp.Kind.EXCITATION),
        _reframe(bytes(zero), bp.Kind.EXCITATION), _reframe(bytes(vb), bp.Kind.EXCITATION),
        _reframe(pe[:10], bp.Kind.EXCITATION), _reframe(cmd[16:-4], 0), _reframe(cmd[16:-4], 6),
        _reframe(cmd[16:-4] + b"\x00", bp.Kind.COMMAND), _reframe(hb[16:-4][:-1], bp.Kind.HEARTBEAT),
        _reframe(cmd[16:-4], bp.Kind.ACK), _reframe(cmd[16:-4], bp.Kind.COMMAND, version=3),
        _reframe(_axes(pe, 9), bp.Kind.EXCITATION), _reframe(_axes(pe, 0), bp.Kind.EXCITATION),
        _reframe(cmd[16:-4], bp.Kind.COMMAND, magic=b"AMBQ"),
    ]
    return out


def test_malformed_datagrams_are_refused_for_the_reason_python_gives(lib):
    cases = _malformed()
    seen = set()
    for d in cases:
        with pytest.raises(bp.ProtocolError) as info:
            bp.unpack_datagram(d)
        reason, _ = c_decode(lib, d)
        assert reason == info.value.reason, (d[:24].hex(), len(d))
        seen.add(reason)
    assert seen == {"oversized", "length", "magic", "version", "crc", "kind", "content"}
    # version 1 (the four radial axes, channel sets 1 and 2) still decodes at a version-1 end, and is
    # refused by a version-2 one
    for msg in (bp.Measurement(1, 10, np.ones((3, 16)), np.zeros(3, np.uint8)), bp.Excitation(1, 10, np.ones((5, 4)))):
        d1 = bp.pack_datagram(msg, version=1)
        reason, m = c_decode(lib, d1, 1)
        assert reason == "ok" and m.axes == 4 and c_encode(lib, m, 1) == d1
        assert c_decode(lib, d1)[0] == "version"
    m5 = to_c(bp.Excitation(1, 0, np.ones((2, 5))))
    assert c_encode(lib, m5, 1) == b""   # version 1 cannot carry five axes


def test_encode_refuses_what_the_protocol_cannot_carry(lib):
    m = to_c(bp.Excitation(0, 0, np.zeros((3, 4))))
    m.data[5] = float("nan")
    assert c_encode(lib, m) == b""
    m = to_c(bp.Measurement(0, 0, np.zeros((11, 16)), np.zeros(11, np.uint8)))
    m.n_samples = 12  # 12 float64 rows exceed 1472 bytes
    assert c_encode(lib, m) == b""
    m.n_samples, m.value_bytes = 0, 8
    assert c_encode(lib, m) == b""
    m.n_samples, m.value_bytes = 3, 2
    assert c_encode(lib, m) == b""
