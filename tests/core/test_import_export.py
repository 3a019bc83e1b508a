"""ambid export then ambid import gives back the session's FRF, modes and design; a closed loop simulated
here with scipy (not ambid's plant, controller or excitation: rig_records_testbench) and logged as a CSV
and a MATLAB v7.3 file is identified by ambid's fit to within 0.5 % in frequency and 10 % in damping of the
test's own model."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from ambid.excitation import design_multisine
from ambid.frf.offline import frf_from_session, session_designs
from ambid.identification import identify_session
from ambid_cli import cli
from rig_records_testbench import AXES, FS, KP, closed_loop, multisine, true_modes, write_logger_csv, write_matlab73
from session_testbench import design_message, write_session

INPUTS = [f"u_{a}" for a in AXES]
PRE, POST = 1500, 700


def _cli(argv, capsys):
    code = cli.main([str(a) for a in argv])
    out = capsys.readouterr()
    assert code == 0, out.err
    return out.out


@pytest.fixture(scope="module")
def ambid_session(tmp_path_factory):
    """A session as the recorder lays it out: an ambid orthogonal multisine on the test's own loop."""
    d = tmp_path_factory.mktemp("session")
    design = design_multisine((20.0, 900.0), 10.0, FS, INPUTS, 0.4, n_periods=2, n_realisations=2,
                              n_transient_periods=1, seed=5)
    r = np.zeros((PRE + design.total_samples + POST, 4))
    r[PRE:PRE + design.total_samples] = design.samples(0, design.total_samples)
    y, u = closed_loop(r, 2e-8, seed=1)
    x = np.hstack([y, u, u - r, r])
    names = [f"{p}_{a}" for p in ("y", "u", "ic", "r") for a in AXES]
    path = d / "session.mcap"
    write_session(path, [(k, x[k:k + 1000]) for k in range(0, len(x), 1000)], names,
                  [(0, design_message(design, PRE))], 1 / FS)
    return path, design


@pytest.mark.parametrize("fmt, ext", [("csv", "csv"), ("mat", "mat")])
def test_export_then_import_gives_the_same_frf_modes_and_design(ambid_session, tmp_path, fmt, ext, capsys):
    session, design = ambid_session
    record = tmp_path / f"rig.{ext}"
    _cli(["export", session, "--format", fmt, "--out", record], capsys)
    rmap = tmp_path / "rig.MAP.yaml"
    assert rmap.is_file() and "design" not in yaml.safe_load(rmap.read_text())   # found again, not carried
    out = _cli(["import", record, "--map", rmap, "--out", tmp_path / "back.mcap"], capsys)
    assert "design found from the excitation" in out and f"N = {design.n_per_period}" in out
    a, b = frf_from_session(session), frf_from_session(tmp_path / "back.mcap")
    np.testing.assert_array_equal(a.freq_hz, b.freq_hz)
    assert np.max(np.abs(b.frf - a.frf) / np.abs(a.frf)) < 1e-9
    found = session_designs(tmp_path / "back.mcap")[0]
    assert found["start_index"] == PRE and found["total_samples"] == design.total_samples
    got, want = found["design"].to_dict(), design.to_dict()
    for key in ("kind", "fs_hz", "n_per_period", "n_periods", "n_transient_periods", "n_realisations",
                "n_experiments", "input_names", "excited_lines", "detection_lines_odd", "detection_lines_even",
                "band_hz"):
        assert got[key] == want[key], key
    assert got["options"]["mimo"] == "orthogonal"
    for key in ("amplitudes_a", "peak_a", "rms_a", "crest_factor"):
        np.testing.assert_allclose(got[key], want[key], rtol=1e-12, err_msg=key)
    np.testing.assert_allclose(found["design"].phasors, design.phasors, atol=1e-12)
    fits = [identify_session(p, tmp_path / f"fit{i}", update=False, report=False)
            for i, p in enumerate((session, tmp_path / "back.mcap"))]
    modes = [[(m["freq_hz"], m["damping"]) for m in s["fit"]["modes"]] for s in fits]
    assert fits[0]["fit"]["order"] == fits[1]["fit"]["order"] and len(modes[0]) == len(modes[1]) > 0
    np.testing.assert_allclose(modes[1], modes[0], rtol=1e-6)


def test_without_hints_the_layout_is_found_and_the_transient_estimated(ambid_session, tmp_path, capsys):
    session, design = ambid_session
    _cli(["export", session, "--format", "npz", "--out", tmp_path / "rig.npz"], capsys)
    m = yaml.safe_load((tmp_path / "rig.MAP.yaml").read_text())
    del m["transient_periods"], m["band_hz"], m["time_column"], m["time_scale"]
    (tmp_path / "bare.yaml").write_text(yaml.safe_dump(m))
    out = _cli(["import", tmp_path / "rig.npz", "--map", tmp_path / "bare.yaml", "--out", tmp_path / "s.mcap"], capsys)
    assert "estimated from the response" in out
    d = session_designs(tmp_path / "s.mcap")[0]["design"]
    seg = design.n_periods + design.n_transient_periods
    assert (d.n_per_period, d.n_realisations, d.n_experiments, d.n_periods + d.n_transient_periods) == \
        (design.n_per_period, design.n_realisations, design.n_experiments, seg)
    assert 0 <= d.n_transient_periods < seg
    np.testing.assert_array_equal(d.excited_lines, design.excited_lines)
    lo, hi = design.excited_lines[[0, -1]]   # no band given: detection lines between the outer excited lines
    np.testing.assert_array_equal(d.detection_lines_odd, design.detection_lines_odd[
        (design.detection_lines_odd > lo) & (design.detection_lines_odd < hi)])


@pytest.fixture(scope="module")
def own_rig():
    """The test's own loop under its own orthogonal multisine (full grid 10-1000 Hz, M = 2, Pt = 1, P = 2)."""
    r = multisine(2000, np.arange(2, 201), 0.03, m=2, nu=4, pt=1, p=2, seed=1)
    r = np.vstack([np.zeros((2000, 4)), r, np.zeros((1000, 4))])
    y, u = closed_loop(r, 2e-8, seed=0)
    return y, u, r


VOLT = 5.0e-5   # the logger records the sensors in volts: 50 um per volt


def _channel_map(col):
    return {"outputs": {f"y_{a}": {"column": col("x", i), "scale": VOLT, "unit": "m"} for i, a in enumerate(AXES)},
            "currents": {f"u_{a}": {"column": col("i", i)} for i, a in enumerate(AXES)},
            "excitation": {f"r_{a}": {"column": col("exc", i)} for i, a in enumerate(AXES)}}


@pytest.mark.parametrize("kind", ["csv", "mat73"])
def test_a_rig_simulated_here_is_identified_from_its_logs(own_rig, tmp_path, kind, capsys):
    y, u, r = own_rig
    cols = {**{f"x{i + 1} [V]": y[:, i] / VOLT for i in range(4)}, **{f"i{i + 1}": u[:, i] for i in range(4)},
            **{f"exc{i + 1}": r[:, i] for i in range(4)}}
    if kind == "csv":
        data = tmp_path / "rig.csv"
        write_logger_csv(data, cols, np.arange(len(r)) / FS * 1e3)
        rmap = {"time_column": "Zeit [ms]", "time_scale": 1e-3, **_channel_map(lambda p, i: f"{p}{i + 1}"
                                                                               + (" [V]" if p == "x" else ""))}
    else:
        data = tmp_path / "rig.mat"
        write_matlab73(data, np.column_stack(list(cols.values())), list(cols))
        rmap = {"sample_rate_hz": FS, **_channel_map(lambda p, i: f"{p}{i + 1}" + (" [V]" if p == "x" else ""))}
    # a controller file: the proportional part, one sample late (enough to carry K(z) into the session)
    np.savez(tmp_path / "k.npz", A=np.zeros((4, 4)), B=-KP * np.eye(4), C=np.eye(4), D=np.zeros((4, 4)), dt=1 / FS)
    rmap["controller"] = "k.npz"
    (tmp_path / "MAP.yaml").write_text(yaml.safe_dump(rmap, sort_keys=False))
    out = _cli(["import", data, "--map", tmp_path / "MAP.yaml", "--out", tmp_path / "rig.mcap"], capsys)
    assert "orthogonal design, Ne = 4 experiment(s) x M = 2 realisation(s)" in out and "N = 2000" in out
    s = identify_session(tmp_path / "rig.mcap", tmp_path / "fit", update=False, report=False)
    assert s["controller"]["kind"] == "file"
    fitted = [(m["freq_hz"], m["damping"]) for m in s["fit"]["modes"]]
    for f0, z0 in true_modes():
        f, z = min(fitted, key=lambda m: abs(m[0] - f0))
        assert abs(f / f0 - 1) < 0.005 and abs(z / z0 - 1) < 0.10, (f0, z0, fitted)
    unstable = [p["pole_hz"] for p in s["fit"]["real_poles"] if p["unstable"]]
    assert any(abs(p / 50.33 - 1) < 0.01 for p in unstable)   # sqrt(ks/m) / 2 pi, the magnets' pair
    assert json.loads((tmp_path / "fit" / "identification.json").read_text())["experiment_id"] == "import"


def test_a_given_design_is_used_and_checked_against_the_record(ambid_session, tmp_path, capsys):
    session, design = ambid_session
    _cli(["export", session, "--format", "csv", "--out", tmp_path / "rig.csv"], capsys)
    m = yaml.safe_load((tmp_path / "rig.MAP.yaml").read_text())
    (tmp_path / "design.json").write_text(json.dumps(design.to_dict()))   # as 'ambid design --out' writes it
    (tmp_path / "d.yaml").write_text(yaml.safe_dump({**m, "design": "design.json"}))
    out = _cli(["import", tmp_path / "rig.csv", "--map", tmp_path / "d.yaml", "--out", tmp_path / "s.mcap"], capsys)
    assert "design given" in out
    assert session_designs(tmp_path / "s.mcap")[0]["design"] == design
    assert np.max(np.abs(frf_from_session(tmp_path / "s.mcap").frf / frf_from_session(session).frf - 1)) < 1e-9
    other = design_multisine((20.0, 900.0), 10.0, FS, INPUTS, 0.4, n_periods=2, n_realisations=2,
                             n_transient_periods=1, seed=6)   # the same layout, other phases: not what ran
    (tmp_path / "design.json").write_text(json.dumps(other.to_dict()))
    code = cli.main(["import", str(tmp_path / "rig.csv"), "--map", str(tmp_path / "d.yaml"), "--out",
                     str(tmp_path / "t.mcap")])
    err = capsys.readouterr().err
    assert code == 2 and f"excitation column 'r_a_x' at row {PRE + 1} is" in err and "gives" in err
    assert not (tmp_path / "t.mcap").exists() and not list(tmp_path.glob(".*.part"))


def test_one_experiment_of_several_is_exported(ambid_session, tmp_path, capsys):
    """Two experiments in one session: the export of either holds its own rows only and imports back."""
    _, design = ambid_session
    gap = 600
    r = np.zeros((PRE + 2 * design.total_samples + gap + POST, 4))
    second = PRE + design.total_samples + gap
    r[PRE:PRE + design.total_samples] = design.samples(0, design.total_samples)
    r[second:second + design.total_samples] = design.samples(0, design.total_samples)
    y, u = closed_loop(r, 2e-8, seed=2)
    names = [f"{p}_{a}" for p in ("y", "u", "ic", "r") for a in AXES]
    x = np.hstack([y, u, u - r, r])
    write_session(tmp_path / "two.mcap", [(k, x[k:k + 1000]) for k in range(0, len(x), 1000)], names,
                  [(0, design_message(design, PRE, experiment_id="one")),
                   (1, design_message(design, second, experiment_id="two"))], 1 / FS)
    for exp in ("one", "two"):
        _cli(["export", tmp_path / "two.mcap", "--format", "npz", "--experiment", exp, "--out",
              tmp_path / f"{exp}.npz"], capsys)
        _cli(["import", tmp_path / f"{exp}.npz", "--map", tmp_path / f"{exp}.MAP.yaml", "--out",
              tmp_path / f"{exp}_back.mcap"], capsys)
        a = frf_from_session(tmp_path / "two.mcap", experiment_id=exp)
        b = frf_from_session(tmp_path / f"{exp}_back.mcap")
        assert np.max(np.abs(b.frf / a.frf - 1)) < 1e-9
    assert np.load(tmp_path / "one.npz")["data"].shape[0] == PRE + design.total_samples + gap
