"""Compiled per-sample kernels of the lock-step loop: the simulated plant's free-flight step
and the controller's state-space step.

The loop runs one plant step and one controller step per sample at 10 kHz;
in numpy each costs 10-30 us, mostly interpreter overhead, so the
arithmetic of one sample runs here as plain loops compiled by numba
(``njit``, cached in ``__pycache__``; the first call in a process loads or
compiles them, importing this module compiles nothing).

The kernels hold no state: all of it lives in one float64 *work vector*
per kernel that the caller owns and passes in, matrices included (numba
charges ~0.25 us per array argument, against ~0.8 us of arithmetic in a
plant step).

Plant work vector ``s`` (1-D), for n plant states (:func:`plant_work`,
offsets from :func:`plant_offsets`)::

    s[0:24]                 parameters and counters, indices PAR_*
    s[24:40]                aux at the present sample k: y, gap, current,
                            sensor displacement (4 each) [m, m, A, m]
    s[v:v + n + 17]         v = [x; u[k-1]; u[k]; f; r_s; 1], the fused step's input
    s[v + n + 17:mat]       scratch, n + 20: M v is summed here
    s[mat:noise]            M.T, (n + 17, n + 20) row-major: [x; u[k]; aux][k+1] = M v
    s[noise:]               sensor noise block, (rows, 4) row-major [m]

Controller work vector ``w`` (1-D), for n states, p inputs, q outputs
(:func:`statespace_work`)::

    w[0:n]                  state x
    w[n:n + p]              input y
    w[n + p:n + p + q]      output, saturated
    w[n + p + q:h]          scratch, q + n: m [x; y] is summed here (h = 2 n + p + 2 q)
    w[mat:]                 step matrices m.T, (n + p, q + n) row-major each,
                            [output; x[k+1]] = m [x; y]

Matrices are stored transposed because the product then runs column by
column into the scratch slice, which LLVM vectorises without reassociating
any sum: each output is still summed in column order, as by a plain dot
product. The scratch lives in the work vector so that a step allocates
nothing (an allocation per step cost the controller half its time).
"""

from __future__ import annotations

import numba
import numpy as np

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
N_PAR = 24
STATUS_CONTACT = 1.0  # the rotor touches: sub-step the sample
STATUS_NOISE = 2.0  # the noise block is used up: draw the next one and call again
AUX = N_PAR  # aux block: y (4), gap (4), current (4), sensor displacement (4)
N_AUX = 16
N_EXTRA = 17  # v = [x (n); u[k-1] (4); u[k] (4); f (4); r_s (4); 1]

_F8, _I8, _VEC = numba.float64, numba.int64, numba.float64[::1]


def compiled(kernel, arg_types: tuple):
    """The machine code of ``kernel`` for exactly ``arg_types``, loaded from the cache or compiled
    once per process.

    Calling it skips numba's per-call type dispatch (0.5-1 us of a 2-3 us
    call; ``Dispatcher.compile`` returns the compiled entry point). It
    converts scalars like ``float()`` and ``int()`` but does not check
    arrays: pass only 1-D float64 C-contiguous work vectors.
    """
    return kernel.compile(arg_types)


class KernelOwner:
    """Base of a class that holds compiled kernels (process-local) and views into its own work
    vector: copies (``copy.deepcopy``, pickle) leave out the attributes named in ``_UNPICKLED`` and
    bind them again with ``_bind()``, so a copy steps its own work vector."""

    _UNPICKLED: tuple[str, ...] = ()

    def _bind(self) -> None:
        raise NotImplementedError

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for name in self._UNPICKLED:
            del state[name]
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._bind()


# -- plant -----------------------------------------------------------------
@numba.njit(cache=True)
def plant_offsets(n: int) -> tuple[int, int, int]:
    """Offsets (v, mat, noise) in the plant work vector for n states (module docstring); the
    scratch lies between v and mat."""
    v = AUX + N_AUX
    mat = v + 2 * (n + N_EXTRA) + 3
    return v, mat, mat + (n + N_EXTRA) * (n + N_EXTRA + 3)


def plant_work(m: np.ndarray, noise_rows: int) -> np.ndarray:
    """A plant work vector for the fused step matrix m (n + 20, n + 17): n, M.T and v's constant 1
    set, everything else zero (the caller sets the PAR_* parameters).

    Returns:
        s: (plant_offsets(n)[2] + 4 noise_rows,) float64.
    """
    nr, nc = m.shape
    n = nc - N_EXTRA
    if n < 0 or nr != n + N_EXTRA + 3:
        raise ValueError(f"plant_work: the fused step matrix must be (n + 20, n + 17), got {m.shape}")
    v, mat, noise = plant_offsets.py_func(n)
    s = np.zeros(noise + 4 * noise_rows)
    s[PAR_N] = n
    s[mat:noise] = np.asarray(m, dtype=float).T.ravel()
    s[v + n + N_EXTRA - 1] = 1.0
    return s


@numba.njit(cache=True)
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


@numba.njit(cache=True)
def magnet_residual(s: np.ndarray, cur: np.ndarray, gap: np.ndarray, out: np.ndarray) -> None:
    """The magnets' residual force per axis [N] into out (4,), for the currents cur (4,) [A] and
    gaps gap (4,) [m], with the parameters of the plant work vector s."""
    for j in range(4):
        out[j] = _residual_axis(s, j, cur[j], gap[j])


@numba.njit(cache=True)
def _add_columns(w: np.ndarray, mat: int, n_out: int, x0: int, j0: int, j1: int, out: np.ndarray) -> None:
    """out += M[:, j0:j1] @ w[x0 + j0:x0 + j1], M.T stored row-major at w[mat:] with n_out columns."""
    for j in range(j0, j1):
        wj = w[x0 + j]
        row = w[mat + j * n_out:mat + (j + 1) * n_out]  # a slice: non-negative indices, vectorised
        for i in range(n_out):
            out[i] += row[i] * wj


@numba.njit(cache=True)
def plant_step(s: np.ndarray, u0: float, u1: float, u2: float,
               u3: float) -> tuple[float, float, float, float, bool, bool]:
    """One free-flight sample of the simulated plant with the current reference u [A] held.

    Clips u to the current limit and stores it as u[k] in v; with
    nonlinear magnets, stores the magnets' residual force at sample k, and
    the sensors' cubic term, both held over the step; then, unless the
    rotor touches the backup bearings at k or k + 1, advances v and aux to
    k + 1. Returns contact = True, with s[PAR_STATUS] saying why, when the
    caller has to finish the sample:

    * STATUS_NOISE: the noise block has no row for k + 1; nothing changed:
      draw the next block, advance s[PAR_NOISE_BASE], call again;
    * STATUS_CONTACT: the rotor touches; s[PAR_INDEX] is k + 1, u[k]
      (clipped) is in v, v[:n + 4] and aux are still at k: sub-step the
      sample.

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
    no = n + N_EXTRA + 3
    out = s[mat - no:mat]  # the scratch
    out[:] = 0.0
    _add_columns(s, mat, no, v, 0, n + 8, out)
    if nonlinear:
        _add_columns(s, mat, no, v, n + 8, n + 12, out)
    if c3 != 0.0:
        _add_columns(s, mat, no, v, n + 12, n + 16, out)
    _add_columns(s, mat, no, v, n + 16, n + 17, out)
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


PLANT_STEP_ARGS = (_VEC, _F8, _F8, _F8, _F8)


# -- controller ------------------------------------------------------------
def statespace_work(n: int, p: int, q: int, matrices: list[np.ndarray]) -> tuple[np.ndarray, list[int]]:
    """A controller work vector (module docstring) holding the step matrices, each (q + n, n + p).

    Returns:
        w: float64 work vector, state, input and output zero.
        offsets: where each matrix (transposed) starts in w.
    """
    head = n + p + 2 * q + n  # x, y, output, scratch
    offsets, blocks, at = [], [], head
    for m in matrices:
        m = np.asarray(m, dtype=float)
        if m.shape != (q + n, n + p):
            raise ValueError(f"statespace_work: step matrix must be ({q + n}, {n + p}), got {m.shape}")
        offsets.append(at)
        blocks.append(m.T.ravel())
        at += m.size
    return np.concatenate([np.zeros(head), *blocks]), offsets


@numba.njit(cache=True)
def statespace_step(w: np.ndarray, n: int, p: int, q: int, mat: int, limit: float) -> None:
    """One step of a discrete state-space model with output saturation, in place:
    [out; x[k+1]] = m [x; y], out clipped to [-limit, limit].

    Args:
        w: controller work vector (module docstring), y already in place.
        n, p, q: number of states, inputs, outputs.
        mat: offset of the step matrix m.T in w.
        limit: output saturation.
    """
    o = n + p
    out = w[o + q:o + 2 * q + n]  # the scratch
    out[:] = 0.0
    _add_columns(w, mat, q + n, 0, 0, n + p, out)
    for i in range(q):
        c = out[i]
        w[o + i] = limit if c > limit else -limit if c < -limit else c
    for i in range(n):
        w[i] = out[q + i]


STATESPACE_STEP_ARGS = (_VEC, _I8, _I8, _I8, _I8, _F8)


@numba.njit(cache=True)
def statespace_step4(w: np.ndarray, n: int, mat: int, limit: float,
                     y0: float, y1: float, y2: float, y3: float) -> tuple[float, float, float, float]:
    """:func:`statespace_step` of a 4-input, 4-output model for the input y0..y3; returns the output."""
    w[n] = y0
    w[n + 1] = y1
    w[n + 2] = y2
    w[n + 3] = y3
    statespace_step(w, n, 4, 4, mat, limit)
    o = n + 4
    return w[o], w[o + 1], w[o + 2], w[o + 3]


STATESPACE_STEP4_ARGS = (_VEC, _I8, _I8, _F8, _F8, _F8, _F8, _F8)
