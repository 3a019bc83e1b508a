"""Line sets and non-multisine waveforms of ambid.excitation."""

import numpy as np
import pytest
from ambid.excitation.lines import band_bins, detection_lines, line_set, log_lines, n_per_period, shape_amplitudes
from ambid.excitation.signals import (binary_levels, binary_waveform, dibs_bits, filtered_noise, mls,
                                      noise_filter_spec, noise_taps, stepped_sine_layout, swept_sine_period)


def test_n_per_period_integer_and_error_names_working_resolutions():
    assert n_per_period(10_000, 2.5) == 4000
    with pytest.raises(ValueError) as err:
        n_per_period(10_000, 3.0)
    msg = str(err.value)
    # the two neighbouring integer N: 3333 and 3334
    assert "N=3333" in msg and "N=3334" in msg and repr(10_000 / 3333) in msg
    for bad in (np.nan, np.inf, -1.0, 0.0):
        with pytest.raises(ValueError):
            n_per_period(10_000, bad)


def test_band_bins_and_errors():
    assert band_bins((5.0, 500.0), 10_000, 10_000) == (5, 500)
    assert band_bins((0.0, 500.0), 10_000, 10_000)[0] == 1  # DC never excited
    with pytest.raises(ValueError, match="Nyquist"):
        band_bins((10.0, 5000.0), 10_000, 10_000)
    with pytest.raises(ValueError, match="no frequency line"):
        band_bins((0.2, 0.4), 1000, 1000)
    with pytest.raises(ValueError, match="finite"):
        band_bins((np.nan, 10.0), 1000, 1000)
    with pytest.raises(ValueError, match="f_lo < f_hi"):
        band_bins((20.0, 10.0), 1000, 1000)


@pytest.mark.parametrize("group_size", [3, 4])
def test_random_odd_drops_one_line_per_group(group_size):
    lines = line_set(3, 301, "random_odd", group_size=group_size, rng=np.random.default_rng(5))
    odd = np.arange(3, 302, 2)
    assert np.all(lines % 2 == 1)
    n_groups = odd.size // group_size
    for g in range(n_groups):
        group = odd[g * group_size:(g + 1) * group_size]
        assert np.isin(group, lines).sum() == group_size - 1
    assert np.all(np.isin(odd[n_groups * group_size:], lines))  # partial last group kept whole
    d_odd, d_even = detection_lines(lines, 3, 301)
    assert np.array_equal(np.sort(np.concatenate([lines, d_odd, d_even])), np.arange(3, 302))
    assert d_odd.size == n_groups and np.all(d_even % 2 == 0) and np.all(d_odd % 2 == 1)
    # the choice is random: another seed leaves other lines out
    other = line_set(3, 301, "random_odd", group_size=group_size, rng=np.random.default_rng(6))
    assert not np.array_equal(lines, other)


def test_log_lines_unique_and_log_spaced():
    cand = np.arange(1, 5001)
    lines = log_lines(cand, 60)
    assert lines.size == 60 and np.all(np.diff(lines) > 0)
    ratio = lines[1:] / lines[:-1]
    # every line at the low end (step < 1 bin), then a constant ratio
    wide = ratio[lines[:-1] > 200]
    assert np.ptp(np.log(wide)) < 0.01
    n_dense = int(np.argmax(np.diff(lines) > 1))
    assert np.array_equal(lines[:n_dense + 1], np.arange(1, n_dense + 2))
    assert lines[0] == 1 and lines[-1] * wide.max() > 5000  # the band is spanned
    odd = line_set(1, 4999, "odd", "log", n_lines=40)
    assert np.all(odd % 2 == 1) and odd.size >= 40


def test_line_set_errors():
    with pytest.raises(ValueError, match="grid"):
        line_set(1, 10, "even")
    with pytest.raises(ValueError, match="n_lines"):
        line_set(1, 10, "full", "linear", n_lines=5)
    with pytest.raises(ValueError, match="no excited line"):
        line_set(2, 2, "odd")


def test_shape_amplitudes():
    f = np.array([10.0, 20.0, 40.0])
    assert np.allclose(shape_amplitudes(None, f), 1)
    assert np.allclose(shape_amplitudes(lambda x: 1 / x, f), [1, 0.5, 0.25])
    assert np.allclose(shape_amplitudes(([10, 40], [2, 8]), f), [0.25, 0.5, 1.0])
    with pytest.raises(ValueError, match="positive"):
        shape_amplitudes(lambda x: x - 20, f)
    with pytest.raises(ValueError, match="NaN"):
        shape_amplitudes(lambda x: x * np.nan, f)


@pytest.mark.parametrize("order", [3, 5, 8, 10, 13, 15])
def test_mls_is_maximal_length(order):
    bits = mls(order)
    length = 2**order - 1
    assert bits.size == length and bits.sum() == 2 ** (order - 1)
    s = np.where(bits, 1.0, -1.0)
    # cyclic autocorrelation of an MLS is two-valued: L at lag 0, -1 elsewhere
    acf = np.fft.ifft(np.abs(np.fft.fft(s)) ** 2).real
    assert abs(acf[0] - length) < 1e-6
    assert np.max(np.abs(acf[1:] + 1)) < 1e-6


def test_binary_levels_zero_mean_peak_one():
    bits = mls(7)
    high, low = binary_levels(bits)
    x = binary_waveform(bits, 3)
    assert x.size == 3 * bits.size
    assert abs(x.mean()) < 1e-15 and np.max(np.abs(x)) == 1.0
    assert set(np.unique(x)) == {high, low}
    with pytest.raises(ValueError):
        binary_levels(np.ones(8, bool))


def test_dibs_concentrates_power_and_odd_grid_has_no_even_power():
    n = 512
    lines = np.arange(1, 40, 2)
    bits, frac = dibs_bits(n, lines, np.ones(lines.size), np.random.default_rng(1), 60)
    x = binary_waveform(bits)
    spec = np.abs(np.fft.rfft(x)) ** 2
    total = np.sum(x**2) * n
    assert abs(2 * spec[lines].sum() / total - frac) < 1e-12
    assert frac > 0.7  # a plain square wave puts ~0.8 on its first odd harmonics only
    assert spec[0::2].sum() / total < 1e-20  # even lines (incl. DC) exactly empty


def test_swept_sine_sweeps_the_band():
    fs, n = 1000.0, 4000
    x = swept_sine_period(n, fs, 20.0, 200.0, "linear")
    assert np.max(np.abs(x)) == 1.0 and x[0] == 0.0
    spec = np.abs(np.fft.rfft(x)) ** 2
    band = slice(int(20 * n / fs), int(200 * n / fs) + 1)
    assert spec[band].sum() / spec.sum() > 0.95
    lg = swept_sine_period(n, fs, 20.0, 200.0, "log")
    # log sweep dwells longer at low frequency: more power in the lower half of the band
    lo_band, hi_band = slice(80, 440), slice(440, 801)
    s_lin, s_log = spec, np.abs(np.fft.rfft(lg)) ** 2
    lin_ratio = s_lin[lo_band].sum() / s_lin[hi_band].sum()
    assert s_log[lo_band].sum() / s_log[hi_band].sum() > 2 * lin_ratio
    with pytest.raises(ValueError):
        swept_sine_period(n, fs, 0.0, 200.0, "log")


def test_filtered_noise_random_access_and_band():
    fs = 1000.0
    taps = noise_taps(noise_filter_spec((50.0, 150.0), fs), fs)
    whole = filtered_noise(taps, (3, 0, 0), 0, 6000, 256, 2)
    parts = np.concatenate([filtered_noise(taps, (3, 0, 0), a, min(a + 700, 6000), 256, 2)
                            for a in range(0, 6000, 700)])
    np.testing.assert_allclose(parts, whole, rtol=0, atol=1e-12)
    assert np.corrcoef(whole[:, 0], whole[:, 1])[0, 1] < 0.1  # independent channels
    steady = whole[taps.size:, 0]
    spec = np.abs(np.fft.rfft(steady * np.hanning(steady.size))) ** 2
    f = np.fft.rfftfreq(steady.size, 1 / fs)
    # band plus the 60 dB transition bands (25 Hz wide here)
    assert spec[(f > 25) & (f < 175)].sum() / spec.sum() > 0.999


def test_stepped_sine_layout_integer_periods():
    n, fs = 1000, 1000.0
    lines = np.array([1, 3, 7, 250, 333, 499])
    p, pt, per = stepped_sine_layout(lines, n, fs, settle_s=0.05, n_cycles=12)
    assert np.all((lines * p) % n == 0)  # integer cycles per period
    cycles = lines * p // n
    assert np.all(per * cycles >= 12) and np.all((per - 1) * cycles < 12)
    assert np.all(pt * p >= 0.05 * fs) and np.all((pt - 1) * p < 0.05 * fs)
