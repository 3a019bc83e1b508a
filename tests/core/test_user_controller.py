"""ambid.control.user_controller and kinds: a controller as its owner has it (a file), or named in the rig file.

The controller here is written by the test: a PID with a filtered derivative and a low-pass per axis, from
its transfer function with scipy (bilinear transform), one sample of computational delay, minus sign for
negative feedback. It is not ambid's pid module."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import yaml
from scipy import io as sio
from scipy import signal

from ambid.control.kinds import checked_design, design_controller
from ambid.control.user_controller import load_controller
from ambid.plant.rig import load_rig, make_rig
from ambid.statespace import StateSpace, block_diag

RIG = make_rig({"sensor_noise_m": 0.0})


def _axis_tf(dt: float, kp=12_000.0, ti=0.05, td=1.5e-3, n=10.0, f_lp=5_000.0):
    """-C(z) z^-1 of kp (1 + 1/(ti s) + td s / (1 + td s / n)) / (1 + s / w_lp), Tustin, in z^-1 powers."""
    w = 2 * np.pi * f_lp
    num = np.polymul([kp * ti * td * (1 + 1 / n), kp * (ti + td / n), kp], [1.0])
    den = np.polymul(np.polymul([ti, 0.0], [td / n, 1.0]), [1 / w, 1.0])
    nz, dz = signal.bilinear(-num, den, fs=1 / dt)
    return np.append(0.0, nz), np.append(dz, 0.0)  # times z^-1: the output one sample late


def _own_controller(dt: float) -> StateSpace:
    num, den = _axis_tf(dt)
    with warnings.catch_warnings():  # num[0] = 0: the sample of delay
        warnings.simplefilter("ignore", signal.BadCoefficients)
        a, b, c, d = signal.tf2ss(num, den)
    return block_diag(*[StateSpace(a, b, c, d, dt)] * 4)


def _lift_off(model: StateSpace, n: int = 4000) -> float:
    """Largest |bearing displacement| over the last 1000 samples after a lift-off from the retainers [m]."""
    from ambid.control.stepper import ControllerStepper
    from ambid.plant.simulator import PlantSimulator

    sim = PlantSimulator(RIG)
    ctl = ControllerStepper(model, 3.0)
    worst = 0.0
    for k in range(n):
        sim.step(ctl.step(sim.output()))
        if k >= n - 1000:
            worst = max(worst, float(np.abs(sim.bearing_displacement).max()))
    return worst


@pytest.mark.parametrize("suffix", [".npz", ".mat", ".yaml"])
def test_a_controller_file_levitates_the_rig(tmp_path, suffix):
    own = _own_controller(RIG.dt)
    path = tmp_path / f"ctrl{suffix}"
    if suffix == ".npz":
        np.savez(path, A=own.a, B=own.b, C=own.c, D=own.d, dt=RIG.dt)
    elif suffix == ".mat":  # as MATLAB's save writes a ss object's matrices (Ts its sample time)
        sio.savemat(path, {"A": own.a, "B": own.b, "C": own.c, "D": own.d, "Ts": RIG.dt})
    else:  # per-axis transfer functions, the same on every axis
        num, den = _axis_tf(RIG.dt)
        path.write_text(yaml.safe_dump({"num": num.tolist(), "den": den.tolist(), "dt": RIG.dt}))
    model = load_controller(path, RIG.dt)
    assert (model.n_inputs, model.n_outputs) == (4, 4)
    f = np.array([20.0, 300.0, 1500.0])
    assert np.allclose(model.freqresp(f), own.freqresp(f), rtol=1e-8)
    design = checked_design(str(path), RIG)  # stable on both models
    assert design.kind == "file" and design.delay_samples == 1 and design.parameters["file"] == str(path.resolve())
    assert _lift_off(design.model) < 2e-6  # held near the centre (0.25 mm clearance at rest)


def test_a_rig_file_names_its_controller_beside_it(tmp_path):
    own = _own_controller(RIG.dt)
    np.savez(tmp_path / "mine.npz", A=own.a, B=own.b, C=own.c, D=own.d, dt=RIG.dt)
    (tmp_path / "rig.yaml").write_text("controller: mine.npz\nsensor_noise_m: 0.0\n")
    rig = load_rig(tmp_path / "rig.yaml")
    assert rig.controller == str(tmp_path / "mine.npz")
    assert design_controller(None, rig).kind == "file"
    assert design_controller("lqg", rig).kind == "lqg"  # a named kind overrides the rig's
    (tmp_path / "pid.yaml").write_text("controller: {kind: pid, kp_a_per_m: 15000.0, td_s: 0.002}\n")
    d = design_controller("", load_rig(tmp_path / "pid.yaml"))
    assert d.kind == "pid" and d.parameters["kp_a_per_m"] == 15000.0 and d.parameters["td_s"] == 0.002
    assert design_controller(None, make_rig()).kind == "pid"
    (tmp_path / "bad.yaml").write_text("controller: {kind: pid, gain: 3}\n")
    with pytest.raises(ValueError, match=r"controller pid: unknown parameter\(s\) \['gain'\]"):
        design_controller(None, load_rig(tmp_path / "bad.yaml"))


def test_feedthrough_controller_is_run_as_given(tmp_path):
    """A controller computing ic[k] from y[k] (D != 0): no delay claimed, the stepper steps it as it is."""
    num, den = _axis_tf(RIG.dt)
    a, b, c, d = signal.tf2ss(num[1:], den[:-1])  # without the sample of delay
    model = block_diag(*[StateSpace(a, b, c, d, RIG.dt)] * 4)
    np.savez(tmp_path / "ft.npz", A=model.a, B=model.b, C=model.c, D=model.d, dt=RIG.dt)
    design = design_controller(str(tmp_path / "ft.npz"), RIG)
    assert design.delay_samples == 0 and design.parameters["feedthrough"]


@pytest.mark.parametrize("change, message", [
    ({"dt": 2e-4}, "sample period 0.0002 s differs from the rig's 0.0001 s"),
    ({"B": np.zeros((3, 2))}, "B is 3 x 2, expected"),
    ({"C": np.full((4, 6), np.nan)}, "'C' holds NaN or Inf"),
    ({"D": None}, "has no 'D'"),
])
def test_bad_controller_files_are_named(tmp_path, change, message):
    own = _own_controller(RIG.dt)
    arrays = {"A": own.a, "B": own.b, "C": own.c, "D": own.d, "dt": RIG.dt, **change}
    np.savez(tmp_path / "c.npz", **{k: v for k, v in arrays.items() if v is not None})
    with pytest.raises(ValueError, match=message) as err:
        load_controller(tmp_path / "c.npz", RIG.dt)
    assert str(tmp_path / "c.npz") in str(err.value)
    with pytest.raises(ValueError, match="does not exist"):
        load_controller(tmp_path / "none.npz", RIG.dt)
    (tmp_path / "x.txt").write_text("1 2 3")
    with pytest.raises(ValueError, match="not a controller file type"):
        load_controller(tmp_path / "x.txt", RIG.dt)


def test_a_controller_that_cannot_hold_the_rig_is_refused_with_the_alternatives(tmp_path):
    weak = _own_controller(RIG.dt)
    weak = weak._replace(c=weak.c * 0.1, d=weak.d * 0.1)  # a tenth of the gain: below the negative stiffness
    np.savez(tmp_path / "weak.npz", A=weak.a, B=weak.b, C=weak.c, D=weak.d, dt=RIG.dt)
    with pytest.raises(ValueError, match="the file controller cannot hold this rig: .*unstable.*Try 'pid' or 'lqg'"):
        checked_design(str(tmp_path / "weak.npz"), RIG)


def _own_arrays():
    own = _own_controller(RIG.dt)
    return {"A": own.a, "B": own.b, "C": own.c, "D": own.d, "dt": RIG.dt}


@pytest.mark.parametrize("ext", [".npz", ".mat"])
@pytest.mark.parametrize("kind, message", [
    ("empty", "is empty"), ("random", r"is not an \.npz file|is not a MATLAB \.mat file"),
    ("truncated", r"is not an \.npz file|damaged or cut short"), ("folder", "is a folder"),
])
def test_controller_files_that_cannot_be_read_are_named_with_the_fix(tmp_path, kind, ext, message):
    good = tmp_path / f"good{ext}"
    (np.savez if ext == ".npz" else sio.savemat)(good, _own_arrays())
    path = tmp_path / f"{kind}{ext}"
    if kind == "folder":
        path.mkdir()
    else:
        data = good.read_bytes()
        path.write_bytes({"empty": b"", "random": np.random.default_rng(5).bytes(2000),
                          "truncated": data[:len(data) // 2]}[kind])
    with pytest.raises(ValueError, match=message) as err:
        load_controller(path, RIG.dt)
    assert str(path) in str(err.value) and "give A, B, C, D and dt" in str(err.value)


@pytest.mark.parametrize("change, message", [
    ({"A": "complex"}, "'A' is complex; give real values"),
    ({"dt": "fast"}, "'dt' must be one positive number of seconds"),
])
def test_complex_or_non_numeric_entries_are_named(tmp_path, change, message):
    arrays = _own_arrays()
    if change.get("A") == "complex":
        arrays["A"] = arrays["A"] + 1e-3j
    else:
        arrays.update(change)
    np.savez(tmp_path / "c.npz", **arrays)
    with pytest.raises(ValueError, match=message):
        load_controller(tmp_path / "c.npz", RIG.dt)


def test_a_mat_v73_controller_reads_as_its_npz(tmp_path):
    """MATLAB's save -v7.3: HDF5 behind a 512-byte header, matrices stored column-major."""
    import h5py

    arrays = _own_arrays()
    path = tmp_path / "k73.mat"
    with h5py.File(path, "w", userblock_size=512) as f:
        for key, value in arrays.items():
            f.create_dataset(key, data=np.atleast_2d(value).T).attrs["MATLAB_class"] = np.bytes_("double")
    with open(path, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(116) + b"\x00" * 8 + b"\x00\x02IM")
    np.savez(tmp_path / "k.npz", **arrays)
    got, want = load_controller(path, RIG.dt), load_controller(tmp_path / "k.npz", RIG.dt)
    assert all(np.array_equal(getattr(got, m), getattr(want, m)) for m in "abcd")


@pytest.mark.parametrize("params, message", [
    ({"kind": "pid", "kp_a_per_m": "high"}, r"controller pid: kp_a_per_m is 'high'; give a number"),
    ({"kind": "pid", "td_s": [1e-3, 2e-3]}, r"controller pid: td_s is \[0.001, 0.002\]; give a number"),
    ({"kind": "lqg", "regulate": 3}, r"controller lqg: regulate is 3; give a word"),
])
def test_rig_file_controller_parameters_of_the_wrong_type_are_named(params, message):
    with pytest.raises(ValueError, match=message):
        design_controller(params, RIG)


def test_the_refusal_keeps_the_option_spelling():
    weak = {"kind": "pid", "kp_a_per_m": 100.0}   # far below the magnets' negative stiffness
    with pytest.raises(ValueError, match=r"Try 'lqg' \(--controller\), or your own controller file "
                                         r"\(--controller FILE\)\.$"):
        checked_design(weak, RIG)
