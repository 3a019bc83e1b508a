"""ExcitationDesign: layout, streaming, periodicity, serialisation, errors, headroom."""

import json

import numpy as np
import pytest
from ambid.excitation import (ExcitationDesign, check_headroom, design_dibs, design_multisine, design_noise,
                              design_prbs, design_stepped_sine, design_swept_sine)

NAMES = ("x_a", "y_a", "x_b", "y_b")
FS = 1000.0


def make(kind, seed=0):
    """One small design of each kind (4 inputs, a few segments)."""
    if kind == "multisine":
        return design_multisine((3.0, 60.0), 4.0, FS, NAMES, [1.0, 1.5, 2.0, 0.5], n_periods=2,
                                n_realisations=2, n_transient_periods=1, seed=seed)
    if kind == "stepped_sine":
        return design_stepped_sine((20.0, 60.0), 4.0, FS, NAMES, 1.0, settle_s=0.01, n_cycles=3)
    if kind == "swept_sine":
        return design_swept_sine((10.0, 200.0), 8.0, FS, NAMES, 1.0, n_periods=2,
                                 mimo="orthogonal")
    if kind == "noise":
        return design_noise((20.0, 200.0), 8.0, FS, NAMES, 1.0, n_periods=3, n_realisations=2,
                            seed=seed)
    if kind == "prbs":
        return design_prbs(FS, 6, NAMES, 1.0, clock_divider=2, n_periods=2, n_realisations=2,
                           mimo="orthogonal", seed=seed)
    if kind == "dibs":
        return design_dibs((2.0, 100.0), 4.0, FS, NAMES, 1.0, n_periods=2, n_realisations=2,
                           seed=seed, n_iterations=30)
    raise AssertionError(kind)


KINDS = ("multisine", "stepped_sine", "swept_sine", "noise", "prbs", "dibs")
PERIODIC = tuple(k for k in KINDS if k != "noise")


@pytest.fixture(scope="module")
def designs():
    return {k: make(k) for k in KINDS}


@pytest.mark.parametrize("kind", KINDS)
def test_blocks_join_without_gap_or_overlap(designs, kind):
    d = designs[kind]
    whole = d.samples(0, d.total_samples)
    assert whole.shape == (d.total_samples, d.n_inputs)
    # an odd block size straddles every segment boundary at a different phase
    joined = np.concatenate([blk for _, blk in d.blocks(777)])
    np.testing.assert_allclose(joined, whole, rtol=0, atol=1e-12)
    starts = [s for s, _ in d.blocks(777)]
    assert starts == list(range(0, d.total_samples, 777))
    if kind == "multisine":  # independent check of the layout: direct cosine sums
        rng = np.random.default_rng(0)
        for off in rng.integers(0, d.total_samples, 20):
            m, e, _ = d.segment_of(off)
            t = (off - d.segment_start(m, e)) % d.n_per_period
            arg = 2 * np.pi * d.excited_lines * t / d.n_per_period
            ref = np.sum(d.amplitudes_a * np.real(d.phasors[m, e] * np.exp(1j * arg)), axis=1)
            np.testing.assert_allclose(whole[off], ref, atol=1e-12)
    # blocks cut exactly at segment starts, and one sample at a time near them
    for m in range(d.n_realisations):
        for e in range(d.n_experiments):
            s0 = d.segment_start(m, e)
            a = max(s0 - 3, 0)
            stop = min(s0 + 3, d.total_samples)
            single = np.concatenate([d.samples(k, 1) for k in range(a, stop)])
            np.testing.assert_allclose(single, whole[a:a + single.shape[0]], rtol=0, atol=1e-12)
    assert d.samples(5, 0).shape == (0, d.n_inputs)
    with pytest.raises(ValueError, match="outside the experiment"):
        d.samples(d.total_samples - 1, 2)
    with pytest.raises(ValueError):
        d.samples(-1, 1)


@pytest.mark.parametrize("kind", KINDS)
def test_layout_time_and_segment_of(designs, kind):
    d = designs[kind]
    period, pt, per = d.segment_layout()
    # closed form of the documented layout, computed independently
    total = sum(int(period[m] * (pt[m] + per[m])) * d.n_experiments
                for m in range(d.n_realisations))
    assert d.total_samples == total
    assert d.measurement_time_s == d.total_samples / d.fs_hz
    if kind != "stepped_sine":
        assert total == (d.n_realisations * d.n_experiments
                         * (d.n_transient_periods + d.n_periods) * d.n_per_period)
    offset = 0
    for m in range(d.n_realisations):
        for e in range(d.n_experiments):
            assert d.segment_start(m, e) == offset
            for q in range(pt[m] + per[m]):
                assert d.segment_of(offset + q * period[m]) == (m, e, q)
                assert d.segment_of(offset + (q + 1) * period[m] - 1) == (m, e, q)
            offset += period[m] * (pt[m] + per[m])
    with pytest.raises(ValueError):
        d.segment_of(d.total_samples)


@pytest.mark.parametrize("kind", PERIODIC)
def test_periodic_kinds_repeat_exactly(designs, kind):
    """Within a segment the signal repeats its period: a DFT over all periods of a
    segment has energy only on bins that are multiples of the period count."""
    d = designs[kind]
    period, pt, per = d.segment_layout()
    for m in range(min(d.n_realisations, 3)):
        for e in range(d.n_experiments):
            q = pt[m] + per[m]
            x = d.samples(d.segment_start(m, e), period[m] * q)
            spec = np.abs(np.fft.fft(x, axis=0)) ** 2
            total = spec.sum()
            if total == 0:
                continue  # an input not excited in this experiment
            off_grid = np.arange(spec.shape[0]) % q != 0
            assert spec[off_grid].sum() / total < 1e-10


def energy_outside(d, lines, m, e):
    x = d.period(m, e)
    x = np.tile(x, (d.n_per_period // x.shape[0], 1))
    spec = np.abs(np.fft.fft(x, axis=0)) ** 2
    keep = np.zeros(d.n_per_period, bool)
    keep[lines] = keep[d.n_per_period - np.asarray(lines)] = True
    return spec[~keep].sum() / spec.sum()


def test_prbs_and_stepped_sine_energy_only_on_designed_lines(designs):
    prbs = designs["prbs"]
    for m in range(prbs.n_realisations):
        for e in range(prbs.n_experiments):
            assert energy_outside(prbs, prbs.excited_lines, m, e) < 1e-10
    # every line of the PRBS with clock divider 2 except multiples of 63 is excited
    n = prbs.n_per_period
    assert n == 2 * 63
    k = np.arange(1, (n - 1) // 2 + 1)
    assert np.array_equal(prbs.excited_lines, k[k % 63 != 0])
    stepped = designs["stepped_sine"]
    for m in range(stepped.n_realisations):
        e = m % stepped.n_experiments
        assert energy_outside(stepped, stepped.excited_lines[m:m + 1], m, e) < 1e-10
        assert np.abs(stepped.reference_spectrum(m, e)[e, m]) == pytest.approx(
            stepped.amplitudes_a[e, m], rel=1e-12)


def test_dibs_is_binary_with_clean_even_lines(designs):
    d = designs["dibs"]
    x = d.samples(0, d.total_samples)
    for i in range(d.n_inputs):
        assert np.unique(np.abs(x[:, i][x[:, i] != 0])).size == 1  # two levels +-peak
    assert min(d.options["power_fraction"]) > 0.6
    even = np.arange(0, d.n_per_period, 2)
    for m in range(d.n_realisations):
        assert energy_outside(d, np.setdiff1d(np.arange(d.n_per_period), even), m, m % 4) < 1e-10
    assert d.detection_lines_even.size > 0


def test_noise_statistics_and_clipping(designs):
    d = designs["noise"]
    x = d.samples(0, d.total_samples)
    assert np.all(np.abs(x) <= d.peak_a + 1e-15)
    steady = x[200:]  # past the filter's start-up
    assert np.allclose(np.std(steady, axis=0), d.rms_a, rtol=0.25)
    assert np.max(np.abs(np.corrcoef(steady.T) - np.eye(4))) < 0.2  # independent inputs
    # realisations differ, and the same realisation is reproduced
    r0 = d.samples(d.segment_start(0, 0), 100)
    r1 = d.samples(d.segment_start(1, 0), 100)
    assert not np.allclose(r0, r1)
    with pytest.raises(ValueError, match="no period"):
        d.period(0, 0)


@pytest.mark.parametrize("kind", KINDS)
def test_seed_determinism(kind):
    a, b = make(kind, seed=11), make(kind, seed=11)
    assert a == b
    np.testing.assert_array_equal(a.samples(0, a.total_samples), b.samples(0, b.total_samples))
    if kind in ("multisine", "noise", "prbs", "dibs"):
        c = make(kind, seed=12)
        assert not np.array_equal(a.samples(0, a.total_samples), c.samples(0, c.total_samples))


@pytest.mark.parametrize("kind", KINDS)
def test_dict_round_trip_through_json(designs, kind):
    d = designs[kind]
    text = json.dumps(d.to_dict(), allow_nan=False)
    back = ExcitationDesign.from_dict(json.loads(text))
    assert back == d
    assert back.to_dict() == d.to_dict()
    for name in ("excited_lines", "detection_lines_odd", "detection_lines_even", "amplitudes_a",
                 "peak_a", "rms_a", "crest_factor"):
        np.testing.assert_array_equal(getattr(back, name), getattr(d, name))
    if d.phasors is not None:
        np.testing.assert_array_equal(back.phasors, d.phasors)
    np.testing.assert_array_equal(back.samples(0, back.total_samples),
                                  d.samples(0, d.total_samples))
    with pytest.raises(ValueError, match="format"):
        ExcitationDesign.from_dict({**d.to_dict(), "format": "other"})


def test_design_is_immutable(designs):
    d = designs["multisine"]
    with pytest.raises(Exception):
        d.fs_hz = 2.0
    with pytest.raises(ValueError):
        d.amplitudes_a[0, 0] = 1.0


def test_bad_input_errors():
    ok = dict(band_hz=(3.0, 60.0), resolution_hz=4.0, fs_hz=FS, input_names=NAMES,
              peak_current_a=1.0)
    with pytest.raises(ValueError, match=r"resolution_hz = fs_hz/N.*N=333"):
        design_multisine(**{**ok, "resolution_hz": 3.0})
    with pytest.raises(ValueError, match="Nyquist"):
        design_multisine(**{**ok, "band_hz": (3.0, 600.0)})
    with pytest.raises(ValueError, match="finite"):
        design_multisine(**{**ok, "band_hz": (np.nan, 60.0)})
    with pytest.raises(ValueError, match="peak_current_a"):
        design_multisine(**{**ok, "peak_current_a": [1.0, np.nan, 1.0, 1.0]})
    with pytest.raises(ValueError, match="peak_current_a"):
        design_multisine(**{**ok, "peak_current_a": [1.0, 2.0]})
    with pytest.raises(ValueError, match="no frequency line"):
        design_multisine(**{**ok, "band_hz": (4.5, 7.5)})
    with pytest.raises(ValueError, match="no excited line"):
        design_multisine(**{**ok, "band_hz": (7.5, 8.5), "grid": "odd"})
    with pytest.raises(ValueError, match="mimo"):
        design_multisine(**ok, mimo="all")
    with pytest.raises(ValueError, match="n_periods"):
        design_multisine(**ok, n_periods=0)
    with pytest.raises(ValueError, match="unique"):
        design_multisine(**{**ok, "input_names": ("a", "a")})
    with pytest.raises(ValueError, match="power-of-two"):
        design_prbs(FS, 5, ("a", "b", "c"), 1.0, mimo="orthogonal")
    with pytest.raises(ValueError, match="seed"):
        design_noise(**ok, seed=-1)
    good = design_multisine(**ok).to_dict()
    bad = {**good, "amplitudes_a": [[float("nan")] + row[1:] for row in good["amplitudes_a"]]}
    with pytest.raises(ValueError, match="amplitudes_a holds NaN"):
        ExcitationDesign.from_dict(bad)
    with pytest.raises(ValueError, match=r"shape \(Nu, L\)"):
        ExcitationDesign.from_dict({**good, "amplitudes_a": good["amplitudes_a"][:2]})


def test_check_headroom():
    d = design_multisine((3.0, 60.0), 4.0, FS, NAMES, [2.5, 1.0, 1.0, 1.0], seed=0)
    margin = check_headroom(d, 4.0, [1.0, 1.8, 1.8, 1.8])
    np.testing.assert_allclose(margin, [0.5, 1.2, 1.2, 1.2])
    with pytest.raises(ValueError) as err:
        check_headroom(d, 4.0, 1.8)
    msg = str(err.value)
    assert ("input 'x_a': excitation peak 2.5 A + working current 1.8 A exceeds the 4.0 A limit; "
            "at most 2.2 A is available for excitation") in msg
    assert "lower peak_current_a" in msg and "y_a" not in msg
    with pytest.raises(ValueError, match="finite"):
        check_headroom(d, np.nan, 1.0)
