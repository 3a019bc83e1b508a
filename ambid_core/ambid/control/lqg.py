"""Centralised model-based position controller: discrete LQG from the analytical model.

The design model is :func:`ambid.plant.analytical.analytical_model` (zero-order hold at
the control rate) with

* the computational delay: the controller is the *predictor* form, so
  ic[k] depends on y[k-1] and older, like the PID of
  :mod:`ambid.control.pid` (extra samples of delay are added to the design
  model as input-delay states);
* a constant input-disturbance model d (na states, a current offset per
  axis) that the estimator tracks and the control cancels, so the rotor
  levitates without offset under gravity and model errors (integral
  action).

Design, with x the design-model state and z = [x; d]::

    z[k+1] = [[A, B], [0, I]] z[k] + [B; 0] ic[k] + w[k],   y[k] = [C, 0] z[k] + v[k]
    ic[k]  = -L x_hat[k|k-1] - d_hat[k|k-1]

L from the LQR Riccati equation (cost y' y / y_w^2 + ic' ic / i_w^2, plus a
small weight on every state), the predictor gain from the Kalman Riccati
equation (process noise through the current inputs, disturbance drift,
sensor noise), both by ``scipy.linalg.solve_discrete_are``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from ambid.plant.analytical import analytical_model
from ambid.plant.rig import Rig
from ambid.statespace import StateSpace, delay, series


@dataclass(frozen=True)
class LqgParameters:
    """Weights and noise levels of the LQG design (Bryson-style scales, SI units).

    Attributes
    ----------
    displacement_scale_m
        sensor displacement that costs as much as
        ``current_scale_a`` of control current [m].
    current_scale_a
        control current scale [A].
    state_weight
        weight of every (scaled) state besides y, keeps the
        Riccati equation well posed [-].
    input_noise_a
        process noise at each current input, std per sample [A].
    disturbance_drift_a
        random-walk std per sample of the input
        disturbance (sets how fast the integral action acts) [A].
    state_noise
        process noise on every design-model state, std per
        sample relative to the state's size for a unit current pulse
        [-]; > 0 keeps the estimator from cancelling the plant's lightly
        damped zeros (noise through the inputs only would, as in loop
        transfer recovery, and that is fragile).
    measurement_noise_m
        sensor noise std [m]; None takes the rig's
        ``sensor_noise_m`` (at least 0.05 um).
    n_bending
        bending modes per plane in the design model; None takes
        the rig's ``bending_modes``.
    delay_samples
        computational delay [samples], >= 1.
    regulate
        "bearings" weights the rotor displacement at the bearing
        planes (collocated with the forces: robust), "sensors" the
        measured displacements.
    resonance_weight
        weight of the lightly damped modes' amplitudes
        relative to the displacement cost [-]; > 0 makes the controller
        damp the bending modes instead of notching them (a notch lags
        below its frequency, which destabilises the housing mode).
    """

    displacement_scale_m: float = 100e-6
    current_scale_a: float = 1.0
    state_weight: float = 1e-6
    input_noise_a: float = 0.05
    disturbance_drift_a: float = 1e-2
    state_noise: float = 1.0
    measurement_noise_m: float | None = None
    n_bending: int | None = None
    delay_samples: int = 1
    regulate: str = "bearings"
    resonance_weight: float = 0.5

    def __post_init__(self) -> None:
        checks = {"displacement_scale_m": (1e-9, 1e-2), "current_scale_a": (1e-6, 1e3),
                  "state_weight": (0.0, 1e6), "input_noise_a": (1e-9, 1e3),
                  "disturbance_drift_a": (1e-12, 1e3), "state_noise": (0.0, 1e3), "delay_samples": (1, 100)}
        for name, (lo, hi) in checks.items():
            v = getattr(self, name)
            if not (np.isfinite(v) and lo <= v <= hi):
                raise ValueError(f"LQG parameter {name} = {v!r} is outside [{lo:g}, {hi:g}]")
        if self.measurement_noise_m is not None and not (np.isfinite(self.measurement_noise_m)
                                                         and 0 < self.measurement_noise_m < 1e-2):
            raise ValueError(f"LQG parameter measurement_noise_m = {self.measurement_noise_m!r} must lie in "
                             "(0, 0.01) m, or be None for the rig's sensor noise")
        if self.n_bending is not None and not (int(self.n_bending) == self.n_bending and 0 <= self.n_bending <= 8):
            raise ValueError(f"LQG parameter n_bending = {self.n_bending!r} must be a whole number in [0, 8]")
        if self.regulate not in ("bearings", "sensors"):
            raise ValueError(f"LQG parameter regulate = {self.regulate!r} must be 'bearings' or 'sensors'")
        if int(self.delay_samples) != self.delay_samples:
            raise ValueError(f"LQG parameter delay_samples = {self.delay_samples!r} must be a whole number")


def lqg_design_model(rig: Rig, params: LqgParameters) -> StateSpace:
    """Discrete design model: (delay_samples - 1) input delays, then the analytical model (ZOH)."""
    plant = analytical_model(rig, params.n_bending).to_discrete(rig.dt)
    extra = int(params.delay_samples) - 1
    if extra:
        plant = series(delay(plant.n_inputs, extra, rig.dt), plant)
    return plant


def lqg_controller(rig: Rig, params: LqgParameters | None = None) -> StateSpace:
    """Discrete LQG controller y (na) [m] -> ic (na) [A] on the rig's axes, minus sign and computational
    delay included.

    Parameters
    ----------
    rig
        rig whose analytical model is the design model.
    params
        weights and noise levels; None takes the defaults.

    Returns
    -------
    StateSpace, dt = rig.dt, D = 0 (ic[k] depends on y[k-1] and older);
    states: predicted design-model state, the disturbance estimate, then
    (delay_samples - 1) x na output-delay states.

    Raises
    ------
    ValueError
        a Riccati equation has no stabilising solution (the
        weights or noise levels are degenerate).
    """
    p = LqgParameters() if params is None else params
    plant = lqg_design_model(rig, p)
    a, b, c = plant.a, plant.b, plant.c
    n, na = a.shape[0], b.shape[1]
    eye = np.eye(na)
    # state scaling: Riccati solvers behave with states of similar size
    scale = _state_scales(a, b, c)
    a_s, b_s, c_s = a * (1 / scale)[:, None] * scale, b / scale[:, None], c * scale
    cost_c = _cost_outputs(rig, p, plant) * scale
    q = cost_c.T @ cost_c / p.displacement_scale_m**2
    q += p.state_weight * np.trace(q) / n * np.eye(n)
    if p.resonance_weight > 0:
        q += p.resonance_weight * np.trace(q) * _resonance_cost(a_s, rig.dt)
    r = eye / p.current_scale_a**2
    try:
        x_lqr = linalg.solve_discrete_are(a_s, b_s, q, r)
        gain_s = linalg.solve(r + b_s.T @ x_lqr @ b_s, b_s.T @ x_lqr @ a_s)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise ValueError(f"lqg_controller: the LQR Riccati equation has no stabilising solution ({exc}); "
                         "check the weights") from None
    gain = gain_s / scale  # in unscaled states
    # estimator on z = [x; d]
    az = np.block([[a, b], [np.zeros((na, n)), eye]])
    bz = np.vstack([b, np.zeros((na, na))])
    cz = np.hstack([c, np.zeros((na, na))])
    zscale = np.concatenate([scale, np.full(na, p.disturbance_drift_a)])
    az_s, cz_s = az * (1 / zscale)[:, None] * zscale, cz * zscale
    g_in = np.vstack([b, np.zeros((na, na))])
    w = p.input_noise_a**2 * g_in @ g_in.T
    w[n:, n:] += p.disturbance_drift_a**2 * eye
    w_s = w / np.outer(zscale, zscale)
    w_s[:n, :n] += p.state_noise**2 * np.eye(n)
    w_s += 1e-9 * np.trace(w_s) / (n + na) * np.eye(n + na)
    sigma_y = p.measurement_noise_m if p.measurement_noise_m is not None else max(rig.sensor_noise_m, 0.05e-6)
    v = sigma_y**2 * eye
    try:
        pz = linalg.solve_discrete_are(az_s.T, cz_s.T, w_s, v)
        kp_s = az_s @ pz @ cz_s.T @ np.linalg.inv(cz_s @ pz @ cz_s.T + v)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise ValueError(f"lqg_controller: the Kalman Riccati equation has no stabilising solution ({exc}); "
                         "check the noise levels") from None
    k_pred = kp_s * zscale[:, None]
    lz = np.hstack([gain, eye])
    ak = az - bz @ lz - k_pred @ cz
    ctl = StateSpace(ak, k_pred, -lz, np.zeros((na, na)), rig.dt)
    extra = int(p.delay_samples) - 1
    if extra:  # the design model delays its input; the controller's output must wait as long
        ctl = series(ctl, delay(na, extra, rig.dt))
    layout = rig.layout
    return ctl._replace(input_names=layout.outputs, output_names=layout.controls, input_units=layout.units("y"),
                        output_units=layout.units("ic"))


def _cost_outputs(rig: Rig, p: LqgParameters, plant: StateSpace) -> np.ndarray:
    """(na, n) map from the design state to the regulated displacements."""
    if p.regulate == "sensors":
        return plant.c
    rotor = rig.rotor_model(p.n_bending)
    na = plant.n_inputs
    n_delay = plant.n_states - rotor.n_states - na  # series(delay, plant): delay states come first
    return np.hstack([np.zeros((na, n_delay)), rotor.c_bearing, np.zeros((na, na))])


def _resonance_cost(a: np.ndarray, dt: float, max_damping: float = 0.05) -> np.ndarray:
    """(n, n) PSD cost of the lightly damped modes' amplitudes: sum of w_k^H w_k over the normalised
    left eigenvectors w_k of the stable oscillatory eigenvalues with damping < max_damping."""
    lam, vl = linalg.eig(a, left=True, right=False)
    s = np.log(np.where(lam == 0, 1.0, lam).astype(complex)) / dt  # z = 0 (delay states): not a resonance
    pick = (np.abs(s.imag) > 0) & (-s.real < max_damping * np.abs(s)) & (s.real < 0) & (lam != 0)
    q = np.zeros(a.shape)
    for k in np.nonzero(pick)[0]:
        w = vl[:, k] / np.linalg.norm(vl[:, k])
        q += np.real(np.outer(w.conj(), w))
    return q


def _state_scales(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Relative size of each state, (n,): its largest excursion in the first 60 samples after a
    unit pulse on any input (long enough to reach every mode, short enough that the unstable ones
    grow less than tenfold)."""
    x = b.copy()
    acc = np.abs(x).max(axis=1)
    for _ in range(60):
        x = a @ x
        acc = np.maximum(acc, np.abs(x).max(axis=1))
    acc = np.where(acc > 0, acc, 1.0)
    return acc / acc.max()
