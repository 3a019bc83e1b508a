"""SessionWriter -> MCAP file in rosbag2's layout -> reader/inspect, checked record by record."""

import enum
import json
import os
import struct
import sys
from pathlib import Path

import pytest
import yaml
from ambid.recording import (IncompleteSessionError, QosProfile, SessionWriter, format_inspection, inspect_session,
                           iter_decoded, iter_messages, read_metadata, scan_session)
from ambid.recording.writer import parse_qos_profiles, qos_profile_from, serialize_qos_profiles
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import SummaryOffset
from mcap.stream_reader import StreamReader
from mcap_ros2._dynamic import serialize_dynamic

SHARE = Path(sys.prefix) / "share"
SEP = "=" * 80
QOS_KEYS = [
    "history", "depth", "reliability", "durability", "deadline", "lifespan",
    "liveliness", "liveliness_lease_duration", "avoid_ros_namespace_conventions",
]


@pytest.fixture(autouse=True)
def ament_prefix(monkeypatch):
    monkeypatch.setenv("AMENT_PREFIX_PATH", sys.prefix)


def msg_text(pkg, name):
    return (SHARE / pkg / "msg" / f"{name}.msg").read_text()


def json_hash(type_name):
    pkg, _, name = type_name.split("/")
    doc = json.loads((SHARE / pkg / "msg" / f"{name}.json").read_text())
    return {e["type_name"]: e["hash_string"] for e in doc["type_hashes"]}[type_name]


# Schema texts built in the test from the .msg files, independent of ros2_schema.
FULL_TEXT = {
    "std_msgs/msg/String": msg_text("std_msgs", "String"),
    "builtin_interfaces/msg/Time": msg_text("builtin_interfaces", "Time"),
    "std_msgs/msg/Float64MultiArray": (
        msg_text("std_msgs", "Float64MultiArray")
        + f"\n{SEP}\nMSG: std_msgs/MultiArrayLayout\n" + msg_text("std_msgs", "MultiArrayLayout")
        + f"\n{SEP}\nMSG: std_msgs/MultiArrayDimension\n" + msg_text("std_msgs", "MultiArrayDimension")
    ),
}


def encoder(type_name):
    return serialize_dynamic(type_name, FULL_TEXT[type_name])[type_name]


def cdr_string(s):
    # CDR little-endian encapsulation, uint32 length incl. NUL, bytes, NUL.
    b = s.encode()
    return b"\x00\x01\x00\x00" + struct.pack("<I", len(b) + 1) + b + b"\x00"


def cdr_time(sec, nanosec):
    return b"\x00\x01\x00\x00" + struct.pack("<iI", sec, nanosec)


def make_session(path, n=300, **kw):
    """Write three topics; return the list of (topic, log_time, bytes, value) written."""
    enc_arr = encoder("std_msgs/msg/Float64MultiArray")
    written = []
    qos_fast = QosProfile(reliability="best_effort", depth=5, deadline_ns=100_000_000)
    with SessionWriter(path, **kw) as w:
        w.write_session_facts({"rig": "sim-rig-1", "excitation": {"kind": "multisine", "band_hz": [1.0, 500.0]}})
        w.add_topic("/chatter", "std_msgs/msg/String", [QosProfile()])
        w.add_topic("/arr", "std_msgs/msg/Float64MultiArray", [qos_fast, QosProfile()])
        w.add_topic("/stamp", "builtin_interfaces/msg/Time")
        w.add_attachment("config.yaml", b"gain: 1.5\n", "application/yaml", log_time_ns=7)
        for i in range(n):
            t = 1_700_000_000_000_000_000 + i * 2_000_000
            topic = ("/chatter", "/arr", "/stamp")[i % 3]
            if topic == "/chatter":
                value = f"hello {i}"
                data = cdr_string(value)
            elif topic == "/arr":
                value = [0.5 * i, -1.0, float(i) ** 0.5]
                data = enc_arr({
                    "layout": {"dim": [{"label": "x", "size": 3, "stride": 3}], "data_offset": i},
                    "data": value,
                })
            else:
                value = (i, 1000 * i)
                data = cdr_time(*value)
            w.write(topic, data, t)
            written.append((topic, t, data, value))
    return written


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = tmp_path_factory.mktemp("s") / "session.mcap"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("AMENT_PREFIX_PATH", sys.prefix)
        written = make_session(path, chunk_size_bytes=2048)
    return path, written


def test_messages_read_back_bit_identical_in_log_time_order(session):
    path, written = session
    got = list(iter_messages(path))
    assert [(m.topic, m.log_time_ns, m.data) for m in got] == [(t, lt, d) for t, lt, d, _ in written]
    types = {"/chatter": "std_msgs/msg/String", "/arr": "std_msgs/msg/Float64MultiArray",
             "/stamp": "builtin_interfaces/msg/Time"}
    assert all(m.type_name == types[m.topic] for m in got)
    only = list(iter_messages(path, topics="/stamp"))
    assert [m.data for m in only] == [d for t, _, d, _ in written if t == "/stamp"]


def test_messages_decode_to_the_written_values(session):
    path, written = session
    decoded = list(iter_decoded(path))
    assert len(decoded) == len(written)
    for (msg, obj), (topic, _, _, value) in zip(decoded, written):
        if topic == "/chatter":
            assert obj.data == value
        elif topic == "/arr":
            assert list(obj.data) == value
            assert obj.layout.dim[0].label == "x" and obj.layout.dim[0].stride == 3
            assert obj.layout.data_offset == written.index((topic, msg.log_time_ns, msg.data, value))
        else:
            assert (obj.sec, obj.nanosec) == value


def test_header_schemas_and_channels_follow_the_ros2_profile(session):
    path, _ = session
    with open(path, "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
    assert header.profile == "ros2"
    assert header.library.startswith("ambid ") and "mcap" in header.library
    schemas = {s.name: s for s in summary.schemas.values()}
    assert set(schemas) == set(FULL_TEXT)
    for name, schema in schemas.items():
        assert schema.encoding == "ros2msg"
        assert schema.data.decode() == FULL_TEXT[name]
    arr = schemas["std_msgs/msg/Float64MultiArray"].data.decode()
    assert "MSG: std_msgs/MultiArrayLayout" in arr and "MSG: std_msgs/MultiArrayDimension" in arr

    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == {"/chatter", "/arr", "/stamp"}
    for topic, ch in channels.items():
        assert ch.message_encoding == "cdr"
        type_name = summary.schemas[ch.schema_id].name
        assert ch.metadata["topic_type_hash"] == json_hash(type_name)
        profiles = yaml.safe_load(ch.metadata["offered_qos_profiles"])
        assert isinstance(profiles, list)
        for p in profiles:
            assert list(p) == QOS_KEYS
            assert set(p["deadline"]) == {"sec", "nsec"}
    arr_qos = yaml.safe_load(channels["/arr"].metadata["offered_qos_profiles"])
    assert arr_qos[0]["reliability"] == "best_effort" and arr_qos[0]["depth"] == 5
    assert arr_qos[0]["deadline"] == {"sec": 0, "nsec": 100_000_000}
    assert arr_qos[1]["deadline"] == {"sec": 9223372036, "nsec": 854775807}
    assert arr_qos[1]["avoid_ros_namespace_conventions"] is False
    assert channels["/stamp"].metadata["offered_qos_profiles"] == "[]"


def test_summary_statistics_indexes_and_compression(session):
    path, written = session
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    stats = summary.statistics
    assert stats.message_count == len(written)
    by_topic = {c.topic: stats.channel_message_counts[c.id] for c in summary.channels.values()}
    assert by_topic == {t: sum(1 for w in written if w[0] == t) for t in by_topic}
    assert stats.message_start_time == written[0][1] and stats.message_end_time == written[-1][1]
    assert stats.schema_count == 3 and stats.channel_count == 3
    assert stats.chunk_count == len(summary.chunk_indexes) > 3
    assert stats.metadata_count == 2  # ambid.session + rosbag2
    assert stats.attachment_count == 1
    with open(path, "rb") as f:
        (att,) = list(make_reader(f).iter_attachments())
    assert (att.name, att.media_type, att.data, att.log_time) == ("config.yaml", "application/yaml", b"gain: 1.5\n", 7)
    for ci in summary.chunk_indexes:
        assert ci.compression == "zstd"
        assert ci.compressed_size < ci.uncompressed_size
        assert ci.message_index_length > 0 and len(ci.message_index_offsets) >= 1
    with open(path, "rb") as f:  # chunk CRCs are checked while reading every record
        offsets = [r for r in StreamReader(f, validate_crcs=True).records if isinstance(r, SummaryOffset)]
    assert {o.group_opcode for o in offsets} >= {
        Opcode.SCHEMA, Opcode.CHANNEL, Opcode.STATISTICS, Opcode.CHUNK_INDEX, Opcode.METADATA_INDEX
    }


def test_session_facts_and_rosbag2_metadata_round_trip(session):
    path, written = session
    meta = read_metadata(path)
    facts = meta["ambid.session"]
    assert facts["rig"] == "sim-rig-1"
    assert json.loads(facts["excitation"]) == {"kind": "multisine", "band_hz": [1.0, 500.0]}
    assert "ambid_version" in facts
    bag = yaml.safe_load(meta["rosbag2"]["serialized_metadata"])
    assert bag["version"] == 9 and bag["storage_identifier"] == "mcap" and bag["ros_distro"] == "jazzy"
    assert bag["message_count"] == len(written)
    assert bag["starting_time"]["nanoseconds_since_epoch"] == written[0][1]
    assert bag["duration"]["nanoseconds"] == written[-1][1] - written[0][1]
    assert bag["relative_file_paths"] == ["session.mcap"]
    topics = {t["topic_metadata"]["name"]: t for t in bag["topics_with_message_count"]}
    assert topics["/arr"]["message_count"] == sum(1 for w in written if w[0] == "/arr")
    assert topics["/arr"]["topic_metadata"]["type_description_hash"] == json_hash("std_msgs/msg/Float64MultiArray")
    assert topics["/arr"]["topic_metadata"]["offered_qos_profiles"][0]["reliability"] == "best_effort"
    assert bag["custom_data"]["rig"] == "sim-rig-1"


def test_scan_and_recover_agree_with_the_summary_on_a_complete_file(session):
    path, written = session
    scan = scan_session(path)
    assert scan.complete and scan.problem is None and scan.valid_bytes == scan.file_bytes
    assert scan.message_count == len(written)
    assert [m.data for m in iter_messages(path, recover=True)] == [w[2] for w in written]


def test_inspect_reports_counts_rates_and_facts(session):
    path, written = session
    d = inspect_session(path)
    assert d["complete"] and d["profile"] == "ros2" and d["message_count"] == len(written)
    chatter = [w[1] for w in written if w[0] == "/chatter"]
    info = d["topics"]["/chatter"]
    assert info["message_count"] == len(chatter)
    assert info["rate_hz"] == pytest.approx((len(chatter) - 1) / ((chatter[-1] - chatter[0]) * 1e-9))
    assert d["duration_s"] == pytest.approx((written[-1][1] - written[0][1]) * 1e-9)
    assert d["metadata"]["ambid.session"]["rig"] == "sim-rig-1"
    assert d["attachments"] == ["config.yaml"]
    text = format_inspection(d)
    assert "/arr" in text and "sim-rig-1" in text and "complete" in text


def test_chunks_close_on_log_time_span(tmp_path):
    path = tmp_path / "slow.mcap"
    step = 300_000_000  # 0.3 s between messages, 1 s chunks
    with SessionWriter(path, chunk_max_duration_ns=1_000_000_000) as w:
        w.add_topic("/s", "std_msgs/msg/String")
        for i in range(40):
            w.write("/s", cdr_string(str(i)), i * step)
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) == 10  # 4 messages (0, .3, .6, .9 s) per chunk
    for a, b in zip(chunks, chunks[1:]):
        assert a.message_end_time - a.message_start_time < 1_000_000_000
        assert b.message_start_time - a.message_start_time >= 1_000_000_000


def test_flush_closes_the_open_chunk_and_fsync_runs_per_chunk(tmp_path, monkeypatch):
    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))
    path = tmp_path / "timer.mcap"
    with SessionWriter(path, fsync=True) as w:
        w.add_topic("/s", "std_msgs/msg/String")
        w.write("/s", cdr_string("a"), 1)
        assert (w.chunk_count, w.flushed_message_count) == (0, 0)
        size_before = path.stat().st_size
        w.flush()  # what a recorder's wall-clock timer calls
        assert (w.chunk_count, w.flushed_message_count) == (1, 1) and len(synced) == 1
        assert path.stat().st_size > size_before  # the chunk is in the file, not in a buffer
        assert [m.data for m in iter_messages(path, recover=True)] == [cdr_string("a")]
        w.flush()  # nothing new: no empty chunk
        assert w.chunk_count == 1
        w.write("/s", cdr_string("b"), 2)
    assert len(synced) >= 3  # the explicit flushes, the last chunk and the summary
    with open(path, "rb") as f:
        assert len(make_reader(f).get_summary().chunk_indexes) == 2


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_chunks_close_on_size_for_every_compression(tmp_path, compression):
    path = tmp_path / f"{compression}.mcap"
    payload = cdr_string("x" * 991)  # 1000 bytes -> 1031-byte message records
    with SessionWriter(path, chunk_size_bytes=4096, compression=compression) as w:
        w.add_topic("/big", "std_msgs/msg/String")
        for i in range(20):
            w.write("/big", payload, i)
        assert w.chunk_count == 5 and w.flushed_message_count == 20
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) == 5
    assert {c.compression for c in chunks} == {"" if compression == "none" else compression}
    assert all(4 * 1031 <= c.uncompressed_size < 4 * 1031 + 1000 for c in chunks)
    assert [m.data for m in iter_messages(path)] == [payload] * 20


def test_sample_index_gap_hook(tmp_path):
    block_def = "uint64 first_index\nfloat64[] y\n"
    firsts = [0, 10, 20, 45, 55, 50, 65]  # gap 30..44 (15 samples), overlap at 50
    path = tmp_path / "blocks.mcap"
    with SessionWriter(path) as w:
        w.add_topic("/amb/y", "ambid_test/msg/Block", definition=block_def)
        enc = serialize_dynamic("ambid_test/msg/Block", block_def)["ambid_test/msg/Block"]
        for k, first in enumerate(firsts):
            w.write("/amb/y", enc({"first_index": first, "y": [0.0] * 10}), 1000 * k)
    d = inspect_session(path, sample_index={"ambid_test/msg/Block": lambda m: (m.first_index, len(m.y))})
    rep = d["sample_index"]["/amb/y"]
    assert rep["blocks"] == 7 and rep["samples"] == 70
    assert rep["gap_count"] == 1 and rep["missing_samples"] == 15
    assert rep["gaps"] == [{"log_time_ns": 3000, "expected_index": 30, "got_index": 45}]
    assert rep["overlapping_blocks"] == 1 and rep["overlapping_samples"] == 10
    assert rep["first_index"] == 0 and rep["end_index"] == 75
    assert d["topics"]["/amb/y"]["type_hash"] == ""
    assert "missing 15" in format_inspection(d)


class HistoryPolicy(enum.IntEnum):  # stand-ins for rclpy's enums and Duration
    KEEP_LAST = 1
    KEEP_ALL = 2


class ReliabilityPolicy(enum.IntEnum):
    RELIABLE = 1
    BEST_EFFORT = 2


class DurabilityPolicy(enum.IntEnum):
    TRANSIENT_LOCAL = 1
    VOLATILE = 2


class LivelinessPolicy(enum.IntEnum):
    AUTOMATIC = 1


class Duration:
    def __init__(self, nanoseconds):
        self.nanoseconds = nanoseconds


class FakeRclpyQoS:
    history = HistoryPolicy.KEEP_ALL
    depth = 0
    reliability = ReliabilityPolicy.BEST_EFFORT
    durability = DurabilityPolicy.TRANSIENT_LOCAL
    deadline = Duration(1_500_000_000)
    lifespan = Duration(0)
    liveliness = LivelinessPolicy.AUTOMATIC
    liveliness_lease_duration = Duration(2**63 - 1)
    avoid_ros_namespace_conventions = True


def test_qos_from_rclpy_like_profile_and_yaml_round_trip():
    q = qos_profile_from(FakeRclpyQoS())
    assert (q.history, q.reliability, q.durability) == ("keep_all", "best_effort", "transient_local")
    text = serialize_qos_profiles([FakeRclpyQoS(), QosProfile()])
    first = yaml.safe_load(text)[0]
    assert first["deadline"] == {"sec": 1, "nsec": 500_000_000} and first["lifespan"] == {"sec": 0, "nsec": 0}
    assert first["avoid_ros_namespace_conventions"] is True
    assert not text.endswith("\n") and text.startswith("- history: keep_all\n  depth: 0\n")
    assert parse_qos_profiles(text) == [q, QosProfile()]
    with pytest.raises(ValueError, match="reliability"):
        QosProfile(reliability="sometimes")


def test_bad_input_is_rejected_with_clear_errors(tmp_path):
    path = tmp_path / "bad.mcap"
    with pytest.raises(ValueError, match="chunk_size_bytes"):
        SessionWriter(path, chunk_size_bytes=0)
    with pytest.raises(ValueError, match="compression"):
        SessionWriter(path, compression="gzip")
    with SessionWriter(path) as w:
        w.add_topic("/a", "std_msgs/msg/String")
        with pytest.raises(ValueError, match="not registered"):
            w.write("/b", b"\x00\x01\x00\x00", 0)
        with pytest.raises(ValueError, match="bytes"):
            w.write("/a", "text", 0)
        with pytest.raises(ValueError, match="log_time_ns"):
            w.write("/a", b"", -1)
        with pytest.raises(ValueError, match="already recorded"):
            w.add_topic("/a", "std_msgs/msg/Float64MultiArray")
        with pytest.raises(ValueError, match="reserved"):
            w.add_metadata("rosbag2", {})
    with pytest.raises(FileExistsError):
        SessionWriter(path)
    with pytest.raises(ValueError, match="closed"):
        w.write("/a", b"", 0)


def test_reading_a_file_without_footer_needs_recover(tmp_path, session):
    src, written = session
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src.read_bytes()[:-100])
    with pytest.raises(IncompleteSessionError, match="recover=True"):
        list(iter_messages(cut))
    with pytest.raises(IncompleteSessionError):
        inspect_session(cut)
    d = inspect_session(cut, recover=True)
    assert not d["complete"] and d["message_count"] == len(written)  # only the summary was lost


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_message_order_is_the_mcap_librarys_with_overlapping_chunks(tmp_path, compression):
    """Log times out of order across chunks (their time ranges overlap) and equal log times: the
    summary-indexed reader gives the order of mcap's ``iter_messages(log_time_order=True)``, any topics."""
    import random

    rng = random.Random(3)
    path = tmp_path / "shuffled.mcap"
    with SessionWriter(path, chunk_size_bytes=400, compression=compression) as w:
        for topic in ("/a", "/b", "/c"):
            w.add_topic(topic, "std_msgs/msg/String")
        for i in range(120):
            w.write(rng.choice(["/a", "/b", "/c"]), cdr_string(f"m{i}" * rng.randint(1, 9)),
                    rng.randint(0, 40) * 1000, sequence=i)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    spans = sorted((c.message_start_time, c.message_end_time) for c in summary.chunk_indexes)
    assert len(spans) > 5 and any(b[0] < a[1] for a, b in zip(spans, spans[1:]))   # overlapping chunks
    for topics in (None, ["/b"], ["/a", "/c"]):
        with open(path, "rb") as f:
            want = [(c.topic, m.log_time, m.publish_time, m.sequence, m.data)
                    for _, c, m in make_reader(f).iter_messages(topics=topics, log_time_order=True)]
        got = [(m.topic, m.log_time_ns, m.publish_time_ns, m.sequence, m.data) for m in iter_messages(path, topics)]
        assert got == want and len(got) > 10
    assert len({lt for _, lt, *_ in want}) < len(want)                                # equal log times occur


def test_a_corrupt_chunk_raises_instead_of_misreading(tmp_path):
    from mcap.exceptions import McapError

    path = tmp_path / "corrupt.mcap"
    payload = cdr_string("x" * 91)
    with SessionWriter(path, chunk_size_bytes=1024, compression="none") as w:
        w.add_topic("/x", "std_msgs/msg/String")
        for i in range(30):
            w.write("/x", payload, i)
    raw = bytearray(path.read_bytes())
    with open(path, "rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[1]
    records = raw.find(payload, chunk.chunk_start_offset) - 31      # first message record of that chunk
    assert raw[records] == Opcode.MESSAGE
    raw[records + 1:records + 9] = struct.pack("<Q", 10**6)          # its length now runs past the chunk
    path.write_bytes(bytes(raw))
    with pytest.raises(McapError, match="overruns the chunk"):
        list(iter_messages(path))
