"""Splitting records into periods and period spectra (ambid.frf.periods)."""

import numpy as np
import pytest
from ambid.frf import layout_length, period_spectra, split_periods


def test_split_drops_transients_in_realisation_major_order():
    n, p, pt, m, ne, ch = 8, 3, 2, 2, 3, 2
    # tag every sample with (realisation, experiment, period-in-segment, sample, channel)
    tags = np.zeros((m, ne, pt + p, n, ch), dtype=int)
    for idx in np.ndindex(tags.shape):
        tags[idx] = int("".join(str(i) for i in idx))
    x = tags.reshape(-1, ch)                      # the documented sample order
    assert x.shape[0] == layout_length(n, p, pt, m, ne) == m * ne * (pt + p) * n
    out = split_periods(x, n, p, pt, m, ne)
    assert out.shape == (m, ne, p, n, ch)
    np.testing.assert_array_equal(out, tags[:, :, pt:])
    # the first sample of the first steady period of segment (1, 2) sits after
    # (1*ne + 2) whole segments and pt transient periods
    assert out[1, 2, 0, 0, 1] == x[((1 * ne + 2) * (pt + p) + pt) * n, 1]


def test_split_one_channel_and_no_transient():
    x = np.arange(12.0)
    out = split_periods(x, 3, 4, 0, 1, 1)
    assert out.shape == (1, 1, 4, 3, 1)
    np.testing.assert_array_equal(out[0, 0, :, :, 0], x.reshape(4, 3))


def test_split_rejects_wrong_length_and_parameters():
    with pytest.raises(ValueError, match=r"needs exactly"):
        split_periods(np.zeros((100, 2)), 8, 3, 2, 2, 3)
    with pytest.raises(ValueError, match="n_transient"):
        split_periods(np.zeros((10, 1)), 5, 2, -1, 1, 1)
    with pytest.raises(ValueError, match="n_per_period"):
        split_periods(np.zeros((10, 1)), 0, 2, 0, 1, 1)
    with pytest.raises(ValueError, match="shape"):
        split_periods(np.zeros((2, 5, 1)), 5, 2, 0, 1, 1)


def test_sine_of_amplitude_a_gives_a_at_its_bin():
    n, k, amp, phi = 64, 5, 0.7, 0.4
    t = np.arange(n)
    x = amp * np.cos(2 * np.pi * k * t / n + phi) + 0.3     # plus DC
    x2 = np.stack([x, 2 * x], axis=-1)
    periods = np.broadcast_to(x2, (1, 1, 2, n, 2))
    spec = period_spectra(periods, np.array([0, k, k + 1, n // 2]))
    assert spec.shape == (1, 1, 2, 4, 2)
    np.testing.assert_allclose(spec[0, 0, 0, 1], [amp * np.exp(1j * phi), 2 * amp * np.exp(1j * phi)])
    np.testing.assert_allclose(spec[0, 0, 0, 0], [0.3, 0.6], atol=1e-12)    # DC: 1/N scaling
    np.testing.assert_allclose(spec[0, 0, 0, 2], 0, atol=1e-12)
    nyq = np.broadcast_to(np.cos(np.pi * t)[:, None], (1, 1, 1, n, 1))       # (-1)^n
    np.testing.assert_allclose(period_spectra(nyq, np.array([n // 2]))[..., 0], 1.0)


def test_white_noise_line_variance_is_4_sigma2_over_n():
    n, sigma = 128, 0.5
    x = sigma * np.random.default_rng(0).standard_normal((4, 2, 50, n, 1))
    spec = period_spectra(x, np.arange(1, n // 2))
    ratio = np.mean(np.abs(spec) ** 2) / (4 * sigma**2 / n)
    assert abs(ratio - 1) < 0.03


def test_period_spectra_rejects_bad_lines_and_shapes():
    periods = np.zeros((1, 1, 2, 16, 1))
    with pytest.raises(ValueError, match=r"\[0, N/2\]"):
        period_spectra(periods, np.array([1, 9]))
    with pytest.raises(ValueError, match="integer"):
        period_spectra(periods, np.array([1.0, 2.0]))
    with pytest.raises(ValueError, match="split_periods"):
        period_spectra(np.zeros((2, 16, 1)), np.array([1]))
    with pytest.raises(ValueError, match="real"):
        period_spectra(periods.astype(complex), np.array([1]))
