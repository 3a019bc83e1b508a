"""ambid.identification: the whole offline job on a simulated session, and its pieces.

The session is a core-level closed loop of the default rig (true rig: housing mode, sensor filter, delay,
ki and ks off their nominal values) with the default PID, excited by an orthogonal random-odd multisine on
the four inputs, written to MCAP as a recorder would (PlantDescription, ExcitationDesign, SampleBlocks).
"""

import json
import struct
from argparse import Namespace

import numpy as np
import pytest
from ambid.control.pid import PidParameters, pid_controller
from ambid.excitation import design_multisine
from ambid.fit import load_model_npz, load_statespace_json
from ambid.fit.model_update import nominal_parameters, true_parameters
from ambid.fit.order_selection import StabilisationDiagram
from ambid.frf.levels import line_levels
from ambid.frf.sensitivity import iso14839_zone
from ambid.plant.rig import make_rig
from ambid.plant.true_rig import true_linear_model
from ambid.frf.accuracy import frf_relative_error
from ambid.identification import (compare_modes, identify_session, select_order,
                                          session_rig, true_modes)
from ambid_cli.commands import fit as fit_command
from ambid_cli.commands.inputs import BadInput
from session_testbench import design_message, plant_message, simulate_closed_loop, write_session

RIG = make_rig()
PRE = 3000


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    design = design_multisine((10.0, 1000.0), 10.0, RIG.sample_rate_hz, list(RIG.layout.inputs), 0.5,
                              n_periods=4, n_realisations=1, seed=3)
    names, x = simulate_closed_loop(RIG, design, PRE, post_samples=200, seed=4)
    path = tmp_path_factory.mktemp("session") / "session.mcap"
    write_session(path, [(k, x[k:k + 1000]) for k in range(0, len(x), 1000)], names,
                  [(0, design_message(design, PRE))], RIG.dt, plant=plant_message(RIG))
    return dict(path=path, design=design)


@pytest.fixture(scope="module")
def identified(session, tmp_path_factory):
    out = tmp_path_factory.mktemp("ident")
    nom = nominal_parameters(RIG)
    start = {"ki_n_per_a": 0.8 * nom["ki_n_per_a"], "ks_n_per_m": 1.2 * nom["ks_n_per_m"]}  # 20 % off
    summary = identify_session(session["path"], out, max_order=24, nominal=start)
    return dict(out=out, summary=summary, start=start)


def test_fitted_modes_match_the_true_rig(identified):
    s = identified["summary"]
    expected = true_modes(true_linear_model(RIG).poles(), s["band_hz"])
    # housing modes (two pedestal modes, 0.24 Hz apart), first and second bending modes
    assert [round(f) for f, _ in expected] == [177, 177, 310, 927]
    rows = s["modes_vs_true"]
    assert [r["n_true"] for r in rows] == [2, 1, 1]      # closer than the 10 Hz resolution: one cluster
    for row in rows:
        assert abs(row["freq_error"]) < 0.005 and abs(row["damping_error"]) < 0.10, row
    assert s["max_mode_freq_error"] == max(abs(r["freq_error"]) for r in rows)
    # the open-loop unstable rigid-body poles (about +37 and +56 Hz) are among the fitted real RHP poles
    unstable = np.array([r["pole_hz"] for r in s["fit"]["real_poles"] if r["unstable"]])
    for f in (36.86, 56.17):
        assert np.min(np.abs(unstable / f - 1)) < 0.03, unstable
    assert s["fit"]["order"] in s["fit"]["orders_tried"] and s["fit"]["order"] <= 24


def test_compare_modes_clusters_modes_closer_than_the_resolution():
    true = [(100.0, 0.02), (100.5, 0.04), (300.0, 0.01)]
    fitted = [(99.8, 0.025), (100.9, 0.035), (250.0, 0.2), (303.0, 0.011)]
    rows = compare_modes(fitted, true, resolution_hz=5.0)
    assert len(rows) == 2
    assert rows[0]["true_freq_hz"] == pytest.approx(100.25) and rows[0]["true_damping"] == pytest.approx(0.03)
    assert rows[0]["freq_hz"] == pytest.approx(100.35) and rows[0]["n_fitted"] == 2 and rows[0]["n_true"] == 2
    assert rows[1]["freq_error"] == pytest.approx(0.01) and rows[1]["damping_error"] == pytest.approx(0.1)
    # no fitted mode within the resolution: the nearest one
    assert compare_modes([(250.0, 0.2)], [(300.0, 0.01)], 5.0)[0]["freq_hz"] == 250.0
    assert compare_modes([], true, 5.0) == []


def test_updating_from_a_nominal_20_percent_off_recovers_ki_and_ks(identified):
    # a nominal model 4 and 2 of its tolerances off: the data tell ki and ks, the prior hardly counts
    s = identified["summary"]
    params = s["update"]["parameters"]
    true = true_parameters(RIG)
    for name in ("ki_n_per_a", "ks_n_per_m"):
        p = params[name]
        assert p["nominal"] == pytest.approx(identified["start"][name]) == p["prior"]["mean"]
        assert p["prior_ratio"] < 0.1 and not p["prior_dominated"]
        assert abs(p["value"] / true[name] - 1) < 0.02, (name, p)
        assert p["true"] == pytest.approx(true[name]) and p["error"] == pytest.approx(p["value"] / true[name] - 1)
        assert p["ci95"][0] < p["value"] < p["ci95"][1]
    # the fit found the housing mode the analytical model lacks, and updating placed the support there
    assert params["support_freq_hz"]["value"] == pytest.approx(RIG.housing_freq_hz, rel=0.02)
    assert s["frf_error"]["updated_median"] < s["frf_error"]["median"]


def test_frf_error_noise_and_sensitivity_figures(identified, session):
    s = identified["summary"]
    data = np.load(identified["out"] / "frf.npz")
    g_true = true_linear_model(RIG, discrete=True).freqresp(data["freq_hz"])
    err = frf_relative_error(data["frf"], g_true)
    assert s["frf_error"]["median"] == pytest.approx(np.median(err)) and s["frf_error"]["worst"] == pytest.approx(
        err.max())
    assert s["frf_error"]["median"] < 0.05
    # output noise: the white sensor noise through the closed loop, y = (I - G K)^-1 v (ic = K y)
    f = (np.arange(800) + 0.5) / 800 * RIG.sample_rate_hz / 2
    g = true_linear_model(RIG, discrete=True).freqresp(f)
    k = pid_controller(PidParameters(), RIG.dt).freqresp(f)
    s_out = np.linalg.inv(np.eye(4) - g @ k)
    expected = RIG.sensor_noise_m * np.sqrt((np.abs(s_out) ** 2).sum(axis=2).mean(axis=0))
    np.testing.assert_allclose(s["noise"]["output_noise_std_m"], expected, rtol=0.1)
    # a 95 % interval about the estimate (no recorded controller in this session: no true noise level)
    assert s["noise"]["true_output_noise_std_m"] is None
    # what the band claims to cover is written beside it
    assert "best linear approximation at this excitation level" in s["intervals"]["frf_band"]
    assert "noise std" in s["intervals"]["noise_std"]
    ci = np.array(s["noise"]["output_noise_std_ci95_m"])
    assert ci.shape == (4, 2) and np.all((ci[:, 0] < s["noise"]["output_noise_std_m"])
                                         & (s["noise"]["output_noise_std_m"] < ci[:, 1]))
    # linear simulation: the detection lines hold noise only (about 0 dB above the noise floor)
    assert np.all(np.abs(s["noise"]["distortion_odd_db"]) < 3) and np.all(np.abs(s["noise"]["distortion_even_db"]) < 3)
    sens = s["sensitivity"]
    assert sens["iso_zone"] == iso14839_zone(sens["worst_peak"]) and sens["worst_peak"] == max(sens["peak"])
    assert s["band_hz"] == [session["design"].freq_hz[0], session["design"].freq_hz[-1]]
    assert s["inputs"] == list(RIG.layout.inputs) and s["outputs"] == list(RIG.layout.outputs)
    # the only note: a parameter the data tell little about (its interval is mostly its tolerance)
    assert s["estimator"] == "indirect" and s["simulated"]
    assert all(n.startswith("the data tell little about") for n in s["notes"]), s["notes"]


def test_files_model_export_and_report(identified):
    out, s = identified["out"], identified["summary"]
    assert json.loads((out / "identification.json").read_text()) == s
    model = load_model_npz(out / "model.npz")
    assert model.order == s["fit"]["order"]
    f = np.load(out / "frf.npz")["freq_hz"]
    ss = load_statespace_json(out / "model.json")
    np.testing.assert_allclose(ss.freqresp(f) * np.exp(-2j * np.pi * f * model.delay_s)[:, None, None],
                               model.freqresp(f), rtol=1e-6, atol=1e-6 * np.abs(model.freqresp(f)).max())
    index = (out / "report" / "index.html").read_text()
    pngs = ["bode_magnitude.png", "bode_phase.png", "frf_error.png", "noise_distortion.png", "stabilisation.png",
            "excitation.png", "input_sensitivity.png", "time_records.png"]
    for name in pngs:
        assert f"src='{name}'" in index
        head = (out / "report" / name).read_bytes()[:24]
        assert head[:8] == b"\x89PNG\r\n\x1a\n"
        width, height = struct.unpack(">II", head[16:24])
        assert width > 500 and height > 300
    assert f"{s['fit']['order']} (" in index and f">{s['sensitivity']['iso_zone']}<" in index
    assert "ki_n_per_a" in index and "support_freq_hz" in index


def test_rig_facts_from_metadata_or_plant_message(session, tmp_path):
    rig, source = session_rig(session["path"])
    assert source == "sim" and make_rig(rig).values == RIG.values
    path = tmp_path / "facts.mcap"
    other = make_rig({"true_ki_factor": 1.1})
    write_session(path, [], ["y_a_x"], [(0, design_message(session["design"], 0))], RIG.dt,
                  facts={"plant": {"source": "hardware", "rig": other.to_dict()}})
    rig, source = session_rig(path)
    assert source == "hardware" and make_rig(rig).values == other.values
    path2 = tmp_path / "bare.mcap"
    write_session(path2, [], ["y_a_x"], [(0, design_message(session["design"], 0))], RIG.dt)
    assert session_rig(path2) == (None, None)


def test_select_order_rule():
    orders = [4, 6, 8, 10]

    def diagram(rows, chi2):
        order, pole, status = zip(*rows)
        pole = np.array(pole)
        return StabilisationDiagram(order=np.array(order), pole_rad_s=pole, freq_hz=np.abs(pole) / (2 * np.pi),
                                    damping=-pole.real / np.abs(pole), status=np.array(status),
                                    orders=np.array(orders), chi2_per_dof=np.array(chi2),
                                    band_hz=np.array([10.0, 1000.0]))

    def pair(f, z):
        w = 2 * np.pi * f
        return complex(-z * w, w * np.sqrt(1 - z * z))

    band = (10.0, 1000.0)
    rows = [(4, pair(100, 0.01), 0), (6, pair(100, 0.01), 3), (6, pair(300, 0.01), 0),
            (8, pair(100, 0.01), 3), (8, pair(300, 0.01), 1), (8, pair(2000, 0.01), 0),  # 2 kHz: out of band
            (10, pair(100, 0.01), 3), (10, pair(300, 0.01), 3), (10, pair(500, 0.02), 0)]
    chi = [50.0, 1.3, 1.0, 0.98]
    # N = 2 L Ny Nu = 100 residuals, p = n + (n + 1): AICc = chi2/dof (N - p) + 2 p N / (N - p - 1)
    # = 4570, 143.3, 124.5, 131.3
    assert select_order(diagram(rows, chi), band, n_lines=50, n_entries=1) == 8
    # an unstable lightly damped pair disqualifies order 8; order 10 with its 500 Hz mode stable is taken
    bad = rows[:5] + [(8, pair(600, -0.01), 3)] + rows[6:8] + [(10, pair(500, 0.02), 1)]
    assert select_order(diagram(bad, chi), band, n_lines=50, n_entries=1) == 10
    # heavily damped poles are not checked; a large penalty prefers the lower of the clean orders
    rows[-1] = (10, pair(500, 0.5), 0)
    assert select_order(diagram(rows, [50.0, 1.3, 1.0, 0.5]), band, n_lines=50, n_entries=1) == 10
    assert select_order(diagram(rows, [50.0, 1.3, 1.0, 0.5]), band, n_lines=50, n_entries=1, penalty=50) == 8
    # unweighted fits (the diagram holds the cost V): the scale of V does not matter
    v = np.array(chi) * (100 - np.array([9, 13, 17, 21])) / 2
    for scale in (1.0, 1e-12):
        assert select_order(diagram(rows, scale * v), band, n_lines=50, n_entries=1, weighted=False) == 8
    # nothing clean: the smallest criterion
    none_clean = [(n, pair(100, 0.01), 0) for n in orders]
    assert select_order(diagram(none_clean, chi), band, n_lines=50, n_entries=1) == 8
    with pytest.raises(ValueError, match="penalty"):
        select_order(diagram(rows, chi), band, n_lines=50, n_entries=1, penalty=-1)


def test_line_levels_against_closed_forms():
    d = design_multisine((20.0, 400.0), 20.0, 4000.0, ["u_1"], 1.0, n_periods=8, n_realisations=2, seed=1)
    n, res = d.n_per_period, d.fs_hz / d.n_per_period
    t = np.arange(d.total_samples) / d.fs_hz
    amp_ex = 1e-6 * (1 + np.arange(d.excited_lines.size))
    y = sum(a * np.cos(2 * np.pi * k * res * t + k) for a, k in zip(amp_ex, d.excited_lines))
    k_odd = d.detection_lines_odd[2]
    y = y + 3e-8 * np.cos(2 * np.pi * k_odd * res * t)           # an odd distortion tone
    sigma = 1e-7
    y = y + sigma * np.random.default_rng(0).standard_normal(t.size)
    lv = line_levels(y[:, None], d)
    np.testing.assert_allclose(lv.excited_amp[:, 0], amp_ex, rtol=0.05, atol=2e-8)
    assert lv.odd_amp[2, 0] == pytest.approx(3e-8, rel=0.3)
    # white noise: E|X|^2 = 4 sigma^2 / N per period, the mean of P periods has variance / P
    floor = np.sqrt(4 * sigma**2 / n / d.n_periods)
    assert np.median(lv.even_noise[:, 0]) == pytest.approx(floor, rel=0.25)
    assert np.median(lv.even_amp[:, 0]) == pytest.approx(floor, rel=0.5)
    np.testing.assert_array_equal(lv.odd_hz, d.detection_lines_odd * res)
    # a lost stretch of samples drops its periods, not the estimate
    y_gap = y.copy()
    y_gap[d.segment_start(1, 0) + 3 * n: d.segment_start(1, 0) + 3 * n + 10] = np.nan
    lv_gap = line_levels(y_gap[:, None], d)
    assert np.all(np.isfinite(lv_gap.excited_amp)) and np.all(np.isfinite(lv_gap.even_noise))
    assert line_levels(y[:, None], design_multisine((20.0, 400.0), 20.0, 4000.0, ["u_1"], 1.0, n_periods=1)) is None


def test_true_modes_and_relative_error():
    w = 2 * np.pi * np.array([100.0, 100.0, 300.0, 5000.0])
    p = w * (-0.01 + 1j * np.sqrt(1 - 0.01**2))
    poles = np.concatenate([p, p.conj(), [-50.0, 300.0]])
    modes = true_modes(poles, (10.0, 1000.0))
    assert [round(f, 6) for f, _ in modes] == [100.0, 300.0] and all(z == pytest.approx(0.01, rel=1e-3)
                                                                    for _, z in modes)
    g = np.ones((3, 2, 2))
    assert frf_relative_error(1.1 * g, g) == pytest.approx([0.1] * 3)
    with pytest.raises(ValueError, match="both be"):
        frf_relative_error(g, g[:, :1])


def test_fit_command_prints_headline_figures(session, tmp_path, capsys):
    args = Namespace(file=str(session["path"]), out=str(tmp_path / "cli"), estimator="h1", order=12, max_order=14,
                     experiment=None, rig=None, no_update=True, no_report=True, recover=False, json=False)
    assert fit_command.run(args) == 0
    text = capsys.readouterr().out
    assert "model order 12" in text and "h1 estimator" in text and "ISO 14839-3 zone" in text
    assert (tmp_path / "cli" / "model.npz").is_file() and not (tmp_path / "cli" / "report").exists()
    args.file = str(tmp_path / "missing.mcap")
    with pytest.raises(BadInput, match="missing.mcap: no such file"):  # ambid_cli.cli prints it, exit code 2
        fit_command.run(args)
