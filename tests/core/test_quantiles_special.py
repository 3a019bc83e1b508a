"""The quantiles ambid takes from scipy.special (scipy.stats costs ~0.6 s to import on every command)
equal scipy.stats' own, bit for bit, over the degrees of freedom ambid meets."""
import numpy as np
from scipy import special, stats

from ambid.frf.lpm import f_quantile

DOF = np.array([0.5, 1.0, 2.0, 3.0, 7.5, 10.0, 40.0, 1e3, 1e6, np.inf])


def test_student_t_quantile_is_stats_t_ppf():
    # identification.model_fit, fit.updating, fit.model_update: the 95 % intervals' t factor
    np.testing.assert_array_equal(special.stdtrit(DOF, 0.975), stats.t.ppf(0.975, DOF))
    np.testing.assert_allclose(special.stdtrit(np.inf, 0.975), stats.norm.ppf(0.975), rtol=1e-15)   # no dof: normal


def test_f_quantile_is_stats_f_ppf():
    # frf.lpm (f_quantile, detection of transients) and frf.transient_model
    q = np.array([1, 2, 3, 5, 8, 20, 100])
    for level in (0.5, 0.95, 0.99, 1 - 1e-4):
        np.testing.assert_array_equal(f_quantile(level, q), stats.f.ppf(level, 2, 2 * q))
        for dfn in (2, 6, 24):
            np.testing.assert_array_equal(special.fdtri(dfn, 2 * q, level), stats.f.ppf(level, dfn, 2 * q))
    assert f_quantile(0.95, 10) == float(stats.f.ppf(0.95, 2, 20))


def test_chi2_median_is_stats_chi2_median():
    # frf.lpm: the median of a chi-square with 2q dof that corrects a running median of variances
    q = np.array([1, 2, 3, 5, 8, 20, 100])
    np.testing.assert_array_equal(2 * special.gammaincinv(q, 0.5), stats.chi2.median(2 * q))
