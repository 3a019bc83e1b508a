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
from ambid.hardware.link_key import LinkKey, key_fingerprint

ROOT = Path(__file__).resolve().parents[2]
V2 = 2  # the golden and malformed datagrams of version 2 (and 1) first; version 3's sealed ones below
LIB = ROOT / "ros_ws" / "install" / "target_c" / "libambp.so"
REASONS = ["ok", "oversized", "length", "magic", "version", "crc", "kind", "content", "foreign", "auth", "direction",
           "session", "replay", "duplicate"]


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
                ("data", ctypes.c_double * 359), ("sample_flags", ctypes.c_uint8 * 84),
                ("sender", ctypes.c_uint8), ("session", ctypes.c_uint8 * 8), ("bridge_nonce", ctypes.c_uint8 * 16),
                ("target_nonce", ctypes.c_uint8 * 16), ("refused_auth", ctypes.c_uint32),
                ("refused_session", ctypes.c_uint32), ("refused_replay", ctypes.c_uint32),
                ("duplicates", ctypes.c_uint32)]


class HmacKey(ctypes.Structure):
    """ambp_hmac_key of ambp_hmac.h: two SHA-256 states."""

    _fields_ = [("state", ctypes.c_uint64 * 28)]


@pytest.fixture(scope="module")
def lib():
    assert LIB.is_file(), f"{LIB} is missing: run './launch_scripts/ambid setup' (it compiles the C target)"
    so = ctypes.CDLL(str(LIB))
    so.ambp_encode.restype = ctypes.c_size_t
    so.ambp_encode.argtypes = [ctypes.POINTER(Message), ctypes.c_uint8, ctypes.POINTER(HmacKey), ctypes.c_char_p,
                               ctypes.c_size_t]
    so.ambp_decode.restype = ctypes.c_int
    so.ambp_decode.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint8, ctypes.POINTER(HmacKey),
                               ctypes.POINTER(Message)]
    so.ambp_hmac_key_init.argtypes = [ctypes.POINTER(HmacKey), ctypes.c_char_p, ctypes.c_size_t]
    so.ambp_crc32.restype = ctypes.c_uint32
    so.ambp_crc32.argtypes = [ctypes.c_char_p, ctypes.c_size_t]
    return so


def pack(msg, version: int = V2, value_bytes: int = 8) -> bytes:
    return bp.pack_datagram(msg, version, value_bytes)


def unpack(d: bytes, version: int = V2):
    return bp.unpack_datagram(d, version)


def c_key(lib, secret: bytes | None) -> HmacKey | None:
    """The C key of a secret (None: no key)."""
    if secret is None:
        return None
    k = HmacKey()
    lib.ambp_hmac_key_init(ctypes.byref(k), secret, len(secret))
    return k


def c_encode(lib, m: Message, version: int = V2, key: HmacKey | None = None) -> bytes:
    buf = ctypes.create_string_buffer(2048)
    n = lib.ambp_encode(ctypes.byref(m), version, None if key is None else ctypes.byref(key), buf, len(buf))
    return buf.raw[:n]


def c_decode(lib, d: bytes, version: int = V2, key: HmacKey | None = None) -> tuple[str, Message]:
    m = Message()
    return REASONS[lib.ambp_decode(d, len(d), version, None if key is None else ctypes.byref(key),
                                   ctypes.byref(m))], m


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
    py = pack(msg, value_bytes=value_bytes)
    c = c_encode(lib, to_c(msg, value_bytes))
    assert c == py  # C encodes the fields to Python's bytes
    reason, m = c_decode(lib, py)  # C decodes Python's bytes to the same fields ...
    assert reason == "ok"
    back = from_c(m)
    expect = unpack(py)  # (float32 values compared after Python's own rounding)
    for name in expect.__dataclass_fields__:
        a, b = getattr(back, name), getattr(expect, name)
        assert (np.array_equal(a, b) if isinstance(b, np.ndarray) else a == b), name
    assert c_encode(lib, m) == py  # ... and re-encodes them to the same bytes
    assert unpack(c_encode(lib, m)) is not None
    assert lib.ambp_crc32(py[:-4], len(py) - 4) == zlib.crc32(py[:-4])


def _reframe(payload: bytes, kind: int, payload_len: int | None = None, version: int = V2,
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
    meas = pack(bp.Measurement(1, 10, rng.standard_normal((3, 16)), np.zeros(3, np.uint8)))
    exc = pack(bp.Excitation(1, 10, rng.standard_normal((5, 4))))
    hb = pack(bp.Heartbeat(1, 1))
    cmd = pack(bp.Command(1, 1, 1))
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
            unpack(d)
        reason, _ = c_decode(lib, d)
        assert reason == info.value.reason, (d[:24].hex(), len(d))
        seen.add(reason)
    assert seen == {"oversized", "length", "magic", "version", "crc", "kind", "content"}
    # version 1 (the four radial axes, channel sets 1 and 2) still decodes at a version-1 end, and is
    # refused by a version-2 one
    for msg in (bp.Measurement(1, 10, np.ones((3, 16)), np.zeros(3, np.uint8)), bp.Excitation(1, 10, np.ones((5, 4)))):
        d1 = pack(msg, version=1)
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


# --- version 3: sealed datagrams --------------------------------------------------------------------------
SECRET = bytes(range(100, 132))
SESSION = bytes.fromhex("0123456789abcdef")


def to_c_v3(msg, value_bytes: int, sender: int, session: bytes) -> Message:
    if isinstance(msg, (bp.Hello, bp.Welcome)):
        m = Message()
        m.sequence = msg.sequence
        m.kind = bp.kind_of(msg)
        m.bridge_nonce[:] = list(msg.bridge_nonce)
        if isinstance(msg, bp.Welcome):
            m.target_nonce[:] = list(msg.target_nonce)
    else:
        m = to_c(msg, value_bytes)
        if isinstance(msg, bp.Heartbeat):
            for f in ("refused_auth", "refused_session", "refused_replay", "duplicates"):
                setattr(m, f, getattr(msg, f))
    m.sender = sender
    m.session[:] = list(session)
    return m


def _golden_v3():
    rng = np.random.default_rng(33)
    most = bp.max_block_samples(bp.Kind.MEASUREMENT, 8, 4, 3)
    return [
        (bp.Measurement(2**32 - 1, 12345, rng.standard_normal((most, 16)), rng.integers(0, 32, most).astype(np.uint8)),
         8, bp.Sender.TARGET),
        (bp.Measurement(3, 0, rng.standard_normal((8, 20)), np.zeros(8, np.uint8)), 4, bp.Sender.TARGET),
        (bp.Excitation(5, 2**40, rng.standard_normal((44, 4))), 8, bp.Sender.BRIDGE),
        (bp.Heartbeat(7, bp.TargetState.RUNNING, 0, True, 10_000, 99, 90, bp.NO_INDEX, 3, 4, 5, 6, 7, 4, 11, 12, 13,
                      14), 8, bp.Sender.TARGET),
        (bp.Command(8, 42, bp.CommandCode.STOP), 8, bp.Sender.BRIDGE),
        (bp.Ack(9, 42, bp.CommandCode.STOP, bp.AckResult.OK, bp.TargetState.DONE, 5), 8, bp.Sender.TARGET),
        (bp.Hello(0, rng.bytes(16)), 8, bp.Sender.BRIDGE),
        (bp.Welcome(1, rng.bytes(16), rng.bytes(16)), 8, bp.Sender.TARGET),
    ]


def test_version_3_datagrams_are_byte_identical_both_ways_and_sealed_alike(lib):
    key, ckey = LinkKey(SECRET), c_key(lib, SECRET)
    for msg, value_bytes, sender in _golden_v3():
        session = bp.NO_SESSION if isinstance(msg, bp.Hello) else SESSION
        py = bp.pack_datagram(msg, 3, value_bytes, bp.Seal(key, sender, session))
        assert len(py) <= bp.MAX_DATAGRAM_BYTES
        assert c_encode(lib, to_c_v3(msg, value_bytes, sender, session), 3, ckey) == py, type(msg).__name__
        reason, m = c_decode(lib, py, 3, ckey)
        assert reason == "ok" and m.sender == sender and bytes(m.session) == session
        assert c_encode(lib, m, 3, ckey) == py  # every field decoded, the tag recomputed alike
        env = bp.open_datagram(py, 3, None, key)
        assert (env.sender, env.session) == (sender, session)
        # the same fields under another key: a different tag, refused as not the key's on both sides
        other = bp.pack_datagram(msg, 3, value_bytes, bp.Seal(LinkKey(SECRET[::-1]), sender, session))
        assert other[:-20] == py[:-20] and other[-20:-4] != py[-20:-4]
        assert c_decode(lib, other, 3, ckey)[0] == "auth"
        with pytest.raises(bp.ProtocolError, match="not the rig key's") as info:
            bp.open_datagram(other, 3, None, key)
        assert info.value.reason == "auth"
    assert c_encode(lib, to_c_v3(bp.Command(0, 1, 1), 8, bp.Sender.BRIDGE, SESSION), 3, None) == b""  # no key
    assert c_encode(lib, to_c_v3(bp.Hello(0, bytes(16)), 8, bp.Sender.BRIDGE, SESSION), 2, ckey) == b""  # no HELLO
    with pytest.raises(ValueError, match="authenticates every datagram"):
        bp.pack_datagram(bp.Command(0, 1, 1), 3)


def _reseal(key: LinkKey, d: bytes, tag: bytes | None = None) -> bytes:
    """A version-3 datagram with its tag replaced (recomputed under ``key``, or ``tag``) and a valid CRC: a
    forgery that passes every check before the tag."""
    body = d[:-20]
    tag = key.tag(body) if tag is None else tag
    return body + tag + struct.pack("<I", zlib.crc32(body + tag))


def _sealed(key: LinkKey, kind: int, payload: bytes) -> bytes:
    """A sealed datagram of any payload: header, payload, tag, CRC, as the protocol frames them."""
    body = bp.HEADER_V3.pack(bp.MAGIC, 3, kind, bp.Sender.BRIDGE, 0, 0, len(payload), 0, SESSION) + payload
    body += key.tag(body)
    return body + struct.pack("<I", zlib.crc32(body))


def test_version_3_refusals_agree_between_c_and_python(lib):
    key, ckey = LinkKey(SECRET), c_key(lib, SECRET)
    seal = bp.Seal(key, bp.Sender.BRIDGE, SESSION)
    exc = bp.pack_datagram(bp.Excitation(1, 10, np.ones((5, 4))), 3, seal=seal)
    hb = bp.pack_datagram(bp.Heartbeat(1, 1, axes=4), 3, seal=seal)
    cases = {
        "auth": [_reseal(key, exc, bytes(16)),                       # no key: a zero tag, the CRC right
                 _reseal(LinkKey(b"\x01" * 32), exc),                # another key
                 _reseal(key, exc[:30] + b"\x07" + exc[31:], exc[-20:-4])],  # a payload byte changed, its old tag
        "crc": [exc[:30] + bytes([exc[30] ^ 4]) + exc[31:]],
        "version": [bp.pack_datagram(bp.Excitation(1, 10, np.ones((5, 4))), 2)],  # version 2 at a version-3 end
        "length": [exc[:43], _sealed(key, bp.Kind.COMMAND, bytes(31)), _sealed(key, bp.Kind.HELLO, bytes(15))],
        "kind": [_reseal(key, hb[:5] + b"\x08" + hb[6:])],
        "content": [_reseal(key, exc[:36] + struct.pack("<H", 9) + exc[38:])],  # a block of 9 axes
    }
    for want, datagrams in cases.items():
        for d in datagrams:
            with pytest.raises(bp.ProtocolError) as info:
                bp.open_datagram(d, 3, None, key)
            assert info.value.reason == want, (want, info.value)
            assert c_decode(lib, d, 3, ckey)[0] == want
    # every single-bit error of a sealed datagram is caught by the CRC before the tag is computed
    for bit in range(len(hb) * 8):
        bad = bytearray(hb)
        bad[bit // 8] ^= 1 << (bit % 8)
        with pytest.raises(bp.ProtocolError) as info:
            bp.open_datagram(bytes(bad), 3, None, key)
        assert info.value.reason in ("crc", "magic", "version") and c_decode(lib, bytes(bad), 3, ckey)[0] == \
            info.value.reason


def test_key_fingerprint_and_session_id_are_computed_alike(lib):
    lib.ambp_key_fingerprint.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_char_p]
    lib.ambp_session_id.argtypes = [ctypes.POINTER(HmacKey), ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p]
    for secret in (SECRET, bytes(16), b"\xff" * 64):
        out = ctypes.create_string_buffer(17)
        lib.ambp_key_fingerprint(secret, len(secret), out)
        assert out.value.decode() == key_fingerprint(secret) == LinkKey(secret).fingerprint
        nb, nt = bytes(range(16)), bytes(range(16, 32))
        sid = ctypes.create_string_buffer(8)
        lib.ambp_session_id(ctypes.byref(c_key(lib, secret)), nb, nt, sid)
        assert sid.raw == bp.session_id(LinkKey(secret), nb, nt)
