"""Timing of the common-denominator fit on a synthetic 4x4 AMB plant.

Not a test: a helper to call by hand (``python -m ambid.fit.benchmark``) to
check the fit stays within its time budget on the target machine.
"""

from __future__ import annotations

import time

import numpy as np

from ambid.fit.blas_threads import single_threaded_blas
from ambid.fit.common_denominator import fit_common_denominator
from ambid.statespace import StateSpace, block_diag

__all__ = ["synthetic_amb_plant", "benchmark_fit"]


def _plane(mass_kg: float, inertia_kgm2: float, bearing_z_m: tuple[float, float], ks_n_per_m: float,
           ki_n_per_a: float, bending_hz: tuple[float, ...], bending_zeta: float,
           amp_hz: float) -> StateSpace:
    # rigid (centre, tilt) plus bending modes with unit modal mass and alternating shapes;
    # bearing forces ks x + ki i, first-order current amplifiers
    za, zb = bearing_z_m
    nb = len(bending_hz)
    shapes = np.array([[1.0, (-1.0) ** (k + 1) * (0.6 + 0.2 * k)] for k in range(nb)]).T.reshape(2, nb)
    t = np.hstack([np.array([[1.0, za], [1.0, zb]]), shapes])
    nq = 2 + nb
    minv = np.diag(1.0 / np.array([mass_kg, inertia_kgm2] + [1.0] * nb))
    wb = 2 * np.pi * np.asarray(bending_hz, dtype=float)
    k_mech = np.diag(np.concatenate([[0.0, 0.0], wb**2])) - ks_n_per_m * t.T @ t
    c_mech = np.diag(np.concatenate([[0.0, 0.0], 2 * bending_zeta * wb]))
    wa = 2 * np.pi * amp_hz
    a = np.zeros((2 * nq + 2, 2 * nq + 2))
    a[:nq, nq:2 * nq] = np.eye(nq)
    a[nq:2 * nq, :nq] = -minv @ k_mech
    a[nq:2 * nq, nq:2 * nq] = -minv @ c_mech
    a[nq:2 * nq, 2 * nq:] = ki_n_per_a * minv @ t.T
    a[2 * nq:, 2 * nq:] = -wa * np.eye(2)
    b = np.zeros((2 * nq + 2, 2))
    b[2 * nq:] = wa * np.eye(2)
    c = np.zeros((2, 2 * nq + 2))
    c[:, :nq] = t
    return StateSpace(a, b, c, np.zeros((2, 2)))


def synthetic_amb_plant() -> StateSpace:
    """4x4 open-loop AMB plant, currents [A] -> displacements [m] (x plane, y plane).

    Two unstable real poles per plane (negative magnet stiffness), three
    lightly damped bending modes per plane (x and y slightly different),
    a 1.5 kHz first-order amplifier on each input: 21 distinct poles.
    """
    x = _plane(12.0, 0.25, (-0.18, 0.22), 4.0e5, 220.0, (310.0, 620.0, 940.0), 0.008, 1500.0)
    y = _plane(12.0, 0.25, (-0.18, 0.22), 4.6e5, 220.0, (330.0, 660.0, 980.0), 0.006, 1500.0)
    return block_diag(x, y)


def benchmark_fit(n_lines: int = 2000, order: int = 24, noise_rel: float = 0.01, seed: int = 0,
                  f_min_hz: float = 10.0, f_max_hz: float = 1000.0) -> dict:
    """Fit :func:`synthetic_amb_plant` plus complex Gaussian noise and time it.

    Parameters
    ----------
    n_lines
        number of lines L, linearly spaced over [f_min_hz, f_max_hz].
    order
        fitted denominator order.
    noise_rel
        noise std per line relative to the rms |G| over entries.
    seed
        noise seed.

    Returns
    -------
    dict with ``time_s`` (wall time of the whole fit), ``cpu_time_s``
    (process CPU time, all threads; below time_s on a busy machine), ``chi2_per_dof``,
    ``n_vf_iterations``, ``n_refine_evaluations``, ``max_rel_error``
    (max |G_fit - G_true| / max |G_true|), ``n_lines``, ``order``.
    """
    plant = synthetic_amb_plant()
    f = np.linspace(f_min_hz, f_max_hz, n_lines)
    with single_threaded_blas():  # one small solve per line: threads only wait for each other
        g = plant.freqresp(f)
    rng = np.random.default_rng(seed)
    sig = noise_rel * np.sqrt(np.mean(np.abs(g) ** 2, axis=(1, 2)))
    var = np.broadcast_to(sig[:, None, None] ** 2, g.shape).copy()
    noise = np.sqrt(var / 2) * (rng.standard_normal(g.shape) + 1j * rng.standard_normal(g.shape))
    t0, c0 = time.perf_counter(), time.process_time()
    res = fit_common_denominator(f, g + noise, var, order=order)
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    err = np.abs(res.model.freqresp(f) - g).max() / np.abs(g).max()
    return dict(time_s=elapsed, cpu_time_s=cpu, chi2_per_dof=res.chi2_per_dof, n_vf_iterations=res.n_vf_iterations,
                n_refine_evaluations=res.n_refine_evaluations, max_rel_error=float(err),
                n_lines=n_lines, order=order)


if __name__ == "__main__":
    print(benchmark_fit())
