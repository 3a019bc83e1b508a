"""recorder (a separate process) and ``ambid inspect``: complete, bit-identical and recoverable sessions.

The plant and controller run composed on the test's context; a watcher node
subscribes raw to the same topics, so every recorded message can be compared
byte for byte with what DDS delivered to an independent subscriber.
"""

from __future__ import annotations

import argparse
import json
import resource
import signal
import subprocess
import sys
import time

import ambid
import numpy as np
import pytest
import rclpy
import yaml
from ambid.recording import SessionWriter, iter_decoded, iter_messages, read_metadata, scan_session
from ambid.recording.blocks import decode_sample_block
from ambid.recording.writer import parse_qos_profiles
from ambid_cli import cli
from ambid_cli.commands import inspect as inspect_cmd
from ambid_nodes.conversions import block_msg
from ambid_nodes.node_main import SUMMARY_PREFIX
from ambid_nodes.plant_sim import PlantSim
from ambid_nodes.position_controller import PositionController
from mcap.reader import make_reader
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message

from ambid_msgs.msg import ExcitationDesign, SampleBlock, SessionEvent, SessionStatus
from ambid_nodes import qos
from ambid.channels import RADIAL

MEASUREMENT_NAMES = RADIAL.measurement_names  # the default rig's channels

NS = "/amb"
MEAS = f"{NS}/measurement"
EXC = f"{NS}/excitation"
SEP = "=" * 80


class Watcher(Node):
    """Raw subscriber to measurement/excitation plus the recorder's status and events."""

    def __init__(self, context) -> None:
        super().__init__("watcher", namespace=NS, context=context)
        self.blocks: dict[str, dict[int, bytes]] = {MEAS: {}, EXC: {}}
        for topic in self.blocks:
            self.create_subscription(SampleBlock, topic, lambda data, t=topic: self.on_block(t, data),
                                     qos.BLOCKS, raw=True)
        self.status: dict | None = None
        self.events: list[SessionEvent] = []
        self.create_subscription(SessionStatus, "status", self.on_status,
                                 rclpy.qos.QoSProfile(depth=100, durability=qos.STATUS.durability))
        self.create_subscription(SessionEvent, "events", self.on_event, qos.EVENTS)

    def on_block(self, topic: str, data: bytes) -> None:
        self.blocks[topic][deserialize_message(data, SampleBlock).first_index] = data

    def on_status(self, msg: SessionStatus) -> None:
        if msg.node == f"{NS}/recorder":
            self.status = {"state": msg.state, **{k: json.loads(v) for k, v in zip(msg.keys, msg.values)}}

    def on_event(self, msg: SessionEvent) -> None:
        if msg.node == f"{NS}/recorder":
            self.events.append(msg)

    def recorded(self, topic: str) -> int:
        return (self.status or {}).get(f"messages:{topic}", 0)

    def recorder_subscribed(self, topic: str) -> bool:
        return any(i.node_name == "recorder" for i in self.get_subscriptions_info_by_topic(topic))


def start_recorder(env: dict, path, *, preexec_fn=None, **params) -> subprocess.Popen:
    params = {"output": str(path), "flush_period_s": 0.2, "status_period_s": 0.1, "discovery_period_s": 0.05, **params}
    args = [sys.executable, "-m", "ambid_nodes.recorder", "--ros-args", "-r", f"__ns:={NS}"]
    for key, value in params.items():
        args += ["-p", f"{key}:={value}"]
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=preexec_fn)


def spin_or_fail(ros, predicate, what: str, proc: subprocess.Popen | None = None, timeout_s: float = 40.0):
    def done():
        if proc is not None and proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"recorder exited with {proc.returncode} while waiting for {what}:\n{out}\n{err}")
        return predicate()

    assert ros.spin_until(done, timeout_s), f"timed out waiting for {what}"


def stop(proc: subprocess.Popen, sig: int) -> tuple[int, str, str]:
    proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"recorder ignored signal {sig}:\n{err}")
    return proc.returncode, out, err


def plant_graph(ros, sim_seconds: float, block_size: int):
    plant = ros.add(PlantSim(namespace=NS, context=ros.context, parameter_overrides=[
        Parameter("sim_seconds", value=sim_seconds), Parameter("block_size", value=block_size)]))
    return plant


def inspect_json(capsys, path, recover: bool) -> tuple[int, dict | None, str]:
    code = cli.main(["inspect", str(path), "--json"] + (["--recover"] if recover else []))
    out, err = capsys.readouterr()
    return code, (json.loads(out) if code == 0 else None), err


def test_sigint_closes_a_complete_rosbag2_session_bit_identical_to_a_live_subscriber(ros, ros_env, tmp_path):
    path = tmp_path / "session.mcap"
    watcher = ros.add(Watcher(ros.context))
    rec = start_recorder(ros_env, path)
    try:
        plant = plant_graph(ros, sim_seconds=0.2, block_size=250)
        # the plant waits for a controller: start the loop only once the recorder and the watcher are matched
        ros.matched(watcher, to=plant)
        spin_or_fail(ros, lambda: plant.pub_block.get_subscription_count() >= 2
                     and plant.pub_desc.get_subscription_count() >= 1, "the recorder to subscribe", rec)
        ros.add(PositionController(namespace=NS, context=ros.context))
        spin_or_fail(ros, lambda: plant.finished.done(), "the plant to finish", rec, timeout_s=90)
        n_blocks = 2000 // 250
        spin_or_fail(ros, lambda: len(watcher.blocks[MEAS]) == n_blocks and watcher.recorded(MEAS) == n_blocks
                     and watcher.recorded(f"{NS}/controller/description") >= 1,
                     "the recorder to write every block", rec)
        hashes = {t: str(watcher.get_publishers_info_by_topic(t)[0].topic_type_hash)
                  for t in (MEAS, f"{NS}/plant/description")}
        t0 = time.perf_counter()
        code, out, err = stop(rec, signal.SIGINT)
        close_s = time.perf_counter() - t0
    finally:
        if rec.poll() is None:
            rec.kill()
    assert code == 130, err
    print(f"\nrecorder closed {close_s:.2f} s after SIGINT; status figures {watcher.status}")

    scan = scan_session(path)
    assert scan.complete and scan.problem is None
    assert scan.profile == "ros2"
    # the lock-step topics are left out by default
    assert f"{NS}/displacement" not in scan.topic_types and f"{NS}/control_current" not in scan.topic_types

    # every measurement block, byte for byte as the independent subscriber got it
    recorded = {deserialize_message(m.data, SampleBlock).first_index: m.data for m in iter_messages(path, MEAS)}
    assert sorted(recorded) == sorted(watcher.blocks[MEAS]) == list(range(0, 2000, 250))
    assert all(recorded[k] == watcher.blocks[MEAS][k] for k in recorded)
    # ... decoding with mcap_ros2 (from the stored schema) and with the hand-written CDR reader
    for msg, decoded in iter_decoded(path, MEAS):
        ref = deserialize_message(msg.data, SampleBlock)
        assert decoded.first_index == ref.first_index and list(decoded.channel_names) == list(MEASUREMENT_NAMES)
        assert np.array_equal(np.asarray(decoded.data), np.asarray(ref.data))
        fast = decode_sample_block(msg.data)
        assert fast.first_index == ref.first_index and fast.channel_names == tuple(ref.channel_names)
        assert np.array_equal(fast.data, np.reshape(ref.data, (ref.n_samples, len(ref.channel_names))))
        assert np.array_equal(fast.sample_flags, np.asarray(ref.sample_flags, dtype=np.uint8))

    # the latched descriptions published before the recorder joined
    for topic in ("plant/description", "controller/description"):
        assert scan.topic_message_counts[f"{NS}/{topic}"] >= 1
    facts = read_metadata(path)["ambid.session"]
    assert json.loads(facts["rig"]) == plant.rig.to_dict()
    assert json.loads(facts["plant"])["seed"] == plant.seed
    assert json.loads(facts["controller"])["kind"] == "pid"
    assert facts["ambid_version"] == ambid.__version__
    # a file without the metadata (as ros2 bag record writes it): inspect reads the latched messages instead
    bare = tmp_path / "bare.mcap"
    with SessionWriter(bare) as w:
        for topic, type_name in scan.topic_types.items():
            w.add_topic(topic, type_name)
        for m in iter_messages(path):
            w.write(m.topic, m.data, m.log_time_ns)
    from_meta, from_msgs = inspect_cmd.describe(str(path))["facts"], inspect_cmd.describe(str(bare))["facts"]
    assert (from_meta["source"], from_msgs["source"]) == ("metadata", "messages")
    assert from_msgs["rig"] == from_meta["rig"] and from_msgs["rig"]["name"] == plant.rig.name
    assert from_msgs["plant"] == from_meta["plant"] and from_msgs["controller"] == from_meta["controller"]

    bag = yaml.safe_load(read_metadata(path)["rosbag2"]["serialized_metadata"])
    assert bag["message_count"] == scan.message_count
    assert bag["custom_data"]["rig"] == facts["rig"]

    # rosbag2's layout: ros2msg schemas with dependencies, cdr channels, QoS and type hash metadata
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    schemas = {s.id: s for s in summary.schemas.values()}
    channels = {c.topic: c for c in summary.channels.values()}
    assert all(c.message_encoding == "cdr" for c in channels.values())
    assert all(s.encoding == "ros2msg" for s in schemas.values())
    block_schema = schemas[channels[MEAS].schema_id].data.decode()
    assert f"{SEP}\nMSG: builtin_interfaces/Time\n" in block_schema
    desc_schema = schemas[channels[f"{NS}/plant/description"].schema_id].data.decode()
    assert "MSG: ambid_msgs/StateSpace" in desc_schema
    for topic, type_hash in hashes.items():
        assert channels[topic].metadata["topic_type_hash"] == type_hash
    meas_qos = parse_qos_profiles(channels[MEAS].metadata["offered_qos_profiles"])
    assert [(q.reliability, q.durability) for q in meas_qos] == [("reliable", "volatile")]
    desc_qos = parse_qos_profiles(channels[f"{NS}/plant/description"].metadata["offered_qos_profiles"])
    assert [q.durability for q in desc_qos] == ["transient_local"]
    assert [q.reliability for q in parse_qos_profiles(channels["/clock"].metadata["offered_qos_profiles"])] == [
        "best_effort"]


def test_sigkill_leaves_a_file_inspect_recovers(ros, ros_env, tmp_path, capsys):
    path = tmp_path / "killed.mcap"
    watcher = ros.add(Watcher(ros.context))
    rec = start_recorder(ros_env, path)
    try:
        plant = plant_graph(ros, sim_seconds=0.5, block_size=250)
        ros.matched(watcher, to=plant)
        spin_or_fail(ros, lambda: plant.pub_block.get_subscription_count() >= 2, "the recorder to subscribe", rec)
        ros.add(PositionController(namespace=NS, context=ros.context))
        # kill mid-run, once a chunk was flushed after blocks and the plant's description were recorded: that
        # chunk (or an earlier one) holds them; chunks flushed before they arrived hold none (the description's
        # reader may match after the measurement's, and its message come after the first blocks)
        spin_or_fail(ros, lambda: watcher.recorded(MEAS) >= 3 and watcher.recorded(f"{NS}/plant/description") >= 1,
                     "recorded measurement blocks and the plant's description", rec)
        chunks_then = watcher.status["chunks"]
        spin_or_fail(ros, lambda: watcher.status["chunks"] > max(chunks_then, 1), "flushed measurement blocks",
                     rec)
        flushed_before_kill = watcher.status["flushed_messages"]
        code, _, _ = stop(rec, signal.SIGKILL)
    finally:
        if rec.poll() is None:
            rec.kill()
    assert code == -signal.SIGKILL
    running = not plant.finished.done()

    code, _, err = inspect_json(capsys, path, recover=False)
    assert code == 2 and "--recover" in err

    code, report, err = inspect_json(capsys, path, recover=True)
    assert code == 0, err
    rec_info = report["recovery"]
    assert rec_info["complete"] is False and rec_info["problem"]
    assert rec_info["recovered_messages"] >= flushed_before_kill > 0
    blocks = report["sample_index"][MEAS]
    assert blocks["blocks"] >= 1 and blocks["first_index"] == 0 and blocks["gap_count"] == 0
    assert report["facts"]["rig"]["name"] == plant.rig.name
    # what was recovered is what was sent
    recovered = list(iter_messages(path, MEAS, recover=True))
    assert len(recovered) == blocks["blocks"]
    for m in recovered:
        assert m.data == watcher.blocks[MEAS][deserialize_message(m.data, SampleBlock).first_index]
    print(f"\nSIGKILL {'during' if running else 'after'} the run: {rec_info['recovered_messages']} messages "
          f"recovered ({flushed_before_kill} flushed by the last status), {rec_info['valid_bytes']} of "
          f"{rec_info['file_bytes']} bytes readable")


def design_msg() -> ExcitationDesign:
    return ExcitationDesign(
        experiment_id="exp", kind="multisine", multi_input="orthogonal", start_index=0, total_samples=400,
        sample_rate=10_000.0, samples_per_period=100, n_periods=2, n_transient_periods=1, n_realisations=1,
        n_experiments=2, input_names=["u_a_x", "u_b_x"], excited_lines=[1, 3, 7], rms=[0.1, 0.1],
        peak=[0.3, 0.3], crest_factor=[3.0, 3.0], measurement_time=0.04, seed=7,
        design_json=json.dumps({"amplitudes": [1.0, 2.0]}))


def test_sigterm_closes_the_file_with_design_facts_and_gaps(ros, ros_env, tmp_path, capsys):
    path = tmp_path / "sigterm.mcap"
    node = ros.add(Watcher(ros.context))
    design_pub = node.create_publisher(ExcitationDesign, "excitation/design", qos.LATCHED)
    design_pub.publish(design_msg())
    rec = start_recorder(ros_env, path, topics="['excitation', 'excitation/design', 'events']")
    try:
        # excitation has only a subscriber (the watcher) yet: the recorder subscribes all the same
        spin_or_fail(ros, lambda: node.recorder_subscribed(EXC) and node.recorder_subscribed(
            f"{NS}/excitation/design"), "the recorder to subscribe", rec)
        assert node.count_publishers(EXC) == 0
        exc_pub = node.create_publisher(SampleBlock, "excitation", qos.BLOCKS)
        spin_or_fail(ros, lambda: exc_pub.get_subscription_count() >= 2, "the publisher to match", rec)
        rng = np.random.default_rng(3)
        firsts = (0, 100, 300)  # samples 200..299 missing
        for first in firsts:
            exc_pub.publish(block_msg(first, 1e-4, ["r_a_x", "r_b_x"], ["A", "A"], rng.normal(size=(100, 2)),
                                      experiment_id="exp"))
        spin_or_fail(ros, lambda: len(node.blocks[EXC]) == 3 and node.recorded(EXC) == 3
                     and node.recorded(f"{NS}/excitation/design") == 1, "the recorder to write", rec)
        code, _, err = stop(rec, signal.SIGTERM)
    finally:
        if rec.poll() is None:
            rec.kill()
    assert code == 130, err
    scan = scan_session(path)
    assert scan.complete
    # registered at the first message, with the publisher's QoS
    offered = parse_qos_profiles(scan.channel_metadata[EXC]["offered_qos_profiles"])
    assert [(q.reliability, q.durability) for q in offered] == [("reliable", "volatile")]

    code, report, err = inspect_json(capsys, path, recover=False)
    assert code == 0, err
    gaps = report["sample_index"][EXC]
    assert (gaps["blocks"], gaps["gap_count"], gaps["missing_samples"], gaps["end_index"]) == (3, 1, 100, 400)
    assert gaps["gaps"][0]["expected_index"] == 200 and gaps["gaps"][0]["got_index"] == 300
    design = report["facts"]["excitation"]["exp"]
    assert design["band_hz"] == [100.0, 700.0] and design["n_excited_lines"] == 3
    assert design["input_names"] == ["u_a_x", "u_b_x"] and design["total_samples"] == 400
    assert json.loads(report["metadata"]["ambid.session"]["excitation"])["exp"]["design"] == {
        "amplitudes": [1.0, 2.0]}
    for m in iter_messages(path, EXC):
        block = decode_sample_block(m.data)  # 3-character experiment_id: the uint64 after it is padded
        assert block.experiment_id == "exp" and m.data == node.blocks[EXC][block.first_index]
    assert inspect_cmd.run(argparse.Namespace(file=str(path), json=False, recover=False)) == 0
    text = capsys.readouterr().out
    assert "exp: multisine (orthogonal) on u_a_x, u_b_x, 100-700 Hz, 3 lines" in text
    assert "missing 100" in text


def limit_file_size(n_bytes: int):
    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write beyond the limit then fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (n_bytes, n_bytes))
    return apply


def test_a_write_failure_is_reported_and_leaves_a_readable_file(ros, ros_env, tmp_path):
    path = tmp_path / "full.mcap"
    node = ros.add(Watcher(ros.context))
    pub = node.create_publisher(SampleBlock, "measurement", qos.BLOCKS)
    rec = start_recorder(ros_env, path, topics="['measurement', 'events']", compression="none",
                         preexec_fn=limit_file_size(120_000))
    try:
        spin_or_fail(ros, lambda: pub.get_subscription_count() >= 2, "the recorder to subscribe", rec)
        rng = np.random.default_rng(5)
        for k in range(12):  # 32 kB each: the file limit is reached after about three
            pub.publish(block_msg(1000 * k, 1e-4, ["y_a_x", "y_b_x", "y_a_y", "y_b_y"], ["m"] * 4,
                                  rng.normal(size=(1000, 4))))
            ros.spin_until(lambda: False, 0.1)
        spin_or_fail(ros, lambda: any(e.code == "write_failed" for e in node.events), "the write_failed event")
        out, err = rec.communicate(timeout=30)
    finally:
        if rec.poll() is None:
            rec.kill()
    assert rec.returncode == 1, err
    summary = json.loads(next(line for line in out.splitlines() if line.startswith(SUMMARY_PREFIX))
                         [len(SUMMARY_PREFIX):])
    assert summary["state"] == "failed" and "File too large" in summary["error"]
    event = next(e for e in node.events if e.code == "write_failed")
    assert event.severity == SessionEvent.ERROR and "--recover" in event.text
    assert "write_failed" in err or "failed" in err
    scan = scan_session(path)
    assert not scan.complete and scan.file_bytes <= 120_000
    assert scan.message_count == summary["flushed_messages"]
    recovered = list(iter_messages(path, MEAS, recover=True))
    assert 1 <= len(recovered) < 12
    for m in recovered:
        assert m.data == node.blocks[MEAS][deserialize_message(m.data, SampleBlock).first_index]
