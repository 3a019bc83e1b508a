"""ambid.report: each figure shows the data it is given, with units; the HTML page holds the numbers and figures.

Small 2 x 2 data keep the figures cheap; the full 4 x 4 report of a simulated session is checked in
test_identification.py.
"""

import html
import struct

import numpy as np
import pytest
from ambid.excitation import design_multisine
from ambid.fit import stabilisation_diagram
from ambid.frf.levels import LineLevels
from ambid.frf.offline import frf_from_arrays
from ambid.frf.sensitivity import iso14839_zone
from ambid.report import figures
from ambid.report.html import render_index, write_report
from frf_testbench import FS, loop_model, simulate

F = np.geomspace(10.0, 1000.0, 30)
FD = np.geomspace(7.0, 1500.0, 200)


def _model(f, zero_cross=False):
    s = 2j * np.pi * f[:, None, None]
    g = np.array([[1.0, 0.3], [0.2, 0.8]]) * 1e-6 / (s**2 / (2 * np.pi * 300) ** 2 + 0.02 * s / (2 * np.pi * 300) + 1)
    if zero_cross:
        g = g * np.array([[1.0, 0.0], [0.0, 1.0]])
    return g


def _lines(ax, label):
    return [ln for ln in ax.get_lines() if ln.get_label() == label]


def test_bode_matrix_draws_the_given_curves_and_the_uncertainty_band():
    g = _model(F)
    curves = {"fitted model": (FD, _model(FD)), "true rig (simulated)": (FD, _model(FD, zero_cross=True))}
    fig = figures.bode_matrix(F, g, 0.05 * np.abs(g), curves, "magnitude", input_names=("u_1", "u_2"),
                              output_names=("y_1", "y_2"))
    axes = fig.axes
    assert len(axes) == 4 and all(ax.get_xscale() == "log" for ax in axes)
    assert "dB re 1 m/A" in axes[0].get_ylabel() and "y_1" in axes[0].get_ylabel()
    assert axes[2].get_xlabel() == "frequency [Hz]" and axes[0].get_title() == "from u_1 [A]"
    fitted = _lines(axes[1], "fitted model")[0]
    np.testing.assert_allclose(fitted.get_ydata(), 20 * np.log10(np.abs(_model(FD)[:, 0, 1])))
    assert _lines(axes[1], "true rig (simulated)") == []          # structurally zero entry: not drawn
    assert len(_lines(axes[0], "true rig (simulated)")) == 1
    assert all(len(ax.collections) == 1 for ax in axes)           # the +-2 sigma band
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == ["measured +-2 sigma", "measured", "fitted model", "true rig (simulated)"]
    phase = figures.bode_matrix(F, g, None, curves, "phase")
    ax = phase.axes[0]
    assert len(ax.collections) == 0 and "phase [deg]" in ax.get_ylabel()
    meas = [ln for ln in ax.get_lines() if ln.get_marker() == "o"][0]
    np.testing.assert_allclose(meas.get_ydata(), np.angle(g[:, 0, 0], deg=True))
    y = np.asarray(_lines(ax, "fitted model")[0].get_ydata(), dtype=float)
    assert np.nanmax(np.abs(y)) <= 180 and np.all(np.abs(np.diff(y)[np.isfinite(np.diff(y))]) <= 180)
    with pytest.raises(ValueError, match="quantity"):
        figures.bode_matrix(F, g, None, curves, "gain")
    with pytest.raises(ValueError, match=r"\(L, Ny, Nu\)"):
        figures.bode_matrix(F, g[:-1], None, curves)


def test_input_sensitivity_shades_the_iso_zones():
    s = np.ones((F.size, 2, 2)) * 0.1
    s[:, 0, 0] = 1.0 + 2.5 * np.exp(-((F - 300) / 50) ** 2)      # peak 3.5: zone B
    s[:, 1, 1] = 1.2
    fig = figures.input_sensitivity(F, s, ("u_1", "u_2"))
    ax = fig.axes[0]
    spans = sorted((p.get_y(), p.get_y() + p.get_height()) for p in ax.patches)
    assert spans[:3] == [(0.0, 3.0), (3.0, 4.0), (4.0, 5.0)] and spans[3][0] == 5.0
    peak = np.max(s[:, 0, 0])
    assert f"zone {iso14839_zone(peak)}" in ax.get_title() and iso14839_zone(peak) == "B"
    np.testing.assert_allclose(_lines(ax, f"|S| u_1: peak {peak:.2f} at {F[np.argmax(s[:, 0, 0])]:.4g} Hz")[0]
                               .get_ydata(), s[:, 0, 0])
    assert "[A/A]" in ax.get_ylabel()


def test_noise_distortion_figure_in_micrometres():
    rng = np.random.default_rng(0)
    lv = LineLevels(excited_hz=np.array([10.0, 30.0, 70.0]), odd_hz=np.array([50.0]), even_hz=np.array([20.0, 40.0]),
                    excited_amp=rng.uniform(1e-6, 2e-6, (3, 2)), odd_amp=np.full((1, 2), 3e-8),
                    even_amp=np.full((2, 2), 1e-8), excited_noise=np.full((3, 2), 1e-8),
                    odd_noise=np.full((1, 2), 1e-8), even_noise=np.full((2, 2), 1e-8))
    fig = figures.noise_distortion(lv, ("y_1", "y_2"), odd_db=np.array([9.5, 0.1]), even_db=np.array([0.0, -0.2]))
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert len(visible) == 2 and "[um]" in visible[0].get_ylabel()
    assert "odd +9.5 dB" in visible[0].get_title() and "even -0.2 dB" in visible[1].get_title()
    np.testing.assert_allclose(_lines(visible[1], "excited lines (signal)")[0].get_ydata(), lv.excited_amp[:, 1] * 1e6)
    floor = _lines(visible[0], "noise floor (std of mean)")[0]
    np.testing.assert_allclose(floor.get_xdata(), [10, 20, 30, 40, 50, 70])


def test_excitation_figure_gives_each_inputs_crest_factor_and_line_amplitudes():
    d = design_multisine((20.0, 400.0), 20.0, 4000.0, ["u_1", "u_2"], 0.8, n_periods=2, seed=1)
    fig = figures.excitation(d)
    ax_f, ax_t = fig.axes
    texts = [t.get_text() for t in ax_f.get_legend().get_texts()]
    for i, name in enumerate(d.input_names):
        label = [t for t in texts if t.startswith(name)][0]
        assert f"crest factor {d.crest_factor[i]:.2f}" in label and f"peak {d.peak_a[i]:.3g} A" in label
        line = _lines(ax_f, label)[0]
        np.testing.assert_allclose(line.get_xdata(), d.freq_hz)
        np.testing.assert_allclose(line.get_ydata(), d.amplitudes_a[i], rtol=1e-9)   # unit-modulus phasors
    assert ax_f.get_ylabel() == "line amplitude [A]" and ax_t.get_xlabel() == "time [ms]"
    assert max(np.max(np.abs(ln.get_ydata())) for ln in ax_t.get_lines()) == pytest.approx(0.8)


def test_time_records_frf_error_and_stabilisation_figures():
    t = np.arange(100) / 1e4 + 2.0
    y = 1e-6 * np.sin(np.arange(100))[:, None] * np.ones((1, 2))
    fig = figures.time_records(t, y, np.ones((100, 2)), np.zeros((100, 2)), ("y_1", "y_2"), ("u_1", "u_2"))
    ax_y, ax_u = fig.axes
    np.testing.assert_allclose(ax_y.get_lines()[0].get_ydata(), y[:, 0] * 1e6)
    np.testing.assert_allclose(ax_y.get_lines()[0].get_xdata(), np.arange(100) * 0.1)
    assert "[um]" in ax_y.get_ylabel() and "[A]" in ax_u.get_ylabel() and "[ms]" in ax_u.get_xlabel()
    errs = {"measured": np.full(F.size, 0.02), "fitted model": np.linspace(0.001, 0.01, F.size)}
    fig = figures.frf_error(F, errs, np.full(F.size, 0.05))
    labels = [tx.get_text() for tx in fig.axes[0].get_legend().get_texts()]
    assert labels[0] == "measured: median 2.00%, worst 2.00%" and labels[1].endswith("worst 1.00%")
    g = _model(F)[:, :1, :1]
    diagram = stabilisation_diagram(F, g, orders=[2, 4, 6])
    fig = figures.stabilisation(diagram, F, g, 4)
    chosen = _lines(fig.axes[0], "chosen order 4")
    assert len(chosen) == 1 and list(chosen[0].get_ydata()) == [4, 4]
    assert "chosen order 4" in fig.axes[0].get_title()


def _summary():
    return {
        "session": "run<1>.mcap", "experiment_id": "exp1", "estimator": "indirect",
        "excitation": {"kind": "multisine", "mimo": "orthogonal", "grid": "random_odd", "n_excited_lines": 30,
                       "samples_per_period": 1000, "n_periods": 4, "n_transient_periods": 1, "n_realisations": 1,
                       "n_experiments": 2, "measurement_time_s": 1.0, "sample_rate_hz": 10000.0,
                       "crest_factor": [3.1, 3.2]},
        "band_hz": [10.0, 990.0], "inputs": ["u_1", "u_2"], "outputs": ["y_1", "y_2"],
        "frf_error": {"median": 0.0123, "worst": 0.2, "worst_at_hz": 890.0, "fitted_median": 0.01,
                      "fitted_worst": 0.05},
        "noise": {"output_noise_std_m": [2.2e-7, None], "relative_frf_noise_std": 0.3,
                  "nonlinear_variance_ratio": None, "distortion_odd_db": [0.5, -0.2], "distortion_even_db": [0.1, 0.0]},
        "fit": {"order": 14, "order_rule": "rule", "chi2_per_dof": 1.05,
                "modes": [{"freq_hz": 310.37, "damping": 0.00503, "stable": True}],
                "real_poles": [{"pole_hz": 36.8, "unstable": True}]},
        "modes_vs_true": [{"true_freq_hz": 310.374, "true_damping": 0.00505, "freq_hz": 310.37, "damping": 0.00503,
                           "freq_error": -1.3e-5, "damping_error": -0.004, "n_true": 1, "n_fitted": 1}],
        "max_mode_freq_error": 1.3e-5, "max_mode_damping_error": 0.004,
        "update": {"chi2_per_dof": 1.2, "message": "converged",
                   "parameters": {"ki_n_per_a": {"value": 179.2, "start": 139.3, "nominal": 174.1, "true": 179.25,
                                                 "error": -0.0003, "unit": "N/A", "ci95": [179.0, 179.4],
                                                 "free": True, "prior": {"mean": 174.1, "ci95": [165.4, 182.8]},
                                                 "prior_ratio": 0.01, "prior_dominated": False},
                                  "sensor_gain_a_x": {"value": 1.0, "start": 1.0, "nominal": 1.0, "true": 1.0,
                                                      "error": 0.0, "unit": "m/m", "ci95": None, "free": False}}},
        "sensitivity": {"worst_peak": 2.66, "worst_input": "u_2", "iso_zone": "A"},
        "notes": ["<script>alert(1)</script>"],
    }


def test_render_index_tables_escaping_and_figures():
    text = render_index(_summary(), [("bode_magnitude.png", "Bode & co")])
    assert "run&lt;1&gt;.mcap" in text and "<script>" not in text and html.escape("<script>") in text
    assert "<td>1.23 % / 20 % (at 890 Hz)</td>" in text               # FRF error median / worst
    assert "<td>14 (rule)</td>" in text and "<td>A</td>" in text and "8.5 dB" in text
    assert "<td>165.4 .. 182.8</td><td>179.2</td><td>179 .. 179.4</td><td>0.01</td><td>179.25</td><td>-0.03 %</td>" \
        in text
    assert "<td>1</td><td>fixed</td>" in text
    assert "<td>310.37</td><td>-</td><td>0.00503</td><td>-</td><td>yes</td>" in text   # no interval: '-'
    assert "<td>310.37</td><td>0.00503</td><td>1</td>" in text
    assert "<img src='bode_magnitude.png'" in text and "<figcaption>Bode &amp; co</figcaption>" in text
    assert "0.22, -" in text                                           # noise std in um, unknown as '-'
    failed = dict(_summary(), update={"error": "not identifiable"}, frf_error=None, modes_vs_true=[])
    text = render_index(failed, [])
    assert "Model updating failed: not identifiable" in text and "FRF error" not in text


def test_write_report_draws_what_the_data_allow(tmp_path):
    loop = loop_model()
    d = design_multisine((20.0, 600.0), 20.0, FS, ("u_1", "u_2"), 0.3, n_periods=2, n_realisations=1,
                         n_transient_periods=1, seed=3)
    r = d.samples(0, d.total_samples)
    y, u = simulate(loop, r[None], 1e-8, seed=1)
    data = {"y_1": y[0, :, 0], "y_2": y[0, :, 1], "u_1": u[0, :, 0], "u_2": u[0, :, 1], "r_1": r[:, 0], "r_2": r[:, 1]}
    frf = frf_from_arrays(data, d, outputs=("y_1", "y_2"), inputs=("u_1", "u_2"), references=("r_1", "r_2"))
    diagram = stabilisation_diagram(frf.freq_hz, frf.frf, orders=[4, 6])
    summary = _summary()
    index = write_report(tmp_path / "report", summary, frf=frf, design=d, diagram=diagram, order=6,
                         curves={"fitted model": (frf.freq_hz, frf.frf)}, true_frf=frf.frf * 1.01,
                         line_models={"fitted model": frf.frf})
    text = index.read_text()
    expected = ["bode_magnitude.png", "bode_phase.png", "frf_error.png", "stabilisation.png", "excitation.png",
                "input_sensitivity.png"]
    assert [p.name for p in sorted((tmp_path / "report").glob("*.png"))] == sorted(expected)
    for name in expected:
        assert f"src='{name}'" in text
        head = (tmp_path / "report" / name).read_bytes()[:24]
        assert head[:8] == b"\x89PNG\r\n\x1a\n" and struct.unpack(">II", head[16:24])[0] > 500
    assert "noise_distortion.png" not in text and "time_records.png" not in text   # no levels, no window given
