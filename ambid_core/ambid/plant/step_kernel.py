"""The simulated plant's compiled free-flight step (:func:`plant_step`), one call per sample.

Shared conventions (work vectors, compiled entry points): :mod:`ambid.compiled`.

Plant work vector ``s`` (1-D), for n plant states (:func:`plant_work`,
offsets from :func:`plant_offsets`)::

    s[0:N_PAR]              parameters and counters, indices PAR_*
    s[AUX:AUX + 16]         aux at the present sample k: y, gap, current,
                            sensor displacement (4 each) [m, m, A, m]
    s[v:v + n + 19]         v = [x; u[k-1]; u[k]; f; r_s; cos theta; sin theta; 1], the
                            fused step's input (theta the rotor angle at k)
    s[v + n + 19:mat]       scratch, n + 20: M v is summed here
    s[mat:noise]            M.T, (n + 19, n + 20) row-major: [x; u[k]; aux][k+1] = M v
    s[noise:]               sensor noise block, (rows, 4) row-major [m]
"""

from __future__ import annotations

import numpy as np

from ambid.compiled import F8, VEC, add_columns, njit
from ambid.plant.sensors import RUNOUT_HARMONICS

# plant parameters, s[PAR_*]
PAR_N = 0  # number of plant states n
PAR_LIMIT = 1  # amplifier current limit [A]
PAR_NONLINEAR = 2  # 1.0: add the magnets' residual force (eq. 2.14 minus its linearisation)
PAR_KC = 3  # k cos(alpha) of the magnet law [N m^2 / A^2]
PAR_IB = 4  # bias current [A]
PAR_S0 = 5  # nominal air gap [m]
PAR_GAP_GUARD = 6  # |gap| clamp of the magnet law [m]
PAR_CUBIC = 7  # sensor probe-curve cubic coefficient [1/m^2]
PAR_CLEAR2 = 8  # backup-bearing clearance squared [m^2]
PAR_LIN = 9  # (force_const [N], ki [N/A], ks [N/m]) of axis j at PAR_LIN + 3 j
PAR_INDEX = 21  # sample index k of the present sample
PAR_NOISE_BASE = 22  # sample index of the noise block's first row
PAR_STATUS = 23  # why the last plant_step returned contact = True: STATUS_*
PAR_COS_STEP = 24  # cos(Omega dt): the rotor angle turned per sample, as a rotation
PAR_SIN_STEP = 25  # sin(Omega dt)
PAR_COS = 26  # cos theta of the rotor angle at the present sample k
PAR_SIN = 27  # sin theta
PAR_UNBALANCE = 28  # 1.0: the unbalance columns of M are in use
PAR_RUNOUT_N = 29  # harmonics of the probes' runout in use (0: none)
PAR_RUNOUT = 30  # runout table, (RUNOUT_HARMONICS, 4, 2) row-major [m] (ambid.plant.sensors.runout_table)
N_PAR = PAR_RUNOUT + 8 * RUNOUT_HARMONICS
STATUS_CONTACT = 1.0  # the rotor touches: sub-step the sample
STATUS_NOISE = 2.0  # the noise block is used up: draw the next one and call again
AUX = N_PAR  # aux block: y (4), gap (4), current (4), sensor displacement (4)
N_AUX = 16
N_EXTRA = 19  # v = [x (n); u[k-1] (4); u[k] (4); f (4); r_s (4); cos theta; sin theta; 1]
N_OUT = 20  # M v = [x (n); u[k] (4); aux (16)][k+1]


@njit(cache=True)
def plant_offsets(n: int) -> tuple[int, int, int]:
    """Offsets (v, mat, noise) in the plant work vector for n states (module docstring); the
    scratch lies between v and mat."""
    v = AUX + N_AUX
    mat = v + n + N_EXTRA + n + N_OUT
    return v, mat, mat + (n + N_EXTRA) * (n + N_OUT)


def plant_work(m: np.ndarray, noise_rows: int) -> np.ndarray:
    """A plant work vector for the fused step matrix m (n + 20, n + 19): n, M.T and v's constant 1
    set, everything else zero (the caller sets the PAR_* parameters).

    Returns:
        s: (plant_offsets(n)[2] + 4 noise_rows,) float64.
    """
    nr, nc = m.shape
    n = nc - N_EXTRA
    if n < 0 or nr != n + N_OUT:
        raise ValueError(f"plant_work: the fused step matrix must be (n + 20, n + 19), got {m.shape}")
    v, mat, noise = plant_offsets.py_func(n)
    s = np.zeros(noise + 4 * noise_rows)
    s[PAR_N] = n
    s[mat:noise] = np.asarray(m, dtype=float).T.ravel()
    s[v + n + N_EXTRA - 1] = 1.0
    return s


@njit(cache=True)
def _residual_axis(s: np.ndarray, j: int, i: float, g: float) -> float:
    """Eq. 2.14 minus its affine linearisation on axis j [N], current i [A], gap g [m].

    The gap is clamped short of the pole face (only reached in contact).
    """
    kc, ib, s0, lim = s[PAR_KC], s[PAR_IB], s[PAR_S0], s[PAR_GAP_GUARD]
    if not -lim < g < lim:
        g = lim if g > 0 else -lim
    a, b, ip, im = s0 - g, s0 + g, ib + i, ib - i
    fc, ki, ks = s[PAR_LIN + 3 * j], s[PAR_LIN + 3 * j + 1], s[PAR_LIN + 3 * j + 2]
    return kc * (ip * ip / (a * a) - im * im / (b * b)) - fc - ki * i - ks * g


@njit(cache=True)
def magnet_residual(s: np.ndarray, cur: np.ndarray, gap: np.ndarray, out: np.ndarray) -> None:
    """The magnets' residual force per axis [N] into out (4,), for the currents cur (4,) [A] and
    gaps gap (4,) [m], with the parameters of the plant work vector s."""
    for j in range(4):
        out[j] = _residual_axis(s, j, cur[j], gap[j])


@njit(cache=True)
def add_runout(s: np.ndarray, c1: float, s1: float, y: np.ndarray, at: int) -> None:
    """Add the probes' runout at the rotor angle (cos theta, sin theta) = (c1, s1) to y[at:at + 4] [m]
    (the table in s)."""
    ch, sh = c1, s1
    for h in range(int(s[PAR_RUNOUT_N])):
        base = PAR_RUNOUT + 8 * h
        for j in range(4):
            y[at + j] += s[base + 2 * j] * ch + s[base + 2 * j + 1] * sh
        ch, sh = ch * c1 - sh * s1, sh * c1 + ch * s1  # (h + 1) theta from h theta



@njit(cache=True)
def plant_step(s: np.ndarray, u0: float, u1: float, u2: float,
               u3: float) -> tuple[float, float, float, float, bool, bool]:
    """One free-flight sample of the simulated plant with the current reference u [A] held.

    Clips u to the current limit and stores it as u[k] in v, and the rotor
    angle's cos and sin at k; turns the rotor angle by Omega dt (a rotation
    of its phasor, held at unit length); with
    nonlinear magnets, stores the magnets' residual force at sample k, and
    the sensors' cubic term, both held over the step; then, unless the
    rotor touches the backup bearings at k or k + 1, advances v and aux to
    k + 1. Returns contact = True, with s[PAR_STATUS] saying why, when the
    caller has to finish the sample:

    * STATUS_NOISE: the noise block has no row for k + 1; nothing changed:
      draw the next block, advance s[PAR_NOISE_BASE], call again;
    * STATUS_CONTACT: the rotor touches; s[PAR_INDEX] and s[PAR_COS],
      s[PAR_SIN] are at k + 1, u[k] (clipped) and the angle at k are in v, v[:n + 4]
      and aux are still at k: sub-step the sample.

    Args:
        s: plant work vector (module docstring).
        u0, u1, u2, u3: current reference [A].

    Returns:
        (y0, y1, y2, y3, clipped, contact): y[k+1] [m] with the noise of
        sample k + 1 (NaN when contact is True); u was clipped; see above.
    """
    nan = np.nan
    n = int(s[PAR_N])
    v, mat, noise = plant_offsets(n)
    k = s[PAR_INDEX] + 1.0
    row = int(k - s[PAR_NOISE_BASE])
    if row >= (s.shape[0] - noise) // 4:
        s[PAR_STATUS] = STATUS_NOISE
        return nan, nan, nan, nan, False, True
    s[PAR_INDEX] = k
    c, sn = s[PAR_COS], s[PAR_SIN]
    unbalance = s[PAR_UNBALANCE] != 0.0
    if unbalance:
        s[v + n + 16] = c
        s[v + n + 17] = sn
    # the rotor angle, integrated from the speed: e^{j theta[k+1]} = e^{j theta[k]} e^{j Omega dt}, the
    # phasor's length held at 1 by one Newton step of 1 / sqrt(|z|^2) (no trigonometry per sample)
    cs, ss = s[PAR_COS_STEP], s[PAR_SIN_STEP]
    c, sn = c * cs - sn * ss, sn * cs + c * ss
    g = 1.5 - 0.5 * (c * c + sn * sn)
    c *= g
    sn *= g
    s[PAR_COS] = c
    s[PAR_SIN] = sn
    lim = s[PAR_LIMIT]
    clipped = not (-lim <= u0 <= lim and -lim <= u1 <= lim and -lim <= u2 <= lim and -lim <= u3 <= lim)
    if clipped:
        u0 = lim if u0 > lim else -lim if u0 < -lim else u0
        u1 = lim if u1 > lim else -lim if u1 < -lim else u1
        u2 = lim if u2 > lim else -lim if u2 < -lim else u2
        u3 = lim if u3 > lim else -lim if u3 < -lim else u3
    iu = v + n + 4
    s[iu] = u0
    s[iu + 1] = u1
    s[iu + 2] = u2
    s[iu + 3] = u3
    nonlinear = s[PAR_NONLINEAR] != 0.0
    if nonlinear:
        for j in range(4):
            s[iu + 4 + j] = _residual_axis(s, j, s[AUX + 8 + j], s[AUX + 4 + j])
    c3 = s[PAR_CUBIC]
    if c3 != 0.0:
        for j in range(4):
            d = s[AUX + 12 + j]
            s[iu + 8 + j] = c3 * d * d * d
    c2 = s[PAR_CLEAR2]
    g = AUX + 4
    if s[g] * s[g] + s[g + 2] * s[g + 2] > c2 or s[g + 1] * s[g + 1] + s[g + 3] * s[g + 3] > c2:
        s[PAR_STATUS] = STATUS_CONTACT
        return nan, nan, nan, nan, clipped, True
    # out = [x; u; y; gap; current; sensor displacement][k+1] = M v; the f and r_s columns
    # only when they are in use (skipping exact zeros leaves every sum unchanged)
    no = n + N_OUT
    out = s[mat - no:mat]  # the scratch
    out[:] = 0.0
    add_columns(s, mat, no, v, 0, n + 8, out)
    if nonlinear:
        add_columns(s, mat, no, v, n + 8, n + 12, out)
    if c3 != 0.0:
        add_columns(s, mat, no, v, n + 12, n + 16, out)
    if unbalance:
        add_columns(s, mat, no, v, n + 16, n + 19, out)
    else:
        add_columns(s, mat, no, v, n + 18, n + 19, out)
    if s[PAR_RUNOUT_N] > 0.0:
        add_runout(s, c, sn, out, n + 4)
    g = n + 8
    if out[g] * out[g] + out[g + 2] * out[g + 2] > c2 or out[g + 1] * out[g + 1] + out[g + 3] * out[g + 3] > c2:
        s[PAR_STATUS] = STATUS_CONTACT
        return nan, nan, nan, nan, clipped, True
    for i in range(n + 4):
        s[v + i] = out[i]
    for i in range(N_AUX):
        s[AUX + i] = out[n + 4 + i]
    r = noise + 4 * row
    return out[n + 4] + s[r], out[n + 5] + s[r + 1], out[n + 6] + s[r + 2], out[n + 7] + s[r + 3], clipped, False


PLANT_STEP_ARGS = (VEC, F8, F8, F8, F8)
