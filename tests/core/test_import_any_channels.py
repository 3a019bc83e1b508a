"""Channels are data: closed-loop records of a one-axis rig, one bearing plane, the four radial axes and the
five-axis machine (the axial z too), simulated by the test's own scipy loop (rig_records_testbench, not ambid's
plant, controller or excitation) and logged as a CSV, a MAT v5 (scipy.io.savemat, as MATLAB's save -v7) and a
MAT v7.3 file (HDF5 in MATLAB's layout), import with a MAP.yaml whose numbers are written as people write them
(``scale: 2e-05``) and fit: every mode of the test's model within 0.5 % in frequency and 10 % in damping."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io as sio
from ambid_cli import cli
from rig_records_testbench import AXES, FS, closed_loop, gains, multisine, true_modes, write_logger_csv, write_matlab73

LAYOUTS = {1: ("x",), 2: ("a_x", "a_y"), 4: AXES, 5: AXES + ("z",)}
N, LINES = 2000, np.arange(2, 201)          # 5 Hz resolution, 10-1000 Hz full grid
PRE, POST = 2000, 1000
VOLT = 2e-05                                 # the logger records the sensors in volts: 20 um per volt


@pytest.fixture(scope="module", params=list(LAYOUTS), ids=lambda n: f"{n}ch")
def record(request):
    """The test's own loop of ``n`` axes under its own orthogonal multisine (M = 2, Pt = 1, P = 2)."""
    axes = LAYOUTS[request.param]
    na = len(axes)
    r = multisine(N, LINES, 0.03, m=2, nu=na, pt=1, p=2, seed=na)
    r = np.vstack([np.zeros((PRE, na)), r, np.zeros((POST, na))])
    y, u = closed_loop(r, 2e-8, seed=na, axes=axes)
    return axes, y, u, r


def _map_text(axes, time_lines: str, col) -> str:
    """MAP.yaml as a person types it: exponent numbers without a dot or sign (2e-05, 1e0, 1E-3)."""
    lines = [time_lines, "outputs:"]
    lines += [f"  y_{a}: {{column: '{col('x', i)}', scale: 2e-05, unit: m}}" for i, a in enumerate(axes)]
    lines += ["currents:"] + [f"  u_{a}: {{column: '{col('i', i)}', scale: 1e0}}" for i, a in enumerate(axes)]
    lines += ["excitation:"] + [f"  r_{a}: {{column: '{col('exc', i)}'}}" for i, a in enumerate(axes)]
    lines += ["controller: k.npz", "band_hz: [1e1, 1e3]", "transient_periods: 1"]   # as the test's design has it
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("kind", ["csv", "mat5", "mat73"])
def test_a_record_of_any_channels_imports_and_fits(record, tmp_path, kind, capsys):
    axes, y, u, r = record
    na = len(axes)
    cols = {**{f"x{i + 1} [V]": y[:, i] / VOLT for i in range(na)}, **{f"i{i + 1}": u[:, i] for i in range(na)},
            **{f"exc{i + 1}": r[:, i] for i in range(na)}}
    col = lambda p, i: f"{p}{i + 1}" + (" [V]" if p == "x" else "")  # noqa: E731
    if kind == "csv":
        data = tmp_path / "rig.csv"
        write_logger_csv(data, cols, np.arange(len(r)) / FS * 1e3)
        head = "time_column: 'Zeit [ms]'\ntime_scale: 1E-3"
    elif kind == "mat5":   # MATLAB's save -v7 of one matrix and its column names (a cell of strings)
        data = tmp_path / "rig.mat"
        names = np.empty((1, len(cols)), dtype=object)
        names[0, :] = list(cols)
        sio.savemat(data, {"data": np.column_stack(list(cols.values())), "names": names})
        head = "sample_rate_hz: 1e4"
    else:
        data = tmp_path / "rig.mat"
        write_matlab73(data, np.column_stack(list(cols.values())), list(cols))
        head = "sample_rate_hz: 1e4"
    # the controller that ran, as a file: its proportional part, one sample late (K(z) into the session)
    kp = gains(axes)[0]
    np.savez(tmp_path / "k.npz", A=np.zeros((na, na)), B=-np.diag(kp), C=np.eye(na), D=np.zeros((na, na)),
             dt=1 / FS)
    (tmp_path / "MAP.yaml").write_text(_map_text(axes, head, col))
    code = cli.main(["import", str(data), "--map", str(tmp_path / "MAP.yaml"), "--out", str(tmp_path / "rig.mcap")])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert f"orthogonal design, Ne = {na} experiment(s) x M = 2 realisation(s)" in out.out and "N = 2000" in out.out
    # the report of any number of channels, once per layout but the four radial axes: their report is the
    # default rig's, which every identify test's session writes (and test_early_analysis compares figure by figure)
    report = kind == "csv" and na != 4
    code = cli.main(["fit", str(tmp_path / "rig.mcap"), "--out", str(tmp_path / "fit")] + ([] if report else
                                                                                            ["--no-report"]))
    out = capsys.readouterr()
    assert code == 0, out.err
    if report:
        figures = {p.name for p in (tmp_path / "fit" / "report").glob("*.png")}
        assert {"bode_magnitude.png", "input_sensitivity.png", "noise_distortion.png"} <= figures
        assert ("directional_frf.png" in figures) == (na > 1)   # a bearing plane's x and y: whirl directions
    s = json.loads((tmp_path / "fit" / "identification.json").read_text())
    assert s["outputs"] == [f"y_{a}" for a in axes] and s["inputs"] == [f"u_{a}" for a in axes]
    assert s["controller"]["kind"] == "file"
    fitted = [(m["freq_hz"], m["damping"]) for m in s["fit"]["modes"]]
    for f0, z0 in true_modes(axes):
        f, z = min(fitted, key=lambda m: abs(m[0] - f0))
        assert abs(f / f0 - 1) < 0.005 and abs(z / z0 - 1) < 0.10, (f0, z0, fitted)
    # the magnets' unstable poles sqrt(ks / m) / 2 pi: 50.3 Hz radially, 42.1 Hz axially
    unstable = [p["pole_hz"] for p in s["fit"]["real_poles"] if p["unstable"]]
    for want in [50.33] + ([42.11] if "z" in axes else []):
        assert any(abs(p / want - 1) < 0.01 for p in unstable), (want, unstable)
    # no rig model covers a record's own layout: said in one line, not refused
    assert s["update"] is None and s["sensitivity"]["peak"] and len(s["sensitivity"]["peak"]) == na
