"""ambid import takes any excitation: the test's own closed loop (tests/core/lpm_testbench.py: scipy, not ambid's
plant) excited by band-limited noise that never repeats, by a long PRBS, and by chirps one input after the other,
logged mid-run as a rig logs (CSV in volts, a time column that does not start at 0), imports without a design and
fits: its modes within 0.5 % (frequency) and 10 % (damping) of the test's model."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

import lpm_testbench as tb
from ambid.frf.offline import frf_from_session
from ambid.records.importer import import_record
from ambid.identification import identify_session
from ambid_cli import cli

GAIN_Y, GAIN_U = 2.0e4, 0.5          # sensor [V/m], current monitor and excitation input [V/A]
SKIP_S, RECORD_S = 5.0, 30.0          # the log starts mid-run, after the loop ran this long


def _write(d, name: str, r: np.ndarray, t0: float, keep_s: float = RECORD_S) -> tuple:
    """Simulate the loop under r, keep the last keep_s, write CSV (volts) and MAP.yaml; return the paths."""
    y, u = tb.simulate(r, seed=7)
    n = int(keep_s * tb.FS)
    y, u, r = y[-n:], u[-n:], r[-n:]
    t = t0 + np.arange(n) / tb.FS
    cols = {"time": t}
    cols.update({f"disp_{a}": y[:, i] * GAIN_Y for i, a in enumerate(tb.AXES)})
    cols.update({f"cur_{a}": u[:, i] * GAIN_U for i, a in enumerate(tb.AXES)})
    cols.update({f"exc_{a}": r[:, i] * GAIN_U for i, a in enumerate(tb.AXES)})
    csv = d / f"{name}.csv"
    np.savetxt(csv, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="",
               fmt="%.9g")
    mp = d / f"{name}.yaml"
    mp.write_text("time_column: time\n"
                  + "outputs:\n" + "".join(f"  y_{a}: {{column: disp_{a}, scale: {1 / GAIN_Y:.6e}, unit: m}}\n"
                                           for a in tb.AXES)
                  + "currents:\n" + "".join(f"  u_{a}: {{column: cur_{a}, scale: {1 / GAIN_U:.6e}, unit: A}}\n"
                                            for a in tb.AXES)
                  + "excitation:\n" + "".join(f"  r_{a}: {{column: exc_{a}, scale: {1 / GAIN_U:.6e}, unit: A}}\n"
                                              for a in tb.AXES))
    return csv, mp


def _frf_error(session: str) -> float:
    res = frf_from_session(session)
    g0 = tb.frf(res.freq_hz)
    return float(np.median(np.linalg.norm(res.frf - g0, axis=(1, 2)) / np.linalg.norm(g0, axis=(1, 2))))


def test_band_limited_noise_logged_mid_run_imports_without_a_design_and_fits(tmp_path, capsys):
    n = int((SKIP_S + RECORD_S) * tb.FS)
    csv, mp = _write(tmp_path, "noise", tb.band_noise(n, (10.0, 800.0), 0.25, seed=3), t0=1234.5)
    assert cli.main(["import", str(csv), "--map", str(mp), "--out", str(tmp_path / "noise.mcap")]) == 0
    out = capsys.readouterr().out
    line = [ln for ln in out.splitlines() if ln.startswith("estimator:")]
    assert len(line) == 1 and "local polynomial method" in line[0] and "does not repeat" in line[0], out
    s = identify_session(tmp_path / "noise.mcap", tmp_path / "fit", report=True)
    assert s["excitation"]["kind"] == "recorded" and (tmp_path / "fit" / "report" / "index.html").exists()
    fitted = [(m["freq_hz"], m["damping"]) for m in s["fit"]["modes"]]
    for f0, z0 in tb.true_modes(tuple(s["band_hz"])):
        f, z = min(fitted, key=lambda m: abs(m[0] - f0))
        assert abs(f / f0 - 1) < 0.005 and abs(z / z0 - 1) < 0.10, (f0, z0, f, z, fitted)
    assert len(tb.true_modes(tuple(s["band_hz"]))) == 4


def _prbs(n: int, seed: int) -> np.ndarray:
    """(n, 4) maximum-length sequences of order 18 (262143 bits: longer than the record, so they never repeat in
    it), one shift per input, held 2 samples, +-0.25 A."""
    bits = signal.max_len_seq(18)[0].astype(float) * 2 - 1
    shifts = np.random.default_rng(seed).integers(0, bits.size, 4)
    idx = np.arange(n) // 2
    return 0.25 * np.stack([bits[(idx + s) % bits.size] for s in shifts], axis=1)


def _chirps(n: int) -> np.ndarray:
    """(n, 4) linear chirps 5-900 Hz over 6 s, one input after the other (each input's own experiment), repeated
    with the next input each time; never the same sequence twice within the record."""
    t_one = 6.0
    m = int(t_one * tb.FS)
    t = np.arange(m) / tb.FS
    one = 0.4 * signal.chirp(t, 5.0, t_one, 900.0) * signal.windows.tukey(m, 0.05)
    r = np.zeros((n, 4))
    for k in range(0, n // m + 1):
        a, b = k * m, min((k + 1) * m, n)
        if a < b:
            r[a:b, k % 4] = one[:b - a] * (1 + 0.1 * (k // 4))   # each round a little louder: no repeat
    return r


@pytest.mark.parametrize("kind", ["prbs", "chirps"])
def test_prbs_and_chirps_import_and_give_the_frf(tmp_path, kind, capsys):
    n = int((SKIP_S + RECORD_S) * tb.FS)
    r = _prbs(n, 4) if kind == "prbs" else _chirps(n)
    csv, mp = _write(tmp_path, kind, r, t0=77.25)
    assert cli.main(["import", str(csv), "--map", str(mp), "--out", str(tmp_path / f"{kind}.mcap")]) == 0
    assert "local polynomial method" in capsys.readouterr().out
    err = _frf_error(str(tmp_path / f"{kind}.mcap"))
    assert err < 0.03, err


def test_a_periodic_multisine_still_takes_period_averaging(tmp_path):
    """A multisine repeated from the first row: the design is found again and the periods are averaged."""
    from ambid.excitation import design_multisine

    d = design_multisine((10.0, 800.0), 5.0, tb.FS, [f"u_{a}" for a in tb.AXES], 0.4, n_periods=4,
                         n_realisations=2, n_transient_periods=2, seed=5)
    r = np.vstack([d.samples(0, d.total_samples), np.zeros((2000, 4))])
    csv, mp = _write(tmp_path, "multisine", np.vstack([np.zeros((int(SKIP_S * tb.FS), 4)), r]), t0=0.0,
                     keep_s=len(r) / tb.FS)
    res = import_record(csv, mp, tmp_path / "ms.mcap")
    assert res.design.kind == "multisine" and "period averaging" in res.estimator
    assert _frf_error(str(tmp_path / "ms.mcap")) < 0.05
