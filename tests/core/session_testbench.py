"""Session MCAP files without ROS, and a core-level closed loop to fill them (shared test helper).

Messages are CDR-encoded by mcap_ros2 from the repository's .msg files
(builtin_interfaces/Time from the venv's share directory), so the files
read back exactly like a recorder's.
"""

import json
import sys
from pathlib import Path

import numpy as np
from ambid.recording import SessionWriter
from ambid.recording.ros2_schema import load_message_schema
from mcap_ros2._dynamic import serialize_dynamic

MSG_DIR = Path(__file__).resolve().parents[2] / "ambid_msgs" / "msg"
_TIME_MSG = Path(sys.prefix) / "share" / "builtin_interfaces" / "msg" / "Time.msg"
DEFS = {"builtin_interfaces/msg/Time": (_TIME_MSG.read_text() if _TIME_MSG.is_file()
                                        else "int32 sec\nuint32 nanosec\n"),
        **{f"ambid_msgs/msg/{n}": (MSG_DIR / f"{n}.msg").read_text()
           for n in ("SampleBlock", "ExcitationDesign", "PlantDescription", "StateSpace")}}
SAMPLE_BLOCK = "ambid_msgs/msg/SampleBlock"
EXCITATION_DESIGN = "ambid_msgs/msg/ExcitationDesign"
PLANT_DESCRIPTION = "ambid_msgs/msg/PlantDescription"
_ENCODERS = {}
_ZERO_STAMP = {"sec": 0, "nanosec": 0}


def encoder(type_name):
    """CDR encoder of one message type: dict -> bytes."""
    if type_name not in _ENCODERS:
        schema = load_message_schema(type_name, definitions=DEFS, type_hash="")
        _ENCODERS[type_name] = serialize_dynamic(type_name, schema.definition)[type_name]
    return _ENCODERS[type_name]


def design_message(design, start_index, total_samples=None, experiment_id="exp1"):
    """ExcitationDesign message dict of an ``ambid.excitation.ExcitationDesign``."""
    total = design.total_samples if total_samples is None else total_samples
    return {"stamp": _ZERO_STAMP, "experiment_id": experiment_id, "kind": design.kind,
            "multi_input": design.options.get("mimo", "orthogonal"), "start_index": start_index,
            "total_samples": total, "sample_rate": design.fs_hz, "samples_per_period": design.n_per_period,
            "n_periods": design.n_periods, "n_transient_periods": design.n_transient_periods,
            "n_realisations": design.n_realisations, "n_experiments": design.n_experiments,
            "input_names": list(design.input_names), "excited_lines": design.excited_lines.tolist(),
            "detection_lines_odd": design.detection_lines_odd.tolist(),
            "detection_lines_even": design.detection_lines_even.tolist(),
            "rms": design.rms_a.tolist(), "peak": design.peak_a.tolist(),
            "crest_factor": design.crest_factor.tolist(), "measurement_time": total / design.fs_hz,
            "seed": design.seed or 0, "design_json": json.dumps(design.to_dict())}


def block_message(first, data, names, dt, units=None, experiment_id=""):
    """SampleBlock message dict of ``data`` (n, len(names))."""
    units = units or ["m" if n.startswith("y_") else "A" for n in names]
    return {"stamp": _ZERO_STAMP, "experiment_id": experiment_id, "first_index": int(first),
            "sample_period": dt, "n_samples": len(data), "channel_names": list(names),
            "channel_units": list(units), "data": np.asarray(data, dtype=float).ravel().tolist(),
            "sample_flags": b"", "flags": 0}


def plant_message(rig, seed=0, source="sim"):
    """PlantDescription message dict of an ``ambid.plant.rig.Rig`` (analytical model and rig JSON included)."""
    from ambid.plant.analytical import analytical_model

    ss = analytical_model(rig)
    model = {"sample_period": 0.0, "n_states": ss.n_states, "n_inputs": ss.n_inputs, "n_outputs": ss.n_outputs,
             "a": ss.a.ravel().tolist(), "b": ss.b.ravel().tolist(), "c": ss.c.ravel().tolist(),
             "d": ss.d.ravel().tolist(), "input_names": list(ss.input_names),
             "input_units": list(ss.input_units), "output_names": list(ss.output_names),
             "output_units": list(ss.output_units)}
    return {"stamp": _ZERO_STAMP, "name": "/amb/plant_sim", "source": source, "rig_name": rig.name,
            "sample_period": rig.dt, "displacement_names": list(rig.layout.outputs),
            "current_names": list(rig.layout.inputs), "bias_current": [m.bias_current_a for m in rig.axis_magnets()],
            "current_limit": [rig.current_limit_a] * len(rig.layout),
            "backup_clearance": [c for _, c in rig.backup_bearings()],
            "analytical_model": model, "seed": seed, "controller_timeout_samples": 0,
            "rig_json": json.dumps(rig.to_dict())}


def write_session(path, blocks, names, designs, dt, plant=None, facts=None, namespace="/amb",
                  chunk_size_bytes=200_000):
    """Write a session file.

    Args:
        blocks: [(first_index, data (n, len(names)))] measurement blocks.
        designs: [(log_time_ns, ExcitationDesign message dict)].
        dt: sample period [s].
        plant: PlantDescription message dict, or None.
        facts: session facts to store as ``ambid.session`` metadata, or None.
    """
    topics = {f"{namespace}/measurement": SAMPLE_BLOCK, f"{namespace}/excitation/design": EXCITATION_DESIGN}
    messages = [(t_ns, f"{namespace}/excitation/design", encoder(EXCITATION_DESIGN)(d)) for t_ns, d in designs]
    if plant is not None:
        topics[f"{namespace}/plant/description"] = PLANT_DESCRIPTION
        messages.append((0, f"{namespace}/plant/description", encoder(PLANT_DESCRIPTION)(plant)))
    for first, data in blocks:
        messages.append((int(first * dt * 1e9) + 1, f"{namespace}/measurement",
                         encoder(SAMPLE_BLOCK)(block_message(first, data, names, dt))))
    with SessionWriter(path, compression="none", chunk_size_bytes=chunk_size_bytes) as w:
        for topic, type_name in topics.items():
            w.add_topic(topic, type_name, definition=DEFS, type_hash="")
        if facts is not None:
            w.write_session_facts(facts)
        for t_ns, topic, payload in sorted(messages, key=lambda m: m[0]):
            w.write(topic, payload, log_time_ns=t_ns)


def simulate_closed_loop(rig, design, pre_samples, post_samples=0, seed=0, nonlinear_magnets=False, controller=None):
    """The rig in closed loop with the default PID (or ``controller``, a discrete StateSpace y -> ic),
    excited by ``design`` (on every input of the rig, in its order) from ``pre_samples`` on.

    The rotor starts on the backup bearings; the pre-roll lifts it off.
    Loop: y = sim.output(); ic = ctl.step(y); u = ic + r; sim.step(u).

    Returns:
        (names, x): channel names (y_*, u_*, ic_*, r_*) and samples (n, 4 na).
    """
    from ambid.control.pid import PidParameters, pid_controller
    from ambid.control.stepper import ControllerStepper
    from ambid.plant.simulator import PlantSimulator

    sim = PlantSimulator(rig, seed=seed, nonlinear_magnets=nonlinear_magnets)
    pid = PidParameters()
    lay = rig.layout
    na = len(lay)
    ctl = ControllerStepper(pid_controller(pid, rig.dt, lay) if controller is None else controller,
                            pid.current_limit_a)
    n = pre_samples + design.total_samples + post_samples
    r = np.zeros((n, na))
    r[pre_samples:pre_samples + design.total_samples] = design.samples(0, design.total_samples)
    x = np.empty((n, 4 * na))
    for k, rk in enumerate(r.tolist()):
        y = sim.output()
        ic = ctl.step(y)
        u = [a + b for a, b in zip(ic, rk)]
        sim.step(u)
        x[k, :na], x[k, na:2 * na], x[k, 2 * na:3 * na] = y, u, ic
    x[:, 3 * na:] = r
    return list(lay.measurement_names), x
