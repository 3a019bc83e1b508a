"""The simulated plant's compiled free-flight step (:func:`plant_step`), one call per sample.

Shared conventions (work vectors, compiled entry points): :mod:`ambid.compiled`.

Plant work vector ``s`` (1-D), for n plant states and na axes (:func:`plant_work`,
offsets from :func:`plant_offsets`, every one of them a function of n and na)::

    s[0:N_HEAD]             counters and switches, indices PAR_*
    s[axes:groups]          per axis j, AXIS_WORDS values at axes + AXIS_WORDS j: the magnet law
                            (force_const [N], ki [N/A], ks [N/m], k cos(alpha) [N m^2/A^2], ib [A],
                            s0 [m], |gap| clamp [m]), the amplifier's current limit [A] and the
                            sensor's probe-curve cubic coefficient [1/m^2] (AX_*)
    s[groups:runout]        the backup bearings: na groups of (axis, second axis or -1, clearance^2):
                            a radial bearing's x and y touch when x^2 + y^2 > clearance^2, an
                            axial one when z^2 > clearance^2; PAR_GROUPS of them in use
    s[runout:uin]           runout table, (RUNOUT_HARMONICS, na, 2) row-major [m]
                            (ambid.plant.sensors.runout_table)
    s[uin:yout]             the current reference u [A] the caller puts in for the next step (na)
    s[yout:aux]             the measured y[k+1] [m] a step leaves, noise included (na)
    s[aux:v]                aux at the present sample k: y, gap, current, sensor displacement
                            (na each) [m, m, A, m]
    s[v:v + n + 4 na + 3]   v = [x; u[k-1]; u[k]; f; r_s; cos theta; sin theta; 1], the
                            fused step's input (theta the rotor angle at k)
    s[.. :mat]              scratch, n + 5 na: M v is summed here
    s[mat:noise]            M.T, (n + 4 na + 3, n + 5 na) row-major: [x; u[k]; aux][k+1] = M v
    s[noise:]               sensor noise block, (rows, na) row-major [m]
"""

from __future__ import annotations

import numpy as np

from ambid.compiled import F8, HAVE_NUMBA, VEC, add_columns, njit, numba
from ambid.plant.sensors import RUNOUT_HARMONICS

# counters and switches, s[PAR_*]
PAR_N = 0  # number of plant states n
PAR_NA = 1  # number of axes na
PAR_NONLINEAR = 2  # 1.0: add the magnets' residual force (eq. 2.14 minus its linearisation)
PAR_INDEX = 3  # sample index k of the present sample
PAR_NOISE_BASE = 4  # sample index of the noise block's first row
PAR_STATUS = 5  # why the last plant_step returned contact = True: STATUS_*
PAR_COS_STEP = 6  # cos(Omega dt): the rotor angle turned per sample, as a rotation
PAR_SIN_STEP = 7  # sin(Omega dt)
PAR_COS = 8  # cos theta of the rotor angle at the present sample k
PAR_SIN = 9  # sin theta
PAR_UNBALANCE = 10  # 1.0: the unbalance columns of M are in use
PAR_RUNOUT_N = 11  # harmonics of the probes' runout in use (0: none)
PAR_CUBIC = 12  # 1.0: some sensor has a probe-curve error (AX_CUBIC != 0)
PAR_GROUPS = 13  # backup-bearing groups in use
N_HEAD = 14
# per-axis words, s[axes + AXIS_WORDS j + AX_*]
AX_FC, AX_KI, AX_KS, AX_KC, AX_IB, AX_S0, AX_GUARD, AX_LIMIT, AX_CUBIC = range(9)
AXIS_WORDS = 9
STATUS_CONTACT = 1.0  # the rotor touches: sub-step the sample
STATUS_NOISE = 2.0  # the noise block is used up: draw the next one and call again


@njit(cache=True)
def plant_offsets(n: int, na: int) -> tuple[int, int, int, int, int, int, int, int]:
    """Offsets (axes, groups, runout, uin, yout, aux, v, mat) in the plant work vector for n states and
    na axes (module docstring); the scratch lies between v's end and mat, the noise block after M."""
    axes = N_HEAD
    groups = axes + AXIS_WORDS * na
    runout = groups + 3 * na
    uin = runout + 2 * RUNOUT_HARMONICS * na
    yout = uin + na
    aux = yout + na
    v = aux + 4 * na
    mat = v + (n + 4 * na + 3) + (n + 5 * na)
    return axes, groups, runout, uin, yout, aux, v, mat


def noise_offset(n: int, na: int) -> int:
    """Where the noise block starts in the plant work vector."""
    mat = plant_offsets.py_func(n, na)[7]
    return mat + (n + 4 * na + 3) * (n + 5 * na)


def plant_work(m: np.ndarray, n_axes: int, noise_rows: int) -> np.ndarray:
    """A plant work vector for the fused step matrix m (n + 5 na, n + 4 na + 3): n, na, M.T and v's
    constant 1 set, everything else zero (the caller sets the parameters).

    Returns
    -------
    s: (noise_offset(n, na) + na noise_rows,) float64.
    """
    na = int(n_axes)
    nr, nc = m.shape
    n = nc - 4 * na - 3
    if na < 1 or n < 0 or nr != n + 5 * na:
        raise ValueError(f"plant_work: the fused step matrix of {na} axes must be (n + {5 * na}, n + {4 * na + 3}), "
                         f"got {m.shape}")
    v, mat = plant_offsets.py_func(n, na)[6:]
    noise = noise_offset(n, na)
    s = np.zeros(noise + na * noise_rows)
    s[PAR_N] = n
    s[PAR_NA] = na
    s[mat:noise] = np.asarray(m, dtype=float).T.ravel()
    s[v + n + 4 * na + 2] = 1.0
    return s


@njit(cache=True)
def _residual_axis(s: np.ndarray, j: int, i: float, g: float) -> float:
    """Eq. 2.14 minus its affine linearisation on axis j [N], current i [A], gap g [m].

    The gap is clamped short of the pole face (only reached in contact).
    """
    w = N_HEAD + AXIS_WORDS * j
    kc, ib, s0, lim = s[w + AX_KC], s[w + AX_IB], s[w + AX_S0], s[w + AX_GUARD]
    if not -lim < g < lim:
        g = lim if g > 0 else -lim
    a, b, ip, im = s0 - g, s0 + g, ib + i, ib - i
    fc, ki, ks = s[w + AX_FC], s[w + AX_KI], s[w + AX_KS]
    return kc * (ip * ip / (a * a) - im * im / (b * b)) - fc - ki * i - ks * g


@njit(cache=True)
def magnet_residual(s: np.ndarray, cur: np.ndarray, gap: np.ndarray, out: np.ndarray) -> None:
    """The magnets' residual force per axis [N] into out (na,), for the currents cur (na,) [A] and
    gaps gap (na,) [m], with the parameters of the plant work vector s."""
    for j in range(int(s[PAR_NA])):
        out[j] = _residual_axis(s, j, cur[j], gap[j])


@njit(cache=True)
def add_runout(s: np.ndarray, c1: float, s1: float, y: np.ndarray, at: int) -> None:
    """Add the probes' runout at the rotor angle (cos theta, sin theta) = (c1, s1) to y[at:at + na] [m]
    (the table in s)."""
    na = int(s[PAR_NA])
    table = plant_offsets(int(s[PAR_N]), na)[2]
    ch, sh = c1, s1
    for h in range(int(s[PAR_RUNOUT_N])):
        base = table + 2 * na * h
        for j in range(na):
            y[at + j] += s[base + 2 * j] * ch + s[base + 2 * j + 1] * sh
        ch, sh = ch * c1 - sh * s1, sh * c1 + ch * s1  # (h + 1) theta from h theta


@njit(cache=True)
def touching(s: np.ndarray, g: np.ndarray, at: int) -> bool:
    """Whether the gaps g[at:at + na] [m] reach a backup bearing (the groups in s)."""
    groups = N_HEAD + AXIS_WORDS * int(s[PAR_NA])
    for q in range(int(s[PAR_GROUPS])):
        w = groups + 3 * q
        a, b = at + int(s[w]), int(s[w + 1])
        r2 = g[a] * g[a]
        if b >= 0:
            r2 += g[at + b] * g[at + b]
        if r2 > s[w + 2]:
            return True
    return False


@njit(cache=True)
def plant_step(s: np.ndarray) -> tuple[bool, bool]:
    """One free-flight sample of the simulated plant with the current reference u [A] held.

    Takes u from the work vector's input slot (``uin``, na values the
    caller wrote), clips it to each axis' current limit and stores it as
    u[k] in v, and the rotor angle's cos and sin at k; turns the rotor
    angle by Omega dt (a rotation of its phasor, held at unit length); with
    nonlinear magnets, stores the magnets' residual force at sample k, and
    the sensors' cubic term, both held over the step; then, unless the
    rotor touches the backup bearings at k or k + 1, advances v and aux to
    k + 1 and leaves y[k+1] with the noise of sample k + 1 in ``yout``.
    Returns contact = True, with s[PAR_STATUS] saying why, when the caller
    has to finish the sample:

    * STATUS_NOISE: the noise block has no row for k + 1; nothing changed:
      draw the next block, advance s[PAR_NOISE_BASE], call again;
    * STATUS_CONTACT: the rotor touches; s[PAR_INDEX] and s[PAR_COS],
      s[PAR_SIN] are at k + 1, u[k] (clipped) and the angle at k are in v, v[:n + na]
      and aux are still at k: sub-step the sample.

    Args:
        s: plant work vector (module docstring), u in its input slot.

    Returns:
        (clipped, contact): u was clipped; see above (``yout`` is unchanged when contact is True).
    """
    n = int(s[PAR_N])
    na = int(s[PAR_NA])
    axes, _, _, uin, yout, aux, v, mat = plant_offsets(n, na)
    noise = mat + (n + 4 * na + 3) * (n + 5 * na)
    k = s[PAR_INDEX] + 1.0
    row = int(k - s[PAR_NOISE_BASE])
    if row >= (s.shape[0] - noise) // na:
        s[PAR_STATUS] = STATUS_NOISE
        return False, True
    s[PAR_INDEX] = k
    c, sn = s[PAR_COS], s[PAR_SIN]
    iu = v + n + na  # u[k]; then f, r_s, cos, sin, 1
    unbalance = s[PAR_UNBALANCE] != 0.0
    if unbalance:
        s[iu + 3 * na] = c
        s[iu + 3 * na + 1] = sn
    # the rotor angle, integrated from the speed: e^{j theta[k+1]} = e^{j theta[k]} e^{j Omega dt}, the
    # phasor's length held at 1 by one Newton step of 1 / sqrt(|z|^2) (no trigonometry per sample)
    cs, ss = s[PAR_COS_STEP], s[PAR_SIN_STEP]
    c, sn = c * cs - sn * ss, sn * cs + c * ss
    g = 1.5 - 0.5 * (c * c + sn * sn)
    c *= g
    sn *= g
    s[PAR_COS] = c
    s[PAR_SIN] = sn
    clipped = False
    for j in range(na):
        u = s[uin + j]
        lim = s[axes + AXIS_WORDS * j + AX_LIMIT]
        if not -lim <= u <= lim:
            clipped = True
            u = lim if u > lim else -lim if u < -lim else u
        s[iu + j] = u
    nonlinear = s[PAR_NONLINEAR] != 0.0
    if nonlinear:
        for j in range(na):
            s[iu + na + j] = _residual_axis(s, j, s[aux + 2 * na + j], s[aux + na + j])
    cubic = s[PAR_CUBIC] != 0.0
    if cubic:
        for j in range(na):
            d = s[aux + 3 * na + j]
            s[iu + 2 * na + j] = s[axes + AXIS_WORDS * j + AX_CUBIC] * d * d * d
    if touching(s, s, aux + na):
        s[PAR_STATUS] = STATUS_CONTACT
        return clipped, True
    # out = [x; u; y; gap; current; sensor displacement][k+1] = M v; the f and r_s columns
    # only when they are in use (skipping exact zeros leaves every sum unchanged)
    no = n + 5 * na
    out = s[mat - no:mat]  # the scratch
    out[:] = 0.0
    e = n + 2 * na
    add_columns(s, mat, no, v, 0, e, out)
    if nonlinear:
        add_columns(s, mat, no, v, e, e + na, out)
    if cubic:
        add_columns(s, mat, no, v, e + na, e + 2 * na, out)
    e += 2 * na
    if unbalance:
        add_columns(s, mat, no, v, e, e + 3, out)
    else:
        add_columns(s, mat, no, v, e + 2, e + 3, out)
    if s[PAR_RUNOUT_N] > 0.0:
        add_runout(s, c, sn, out, n + na)
    if touching(s, out, n + 2 * na):
        s[PAR_STATUS] = STATUS_CONTACT
        return clipped, True
    for i in range(n + na):
        s[v + i] = out[i]
    for i in range(4 * na):
        s[aux + i] = out[n + na + i]
    r = noise + na * row
    for j in range(na):
        s[yout + j] = out[n + na + j] + s[r + j]
    return clipped, False


@njit(cache=True)
def plant_step_with(s: np.ndarray, u: tuple) -> tuple[bool, bool]:
    """:func:`plant_step` with the current reference ``u`` [A] (a tuple of na floats) put in the input slot
    first: the Python caller's per-sample call (a numpy slice assignment and a second call cost it ~1 us,
    half the step)."""
    uin = plant_offsets(int(s[PAR_N]), int(s[PAR_NA]))[3]
    for i in range(len(u)):
        s[uin + i] = u[i]
    return plant_step(s)


def plant_step_with_args(n_axes: int) -> tuple:
    """The argument types of :func:`plant_step_with` for na axes (for :func:`ambid.compiled.compiled`)."""
    return (VEC, numba.types.UniTuple(F8, int(n_axes))) if HAVE_NUMBA else ()
