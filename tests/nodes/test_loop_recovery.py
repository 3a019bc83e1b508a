"""Issue 21: a loop message lost on the way costs milliseconds, not the session, and changes no sample.

A lossy relay, a real node between the two loop nodes (the sender's topic remapped to it), drops
chosen messages the first time their index passes; the plant notices the loop standing still after
``resend_after_s``, asks again, and the session records exactly the samples of a run without loss.
"""

from __future__ import annotations

import numpy as np
import pytest
from ambid_nodes.conversions import BadMessage, block_data, decode_message
from ambid_nodes.plant_sim import PlantSim
from ambid_nodes.position_controller import PositionController
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message

from ambid_msgs.msg import Sample, SampleBlock, SessionEvent, SessionStatus
from ambid_nodes import qos
from proc_tree import kill_tree
from ambid.channels import RADIAL

MEASUREMENT_NAMES = RADIAL.measurement_names  # the default rig's channels

SIM_S = 0.6  # 6000 samples: lift-off and settling
# the flood between processes is sent once the test has heard 2000 samples: the loop must still be running when
# it lands (a quiet machine runs 6000 samples between two processes before 5000 messages are out)
FLOOD_SIM_S = 3.0


class LossyRelay(Node):
    """Forwards the raw Samples of ``src`` to ``dst``, dropping the first copy of every index in ``drop``."""

    def __init__(self, context, ns: str, name: str, src: str, dst: str, drop: set[int]):
        super().__init__(name, namespace=ns, context=context)
        self.drop, self.dropped = set(drop), []
        self.pub = pub = self.create_publisher(Sample, dst, qos.LOOP)
        self.forward = pub.publish

        def relay(data: bytes) -> None:
            k = int.from_bytes(data[4:12], "little")
            if k in self.drop:
                self.drop.discard(k)
                self.dropped.append(k)
                return
            self.forward(data)

        self.create_subscription(Sample, src, relay, qos.subscription(qos.LOOP), raw=True)


class Blocks(Node):
    def __init__(self, context, ns: str):
        super().__init__("blocks", namespace=ns, context=context)
        self.raw: list[bytes] = []
        self.create_subscription(SampleBlock, "measurement", self.raw.append, qos.subscription(qos.BLOCKS), raw=True)

    def records(self) -> tuple[np.ndarray, np.ndarray]:
        msgs = [deserialize_message(b, SampleBlock) for b in self.raw]
        msgs.sort(key=lambda m: m.first_index)
        assert [m.first_index for m in msgs] == [1000 * i for i in range(len(msgs))]
        return (np.vstack([block_data(m, MEASUREMENT_NAMES) for m in msgs]),
                np.concatenate([np.asarray(m.sample_flags) for m in msgs]))


def run_loop(ros, pipeline: bool, drop_ic: set[int] = frozenset(), drop_y: set[int] = frozenset(),
             sim_s: float = SIM_S):
    """One session of ``sim_s``, seed 3; with drops, each loop topic passes a LossyRelay."""
    ns = "/lossy" if drop_ic or drop_y else "/clean"  # each run its own names
    plant_args, ctrl_args = [], []
    relays = []
    if drop_ic or drop_y:
        plant_args = ["--ros-args", "-r", "displacement:=displacement_lossy"]
        ctrl_args = ["--ros-args", "-r", "control_current:=control_current_lossy"]
        relays = [ros.add(LossyRelay(ros.context, ns, "relay_y", "displacement_lossy", "displacement", drop_y)),
                  ros.add(LossyRelay(ros.context, ns, "relay_ic", "control_current_lossy", "control_current", drop_ic))]
    blocks = ros.add(Blocks(ros.context, ns))
    plant = ros.add(PlantSim(namespace=ns, context=ros.context, cli_args=plant_args, parameter_overrides=[
        Parameter("sim_seconds", value=sim_s), Parameter("seed", value=3)]))
    ros.matched(blocks, to=plant)  # every block heard
    if relays:  # the plant's side of each relay matched before the controller starts the loop
        ros.matched(relays[1].pub)
        ros.matched(relays[0], to=plant)
    ctrl = ros.add(PositionController(namespace=ns, context=ros.context, cli_args=ctrl_args, parameter_overrides=[
        Parameter("pipeline", value=pipeline)]))
    assert ros.spin_until(plant.finished.done, timeout_s=120)
    n = int(round(sim_s / plant.dt))
    assert ros.spin_until(lambda: sum(deserialize_message(b, SampleBlock).n_samples for b in blocks.raw) == n, 10)
    summary = plant.finished.result()
    ros.retire(plant, ctrl, blocks, *relays)
    return summary, ctrl.answers_repeated, blocks.records(), relays


@pytest.mark.parametrize("pipeline", [True, False], ids=["ic[k+1]", "ic[k]"])
def test_lost_loop_messages_are_recovered_with_the_same_samples(ros, pipeline):
    clean, _, (ref, ref_flags), _ = run_loop(ros, pipeline)
    # (a loaded machine may stall the clean run's loop for the 20 ms that make the plant ask again: the samples are
    # the same either way, which is what is compared below)
    assert clean["state"] == "done"
    # every 997th current and every 1499th displacement lost once, at every phase of the lock-step
    drop_ic = set(range(996, 6000, 997))
    drop_y = set(range(1498, 6000, 1499))
    lossy, repeated, (rec, flags), relays = run_loop(ros, pipeline, drop_ic, drop_y)
    lost = sum(len(r.dropped) for r in relays)
    assert lost == len(drop_ic) + len(drop_y)
    assert lossy["state"] == "done" and lossy["levitated"], lossy
    # the same samples, bit for bit: y, u, ic, r and flags of every row
    assert rec.shape == ref.shape and np.array_equal(rec.view(np.uint64), ref.view(np.uint64))
    assert np.array_equal(flags, ref_flags)
    assert lossy["resends"] >= lost and repeated >= 1
    print(f"lead {int(pipeline)}: {lost} loop messages dropped, {lossy['resends']} resends (clean run "
          f"{clean['resends']}), {repeated} answers "
          f"repeated, {lossy['duplicate_answers']} duplicates; records identical ({rec.shape[0]} samples)")


class Flood(Node):
    """Publishes, unpaced, a few thousand malformed and foreign messages on each subscribed topic."""

    def __init__(self, context, ns: str):
        super().__init__("flood", namespace=ns, context=context)
        from test_fuzz import QOS, TYPES
        self.topics = ("control_current", "displacement", "excitation", "excitation/design", "status")
        self.pubs = {t: self.create_publisher(TYPES[t], t, QOS[t]) for t in self.topics}
        from test_fuzz import Fuzzer
        f = Fuzzer(7)
        # made before the session: indices in the past (near = 1), where a valid design or block is refused
        self.payloads = {t: f.payloads(t, 1000, 1) for t in self.topics}

    def send(self) -> int:
        sent = 0
        for t in self.topics:
            for p in self.payloads[t]:
                self.pubs[t].publish(p)
                sent += 1
        return sent


def test_a_flood_on_every_subscribed_topic_changes_no_sample(ros):
    """Composed, the pump's layout: 5 x 1000 unpaced messages mid-session, the records bit-identical."""
    clean, _, (ref, ref_flags), _ = run_loop(ros, True)
    ns = "/clean"
    flood = ros.add(Flood(ros.context, ns))
    blocks = ros.add(Blocks(ros.context, ns))
    plant = ros.add(PlantSim(namespace=ns, context=ros.context, parameter_overrides=[
        Parameter("sim_seconds", value=SIM_S), Parameter("seed", value=3)]))
    ros.matched(blocks, to=plant)
    ros.matched(flood, to=plant)  # the flood reaches the plant (its loop subscription is counted below)
    ctrl = ros.add(PositionController(namespace=ns, context=ros.context))
    ros.matched(*flood.pubs.values())
    assert ros.spin_until(lambda: plant.k >= 2000, 60)
    sent = flood.send()
    assert ros.spin_until(plant.finished.done, timeout_s=120)
    assert ros.spin_until(lambda: sum(deserialize_message(b, SampleBlock).n_samples for b in blocks.raw) == ref.shape[0],
                          10)
    s = plant.finished.result()
    rec, flags = blocks.records()
    assert s["state"] == "done" and s["levitated"], s
    assert np.array_equal(rec.view(np.uint64), ref.view(np.uint64)) and np.array_equal(flags, ref_flags)
    rejected = plant.intake.total_rejected + ctrl.intake.total_rejected
    print(f"flood of {sent} messages during the session: {rejected} rejected by plant and controller, "
          f"{s['resends']} resends; records identical")
    assert sent == 5000 and rejected > 0


FLOOD_ATTEMPTS = 3  # sessions flooded at most, until one whose plant refused the flood mid-run


def test_a_flood_between_processes_changes_no_sample(ros, ros_env):
    """plant_sim and position_controller as processes (graph --processes), flooded from a third
    process mid-session: levitated, and the samples of the composed run without a flood.

    The flood goes out once this process has heard 2000 samples; on a loaded machine this process may hear
    them late and its flood reach the plant after its run (CI at load 7-10: 'rejected 0', nothing tested). The
    plant's rejected_message events say at which sample it refused the flood: a session whose plant refused
    none before its run's end tested nothing, and is run again (each one's records compared)."""
    _, _, (ref, ref_flags), _ = run_loop(ros, True, sim_s=FLOOD_SIM_S)
    for attempt in range(1, FLOOD_ATTEMPTS + 1):
        mid_run, final = flooded_session(ros, ros_env, f"/procs{attempt}", ref, ref_flags)
        if mid_run:
            break
        print(f"attempt {attempt}: the plant refused none of the flood before its run's end (rejected "
              f"{final['rejected:control_current']} control_current in all); the session is run again")
    assert mid_run, f"{FLOOD_ATTEMPTS} flooded sessions, none with the flood refused mid-run: nothing tested"
    # the loop topic's flood is refused as it comes; the excitation flood may still wait in the plant's queue
    # when its run ends (the count is the final status's): refused, never applied, the records say so
    assert int(final["rejected:control_current"]) > 0, str({k: v for k, v in final.items() if ":" in k})
    print(f"processes: flood of 5000, the plant rejected {final['rejected:control_current']} control_current "
          f"({mid_run} refusals reported mid-run, attempt {attempt}), {final['rejected:excitation']} excitation, "
          f"asked again {final['resends']} times; records identical")


def flooded_session(ros, ros_env, ns: str, ref: np.ndarray, ref_flags: np.ndarray) -> tuple[int, dict]:
    """One session of the two processes in ``ns``, flooded once 2000 samples were heard; its records compared
    with ``ref``. Returns the plant's rejected_message events at a sample before its run's end, and its
    final status's figures."""
    import os
    import subprocess
    import sys

    from ambid_nodes.supervisor import ros_args
    blocks = ros.add(Blocks(ros.context, ns))
    flood = ros.add(Flood(ros.context, ns))
    env = dict(ros_env)
    cwd = os.path.join(os.path.dirname(__file__), "..", "..", "ambid_nodes")
    n = ref.shape[0]

    def start(mod: str, params: dict) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", f"ambid_nodes.{mod}", *ros_args(ns, params)], env=env,
                                cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)

    statuses, refused_at = [], []

    def on_status(data: bytes) -> None:  # raw: the flood's malformed status must not reach rosidl here
        try:
            m = decode_message(data, SessionStatus, "status")
        except BadMessage:
            return
        statuses.append((m.node, m.state, m.text, dict(zip(m.keys, m.values))))

    def on_event(data: bytes) -> None:
        m = decode_message(data, SessionEvent, "events")
        if m.node.endswith("plant_sim") and m.code == "rejected_message":
            refused_at.append(m.sample_index)

    blocks.create_subscription(SessionStatus, "status", on_status, qos.subscription(qos.STATUS), raw=True)
    blocks.create_subscription(SessionEvent, "events", on_event, qos.subscription(qos.EVENTS), raw=True)
    # the plant first, and the controller once this process is matched to it: the loop cannot start
    # (and its first blocks go out) before the recording listener hears them
    procs = [start("plant_sim", {"sim_seconds": FLOOD_SIM_S, "seed": 3})]
    try:
        ros.matched(blocks)
        # the flood reaches the plant's topics before the loop starts: its run may be over before a later match
        ros.matched(*(flood.pubs[t] for t in ("control_current", "excitation", "excitation/design")))
        procs.insert(0, start("position_controller", {}))
        got = lambda: sum(deserialize_message(b, SampleBlock).n_samples for b in blocks.raw)  # noqa: E731

        def wait(predicate, timeout_s: float, what: str) -> None:
            if not ros.spin_until(predicate, timeout_s):
                for p in procs:
                    p.kill()
                tails = [p.communicate()[1][-1500:] for p in procs]
                raise AssertionError(f"{what}: {got()} samples recorded; status {statuses[-4:]}; stderr: {tails}")

        wait(lambda: got() >= 2000, 120, "the loop levitates")
        ros.matched(flood.pubs["displacement"])  # and the controller's (the plant's were matched before it started)
        assert flood.send() == 5000
        wait(lambda: got() == n, 120, "the loop runs to its end under the flood")
        errs = [procs[1].communicate(timeout=30)[1]]  # the plant exits by itself once its run is done
        assert procs[1].returncode == 0, errs[0][-2000:]
        procs[0].terminate()
        errs.append(procs[0].communicate(timeout=20)[1])
    finally:
        for p in procs:
            kill_tree(p)
    rec, flags = blocks.records()
    assert np.array_equal(rec.view(np.uint64), ref.view(np.uint64)) and np.array_equal(flags, ref_flags)
    assert ros.spin_until(lambda: any(st[0].endswith("plant_sim") and st[1] == SessionStatus.STATE_DONE
                                      for st in statuses), 5)
    final = next(st[3] for st in statuses[::-1] if st[0].endswith("plant_sim"))
    # every event the plant published before its final status is here: events are reliable and latched, and
    # were sent before the status that said done
    ros.spin_until(lambda: False, 0.5)
    # nothing unattributed on stderr: every line a node's log line (rosidl's refusals are walked first)
    stray = [line for e in errs for line in e.splitlines() if line.strip() and not line.startswith("[")]
    assert not stray, "\n".join(stray[:40])
    ros.retire(blocks, flood)
    return sum(1 for k in refused_at if k < n), final
