"""The lock-step loop of plant_sim and position_controller over real DDS."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from ambid_nodes.conversions import block_data
from ambid_nodes.loop_kernels import LOOP_COUNT, LOOP_GATE
from ambid_nodes.parameters import ParameterError
from ambid_nodes.plant_sim import PlantSim
from ambid_nodes.position_controller import PositionController
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile

from ambid_msgs.msg import ControllerDescription, PlantDescription, Sample, SampleBlock, SessionEvent, SessionStatus
from ambid_nodes import qos
from proc_tree import alive, descendants
from ambid.channels import RADIAL

MEASUREMENT_NAMES = RADIAL.measurement_names  # the default rig's channels

NS = "/amb"


class Spy(Node):
    """Records what crosses the loop topics."""

    def __init__(self, context):
        super().__init__("spy", namespace=NS, context=context)
        self.y_idx, self.ic_idx, self.blocks, self.events = [], [], [], []
        self.plant_desc = self.ctrl_desc = None
        self.create_subscription(Sample, "displacement", lambda m: self.y_idx.append(m.index),
                                 qos.subscription(qos.LOOP))
        self.create_subscription(Sample, "control_current", lambda m: self.ic_idx.append(m.index),
                                 qos.subscription(qos.LOOP))
        self.create_subscription(SampleBlock, "measurement", self.blocks.append, qos.BLOCKS)
        self.create_subscription(SessionEvent, "events", self.events.append, qos.EVENTS)
        self.statuses = []
        self.create_subscription(SessionStatus, "status", self.statuses.append, QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=100, reliability=qos.STATUS.reliability,
            durability=qos.STATUS.durability))
        self.create_subscription(PlantDescription, "plant/description", lambda m: setattr(self, "plant_desc", m),
                                 qos.LATCHED)
        self.create_subscription(ControllerDescription, "controller/description",
                                 lambda m: setattr(self, "ctrl_desc", m), qos.LATCHED)


def sent_again(heard: list[int], n: int) -> tuple[int, int]:
    """The displacements a spy heard, taken apart: y[0] .. y[n - 1] in order, and what the plant sent again
    where the loop stood still (a lost message, or only a starved process on a busy machine): after y[0] y[0]
    again (a start retry), after y[k] the pair y[k - 1], y[k] (a resend), any number of times. Returns
    (start retries, resends); fails on anything else."""
    i = retries = resends = 0
    for k in range(n):
        assert heard[i:i + 1] == [k], f"y[{k}] expected at message {i}, heard {heard[max(0, i - 3):i + 4]}"
        i += 1
        while k == 0 and heard[i:i + 1] == [0]:
            retries, i = retries + 1, i + 1
        while k > 0 and heard[i:i + 2] == [k - 1, k]:
            resends, i = resends + 1, i + 2
    assert i == len(heard), f"after y[{n - 1}]: {heard[i:i + 5]}"
    return retries, resends


def answered_again(heard: list[int], n: int) -> int:
    """The currents a spy heard: ic[0] .. ic[n - 1] each first heard in order; every other message repeats one of
    the last three currents heard (an answer given again to a displacement the plant sent again). Returns the
    repeats."""
    assert list(dict.fromkeys(heard)) == list(range(n))
    newest, repeats = -1, 0
    for index in heard:
        if index <= newest:
            assert index >= newest - 2, f"ic[{index}] again after ic[{newest}]"
            repeats += 1
        newest = max(newest, index)
    return repeats


def assert_every_sample_once(spy, summary: dict, n: int, lead: int) -> None:
    """The spy heard every displacement and current of the loop in order, once each, except what the plant sent
    again and counted (resends, start retries) and the controller's answers to that: one per displacement, two
    to y[0] of a pipelined controller (ic[0], ic[1])."""
    retries, resends = summary["start_retries"], summary["resends"]
    assert ros_heard(spy, n + retries + 2 * resends, "y_idx"), (len(spy.y_idx), summary)
    assert sent_again(spy.y_idx, n) == (retries, resends), summary
    most = n + lead + 2 * resends + (1 + lead) * retries
    assert ros_heard(spy, n + lead, "ic_idx", most), (len(spy.ic_idx), summary)
    repeats = answered_again(spy.ic_idx, n + lead)
    assert repeats <= most - n - lead
    print(f"lead {lead}: {retries} start retries, {resends} resends, {repeats} currents repeated")


def ros_heard(spy, n: int, what: str, most: int | None = None) -> bool:
    """Spin until the spy heard at least n messages of ``what`` (where up to ``most`` may come, until no more come
    for 0.5 s: the answers to what was sent again); False if fewer than n or more than ``most`` (default n)."""
    ros = spy.ros
    heard = getattr(spy, what)
    most = n if most is None else most
    if not ros.spin_until(lambda: len(heard) >= n, timeout_s=5):
        return False
    seen = -1
    while most > n and len(heard) != seen:  # the last repeated answers may still be on their way
        seen = len(heard)
        ros.spin_until(lambda: False, 0.5, scale=False)
    return n <= len(heard) <= most


def make_loop(ros, sim_seconds: float, controller_params=(), **plant_params):
    """A spy and the plant, matched, then the controller: its arrival starts the loop, so the spy hears
    every message of it."""
    spy = ros.add(Spy(ros.context))
    spy.ros = ros
    plant = ros.add(PlantSim(namespace=NS, context=ros.context, parameter_overrides=[
        Parameter("sim_seconds", value=sim_seconds), *(Parameter(k, value=v) for k, v in plant_params.items())]))
    ros.matched(spy, to=plant)
    ctrl = ros.add(PositionController(namespace=NS, context=ros.context, parameter_overrides=[
        Parameter(k, value=v) for k, v in controller_params]))
    return plant, ctrl, spy


def test_lockstep_10000_steps_levitates_from_rest(ros):
    plant, ctrl, spy = make_loop(ros, 1.0, block_size=2000)
    assert ros.spin_until(plant.finished.done, timeout_s=120)
    s = plant.finished.result()
    # every sample index in order on both loop topics, once but for what the plant asked again; the controller
    # (one sample of computational delay) answers y[k] with ic[k + 1], y[0] with ic[0] and ic[1]
    assert_every_sample_once(spy, s, 10_000, lead=1)
    assert s["state"] == "done" and s["levitated"], s
    assert s["contact_samples"] > 0  # it started on the retainer ...
    assert s["lift_off_index"] is not None and s["lift_off_index"] < 2000  # ... and lifted off
    assert s["max_abs_displacement_m"] < 0.5 * plant.rig.backup_clearance_m
    assert s["messages_rejected"] == 0
    # measurement blocks: contiguous, all channels, finite
    assert ros.spin_until(lambda: sum(b.n_samples for b in spy.blocks) == 10_000, timeout_s=10)
    starts = [b.first_index for b in spy.blocks]
    assert starts == list(range(0, 10_000, 2000))
    data = block_data(spy.blocks[-1], MEASUREMENT_NAMES)
    assert data.shape == (2000, 16)
    # u = ic + r column-wise, r = 0 without excitation
    assert (data[:, 4:8] == data[:, 8:12] + data[:, 12:16]).all()
    # latched descriptions reach a subscriber
    assert ros.spin_until(lambda: spy.plant_desc is not None and spy.ctrl_desc is not None, timeout_s=5)
    assert list(spy.plant_desc.displacement_names) == ["y_a_x", "y_b_x", "y_a_y", "y_b_y"]
    assert spy.ctrl_desc.model.sample_period == pytest.approx(1e-4)
    assert spy.ctrl_desc.delay_samples == 1
    # the plant's status: one at the first block end past each 10,000 samples while running, and the last
    def plant_status():  # (an idle status may come first: the plant waited for the controller)
        return [(m.state, m.sample_index) for m in spy.statuses
                if m.node == plant.fqn and m.state != SessionStatus.STATE_IDLE]

    assert ros.spin_until(lambda: len(plant_status()) >= 2, timeout_s=5)
    # (then the done one again, once a second, while messages still come: the pipelined ic[10000], repeats)
    running, *done = plant_status()
    assert running == (SessionStatus.STATE_RUNNING, 10_000)
    assert done and set(done) == {(SessionStatus.STATE_DONE, 10_000)}


def test_pipelined_controller_gives_the_same_samples_as_lock_step_answers(ros):
    """Answering y[k] with ic[k + 1] changes when the currents travel, not one recorded number."""
    runs = {}
    for pipeline in (True, False):
        # the spy matched before the controller joins: it hears the loop from y[0] on
        plant, ctrl, spy = make_loop(ros, 0.3, [("pipeline", pipeline)], seed=5, block_size=1000)
        assert ros.spin_until(plant.finished.done, timeout_s=120)
        s = plant.finished.result()
        assert s["messages_rejected"] == 0, s
        assert ros.spin_until(lambda: sum(b.n_samples for b in spy.blocks) == 3000, timeout_s=10)
        assert_every_sample_once(spy, s, 3000, lead=int(pipeline))
        runs[pipeline] = np.vstack([block_data(b, MEASUREMENT_NAMES) for b in spy.blocks])
        ros.retire(spy, plant, ctrl)
    assert np.array_equal(runs[True], runs[False])
    assert np.abs(runs[True][:, 8:12]).max() > 0.1  # the controller did carry the rotor


@pytest.mark.parametrize("user_controller", [False, True], ids=["pid", "user_file"])
def test_compiled_callbacks_give_the_same_samples_as_the_python_path(ros, monkeypatch, tmp_path, user_controller):
    """The kernels the subscription callbacks run and the nodes' Python path record the same numbers, for the
    default PID and for a user's controller file (a dense one: the LQG's matrices saved as .npz)."""
    controller = ""
    if user_controller:
        from ambid.control.lqg import lqg_controller
        from ambid.plant.rig import make_rig

        model = lqg_controller(make_rig())
        controller = str(tmp_path / "dense.npz")
        np.savez(controller, A=model.a, B=model.b, C=model.c, D=model.d, dt=model.dt)
    runs = {}
    for compiled in (True, False):
        if not compiled:  # the gates stay closed: every message goes the Python way
            monkeypatch.setattr(PlantSim, "regate", lambda self: self.fast.set(LOOP_GATE, 0))
            monkeypatch.setattr(PositionController, "regate", lambda self: self.fast.set(LOOP_GATE, 0))
        # the paths' numbers are under test, not the watchdog: a starved machine may hold an answer past 2 s
        plant, ctrl, spy = make_loop(ros, 0.3, [("controller", controller)], seed=5, block_size=1000,
                                     controller_timeout_s=30.0)
        assert ctrl.design.kind == ("file" if user_controller else "pid")
        assert ros.spin_until(plant.finished.done, timeout_s=120)
        summary = plant.finished.result()
        assert summary["messages_rejected"] == 0 and summary["accepted:control_current"] >= 3000, (
            summary, [e.message for e in spy.events])
        # the compiled callbacks answered nearly every message, or none
        answered = (int(plant.fast.context[LOOP_COUNT]), int(ctrl.fast.context[LOOP_COUNT]))
        if compiled:
            assert min(answered) > 2900, answered
        else:
            assert answered == (0, 0)
        assert ros.spin_until(lambda: sum(b.n_samples for b in spy.blocks) == 3000, timeout_s=10)
        runs[compiled] = np.vstack([block_data(b, MEASUREMENT_NAMES) for b in spy.blocks])
        ros.retire(spy, plant, ctrl)
    assert np.array_equal(runs[True], runs[False])
    assert np.abs(runs[True][:, 8:12]).max() > 0.1  # the controller did carry the rotor


def test_declared_parameters_have_descriptions_and_ranges(ros):
    plant = ros.add(PlantSim(namespace=NS, context=ros.context))
    ctrl = ros.add(PositionController(namespace=NS, context=ros.context))
    for node in (plant, ctrl):
        names = [n for n in node._parameters if n != "use_sim_time"]
        assert names
        for name in names:
            d = node.describe_parameter(name)
            assert d.description, f"{node.get_name()}.{name} has no description"
            if d.type in (2, 3):  # integer, double
                assert d.integer_range or d.floating_point_range, f"{node.get_name()}.{name} has no range"


@pytest.mark.parametrize("params, fragment", [
    ({"sim_second": 1.0}, "unknown parameter(s) ['sim_second']"),
    ({"block_size": 0}, "'block_size' is invalid (allowed range [1, 100000])"),
    ({"rig_file": "/nonexistent/rig.yaml"}, "does not exist"),
])
def test_bad_plant_parameters_named(ros, params, fragment):
    with pytest.raises((ParameterError, ValueError)) as err:
        PlantSim(namespace=NS, context=ros.context, parameter_overrides=[Parameter(k, value=v)
                                                                         for k, v in params.items()])
    assert fragment in str(err.value)


def test_unstable_controller_refused_naming_poles(ros):
    with pytest.raises(ParameterError) as err:
        PositionController(namespace=NS, context=ros.context, parameter_overrides=[Parameter("kp_a_per_m", value=100.0)])
    assert "unstable poles" in str(err.value) and "Hz" in str(err.value)


class BadController(Node):
    """Answers like a controller but corrupts some answers."""

    def __init__(self, context):
        super().__init__("bad_controller", namespace=NS, context=context)
        from ambid.control.pid import PidParameters, pid_controller
        from ambid.control.stepper import ControllerStepper
        self.ctl = ControllerStepper(pid_controller(PidParameters(), 1e-4), 3.0)
        self.pub = self.create_publisher(Sample, "control_current", qos.LOOP)
        self.create_subscription(Sample, "displacement", self.on_y, qos.LOOP)

    def on_y(self, m):
        ic = self.ctl.step(list(m.values))
        if m.index == 3000:
            self.pub.publish(Sample(index=m.index, values=[float("nan")] * 4))
        elif m.index == 3001:
            self.pub.publish(Sample(index=m.index, values=[0.0] * 3))
        else:
            if m.index == 3002:  # a stale duplicate first
                self.pub.publish(Sample(index=m.index - 1, values=ic))
            self.pub.publish(Sample(index=m.index, values=ic))


class SlowStarter(Node):
    """A lock-step controller slow to its first answer (a process still starting on a busy machine): it answers
    y[0] 0.6 s after it first heard it (by then the plant has sent it again), every y[0] heard by then and after
    with that same answer, every later y at once."""

    def __init__(self, context):
        super().__init__("slow_starter", namespace=NS, context=context)
        from ambid.control.pid import PidParameters, pid_controller
        from ambid.control.stepper import ControllerStepper
        self.ctl = ControllerStepper(pid_controller(PidParameters(), 1e-4), 3.0)
        self.pub = self.create_publisher(Sample, "control_current", qos.LOOP)
        self.create_subscription(Sample, "displacement", self.on_y, qos.subscription(qos.LOOP))
        self.first: list[Sample] = []  # every y[0] heard
        self.ic0 = None

    def on_y(self, m):
        if m.index > 0:
            self.pub.publish(Sample(index=m.index, values=self.ctl.step(list(m.values))))
            return
        self.first.append(m)
        if self.ic0 is not None:  # the same answer again, as position_controller gives it
            self.pub.publish(Sample(index=0, values=self.ic0))
        elif len(self.first) == 1:
            self.timer = self.create_timer(0.6, self.answer_first)

    def answer_first(self):
        self.timer.cancel()
        self.ic0 = self.ctl.step(list(self.first[0].values))
        for _ in self.first:
            self.pub.publish(Sample(index=0, values=self.ic0))


def test_the_answers_to_a_start_retry_are_duplicates_not_rejected(ros):
    """Until its first answer the plant sends y[0] again every START_RETRY_S; the controller answers each, and the
    answers after the first are duplicates the plant asked for: counted, never rejected as stale."""
    spy = ros.add(Spy(ros.context))
    spy.ros = ros
    plant = ros.add(PlantSim(namespace=NS, context=ros.context,
                             parameter_overrides=[Parameter("sim_seconds", value=0.2)]))
    ros.matched(spy, to=plant)
    starter = ros.add(SlowStarter(ros.context))
    assert ros.spin_until(plant.finished.done, timeout_s=120)
    s = plant.finished.result()
    assert s["start_retries"] >= 1, s  # at 0.25 s: before the answer at 0.6 s
    assert s["messages_rejected"] == 0 and s["state"] == "done", (s, [e.text for e in spy.events])
    assert_every_sample_once(spy, s, 2000, lead=0)
    # the starter's answers to y[0] beyond the first (it may have matched after the first y[0]), the resends'
    assert ros.spin_until(lambda: plant.duplicate_answers == len(starter.first) - 1 + 2 * s["resends"], 5), s
    assert plant.intake.total_rejected == 0


def test_bad_control_messages_rejected_counted_loop_survives(ros):
    spy = ros.add(Spy(ros.context))
    plant = ros.add(PlantSim(namespace=NS, context=ros.context,
                             parameter_overrides=[Parameter("sim_seconds", value=0.5)]))
    ros.matched(spy, to=plant)
    ros.add(BadController(ros.context))
    assert ros.spin_until(plant.finished.done, timeout_s=120)
    s = plant.finished.result()
    assert s["messages_rejected"] == 3
    assert s["state"] == "done" and s["levitated"]
    assert ros.spin_until(lambda: len([e for e in spy.events if e.code == "rejected_message"]) == 3, timeout_s=5)
    texts = " | ".join(e.text for e in spy.events if e.code == "rejected_message")
    assert "non-finite" in texts and "3 values, expected 4" in texts and "stale or duplicated" in texts


def test_processes_layout_runs_and_ctrl_c_leaves_nothing(ros, ros_env, procs):
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    cmd = [sys.executable, "-m", "ambid_cli.cli", "graph", "--processes", "--sim-seconds", "0.3"]
    done = procs(cmd, env=ros_env, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out = done.communicate(timeout=180)[0]  # on a timeout the procs fixture stops the whole tree
    assert done.returncode == 0, out
    assert "simulated samples per wall second" in out and "rotor levitated" in out

    # Ctrl-C in the middle of a long run stops every process it started; the loop is seen running first
    blocks = []
    listener = ros.add(Node("listener", namespace=NS, context=ros.context))
    listener.create_subscription(SampleBlock, "measurement", lambda m: blocks.append(m.first_index),
                                 qos.subscription(qos.BLOCKS), raw=False)
    # started as a script's background job is: SIGINT ignored on entry (the shell's doing), ^C must still stop it
    runner = procs([*cmd[:-1], "1000"], env=ros_env, cwd=root, stdout=subprocess.PIPE,
                   stderr=subprocess.STDOUT, text=True,
                   preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    assert ros.spin_until(lambda: len(blocks) >= 2 or runner.poll() is not None, 180), "the loop never ran"
    assert runner.poll() is None, runner.communicate()[0]
    children = descendants(runner.pid)
    assert len(children) >= 2, f"runner did not start plant and controller: {children}"
    os.killpg(runner.pid, signal.SIGINT)  # what a terminal's Ctrl-C does
    runner.wait(timeout=60)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and [c for c in children if alive(c)]:
        time.sleep(0.1)
    assert [c for c in children if alive(c)] == [], "processes left behind"
    assert runner.returncode in (1, 130)


def test_single_node_main_reports_bad_yaml(tmp_path, ros_env):
    bad = tmp_path / "bad.yaml"
    bad.write_text("/**:\n  ros__parameters:\n    seed: [unclosed\n")
    out = subprocess.run([sys.executable, "-m", "ambid_nodes.plant_sim", "--ros-args", "--params-file", str(bad)],
                         env=ros_env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert "parameter YAML" in out.stderr or "params-file" in out.stderr.lower()


def test_every_node_installed_with_entry_point_and_parameter_file(ros_env):
    """package.xml/setup.py say the truth: each node runs from its entry point with its shipped YAML."""
    from ament_index_python.packages import get_package_prefix, get_package_share_directory

    names = ["plant_sim", "position_controller", "excitation_generator", "frf_consumer", "recorder",
             "hardware_bridge"]  # the design brief's node graph
    prefix = get_package_prefix("ambid_nodes")
    share = get_package_share_directory("ambid_nodes")
    for name in names:
        assert os.access(os.path.join(prefix, "lib", "ambid_nodes", name), os.X_OK), f"no executable for {name}"
        assert os.path.isfile(os.path.join(share, "config", f"{name}.yaml")), f"no config/{name}.yaml"
    # the plant's shipped YAML loads, and the node refuses to run past it with a bad override only
    out = subprocess.run([os.path.join(prefix, "lib", "ambid_nodes", "plant_sim"), "--ros-args", "--params-file",
                          os.path.join(share, "config", "plant_sim.yaml"), "-p", "block_size:=-1"],
                         env=ros_env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "block_size" in out.stderr, out.stderr


def _cli(args, env, timeout=120):
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    return subprocess.run([sys.executable, "-m", "ambid_cli.cli", *args], env=env, cwd=root, capture_output=True,
                          text=True, timeout=timeout)


def test_graph_with_lqg_controller_levitates(ros_env):
    out = _cli(["graph", "--controller", "lqg", "--sim-seconds", "0.4"], ros_env)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "LQG controller" in out.stdout and "rotor levitated" in out.stdout


def test_graph_against_hardware_target_over_loopback(ros_env, tmp_path):
    import socket

    from ambid.hardware.link_key import write_key_file

    key = tmp_path / "rig.key"
    write_key_file(key)

    ports = []
    for _ in range(2):  # two free UDP ports
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        ports.append(s.getsockname()[1])
        s.close()
    target = subprocess.Popen([sys.executable, "-m", "ambid.hardware.rt_target", "--bind", f"127.0.0.1:{ports[0]}",
                               "--bridge", f"127.0.0.1:{ports[1]}", "--pace", "0", "--samples", "20000",
                               "--key-file", str(key)],
                              env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out = _cli(["graph", "--hardware", f"127.0.0.1:{ports[0]}", "--local-port", str(ports[1]),
                    "--key-file", str(key), "--sim-seconds", "0.3"], ros_env)
        assert out.returncode == 0, out.stdout + out.stderr
        assert "lost 0 samples in 0 gaps" in out.stdout and "target running normally" in out.stdout
    finally:
        target.terminate()
        target.wait(timeout=30)


class LateController(BadController):
    """Misses the first y[0], as a controller whose subscription matched a moment too late does."""

    def __init__(self, context):
        super().__init__(context)
        self.missed = False

    def on_y(self, m):
        if m.index == 0 and not self.missed:
            self.missed = True
            return
        self.pub.publish(Sample(index=m.index, values=self.ctl.step(list(m.values))))


def test_loop_starts_when_the_first_sample_is_missed(ros):
    plant = ros.add(PlantSim(namespace=NS, context=ros.context,
                             parameter_overrides=[Parameter("sim_seconds", value=0.2)]))
    ctrl = ros.add(LateController(ros.context))
    assert ros.spin_until(plant.finished.done, timeout_s=60)
    assert ctrl.missed and plant.finished.result()["state"] == "done"


def test_the_loop_waits_for_its_named_readers_not_for_any_listener(ros):
    """A listener the session does not wait for (a monitor, a test's) makes up plant_sim's count of measurement
    readers as well as the recorder would: the plant waits to see the named reader subscribed too, and the reader
    gets the measurement from sample 0 (a drill's recorder, matched after a test's listener, once lost the first
    8000 samples of its session so)."""
    monitor = ros.add(Node("monitor", namespace=NS, context=ros.context))
    monitor.create_subscription(SampleBlock, "measurement", lambda m: None, qos.subscription(qos.BLOCKS))
    plant = ros.add(PlantSim(namespace=NS, context=ros.context, parameter_overrides=[
        Parameter("sim_seconds", value=0.2), Parameter("measurement_readers", value=1),
        Parameter("measurement_reader_nodes", value=["recorder"])]))
    ctrl = ros.add(PositionController(namespace=NS, context=ros.context))
    ros.matched(monitor, ctrl, to=plant)
    ros.spin_until(lambda: False, 1.0, scale=False)   # 20 of the plant's start checks: all but the name are met
    assert plant.k == 0 and not plant.finished.done()
    got: list = []
    recorder = ros.add(Node("recorder", namespace=NS, context=ros.context))
    recorder.create_subscription(SampleBlock, "measurement", got.append, qos.subscription(qos.BLOCKS))
    assert ros.spin_until(plant.finished.done, timeout_s=120)
    assert plant.finished.result()["state"] == "done"
    assert ros.spin_until(lambda: sum(b.n_samples for b in got) == 2000, 30)
    assert min(b.first_index for b in got) == 0
