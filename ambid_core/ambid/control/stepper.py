"""Stepping a discrete position controller sample by sample (the compiled path of the loop)."""

from __future__ import annotations

import numpy as np

from ambid.compiled import KernelOwner, compiled
from ambid.control.step_kernel import STATESPACE_STEP_ARGS, statespace_step, statespace_work
from ambid.statespace import StateSpace


class ControllerStepper(KernelOwner):
    """Runs a discrete controller sample by sample with output saturation.

    ``step(y)`` returns ic[k] for the measurement y[k]; with the model's
    built-in delay, ic[k] depends only on y[k-1] and older. Each step is
    one compiled mat-vec (:func:`ambid.control.step_kernel.statespace_step`).

    Pipelining: a strictly proper controller (D = 0) knows ic[k+1] as soon
    as it has y[k]: ``current_output()`` gives ic[0], then each
    ``step_ahead(y[k])`` returns ic[k+1], the sequence ``step`` gives one
    sample later.

    Parameters
    ----------
    model
        discrete controller, y (p) [m] -> ic (q) [A].
    current_limit_a
        output saturation [A].
    """

    _UNPICKLED = ("_step",)  # the compiled kernel, bound again in a copy

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
        self._mat_ahead = offsets[1] if proper else -1
        self._proper = proper
        self._bind()

    @property
    def n_inputs(self) -> int:
        """p, the measured displacements y taken per step."""
        return self._p

    @property
    def n_outputs(self) -> int:
        """q, the control currents ic returned per step."""
        return self._n_out

    def kernel_args(self, ahead: bool) -> tuple[np.ndarray, int, int, float]:
        """(work vector, state count n, step-matrix offset, output limit [A]) for a compiled caller that
        steps the controller itself (:func:`ambid.control.step_kernel.statespace_step` on ``w`` with
        :attr:`n_inputs` p and :attr:`n_outputs` q; y at w[n:n + p], the output at w[n + p:n + p + q]);
        ``ahead``: the matrix of ``step_ahead``.

        Raises
        ------
        ValueError
            ``ahead`` and the controller has feedthrough.
        """
        mat = self._mat_ahead if ahead else self._mat
        if mat < 0:
            raise ValueError("kernel_args: the step ahead needs a controller without feedthrough")
        return self._w, self._n, mat, self._limit

    def _bind(self) -> None:
        self._step = compiled(statespace_step, STATESPACE_STEP_ARGS)

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

        Raises
        ------
        ValueError
            no such equilibrium (the controller has no integral action on these channels).
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

    def last_output(self) -> tuple[float, ...]:
        """The output of the last step, saturated [A] (q floats; zeros before the first step)."""
        o = self._n + self._p
        return tuple(self._w[o:o + self._n_out].tolist())

    def current_output(self) -> tuple[float, ...]:
        """ic = C x [A] of the present state, saturated (q floats); for a strictly proper controller
        this is what the next ``step`` returns.

        Raises
        ------
        ValueError
            the controller has feedthrough (D != 0).
        """
        if not self._proper:
            raise ValueError("current_output needs a strictly proper controller (D = 0): its output "
                             "depends on the next measurement")
        lim = self._limit
        ic = (self.model.c @ self._w[: self._n]).tolist()
        return tuple(lim if i > lim else -lim if i < -lim else i for i in ic)

    def step_ahead(self, y) -> list[float]:
        """Update the state with y[k] [m] (p floats) and return the next output ic[k+1] = C x[k+1] [A]
        (q floats), saturated (a strictly proper controller; ``step(y[k+1])`` would return the same).

        Raises
        ------
        ValueError
            the controller has feedthrough (D != 0).
        """
        mat = self._mat_ahead
        if mat < 0:
            raise ValueError("step_ahead needs a strictly proper controller (D = 0), this one has "
                             "feedthrough; use step")
        n, p, q, w = self._n, self._p, self._n_out, self._w
        w[n:n + p] = y
        self._step(w, n, p, q, mat, self._limit)
        return w[n + p:n + p + q].tolist()
