"""The bridge <-> target UDP protocol: datagrams, the measurement assembler, and the simulated target."""

from __future__ import annotations

import socket
import struct
import threading
import time
import zlib

import numpy as np
import pytest
from ambid.hardware import bridge_protocol as bp
from ambid.hardware.link_key import LinkKey
from ambid.hardware.rt_target import ExcitationBuffer, FaultInjector, Target, TargetConfig

V2 = 2  # this module: the framing of versions 1 and 2 and the target's mechanics over them; version 3's sealed
        # framing and sessions are test_target_c_codec.py's and test_link_drills.py's


def pack(msg, version: int = V2, value_bytes: int = 8) -> bytes:
    return bp.pack_datagram(msg, version, value_bytes)


def unpack(d: bytes, version: int = V2, n_axes: int | None = None):
    return bp.unpack_datagram(d, version, n_axes)


def _measurement(seq=7, first=1234, n=10, seed=0):
    rng = np.random.default_rng(seed)
    return bp.Measurement(seq, first, rng.standard_normal((n, 16)) * 1e-5, rng.integers(0, 32, n).astype(np.uint8))


ALL_MESSAGES = [
    _measurement(),
    bp.Excitation(3, 2**40, np.random.default_rng(1).standard_normal((40, 4))),
    bp.Heartbeat(2**32 - 1, bp.TargetState.SAFE, bp.SafeReason.BRIDGE_SILENT, True, 10_000, 123_456, 123_450,
                 bp.NO_INDEX, 77, 5, 1, 2, 3),
    bp.Command(0, 42, bp.CommandCode.EXPERIMENT, 5000, 80_000, 3),
    bp.Ack(9, 42, bp.CommandCode.EXPERIMENT, bp.AckResult.REFUSED, bp.TargetState.DONE, 99),
]


def _same(a, b) -> bool:
    if type(a) is not type(b):
        return False
    for name in a.__dataclass_fields__:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            if not (x.shape == np.shape(y) and np.array_equal(x, y)):
                return False
        elif x != y:
            return False
    return True


@pytest.mark.parametrize("msg", ALL_MESSAGES, ids=lambda m: type(m).__name__)
def test_round_trip_every_kind(msg):
    d = pack(msg)
    assert d[:4] == b"AMBP" and d[4] == V2
    assert len(d) <= bp.MAX_DATAGRAM_BYTES
    # the trailer is the IEEE CRC-32 of everything before it
    assert struct.unpack("<I", d[-4:])[0] == zlib.crc32(d[:-4])
    assert _same(unpack(d), msg)


def test_measurement_layout_and_float32():
    m = _measurement(n=10)
    d = pack(m)
    # 16 header + 16 block header + 10 x 16 float64 + 10 flags + 4 CRC
    assert len(d) == 16 + 16 + 1280 + 10 + 4 == 1326
    first, n, n_ch, axes, value_bytes, _ = struct.unpack_from("<QHHHBB", d, 16)
    assert (first, n, n_ch, axes, value_bytes) == (1234, 10, 16, 4, 8)   # version 2: the axes field
    assert struct.unpack_from("<QHHHBB", pack(m, version=1), 16)[3] == 1   # version 1: channel set 1
    assert np.array_equal(np.frombuffer(d, "<f8", 160, 32).reshape(10, 16), m.data)
    d32 = pack(m, value_bytes=4)
    assert len(d32) == 16 + 16 + 640 + 10 + 4
    back = unpack(d32)
    assert back.data.dtype == np.float64
    assert np.array_equal(back.data, m.data.astype(np.float32).astype(float))


def test_every_single_bit_error_is_refused_with_its_reason():
    d = pack(ALL_MESSAGES[2])
    reasons = set()
    for bit in range(len(d) * 8):
        bad = bytearray(d)
        bad[bit // 8] ^= 1 << (bit % 8)
        with pytest.raises(bp.ProtocolError) as info:
            unpack(bytes(bad))
        expected = "magic" if bit < 32 else "version" if bit < 40 else "crc"
        assert info.value.reason == expected, bit
        reasons.add(info.value.reason)
    assert reasons == {"magic", "version", "crc"}


def test_wrong_version_and_magic_are_refused():
    d = pack(ALL_MESSAGES[3], version=1)
    with pytest.raises(bp.ProtocolError, match="protocol version 1, this end speaks version 2") as info:
        unpack(d)
    assert info.value.reason == "version"
    assert _same(unpack(d, version=1), ALL_MESSAGES[3])
    with pytest.raises(bp.ProtocolError, match="protocol version 3, this end speaks version 2"):
        unpack(bp.pack_datagram(ALL_MESSAGES[3], version=3,
                                            seal=bp.Seal(LinkKey(bytes(32)), bp.Sender.BRIDGE, bytes(8))))
    body = b"XXXX" + pack(ALL_MESSAGES[3])[4:-4]
    with pytest.raises(bp.ProtocolError) as info:
        unpack(body + struct.pack("<I", zlib.crc32(body)))
    assert info.value.reason == "magic"


def test_every_truncation_is_refused():
    d = pack(_measurement(n=3))
    for size in range(len(d)):
        with pytest.raises(bp.ProtocolError) as info:
            unpack(d[:size])
        assert info.value.reason in ({"length"} if size < 20 else {"crc", "version", "magic"}), size


def _reframe(payload: bytes, kind: bp.Kind, payload_len: int | None = None) -> bytes:
    """A datagram with a valid CRC around an arbitrary payload (what a buggy sender might produce)."""
    head = bp.HEADER.pack(bp.MAGIC, V2, kind, 0, 0, len(payload) if payload_len is None else
                          payload_len, 0)
    return head + payload + struct.pack("<I", zlib.crc32(head + payload))


def test_consistent_but_invalid_content_is_refused():
    good = pack(_measurement(n=2))
    payload = good[16:-4]
    with pytest.raises(bp.ProtocolError) as info:  # header length disagrees with the datagram
        unpack(_reframe(payload, bp.Kind.MEASUREMENT, len(payload) + 1))
    assert info.value.reason == "length"
    with pytest.raises(bp.ProtocolError) as info:  # one flag byte missing
        unpack(_reframe(payload[:-1], bp.Kind.MEASUREMENT))
    assert info.value.reason == "length"
    nan = bytearray(payload)
    nan[16:24] = struct.pack("<d", float("nan"))
    with pytest.raises(bp.ProtocolError, match="NaN") as info:
        unpack(_reframe(bytes(nan), bp.Kind.MEASUREMENT))
    assert info.value.reason == "content"
    with pytest.raises(bp.ProtocolError) as info:  # a measurement payload labelled EXCITATION
        unpack(_reframe(payload, bp.Kind.EXCITATION))
    assert info.value.reason == "content"
    with pytest.raises(bp.ProtocolError) as info:
        unpack(_reframe(payload, 9))
    assert info.value.reason == "kind"


@pytest.mark.parametrize("n_axes", [1, 2, 4, 5, 8])
def test_version_2_carries_any_number_of_axes(n_axes):
    """Channels are data on the wire: a block says its axes; y, u, ic, r of each (measurement), r (excitation)."""
    rng = np.random.default_rng(n_axes)
    n = bp.max_block_samples(bp.Kind.MEASUREMENT, 8, n_axes, V2)
    assert n == (1472 - 36) // (32 * n_axes + 1)
    assert bp.max_block_samples(bp.Kind.MEASUREMENT, 8, n_axes, 3) == (1472 - 60) // (32 * n_axes + 1)  # sealed
    m = bp.Measurement(5, 77, rng.standard_normal((n, 4 * n_axes)), rng.integers(0, 32, n).astype(np.uint8))
    e = bp.Excitation(6, 80, rng.standard_normal((bp.max_block_samples(bp.Kind.EXCITATION, 8, n_axes, V2), n_axes)))
    h = bp.Heartbeat(1, bp.TargetState.RUNNING, axes=n_axes)
    for msg in (m, e, h):
        d = pack(msg)
        assert len(d) <= bp.MAX_DATAGRAM_BYTES and _same(unpack(d, n_axes=n_axes), msg)
    assert struct.unpack_from("<QHHHBB", pack(m), 16)[2:4] == (4 * n_axes, n_axes)
    assert pack(h)[16 + 3] == n_axes           # heartbeat byte 3: the sender's axes
    # the other end runs another rig: refused by content, naming both
    with pytest.raises(bp.ProtocolError, match=f"of {n_axes} axes, this end runs 3") as info:
        unpack(pack(m), n_axes=3)
    assert info.value.reason == "content"
    assert bp.block_channels(bp.Kind.EXCITATION, __import__("ambid.channels").channels.FIVE_AXIS)[-1] == "r_z"


def test_version_1_is_the_four_radial_axes():
    m5 = bp.Measurement(1, 0, np.zeros((2, 20)), np.zeros(2, np.uint8))
    with pytest.raises(ValueError, match="version 1 must have shape"):
        pack(m5, version=1)
    assert _same(unpack(pack(m5)), m5)     # version 2 carries it
    hb = pack(bp.Heartbeat(1, bp.TargetState.IDLE, axes=4), version=1)
    assert hb[16 + 3] == 0 and unpack(hb, version=1).axes == 0   # reserved in version 1
    with pytest.raises(ValueError, match="1 to 8 axes"):
        pack(bp.Excitation(1, 0, np.zeros((2, 9))))


def test_oversized_datagrams():
    n_max = bp.max_block_samples(bp.Kind.MEASUREMENT, version=V2)   # of four axes
    assert n_max == (1472 - 20 - 16) // 129 == 11
    assert bp.max_block_samples(bp.Kind.MEASUREMENT) == (1472 - 44 - 16) // 129 == 10  # version 3: sealed
    assert len(pack(_measurement(n=n_max))) <= bp.MAX_DATAGRAM_BYTES
    with pytest.raises(ValueError, match="exceeds 1472 bytes"):
        pack(_measurement(n=n_max + 1))
    assert len(pack(_measurement(n=22), value_bytes=4)) <= 1472  # float32 carries twice as many
    assert bp.max_block_samples(bp.Kind.EXCITATION) == bp.max_block_samples(bp.Kind.EXCITATION, 8, 4, V2) == 44
    with pytest.raises(bp.ProtocolError) as info:
        unpack(pack(_measurement(n=5)) + bytes(1472))
    assert info.value.reason == "oversized"


def test_pack_refuses_bad_fields():
    with pytest.raises(ValueError, match="NaN"):
        pack(bp.Excitation(0, 0, np.full((2, 4), np.nan)))
    with pytest.raises(ValueError, match=r"shape \(n >= 1, 4\)"):   # version 1: four axes
        pack(bp.Excitation(0, 0, np.zeros((2, 3))), version=1)
    with pytest.raises(ValueError, match=r"shape \(n >= 1, 4 x axes"):   # a measurement row is 4 per axis
        pack(bp.Measurement(0, 0, np.zeros((2, 7)), np.zeros(2)))
    with pytest.raises(ValueError, match="sequence"):
        pack(bp.Heartbeat(2**32, 0))
    with pytest.raises(ValueError, match="first_index"):
        pack(bp.Excitation(0, -1, np.zeros((2, 4))))
    with pytest.raises(ValueError, match="sample_flags"):
        pack(bp.Measurement(0, 0, np.zeros((2, 16)), np.zeros(3)))


def test_seq_diff_wraps():
    assert bp.seq_diff(0, 2**32 - 1) == 1
    assert bp.seq_diff(2**32 - 1, 0) == -1
    assert bp.seq_diff(5, 5) == 0
    assert bp.seq_diff(100, 40) == 60


# --- the assembler ------------------------------------------------------------

def _stream(n_datagrams, per=10, seed=0):
    rng = np.random.default_rng(seed)
    rows = rng.standard_normal((n_datagrams * per, 16))
    flags = rng.integers(0, 4, n_datagrams * per).astype(np.uint8)
    return rows, flags, [bp.Measurement(i, i * per, rows[i * per:(i + 1) * per], flags[i * per:(i + 1) * per])
                         for i in range(n_datagrams)]


def _collect(asm, items):
    blocks, gaps = [], []
    for it in items:
        (gaps if isinstance(it, bp.Gap) else blocks).append(it)
    return blocks, gaps


def test_assembler_loss_duplicates_reorder_exact():
    rows, flags, msgs = _stream(300)  # 3000 samples
    rng = np.random.default_rng(5)
    lost = set(rng.choice(300, 17, replace=False).tolist()) - {299}
    order = [m for m in msgs if m.sequence not in lost]
    # swap 20 neighbouring pairs (reordering by one) and duplicate 9 datagrams
    for i in rng.choice(len(order) - 2, 20, replace=False):
        order[i], order[i + 1] = order[i + 1], order[i]
    dups = rng.choice(len(order), 9, replace=False)
    order = [x for i, m in enumerate(order) for x in ([m, m] if i in dups else [m])]
    asm = bp.MeasurementAssembler(block_size=1000, reorder_window=4, reorder_timeout_s=10.0)
    asm.start(0, 0)
    out = []
    for m in order:
        asm.push(m)
        out += asm.poll(0.0)
    out += asm.poll(0.0, sent_end=3000, next_sequence=300)
    assert all(not x.final for x in out if isinstance(x, bp.Block))
    # the block ending at 3000 is held: nothing followed it yet, so it may be the last one
    assert max(x.end_index for x in out if isinstance(x, bp.Block)) < 3000
    tail = asm.finish()
    assert len(tail) == 1 and tail[0].end_index == 3000 and tail[0].final
    out += tail
    blocks, gaps = _collect(asm, out)
    assert asm.counts.duplicates == 9
    assert asm.counts.late == 0
    assert asm.counts.missing_samples == 10 * len(lost)
    assert asm.counts.lost_datagrams == len(lost)
    # gaps merge adjacent lost datagrams and name exactly the lost samples
    lost_samples = {s for i in lost for s in range(10 * i, 10 * i + 10)}
    assert {s for g in gaps for s in range(g.start, g.end)} == lost_samples
    assert sum(g.datagrams for g in gaps) == len(lost)
    # blocks hold exactly the rest, in order, contiguous, never across a gap or a multiple of 1000
    got = {s for b in blocks for s in range(b.first_index, b.end_index)}
    assert got == set(range(3000)) - lost_samples
    for b in blocks:
        assert np.array_equal(b.data, rows[b.first_index:b.end_index])
        assert np.array_equal(b.sample_flags, flags[b.first_index:b.end_index])
        assert b.first_index // 1000 == (b.end_index - 1) // 1000
        assert not lost_samples & set(range(b.first_index, b.end_index))
    firsts = [x.first_index if isinstance(x, bp.Block) else x.start for x in out]
    assert firsts == sorted(firsts)
    assert asm.finish() == []


def test_assembler_waits_within_window_and_timeout():
    _, _, msgs = _stream(10)
    asm = bp.MeasurementAssembler(block_size=1000, reorder_window=3, reorder_timeout_s=0.5)
    asm.start(0, 0)
    asm.push(msgs[0])
    asm.push(msgs[2])  # 1 missing
    asm.push(msgs[3])
    assert asm.poll(0.0) == [] and asm.next_index == 10  # two later ones: still waiting
    assert asm.push(msgs[1]) == "reordered"
    assert asm.poll(0.1) == [] and asm.next_index == 40 and asm.counts.gaps == 0
    asm.push(msgs[5])  # 4 missing; only one later datagram, so the timeout decides
    assert asm.poll(1.0) == []
    assert asm.poll(1.49) == []
    # the gap ends the block being filled; both are handed out as the sample after the gap is delivered
    blocks, gaps = _collect(asm, asm.poll(1.5))
    assert gaps == [bp.Gap(40, 50, 1)]
    assert [(b.first_index, b.end_index) for b in blocks] == [(0, 40)]
    assert asm.push(msgs[4]) == "late" and asm.counts.late == 1
    assert asm.push(msgs[5]) == "duplicate"
    # the sender's heartbeat says 100 samples were sent: the missing tail is declared after the timeout
    asm.push(msgs[7])
    assert asm.poll(2.0, sent_end=100, next_sequence=10) == []
    out = asm.poll(2.6, sent_end=100, next_sequence=10)
    assert asm.counts.gaps == 2
    out += asm.poll(3.2, sent_end=100, next_sequence=10)
    assert asm.counts.gaps == 3  # each gap after its own wait
    out += asm.finish()
    assert [(type(x).__name__, getattr(x, "final", None)) for x in out] == [
        ("Block", False), ("Gap", None), ("Block", True), ("Gap", None)]
    blocks, gaps = _collect(asm, out)
    assert gaps == [bp.Gap(60, 70, 1), bp.Gap(80, 100, 2)]
    assert [(b.first_index, b.end_index) for b in blocks] == [(50, 60), (70, 80)]
    assert asm.counts.missing_samples == 40


def test_assembler_splits_datagrams_at_block_boundaries():
    rows, _, msgs = _stream(10, per=7)
    asm = bp.MeasurementAssembler(block_size=25)
    asm.start(0, 0)
    out = []
    for m in msgs:
        asm.push(m)
        out += asm.poll(0.0)
    out += asm.finish()
    assert [(b.first_index, b.end_index, b.final) for b in out] == [(0, 25, False), (25, 50, False), (50, 70, True)]
    assert np.array_equal(np.concatenate([b.data for b in out]), rows)


def test_assembler_start_drops_earlier_datagrams():
    _, _, msgs = _stream(5)
    asm = bp.MeasurementAssembler(block_size=20)
    for m in msgs:
        asm.push(m)
    asm.start(30, 3)
    blocks, gaps = _collect(asm, asm.poll(0.0) + asm.finish())
    assert gaps == [] and asm.counts.late == 3
    assert [(b.first_index, b.end_index) for b in blocks] == [(30, 40), (40, 50)]
    with pytest.raises(ValueError, match="reorder_window"):
        bp.MeasurementAssembler(reorder_window=0)


# --- the simulated target's parts ---------------------------------------------

def test_fault_injector_rates_and_accounting():
    cfg = TargetConfig(drop=0.1, corrupt=0.05, duplicate=0.05, reorder=0.1, reorder_depth=2, fault_seed=3,
                       protocol_version=V2)
    inj = FaultInjector(cfg, bp.Kind.MEASUREMENT)
    sent = [bytes(x) for x in np.random.default_rng(0).integers(0, 256, (4000, 44), dtype=np.uint8)]
    wire = [d for x in sent for d in inj.submit(x, 10)] + inj.flush()
    n = len(sent)
    assert inj.dropped + inj.corrupted + inj.duplicated + inj.reordered <= n
    assert inj.dropped / n == pytest.approx(0.1, abs=0.02)
    assert inj.corrupted / n == pytest.approx(0.05, abs=0.015)
    assert inj.duplicated / n == pytest.approx(0.05, abs=0.015)
    # reorder starts only when nothing is held, so slightly below its probability
    assert 0.06 < inj.reordered / n <= 0.1 + 0.02
    assert len(wire) == n - inj.dropped + inj.duplicated
    originals = set(sent)
    assert len(originals) == len(sent)
    assert sum(d not in originals for d in wire) == inj.corrupted
    assert inj.samples_dropped == 10 * (inj.dropped + inj.corrupted)
    again = FaultInjector(cfg, bp.Kind.MEASUREMENT)
    assert [d for x in sent for d in again.submit(x, 10)] + again.flush() == wire  # reproducible by seed


def test_excitation_buffer_lookup_and_gaps():
    buf = ExcitationBuffer()
    r = np.arange(40.0).reshape(10, 4)
    buf.add(100, r[:5], now_index=0)
    buf.add(110, r[5:], now_index=0)
    assert buf.at(99) is None
    assert buf.at(100) == r[0].tolist() and buf.at(104) == r[4].tolist()
    assert buf.at(105) is None and buf.at(112) == r[7].tolist()
    assert buf.first_missing(112, [(100, 120)]) == 115
    assert buf.first_missing(112, [(100, 115)]) is None
    assert buf.first_missing(112, [(100, 115), (118, 130)]) == 118
    assert buf.first_missing(100, [(100, 120)]) == 100  # blocks behind the clock were forgotten
    buf.add(90, r, now_index=96)  # only the part from 96 on can still be applied
    assert buf.late_datagrams == 1 and buf.at(97) == r[7].tolist()
    with pytest.raises(ValueError, match="hold_for_excitation needs pace 0"):
        TargetConfig(hold_for_excitation=True, pace=1.0)
    with pytest.raises(ValueError, match="drop"):
        TargetConfig(drop=1.5)


# --- the target over a loopback socket ----------------------------------------

def _direct_rows(seed: int, n: int, excitation: dict[int, list[float]]) -> np.ndarray:
    """(n, 16) rows y, u, ic, r of the plant_sim order, computed here without any protocol."""
    from ambid.control.pid import PidParameters, pid_controller
    from ambid.control.stepper import ControllerStepper
    from ambid.plant.rig import make_rig
    from ambid.plant.simulator import PlantSimulator

    rig = make_rig()
    sim = PlantSimulator(rig, seed=seed, nonlinear_magnets=False)
    pid = PidParameters()
    ctl = ControllerStepper(pid_controller(pid, rig.dt), pid.current_limit_a)
    out = np.zeros((n, 16))
    for k in range(n):
        y = sim.output()
        ic = ctl.step(y)
        r = excitation.get(k, [0.0, 0.0, 0.0, 0.0])
        u = [ic[0] + r[0], ic[1] + r[1], ic[2] + r[2], ic[3] + r[3]]
        sim.step(u)
        out[k] = (*y.tolist(), *u, *ic, *r)
    return out


class FakeBridge:
    """A bare UDP socket speaking the protocol, standing in for the ROS bridge."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.02)
        self.addr = self.sock.getsockname()
        self.seq = 0
        self.got = []
        self.last_heartbeat = 0.0

    def send(self, msg, to):
        self.sock.sendto(pack(msg), to)

    def command(self, to, cid, code, *args):
        self.send(bp.Command(self.seq, cid, code, *args), to)
        self.seq += 1

    def pump(self, until, timeout_s=20.0, heartbeat_to=None):
        end = time.monotonic() + timeout_s
        while not until():
            assert time.monotonic() < end, "timed out"
            if heartbeat_to is not None and time.monotonic() - self.last_heartbeat > 0.02:
                self.send(bp.Heartbeat(0, 0), heartbeat_to)
                self.last_heartbeat = time.monotonic()
            try:
                self.got.append(unpack(self.sock.recv(2048)))
            except TimeoutError:
                pass

    def of(self, cls):
        return [m for m in self.got if isinstance(m, cls)]


@pytest.fixture
def target_session():
    started = []

    def start(**kw):
        bridge = FakeBridge()
        cfg = TargetConfig(bind="127.0.0.1:0", bridge=f"127.0.0.1:{bridge.addr[1]}", **{"protocol_version": V2, **kw})
        tg = Target(cfg)
        th = threading.Thread(target=tg.run, daemon=True)
        th.start()
        started.append((tg, th, bridge))
        return tg, bridge, th

    yield start
    for tg, th, bridge in started:
        tg.stop.set()
        th.join(5)
        bridge.sock.close()


def _rows(bridge):
    ms = sorted(bridge.of(bp.Measurement), key=lambda m: m.first_index)
    return np.concatenate([m.data for m in ms]), np.concatenate([m.sample_flags for m in ms]), ms


def test_target_serves_plant_sim_rows_with_excitation_at_its_index(target_session):
    tg, bridge, _ = target_session(seed=4, pace=0, samples=300, block=7, linger=0.2, hold_for_excitation=True)
    to = tg.address
    foreign = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    foreign.bind(("127.0.0.1", 0))
    foreign.sendto(pack(bp.Command(0, 1, bp.CommandCode.START)), to)  # not the bridge: ignored
    bridge.pump(lambda: tg.rx_foreign == 1)
    foreign.close()
    assert tg.state == bp.TargetState.IDLE and tg.k == 0
    r = np.random.default_rng(9).uniform(-0.3, 0.3, (60, 4))
    bridge.command(to, 5, bp.CommandCode.EXPERIMENT, 100, 60, 1)
    bridge.send(bp.Excitation(0, 130, r[30:]), to)  # the later block first
    bridge.pump(lambda: len(bridge.of(bp.Ack)) == 1)
    bridge.command(to, 6, bp.CommandCode.START)
    # the free-running target holds at sample 100 until the first half arrives
    bridge.pump(lambda: any(h.sample_index == 100 and h.excitation_next == 100 for h in bridge.of(bp.Heartbeat)))
    bridge.send(bp.Excitation(1, 100, r[:30]), to)
    bridge.pump(lambda: any(h.state == bp.TargetState.DONE for h in bridge.of(bp.Heartbeat)))
    acks = bridge.of(bp.Ack)
    assert [(a.command_id, a.result) for a in acks] == [(5, bp.AckResult.OK), (6, bp.AckResult.OK)]
    rows, flags, ms = _rows(bridge)
    assert [m.first_index for m in ms] == list(range(0, 300, 7)) and [m.sequence for m in ms] == list(range(43))
    expected = _direct_rows(4, 300, {100 + i: r[i].tolist() for i in range(60)})
    assert np.array_equal(rows, expected)  # bit for bit: same simulator, controller and order as plant_sim
    assert not (flags & (bp.FLAG_EXCITATION_LATE | bp.FLAG_SAFE_STATE)).any()
    last = bridge.of(bp.Heartbeat)[-1]
    assert (last.sent_end, last.sample_index, last.clock_running) == (300, 300, False)


def test_target_flags_missing_excitation_and_goes_safe_when_the_bridge_is_silent(target_session):
    tg, bridge, th = target_session(seed=1, pace=1.0, samples=0, bridge_timeout=0.3, safe_seconds=0.005, linger=0)
    to = tg.address
    bridge.command(to, 1, bp.CommandCode.EXPERIMENT, 50, 1_000_000, 1)  # announced, never sent
    bridge.command(to, 2, bp.CommandCode.START)
    bridge.pump(lambda: tg.k > 200, heartbeat_to=to)
    silent_from = bridge.last_heartbeat
    bridge.pump(lambda: any(h.state == bp.TargetState.SAFE and not h.clock_running for h in bridge.of(bp.Heartbeat)),
                timeout_s=30)
    hb = [h for h in bridge.of(bp.Heartbeat) if h.state == bp.TargetState.SAFE][0]
    assert hb.safe_reason == bp.SafeReason.BRIDGE_SILENT
    assert time.monotonic() - silent_from >= 0.3
    rows, flags, _ = _rows(bridge)
    n = len(rows)
    assert n == tg.k == bridge.of(bp.Heartbeat)[-1].sent_end
    safe = (flags & bp.FLAG_SAFE_STATE) != 0
    late = (flags & bp.FLAG_EXCITATION_LATE) != 0
    # r = 0 and flagged late from sample 50 until the safe state; then 50 samples (5 ms) of zero current
    assert np.flatnonzero(late).tolist() == list(range(50, n - 50))
    assert np.flatnonzero(safe).tolist() == list(range(n - 50, n))
    assert not rows[:, 12:16].any()
    assert not rows[safe, 4:16].any()
    assert rows[~safe, 8:12].any()
    assert tg.late_excitation == n - 100
    # a stopped target (linger 0) waits for STOP, acknowledges it and leaves
    time.sleep(0.3)
    assert th.is_alive()
    bridge.command(to, 3, bp.CommandCode.STOP)
    bridge.pump(lambda: any(a.command_id == 3 and a.result == bp.AckResult.OK for a in bridge.of(bp.Ack)))
    th.join(2)
    assert not th.is_alive()


def test_paced_target_keeps_to_its_schedule(target_session):
    tg, bridge, _ = target_session(seed=0, pace=100.0, samples=0)  # 100 samples/s of wall time
    bridge.command(tg.address, 1, bp.CommandCode.START)
    bridge.pump(lambda: tg.state == bp.TargetState.RUNNING, heartbeat_to=tg.address)
    t0 = time.monotonic()
    bridge.pump(lambda: time.monotonic() - t0 > 0.5, heartbeat_to=tg.address)
    k, elapsed = tg.k, time.monotonic() - tg.t_start
    # never ahead of the schedule (one sample is due at the start); behind only if the machine is starved
    assert k <= int(elapsed / 0.01) + 2
    assert k >= 0.5 * elapsed / 0.01
