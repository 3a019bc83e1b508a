"""Real measurements nobody on this project made (tests/data/real/), fitted and checked against an independent
method written here: sdypy-EMA's LSCF with a stabilisation rule of this test, or the source's published values.

What is counted: the modes ambid prints that the independent method does not find (must be none: a
computational pole printed as a mode is a wrong result) and those it finds that ambid does not print.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

REAL = Path(__file__).resolve().parents[1] / "data" / "real"
BEAM = REAL / "ladisk_beam_uff" / "measurement.uff"


def _lscf_stable(freq_hz, H, lo, hi, top=60, last=6):
    """sdypy-EMA's LSCF poles at its highest orders; a pole is stable when every one of the last ``last`` orders
    holds one within 1 % in frequency (positively damped, zeta < 0.2). H: (n_out, n_in..., L)."""
    from sdypy import EMA

    m = EMA.Model(frf=H, freq=freq_hz, lower=lo, upper=hi, pol_order_high=top, frf_form="accelerance")
    m.get_poles(show_progress=False)
    rows = []
    for p in m.all_poles[-last:]:
        w = np.abs(p)
        z = -p.real / w
        f = w / (2 * np.pi)
        rows.append(np.sort(f[(p.imag > 0) & (z > 0) & (z < 0.2) & (f > lo) & (f < hi)]))
    return np.array([x for x in rows[-1] if all(r.size and np.min(np.abs(r - x)) < 0.01 * x for r in rows)])


@pytest.fixture(scope="module")
def beam_fit(tmp_path_factory):
    pytest.importorskip("pyuff")
    from ambid.frf.frf_file import read_frf_file
    from ambid.identification.frf_file_fit import identify_frf

    measured = read_frf_file(BEAM)
    out = tmp_path_factory.mktemp("beam")
    return measured, identify_frf(measured, out, report=False), out


def test_uff_channels_are_node_and_direction_units_from_the_header(beam_fit):
    measured, _, _ = beam_fit
    assert measured.output_names == ("1+X",) and measured.input_names == ("1+X", "2+X", "3+X")
    assert measured.output_units == ("m/s^2",) and measured.input_units == ("N", "N", "N")
    assert measured.form == "accelerance" and measured.unit == "m/s^2/N"
    assert measured.freq_hz[0] == 1.0 and measured.freq_hz.size == 1000      # the abscissa as written, 0 Hz out
    assert any("0 Hz line is left out" in n for n in measured.notes)
    assert any("'TestCase' on every dataset" in n for n in measured.notes)


def test_beam_modes_against_lscf_none_printed_that_are_not_there(beam_fit):
    measured, summary, out = beam_fit
    H = measured.frf.transpose(1, 2, 0)[0]          # (3 references, L): one accelerometer
    stable = _lscf_stable(measured.freq_hz, H, 5.0, 995.0)
    printed = np.array([m["freq_hz"] for m in summary["fit"]["modes"]])
    extra = [f for f in printed if np.min(np.abs(stable - f)) > 0.001 * f]
    missing = [f for f in stable if np.min(np.abs(printed - f)) > 0.001 * f]
    assert extra == [], f"printed modes LSCF does not find: {extra} (LSCF: {stable})"
    assert len(printed) >= 6 and len(missing) <= 1, (printed, stable)
    for f in printed:   # the same modes, to 0.01 %
        assert np.min(np.abs(stable - f)) / f < 1e-4
    # the fit's other poles are kept apart, each with its reason, and the JSON says so
    comp = summary["fit"]["computational_poles"]
    assert len(comp) >= 5 and all(c["reason"].endswith("computational") for c in comp)
    on_disk = json.loads((out / "identification.json").read_text())
    assert [m["freq_hz"] for m in on_disk["fit"]["modes"]] == pytest.approx(list(printed))
    assert on_disk["form"] == "accelerance" and on_disk["unit"] == "m/s^2/N"


def test_uff_binary_58b_reads_as_the_ascii_file(beam_fit, tmp_path):
    """UFF 58b (binary): the beam's datasets written by pyuff, the format's reference implementation, in binary."""
    import pyuff

    from ambid.frf.frf_file import read_frf_file

    measured, _, _ = beam_fit
    sets = pyuff.UFF(str(BEAM)).read_sets()
    path = tmp_path / "beam_binary.uff"
    writer = pyuff.UFF(str(path))
    for s in sets:
        writer.write_sets(dict(s, binary=1), mode="add")
    again = read_frf_file(path)
    assert again.input_names == measured.input_names and again.form == "accelerance"
    np.testing.assert_allclose(again.frf, measured.frf, rtol=1e-6)


AMB = REAL / "tum_mlps_amb_lms"
# the source's eigenfrequencies (Identifizierte_EF.txt), read off its reference -> acceleration FRFs: 16, 51 and
# 59 Hz are the closed loop's suspension modes, which the plant's FRF (current -> acceleration) does not have
PUBLISHED_FLEXIBLE_HZ = (100.0, 162.0, 212.0)


@pytest.fixture(scope="module")
def amb_fit(tmp_path_factory):
    from ambid.records.importer import import_record
    from ambid.identification import identify_session

    d = tmp_path_factory.mktemp("amb")
    res = import_record([AMB / "Sweep_Time_Anregung.mat", AMB / "Sweep_Time_Ausgang.mat"], AMB / "MAP.yaml",
                        d / "amb.mcap")
    return res, identify_session(d / "amb.mcap", d / "fit", report=False), d


def _welch_indirect_lscf():
    """Independent of ambid's estimator and fit: Welch cross spectra through the excitation (H = S_yr / S_ur,
    consistent in closed loop), then sdypy-EMA's LSCF with this test's stabilisation rule."""
    import scipy.io as sio
    import scipy.signal as sg

    a = sio.loadmat(AMB / "Sweep_Time_Anregung.mat", squeeze_me=True, struct_as_record=False)
    b = sio.loadmat(AMB / "Sweep_Time_Ausgang.mat", squeeze_me=True, struct_as_record=False)
    u, y, r = a["Signal"].y_values.values, b["Signal_0"].y_values.values, b["Signal_1"].y_values.values
    f, s_ur = sg.csd(r, u, fs=2048.0, nperseg=4096)
    H = np.array([sg.csd(r, y[:, k], fs=2048.0, nperseg=4096)[1] / s_ur for k in range(y.shape[1])])
    sel = (f >= 5) & (f <= 250)
    return _lscf_stable(f[sel], H[:, sel], 5.0, 250.0, last=8)


def test_lms_records_of_an_amb_rig_import_with_their_names_units_and_injection_point(amb_fit):
    res, summary, d = amb_fit
    assert res.n_rows == 32768 and res.fs_hz == 2048.0 and res.design.kind == "recorded"
    assert any("Welle:1:+X" in n and "[m/s^2]" in n and "shown by Test.Lab in g" in n for n in res.notes)
    assert any("injected at the reference (r_x [V])" in n for n in res.notes)
    assert summary["outputs"] == [f"y_acc{k}" for k in range(1, 9)] and summary["inputs"] == ["u_x"]
    model = json.loads((d / "fit" / "model.json").read_text())
    assert set(model["output_units"]) == {"m/s^2"} and model["input_units"] == ["A"]



def test_inspect_gives_the_excitation_in_its_own_unit(amb_fit):
    """The sweep is injected at the position reference in V: ``ambid inspect`` says its rms in V, not in A."""
    import re

    import scipy.io as sio

    from ambid_cli.commands.inspect import describe, format_report

    _, _, d = amb_fit
    line = next(ln for ln in format_report(describe(str(d / "amb.mcap"))).splitlines()
                if ln.startswith("  excitation  ") and " rms " in ln)
    m = re.search(r"rms ([0-9.e+-]+) V$", line)
    assert m, line
    sweep = sio.loadmat(AMB / "Sweep_Time_Ausgang.mat", squeeze_me=True, struct_as_record=False)["Signal_1"]
    assert float(m.group(1)) == pytest.approx(np.sqrt(np.mean(sweep.y_values.values ** 2)), rel=0.01)


def test_amb_rig_modes_against_an_independent_fit_and_the_published_values(amb_fit):
    _, summary, _ = amb_fit
    stable = _welch_indirect_lscf()
    printed = np.array([m["freq_hz"] for m in summary["fit"]["modes"]])
    extra = [f for f in printed if np.min(np.abs(stable - f)) > 0.01 * f]
    missing = [f for f in stable if np.min(np.abs(printed - f)) > 0.01 * f]
    assert extra == [], f"printed modes the independent fit does not find: {extra} (it finds {stable})"
    assert len(printed) >= 4 and len(missing) <= 2, (printed, stable)
    for f in PUBLISHED_FLEXIBLE_HZ:
        assert np.min(np.abs(printed - f)) / f < 0.015, (f, printed)
    assert summary["fit"]["computational_poles"], "the fit's other poles are kept apart"


def test_reference_injection_with_accelerometers_reports_no_sensitivity(amb_fit):
    from ambid_cli.commands.fit import format_summary

    _, summary, _ = amb_fit
    sens = summary["sensitivity"]
    assert sens["worst_peak"] is None and sens["iso_zone"] is None and sens["loop"] is None
    assert len(sens["none"]) == 1 and sens["none"][0].startswith("no sensitivity for r_x: it is injected at the "
                                                                 "controller's position reference [V]")
    text = format_summary(summary)
    assert "zone" not in text and "no sensitivity for r_x" in text


def test_an_analysers_coherence_is_read_and_its_low_lines_said(tmp_path, capsys):
    """UFF 58 coherence datasets (function type 6) beside the beam's FRFs, as an analyser writes them: read per
    response/reference pair, and ``ambid fit`` says the lines where it is low, one line per pair."""
    import pyuff

    from ambid.frf.frf_file import read_frf_file
    from ambid_cli import cli

    sets = pyuff.UFF(str(BEAM)).read_sets()
    coherence = []
    for s in sets:
        c = np.ones(s["x"].size)
        if s["ref_node"] == 2:
            c[(s["x"] >= 600) & (s["x"] <= 650)] = 0.3
        coherence.append(dict(s, func_type=6, data=c.astype(complex), ordinate_spec_data_type=0,
                              orddenom_spec_data_type=0))
    path = tmp_path / "beam_with_coherence.uff"
    pyuff.UFF(str(path)).write_sets(list(sets) + coherence, mode="overwrite")
    measured = read_frf_file(path)
    assert measured.coherence.shape == measured.frf.shape and np.nanmin(measured.coherence[:, 0, 1]) == 0.3
    assert cli.main(["fit", str(path), "--out", str(tmp_path / "fit"), "--max-order", "8", "--no-report"]) == 0
    said = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("data quality:")]
    assert said == ["data quality: low coherence on 1+X/2+X (below 0.5, lowest 0.3) at 51 of 1000 lines: 600-650 Hz"]


RING = REAL / "skrf_ring_slot_vna" / "ring_slot_measured.s1p"


@pytest.fixture(scope="module")
def ring_fit(tmp_path_factory):
    from ambid.frf.frf_file import read_frf_file
    from ambid.identification.frf_file_fit import identify_frf

    measured = read_frf_file(RING)
    return measured, identify_frf(measured, tmp_path_factory.mktemp("ring"), report=False)


def test_touchstone_reads_as_scikit_rf_reads_it(ring_fit):
    """ambid's Touchstone reader against scikit-rf's (another implementation of the format)."""
    skrf = pytest.importorskip("skrf")
    measured, _ = ring_fit
    network = skrf.Network(str(RING))
    np.testing.assert_allclose(measured.freq_hz, network.f, rtol=1e-12)
    np.testing.assert_allclose(measured.frf, network.s, rtol=1e-12)
    assert measured.kind == "touchstone" and measured.form == "S-parameters"
    assert measured.output_names == ("b1",) and measured.input_names == ("a1",)
    assert any("Touchstone 1-port S parameters (RI, reference impedance 50 ohm)" in n for n in measured.notes)


def _ring_slot_independent():
    """scikit-rf's vector fitting (its own order rule) and its Q-factor fit of the reflection resonance: the in-band
    resonances [Hz] of the one and the loaded resonance [Hz] of the other."""
    skrf = pytest.importorskip("skrf")
    from skrf.qfactor import Qfactor
    from skrf.vectorFitting import VectorFitting

    network = skrf.Network(str(RING))
    vf = VectorFitting(network)
    vf.auto_fit()
    p = vf.poles[vf.poles.imag > 0]
    f, z = np.abs(p) / (2 * np.pi), -p.real / np.abs(p)
    in_band = np.sort(f[(z > 0) & (z < 0.5) & (f >= network.f[0]) & (f <= network.f[-1])])
    q = Qfactor(network, res_type="reflection")
    q.fit()
    return in_band, float(q.f_L)


def test_ring_slot_one_resonance_and_no_pole_fitted_to_the_analysers_ripple(ring_fit):
    """The VNA's ripple (dips of 2-3 lines at 103 and 106.5 GHz) took two poles of a high-order fit that were printed
    as modes; they are computational, and the one resonance is where scikit-rf's two methods put it."""
    _, summary = ring_fit
    vf, q_f = _ring_slot_independent()
    printed = np.array([m["freq_hz"] for m in summary["fit"]["modes"]])
    assert vf.size == 1, vf
    extra = [f for f in printed if np.min(np.abs(vf - f)) > 0.03 * f]
    missing = [f for f in vf if printed.size == 0 or np.min(np.abs(printed - f)) > 0.03 * f]
    assert extra == [] and missing == [], (printed, vf)
    # a broad resonance (loaded Q 3.7): the three estimates of its frequency differ by up to 2 %
    assert abs(printed[0] - vf[0]) / vf[0] < 0.02 and abs(printed[0] - q_f) / q_f < 0.025, (printed, vf, q_f)
    comp = summary["fit"]["computational_poles"]
    ripple = [c for c in comp if c["freq_hz"] > 100e9 and c["damping"] > 0]
    assert ripple and all(c["reason"].startswith("below the noise") for c in ripple), ripple


def test_bode_axes_carry_each_files_units(beam_fit, ring_fit):
    """The report's Bode matrix labels its rows and columns in the file's units: the beam's accelerance in
    m/s^2/N from hammers in N, the ring slot's S11 dimensionless (not m/A from A, as a session's)."""
    from ambid.report import figures
    from ambid.report.html import frf_column_units, frf_row_units

    for (measured, summary, *_), row, col in ((beam_fit, "|G| [dB re 1 m/s^2/N]", "from 1+X [N]"),
                                              (ring_fit, "|G| [dB]", "from a1 [-]")):
        fig = figures.bode_matrix(measured.freq_hz, measured.frf, None, {}, "magnitude",
                                  input_names=measured.input_names, output_names=measured.output_names,
                                  row_units=frf_row_units(summary), col_units=frf_column_units(summary))
        ax = fig.axes[0]
        assert ax.get_ylabel().endswith(row) and ax.get_title() == col, (ax.get_ylabel(), ax.get_title())


def test_uff_164_units_are_honoured(beam_fit, tmp_path):
    """The beam's datasets written by pyuff in mm (dataset 164: length factor 1000, the values 1000 x larger) read
    back as the SI file: UFF's factors convert the file's units to SI by division."""
    import pyuff

    from ambid.frf.frf_file import read_frf_file

    measured, _, _ = beam_fit
    sets = pyuff.UFF(str(BEAM)).read_sets()
    units = dict(type=164, units_code=5, units_description="mm (milli newton)", temp_mode=1, length=1000.0,
                 force=1.0, temp=1.0, temp_offset=273.15)
    in_mm = [dict(s, data=np.asarray(s["data"]) * 1000.0, ordinate_axis_units_lab="mm/s^2") for s in sets]
    path = tmp_path / "beam_mm.uff"
    writer = pyuff.UFF(str(path))
    writer.write_sets([units] + in_mm, mode="overwrite")
    again = read_frf_file(path)
    np.testing.assert_allclose(again.frf, measured.frf, rtol=1e-5)
    assert again.output_units == ("m/s^2",) and again.input_units == ("N", "N", "N")
    assert any("dataset 164" in n and "length factor 1000" in n and "converted to SI" in n for n in again.notes)


STRIPLINE = REAL / "skrf_stripline_resonator_vna" / "resonator_36mm.s2p"


def test_stripline_resonator_modes_against_lscf_and_the_q_factor_fit(tmp_path):
    """A Keysight PNA-X's 2-port measurement of a stripline resonator: the two resonances ambid prints are the
    stable poles of sdypy-EMA's LSCF on S21 and where scikit-rf's Q-factor fit of S21 puts them (as scikit-rf's
    example fits them); none printed that is not there."""
    skrf = pytest.importorskip("skrf")
    from skrf.qfactor import Qfactor

    from ambid.frf.frf_file import read_frf_file
    from ambid.identification.frf_file_fit import identify_frf

    measured = read_frf_file(STRIPLINE)
    assert measured.output_names == ("b1", "b2") and measured.frf.shape == (401, 2, 2)
    summary = identify_frf(measured, tmp_path / "fit", report=False)
    printed = np.array([m["freq_hz"] for m in summary["fit"]["modes"]])
    network = skrf.Network(str(STRIPLINE))
    np.testing.assert_allclose(measured.frf, network.s, rtol=1e-12)
    stable = _lscf_stable(network.f, network.s[:, 1, 0][None], 1.02e9, 4.9e9, top=40)
    extra = [f for f in printed if np.min(np.abs(stable - f)) > 0.001 * f]
    missing = [f for f in stable if np.min(np.abs(printed - f)) > 0.001 * f]
    assert extra == [] and missing == [] and printed.size == 2, (printed, stable)
    for f, band in zip(printed, ("1.75-2.25GHz", "3.75-4.25GHz")):
        q = Qfactor(network[band].s21, res_type="transmission")
        q.fit()
        assert abs(f - q.f_L) / q.f_L < 5e-4, (f, q.f_L)


def test_a_short_file_with_a_high_order_allowed_still_prints_only_its_resonance(tmp_path):
    """101 lines of S11 with orders up to 64 allowed: without the small-sample correction of the order rule the fit
    chose order 58, its poles followed the ripple (97 and 106 GHz printed) and the resonance was lost."""
    from ambid.frf.frf_file import read_frf_file
    from ambid.identification.frf_file_fit import identify_frf

    summary = identify_frf(read_frf_file(RING), tmp_path / "fit", max_order=64, report=False)
    vf, _ = _ring_slot_independent()
    printed = np.array([m["freq_hz"] for m in summary["fit"]["modes"]])
    assert printed.size == 1 and abs(printed[0] - vf[0]) / vf[0] < 0.02, (printed, vf, summary["fit"]["order"])
    assert summary["fit"]["order"] <= 32
