"""What the compiled per-sample kernels of the lock-step loop share: compile-once entry points,
the owner of a work vector, and the transposed mat-vec both kernels sum with.

The kernels themselves: :mod:`ambid.plant.step_kernel` (the simulated
plant's free-flight step) and :mod:`ambid.control.step_kernel` (the
controller's state-space step).

The loop runs one plant step and one controller step per sample at 10 kHz;
in numpy each costs 10-30 us, mostly interpreter overhead, so the
arithmetic of one sample runs here as plain loops compiled by numba
(``njit``, cached in ``__pycache__``; the first call in a process loads or
compiles them, importing this module compiles nothing).

numba is optional for the core (``pip install ./ambid_core[fast]``):
without it :func:`njit` leaves the kernels plain Python and :func:`compiled`
returns them as they are, so the simulator and the controllers give the
same numbers, bit for bit, some fifty times slower (the kernels' sums run in the
same order either way). Reading sessions, FRFs and fitting never step a
kernel. The ROS nodes' compiled loop needs numba.

The kernels hold no state: all of it lives in one float64 *work vector*
per kernel that the caller owns and passes in, matrices included (numba
charges ~0.25 us per array argument, against ~0.8 us of arithmetic in a
plant step).

Matrices are stored transposed because the product then runs column by
column into the scratch slice, which LLVM vectorises without reassociating
any sum: each output is still summed in column order, as by a plain dot
product. The scratch lives in the work vector so that a step allocates
nothing (an allocation per step cost the controller half its time).
"""

from __future__ import annotations

import numpy as np

try:
    import numba
except ImportError:  # optional: the kernels then run as plain Python
    numba = None

HAVE_NUMBA = numba is not None
if HAVE_NUMBA:
    F8, I8, VEC = numba.float64, numba.int64, numba.float64[::1]  # argument types of the kernels
    njit = numba.njit
else:
    F8 = I8 = VEC = None

    def njit(*args, **options):
        """Without numba: the function itself, with ``py_func`` as numba's dispatcher has it."""
        def plain(func):
            func.py_func = func
            return func
        return plain(args[0]) if args and callable(args[0]) else plain


def compiled(kernel, arg_types: tuple):
    """The machine code of ``kernel`` for exactly ``arg_types``, loaded from the cache or compiled
    once per process (without numba: ``kernel`` itself, plain Python).

    Calling it skips numba's per-call type dispatch (0.5-1 us of a 2-3 us
    call; ``Dispatcher.compile`` returns the compiled entry point). It
    converts scalars like ``float()`` and ``int()`` but does not check
    arrays: pass only 1-D float64 C-contiguous work vectors.
    """
    return kernel.compile(arg_types) if HAVE_NUMBA else kernel


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


@njit(cache=True)
def add_columns(w: np.ndarray, mat: int, n_out: int, x0: int, j0: int, j1: int, out: np.ndarray) -> None:
    """out += M[:, j0:j1] @ w[x0 + j0:x0 + j1], M.T stored row-major at w[mat:] with n_out columns."""
    for j in range(j0, j1):
        wj = w[x0 + j]
        row = w[mat + j * n_out:mat + (j + 1) * n_out]  # a slice: non-negative indices, vectorised
        for i in range(n_out):
            out[i] += row[i] * wj

