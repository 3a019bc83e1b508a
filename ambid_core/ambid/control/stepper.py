"""Stepping a discrete position controller sample by sample (the compiled path of the loop)."""

from __future__ import annotations

import numpy as np

from ambid.compiled import KernelOwner, compiled
from ambid.control.step_kernel import (STATESPACE_STEP4_ARGS, STATESPACE_STEP_ARGS, statespace_step, statespace_step4,
                                       statespace_work)
from ambid.statespace import StateSpace


class ControllerStepper(KernelOwner):
    """Runs a discrete controller sample by sample with output saturation.

    ``step(y)`` returns ic[k] for the measurement y[k]; with the model's
    built-in delay, ic[k] depends only on y[k-1] and older. Each step is
    one compiled mat-vec (:func:`ambid.control.step_kernel.statespace_step`).

    Pipelining: a strictly proper controller (D = 0) knows ic[k+1] as soon
    as it has y[k]: ``current_output()`` gives ic[0], then each
    ``step_ahead4(y[k])`` returns ic[k+1], the sequence ``step4`` gives one
    sample later.

    Args:
        model: discrete controller, y (p) [m] -> ic (q) [A].
        current_limit_a: output saturation [A].
    """

    _UNPICKLED = ("_step", "_step4")  # the compiled kernels, bound again in a copy

    def __init__(self, model: StateSpace, current_limit_a: float) -> None:
        if model.dt <= 0:
            raise ValueError("ControllerStepper needs a discrete model (dt > 0)")
        self.model = model
        n, p, q = model.n_states, model.n_inputs, model.n_outputs
        self._n, self._p, self._n_out = n, p, q
        self._limit = float(current_limit_a)
        # [ic; x[k+1]] = [[C D], [A B]] [x; y]; strictly proper, also the step ahead
        # [ic[k+1]; x[k+1]] = [[C A, C B], [A, B]] [x; y[k]]
        mats = [np.block([[model.c, model.d], [model.a, model.b]])]
        proper = bool(np.all(model.d == 0))
        if proper:
            mats.append(np.block([[model.c @ model.a, model.c @ model.b], [model.a, model.b]]))
        self._w, offsets = statespace_work(n, p, q, mats)  # x, y, ic, the matrices
        self._mat = offsets[0]
        four = p == 4 and q == 4
        self._mat4 = offsets[0] if four else -1
        self._mat_ahead4 = offsets[1] if four and proper else -1
        self._proper = proper
        self._bind()

    def kernel_args(self, ahead: bool) -> tuple[np.ndarray, int, int, float]:
        """(work vector, state count n, step-matrix offset, output limit [A]) for a compiled caller that
        steps a 4 x 4 controller itself (:func:`ambid.control.step_kernel.statespace_step` on ``w``; y at
        w[n:n + 4], the output at w[n + 4:n + 8]); ``ahead``: the matrix of ``step_ahead4``.

        Raises:
            ValueError: the controller is not 4 x 4, or ``ahead`` and it has feedthrough.
        """
        mat = self._mat_ahead4 if ahead else self._mat4
        if mat < 0:
            raise ValueError(f"kernel_args: needs a 4 x 4 controller{' without feedthrough' if ahead else ''}")
        return self._w, self._n, mat, self._limit

    def _bind(self) -> None:
        self._step = compiled(statespace_step, STATESPACE_STEP_ARGS)
        self._step4 = compiled(statespace_step4, STATESPACE_STEP4_ARGS)

    @property
    def strictly_proper(self) -> bool:
        """No feedthrough (D = 0): ic[k] depends on y[k-1] and older only."""
        return self._proper

    @property
    def x(self) -> np.ndarray:
        """Controller state (n,) (a view)."""
        return self._w[: self._n]

    def set_steady_state(self, ic_a, y_m=None) -> None:
        """Set the state to the equilibrium that outputs ``ic_a`` (m,) [A] for the constant input
        ``y_m`` (p,) [m] (default 0), e.g. an integrator already carrying the gravity current.

        Raises:
            ValueError: no such equilibrium (the controller has no integral action on these channels).
        """
        m = self.model
        ic = np.asarray(ic_a, dtype=float).reshape(m.n_outputs)
        y = np.zeros(m.n_inputs) if y_m is None else np.asarray(y_m, dtype=float).reshape(m.n_inputs)
        lhs = np.vstack([np.eye(self._n) - m.a, m.c])
        rhs = np.concatenate([m.b @ y, ic - m.d @ y])
        x = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
        if np.linalg.norm(lhs @ x - rhs) > 1e-9 * max(np.linalg.norm(rhs), 1e-12):
            raise ValueError("set_steady_state: the controller has no steady state with this output "
                             "(it needs integral action on every output channel)")
        self._w[: self._n] = x

    def step(self, y) -> list[float]:
        """ic [A] (m floats) for the measured y [m] (p floats), saturated at the current limit."""
        n, p, q, w = self._n, self._p, self._n_out, self._w
        w[n:n + p] = y
        self._step(w, n, p, q, self._mat, self._limit)
        return w[n + p:n + p + q].tolist()

    def step4(self, y0: float, y1: float, y2: float, y3: float) -> tuple[float, float, float, float]:
        """``step([y0, y1, y2, y3])`` of a 4-input, 4-output controller, as a tuple of 4 floats [A].

        Raises:
            ValueError: the controller is not 4 x 4 (use ``step``).
        """
        mat = self._mat4
        if mat < 0:
            raise ValueError(f"step4 needs a controller with 4 inputs and 4 outputs, this one has "
                             f"{self._p} and {self._n_out}; use step(y)")
        return self._step4(self._w, self._n, mat, self._limit, y0, y1, y2, y3)

    def last_output(self) -> tuple[float, ...]:
        """The output of the last step, saturated [A] (q floats; zeros before the first step)."""
        o = self._n + self._p
        return tuple(self._w[o:o + self._n_out].tolist())

    def current_output(self) -> tuple[float, ...]:
        """ic = C x [A] of the present state, saturated (q floats); for a strictly proper controller
        this is what the next ``step`` returns.

        Raises:
            ValueError: the controller has feedthrough (D != 0).
        """
        if not self._proper:
            raise ValueError("current_output needs a strictly proper controller (D = 0): its output "
                             "depends on the next measurement")
        lim = self._limit
        ic = (self.model.c @ self._w[: self._n]).tolist()
        return tuple(lim if i > lim else -lim if i < -lim else i for i in ic)

    def step_ahead4(self, y0: float, y1: float, y2: float, y3: float) -> tuple[float, float, float, float]:
        """Update the state with y[k] = (y0..y3) [m] and return the next output ic[k+1] = C x[k+1] [A],
        saturated (a strictly proper 4 x 4 controller; ``step4(y[k+1])`` would return the same).

        Raises:
            ValueError: the controller has feedthrough (D != 0) or is not 4 x 4.
        """
        mat = self._mat_ahead4
        if mat < 0:
            if not self._proper:
                raise ValueError("step_ahead4 needs a strictly proper controller (D = 0), this one has "
                                 "feedthrough; use step4")
            raise ValueError(f"step_ahead4 needs a controller with 4 inputs and 4 outputs, this one has "
                             f"{self._p} and {self._n_out}; use step(y)")
        return self._step4(self._w, self._n, mat, self._limit, y0, y1, y2, y3)
