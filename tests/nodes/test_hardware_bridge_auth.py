"""Issue 38's drills at the real hardware_bridge: protocol version 3 between the bridge node and the Python
target, through a relay on the rig network (tests/nodes/udp_relay.py) that forwards every datagram, records
them, and forges its own from each end's peer address: datagrams with right CRCs but no key or another key, a
recorded earlier session replayed to both ends, and this session's own datagrams sent again with old
sequence numbers. Both ends refuse and count each by its reason; the bridge's counters, its events and the
target's (reported through its heartbeat) name them; the session's samples are those of the lock-step graph's
own simulation, bit for bit. The key never appears in the status, events or logs, only its fingerprint."""

from __future__ import annotations

import os
import re
import struct
import threading
import zlib

import numpy as np
import pytest
from ambid.hardware import bridge_protocol as bp
from ambid.hardware.link_key import LinkKey, write_key_file
from ambid.hardware.link_session import WINDOW
from ambid.hardware.rt_target import Target, TargetConfig
from rclpy.parameter import Parameter
from test_hardware_bridge import NS, Spy, direct_rows, stitched

from ambid_msgs.msg import ExcitationDesign, SampleBlock, SessionEvent
from ambid_nodes.hardware_bridge import HardwareBridge
from ambid_nodes.parameters import ParameterError
from udp_port import free_port
from udp_relay import Relay

EXCITATION = [f"r_{a}" for a in ("a_x", "b_x", "a_y", "b_y")]


def forge(d: bytes, tag: bytes) -> bytes:
    """A sealed datagram with another tag and its CRC made right: what a forger without the key sends."""
    body = d[:-20] + tag
    return body + struct.pack("<I", zlib.crc32(body))


def kind_of(d: bytes) -> int:
    return d[5]


def run(ros, key_file, n: int, seed: int, excitation: dict | None = None, attack: dict | None = None):
    """One session of the bridge node and the Python target through a relay; returns (bridge summary, target
    summary, rows, the spy, the relay's recordings). ``excitation``: {start, r} published before the target is
    up. ``attack``: a recording of an earlier session {"to_target": [...], "to_bridge": [...]} arms the forger,
    who strikes once the measurement passes sample 800."""
    spy = ros.add(Spy(ros.context))
    tp, lp = free_port(), free_port()
    relay = Relay(("127.0.0.1", lp), ("127.0.0.1", tp))
    rp = relay.address[1]
    bridge = ros.add(HardwareBridge(namespace=NS, context=ros.context, parameter_overrides=[
        Parameter("target_port", value=rp), Parameter("local_port", value=lp),
        Parameter("protocol_version", value=3), Parameter("key_file", value=str(key_file))]))
    ros.matched(spy, to=bridge)
    if excitation:
        start, r = excitation["start"], excitation["r"]
        ros.matched(spy.pub_exc, spy.pub_design)
        spy.pub_design.publish(ExcitationDesign(experiment_id="e1", kind="noise", start_index=start,
                                                total_samples=len(r), sample_rate=10_000.0))
        for off in range(0, len(r), 1000):
            m = SampleBlock(experiment_id="e1", first_index=start + off, sample_period=1e-4,
                            n_samples=len(r[off:off + 1000]), channel_names=EXCITATION, channel_units=["A"] * 4)
            m.data = r[off:off + 1000].ravel()
            spy.pub_exc.publish(m)
        assert ros.spin_until(lambda: sum(len(c[0]) for c in bridge.chunks.held.values()) == len(r), timeout_s=10)
    target = Target(TargetConfig(bind=f"127.0.0.1:{tp}", bridge=f"127.0.0.1:{rp}", seed=seed, pace=1.0, samples=n,
                                 linger=0.3, protocol_version=3, key_file=str(key_file)))
    result: dict = {}
    th = threading.Thread(target=lambda: result.update(target.run()), daemon=True)
    th.start()
    forged = {"to_bridge": 0, "to_target": 0}
    try:
        if attack:
            assert ros.spin_until(lambda: (bridge.assembler.next_index or 0) >= 800, timeout_s=60), bridge.figures()
            forged = strike(relay, bridge, attack)
        assert ros.spin_until(bridge.finished.done, timeout_s=90), bridge.figures()
        th.join(10)
    finally:
        target.stop.set()
        th.join(5)
        relay.close()
    s = bridge.finished.result()
    assert ros.spin_until(lambda: sum(b.n_samples for b in spy.blocks) == n, timeout_s=10), s
    rows = np.concatenate([d for *_, d, _, _ in stitched(spy.blocks)])
    recording = {"to_target": list(relay.to_target), "to_bridge": list(relay.to_bridge)}
    ros.retire(bridge, spy)
    return s, result, rows, spy, recording, forged


def strike(relay: Relay, bridge: HardwareBridge, old: dict) -> dict:
    """Everything the forger sends, from each end's peer address: per direction, forged datagrams (a zero tag,
    a random tag, another key; right CRC, this session's id, plausible sequences), the earlier session's
    recording, one of this session's datagrams from beyond the replay window and one from within it."""
    session = bridge.link.session
    evil = LinkKey(b"\xa5" * 32)
    kick = bp.Excitation(0, 2000, np.full((40, 4), 2.5))  # 2.5 A at samples the session excites
    cmd = bp.Command(bridge.link.seq[bp.Kind.COMMAND], 77, bp.CommandCode.SAFE_STATE)
    to_target = [bp.pack_datagram(m, 3, seal=bp.Seal(evil, bp.Sender.BRIDGE, session)) for m in (cmd, kick)]
    done = bp.Heartbeat(10**6, bp.TargetState.DONE, sample_rate_hz=10_000, sample_index=900, sent_end=900, axes=4)
    zeros = bp.Measurement(10**6, (bridge.assembler.next_index // 10 + 5) * 10, np.zeros((10, 16)),
                           np.zeros(10, np.uint8))
    to_bridge = [bp.pack_datagram(m, 3, seal=bp.Seal(evil, bp.Sender.TARGET, session)) for m in (done, zeros)]
    sent = {"to_target": 0, "to_bridge": 0}
    for direction, datagrams in (("to_target", to_target), ("to_bridge", to_bridge)):
        for d in datagrams:
            for fake in (forge(d, bytes(16)), forge(d, os.urandom(16)), d):
                relay.inject(direction, fake)
                sent[direction] += 1
        for d in old[direction]:  # the earlier session, replayed whole
            relay.inject(direction, d)
    # this session's own datagrams again: a MEASUREMENT and an EXCITATION from beyond the window, one from within
    meas = [d for d in relay.to_bridge if kind_of(d) == bp.Kind.MEASUREMENT]
    exc = [d for d in relay.to_target if kind_of(d) == bp.Kind.EXCITATION]
    assert len(meas) > WINDOW + 2 and len(exc) > WINDOW + 2, (len(meas), len(exc))
    relay.inject("to_bridge", meas[0])
    relay.inject("to_bridge", meas[-2])
    relay.inject("to_target", exc[0])
    relay.inject("to_target", exc[-1])
    return sent


def test_forged_replayed_and_old_datagrams_are_refused_by_both_ends_and_named(ros, tmp_path):
    key_file = tmp_path / "rig.key"
    key = write_key_file(key_file)
    secret = (key_file.read_text().split()[-1])
    # an earlier session of the same rig, recorded on the network
    s0, t0, rows0, spy0, recording, _ = run(ros, key_file, 1000, 4)
    assert s0["state"] == "done" and t0["state"] == "done" and s0["authenticated"]
    assert np.array_equal(rows0, direct_rows(4, 1000))
    assert not s0["malformed_by_reason"] and not s0["target_refused_by_reason"].get("auth")
    # this session: excited, and attacked from both sides
    n, seed, start = 6000, 11, 600
    r = np.random.default_rng(38).uniform(-0.2, 0.2, (3200, 4))
    s, t, rows, spy, _, forged = run(ros, key_file, n, seed, {"start": start, "r": r}, attack=recording)
    assert s["state"] == "done" and t["state"] == "done", (s, t)
    assert s["session"] != s0["session"] and s["key_fingerprint"] == key.fingerprint == t["key_fingerprint"]
    # the session's samples: the lock-step graph's own, bit for bit, the excitation at its exact samples
    assert np.array_equal(rows, direct_rows(seed, n, {start + i: r[i].tolist() for i in range(len(r))}))
    assert s["missing_samples"] == 0 and s["gaps"] == 0
    # the bridge refused, by reason: 3 forgeries of each of 2 datagrams for their tag, the whole earlier
    # session for its session, one MEASUREMENT for its old sequence, one more as a duplicate
    assert s["malformed_by_reason"] == {"auth": forged["to_bridge"], "session": len(recording["to_bridge"]),
                                        "replay": 1}, s["malformed_by_reason"]
    assert forged["to_bridge"] == 6 and s["duplicates"] == 1
    # the target likewise, and told the bridge through its heartbeat
    assert t["rx_rejected_by_reason"] == {"auth": forged["to_target"], "session": len(recording["to_target"]),
                                          "replay": 1, "duplicate": 1}, t["rx_rejected_by_reason"]
    assert s["target_refused_by_reason"] == {"auth": 6, "session": len(recording["to_target"]), "replay": 1,
                                             "duplicate": 1}
    # the session's events name every reason, both ends'
    assert ros.spin_until(lambda: all(spy.codes(c) for c in ("forged_datagram", "foreign_session_datagram",
                                                                "replayed_datagram", "duplicate_datagram",
                                                                "target_refused")), timeout_s=10)
    assert "(auth)" in spy.codes("forged_datagram")[0].text and spy.codes("forged_datagram")[0].severity == \
        SessionEvent.ERROR
    said = " ".join(e.text for e in spy.codes("target_refused"))
    assert all(f"{reason} " in said for reason in ("auth", "session", "replay", "duplicate")), said
    # the key itself is nowhere: not in an event, a status, the summary
    texts = [e.text for e in spy.events] + [st.text for st in spy.status] + [str(s), str(t)]
    assert not any(secret in x for x in texts)
    print(f"bridge drill: bridge refused {s['malformed_by_reason']} and {s['duplicates']} duplicate; target "
          f"refused {t['rx_rejected_by_reason']}; {n} samples bit for bit")


def test_key_file_parameter_is_checked(ros, tmp_path):
    key_file = tmp_path / "rig.key"
    write_key_file(key_file)
    os.chmod(key_file, 0o640)
    for params, words in (([Parameter("protocol_version", value=3), Parameter("key_file", value=str(key_file))],
                           "may be read by group or others (mode 0640)"),
                          ([Parameter("protocol_version", value=2), Parameter("key_file", value=str(key_file))],
                           "key_file with protocol_version 2"),
                          ([Parameter("protocol_version", value=3), Parameter("key_file", value=str(tmp_path))],
                           "is a folder")):
        with pytest.raises(ParameterError, match=re.escape(words)):
            HardwareBridge(namespace=NS, context=ros.context, parameter_overrides=params)


def test_version_2_bridge_says_on_every_start_that_the_link_is_unauthenticated(ros):
    # version 2 runs only when asked for (protocol_version 2, no key); each start warns, in the session's events
    # as in the log, not only the first: one listener hears one warning per start
    spy = ros.add(Spy(ros.context))
    for start in (1, 2):
        bridge = ros.add(HardwareBridge(namespace=NS, context=ros.context, parameter_overrides=[
            Parameter("target_port", value=free_port()), Parameter("local_port", value=0),
            Parameter("protocol_version", value=2)]))
        ros.matched(spy, to=bridge)
        assert ros.spin_until(lambda: len(spy.codes("unauthenticated_link")) == start, timeout_s=10), spy.events
        warn = spy.codes("unauthenticated_link")[-1]
        assert warn.severity == SessionEvent.WARN and "unauthenticated (protocol version 2)" in warn.text, warn
        assert not bridge.link.authenticated
        ros.retire(bridge)
    ros.spin_until(lambda: False, 0.5, scale=False)
    assert len(spy.codes("unauthenticated_link")) == 2, spy.events  # once per start, not repeated
