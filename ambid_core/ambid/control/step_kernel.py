"""The controller's compiled state-space step (:func:`statespace_step`), one call per sample.

Shared conventions (work vectors, compiled entry points): :mod:`ambid.compiled`.

Controller work vector ``w`` (1-D), for n states, p inputs, q outputs
(:func:`statespace_work`)::

    w[0:n]                  state x
    w[n:n + p]              input y
    w[n + p:n + p + q]      output, saturated
    w[n + p + q:h]          scratch, q + n: m [x; y] is summed here (h = 2 n + p + 2 q)
    w[mat:]                 step matrices m.T, (n + p, q + n) row-major each,
                            [output; x[k+1]] = m [x; y]

"""

from __future__ import annotations

import numpy as np

from ambid.compiled import F8, I8, VEC, add_columns, njit


def statespace_work(n: int, p: int, q: int, matrices: list[np.ndarray]) -> tuple[np.ndarray, list[int]]:
    """A controller work vector (module docstring) holding the step matrices, each (q + n, n + p).

    Returns
    -------
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


@njit(cache=True)
def statespace_step(w: np.ndarray, n: int, p: int, q: int, mat: int, limit: float) -> None:
    """One step of a discrete state-space model with output saturation, in place:
    [out; x[k+1]] = m [x; y], out clipped to [-limit, limit].

    Parameters
    ----------
    w
        controller work vector (module docstring), y already in place.
    n, p, q
        number of states, inputs, outputs.
    mat
        offset of the step matrix m.T in w.
    limit
        output saturation.
    """
    o = n + p
    out = w[o + q:o + 2 * q + n]  # the scratch
    out[:] = 0.0
    add_columns(w, mat, q + n, 0, 0, n + p, out)
    for i in range(q):
        c = out[i]
        w[o + i] = limit if c > limit else -limit if c < -limit else c
    for i in range(n):
        w[i] = out[q + i]


STATESPACE_STEP_ARGS = (VEC, I8, I8, I8, I8, F8)
