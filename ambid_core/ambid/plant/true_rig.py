"""The "true" rig the simulator runs: chapter 2's model plus what reality adds.

Against :func:`ambid.plant.analytical.analytical_model` it adds

* magnets: the nonlinear differential force (eq. 2.14) of the *true* magnet
  (ki, ks off by ``true_ki_factor``, ``true_ks_factor``), linearised at the
  levitated operating point, where the gravity-carrying control current
  raises ks by (1 + ic0^2 / ib^2);
* a housing mode: each bearing stator sits on a pedestal (mass on springs,
  ``housing_freq_hz``) that takes the reaction of the magnet and contact
  forces; the sensors, on the pedestals too, measure rotor minus pedestal;
* sensors (:mod:`ambid.plant.sensors`): first-order low-pass, gain, noise,
  an optional cubic probe-curve error;
* an extra input delay ``extra_delay_s`` (ADC and PWM update, <= 1 sample);
* backup bearings (in :mod:`ambid.plant.simulator`);
* spinning: the unbalance forces m e Omega^2 of the rotor's unbalanced
  planes, rotating with the rotor angle theta = Omega t (``b_unbalance``),
  and the probes' runout, harmonics of theta added to y (``runout``,
  :func:`ambid.plant.sensors.runout_table`). Both are known functions of
  time, not states: the small-signal model and the operating point do
  not see them.

Continuous affine model (:class:`TruePlant`), for the rig's na axes
(:attr:`ambid.plant.rig.Rig.layout`: the four radial ones, and the axial one
with an axial bearing), states x = [rotor (n_r), pedestal displacement h
(nh) [m], pedestal velocity (nh) [m/s], coil control current i (na) [A],
sensor filter s (na) [m]]; the nh pedestals carry the radial stators (x and
y of each bearing), the axial stator is mounted rigidly::

    x' = A x + B_u u(t - tau) + B_f f + B_s r_s + b_c + B_unb [cos theta; sin theta]
    y  = C_y x + runout(theta) (+ noise)

u the current reference [A]; f extra forces on the rotor at the bearing
axes [N] (contact, and the magnets' deviation from their affine
linearisation), reacting on the pedestals; r_s the sensors' static-curve
deviation [m]; b_c gravity and the affine magnets' constant force.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import factorial

import numpy as np
from scipy import linalg

from ambid.plant.magnet import MagnetPair
from ambid.plant.sensors import filter_blocks, runout_table
from ambid.channels import RADIAL, Layout
from ambid.plant.rig import Rig
from ambid.statespace import StateSpace, series, zoh_blocks

_NEWTON_TOL = 1e-13


@dataclass(frozen=True)
class TruePlant:
    """Continuous affine model of the true rig (module docstring), magnets linearised per axis as
    F = force_const + ki i + ks g.

    Attributes
    ----------
    a, b_u, b_f, b_s
        (n, n), (n, na) x 3.
    b_c
        (n,) constant drive: gravity and the magnets' affine constant.
    c_y
        (na, n) measured output y [m] (without noise).
    c_gap
        (na, n) rotor minus stator displacement at the bearing axes [m].
    c_current
        (na, n) coil control currents [A].
    c_sensor
        (na, n) rotor minus pedestal displacement at the sensor axes [m].
    ki, ks, force_const
        (na,) affine magnet law per axis [N/A, N/m, N].
    delay_s
        input delay tau [s].
    n_rotor
        rotor states (the first n_rotor states).
    speed_rad_s
        spin speed Omega [rad/s]; the rotor angle is theta = Omega t.
    b_unbalance
        (n, 2) unbalance drive for [cos theta, sin theta] (Omega^2
        included) [state units / s]; None: none.
    runout
        (H, na, 2) probe runout table (:func:`ambid.plant.sensors.runout_table`)
        [m]; None: none.
    layout
        the axes, in channel order.
    """

    a: np.ndarray
    b_u: np.ndarray
    b_f: np.ndarray
    b_s: np.ndarray
    b_c: np.ndarray
    c_y: np.ndarray
    c_gap: np.ndarray
    c_current: np.ndarray
    c_sensor: np.ndarray
    ki: np.ndarray
    ks: np.ndarray
    force_const: np.ndarray
    delay_s: float
    n_rotor: int
    speed_rad_s: float = 0.0
    b_unbalance: np.ndarray | None = None
    runout: np.ndarray | None = None
    layout: Layout = RADIAL

    @property
    def n_states(self) -> int:
        return self.a.shape[0]

    @property
    def n_axes(self) -> int:
        """na, the number of axes (inputs and outputs)."""
        return len(self.layout)

    def gap_velocity_map(self) -> np.ndarray:
        """(na, n): rotor minus stator velocity at the bearing axes, C_gap A [m/s]."""
        return self.c_gap @ self.a


@dataclass(frozen=True)
class OperatingPoint:
    """Levitated equilibrium of the true rig: sensors read zero (what integral action settles to).

    Attributes
    ----------
    state
        (n,) state of the :class:`TruePlant`.
    current_a
        (na,) control currents ic0 = current references [A].
    gap_m
        (na,) rotor minus stator displacement at the bearings [m].
    force_n
        (na,) magnet forces [N].
    ki_n_per_a, ks_n_per_m
        (na,) slopes of eq. 2.14 there.
    """

    state: np.ndarray
    current_a: np.ndarray
    gap_m: np.ndarray
    force_n: np.ndarray
    ki_n_per_a: np.ndarray
    ks_n_per_m: np.ndarray


def true_plant(rig: Rig, ki: np.ndarray | None = None, ks: np.ndarray | None = None,
               force_const: np.ndarray | None = None) -> TruePlant:
    """Affine model of the true rig with the magnet law F = force_const + ki i + ks g per axis.

    Parameters
    ----------
    rig
        rig parameters.
    ki, ks
        (na,) slopes [N/A], [N/m]; None takes the true magnets' at the
        centre (eqs. 2.16-2.17 times the tolerance factors).
    force_const
        (na,) [N]; None takes 0.
    """
    rotor = rig.rotor_model()
    layout = rotor.layout
    na = len(layout)
    rad = [j for j in range(na) if j not in layout.axial]  # the axes whose stator sits on a pedestal
    nh = len(rad)
    mags = rig.axis_magnets(true=True)
    ki = np.array([m.ki for m in mags]) if ki is None else np.asarray(ki, dtype=float)
    ks = np.array([m.ks for m in mags]) if ks is None else np.asarray(ks, dtype=float)
    fc = np.zeros(na) if force_const is None else np.asarray(force_const, dtype=float)
    v = rig.values
    nr = rotor.n_states
    n = nr + 2 * nh + 2 * na
    r_, h_, hv_, i_, s_ = (slice(0, nr), slice(nr, nr + nh), slice(nr + nh, nr + 2 * nh),
                           slice(nr + 2 * nh, nr + 2 * nh + na), slice(nr + 2 * nh + na, n))
    mh = v["housing_mass_kg"]
    wh = 2 * np.pi * v["housing_freq_hz"]
    kh, ch = mh * wh * wh, 2 * v["housing_damping_ratio"] * wh * mh
    inv_tau = 1.0 / (1.0 / (2 * np.pi * rig.amplifier_bandwidths_hz))  # 1 / tau per axis, as eye / tau was
    a_ss, b_ss, c_ss = filter_blocks(rig.axis_sensors())
    eye = np.eye(na)
    dki, dks = np.diag(ki), np.diag(ks)
    # gap g = C_b x_r - h; magnet force on the rotor F = fc + ki i + ks g, on the pedestal -F
    c_gap = np.zeros((na, n))
    c_gap[:, r_], c_gap[rad, h_] = rotor.c_bearing, -np.eye(nh)
    c_sensor = np.zeros((na, n))
    c_sensor[:, r_], c_sensor[rad, h_] = rotor.c_sensor, -np.eye(nh)
    c_current = np.zeros((na, n))
    c_current[:, i_] = eye
    force_map = dks @ c_gap + dki @ c_current  # F - fc as a function of x
    a = np.zeros((n, n))
    a[r_, :] = rotor.b @ force_map
    a[r_, r_] += rotor.a
    a[h_, hv_] = np.eye(nh)
    a[hv_, :] = -force_map[rad] / mh
    a[hv_, h_] += -kh / mh * np.eye(nh)
    a[hv_, hv_] += -ch / mh * np.eye(nh)
    a[i_, i_] = -np.diag(inv_tau)
    a[s_, :] = b_ss @ c_sensor
    a[s_, s_] += a_ss
    b_u = np.zeros((n, na))
    b_u[i_] = np.diag(inv_tau)
    b_f = np.zeros((n, na))
    b_f[r_] = rotor.b
    b_f[hv_, rad] = -np.eye(nh) / mh
    b_s = np.zeros((n, na))
    b_s[s_] = b_ss
    b_c = b_f @ fc
    b_c[r_] += rotor.b_gravity
    c_y = np.zeros((na, n))
    c_y[:, s_] = c_ss
    omega = rig.speed_rad_s
    b_unb = ro = None
    if omega != 0.0:  # at standstill the unbalance has no force and the runout is calibrated out
        if rotor.b_unbalance is not None:
            b_unb = np.zeros((n, 2))
            b_unb[r_] = omega * omega * rotor.b_unbalance
        ro = runout_table(v, layout)
        if not np.any(ro):
            ro = None
    return TruePlant(a, b_u, b_f, b_s, b_c, c_y, c_gap, c_current, c_sensor, ki, ks, fc,
                     float(v["extra_delay_s"]), nr, omega, b_unb, ro, layout)


def magnet_force_and_slopes(mags: MagnetPair | tuple[MagnetPair, ...], current_a: np.ndarray, gap_m: np.ndarray,
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(F, dF/di, dF/dg) of eq. 2.14 per axis, each shaped like ``current_a`` (na,) [N, N/A, N/m]; ``mags``
    one magnet pair for every axis, or one per axis."""
    if isinstance(mags, MagnetPair):
        return mags.force(current_a, gap_m), *mags.slopes(current_a, gap_m)
    i, g = np.asarray(current_a, dtype=float), np.asarray(gap_m, dtype=float)
    f = np.array([m.force(i[j], g[j]) for j, m in enumerate(mags)])
    slopes = np.array([m.slopes(i[j], g[j]) for j, m in enumerate(mags)])
    return f, slopes[:, 0], slopes[:, 1]


def operating_point(rig: Rig) -> OperatingPoint:
    """Levitated equilibrium of the true rig with the nonlinear magnets: y = 0, x' = 0.

    Newton's method on [A x + B_u u + B_f r(x) + b_c = 0, C_y x = 0] for the
    state x and the static current reference u (= ic0, unit amplifier gain),
    with r the true magnets' deviation from their linearisation at the centre.
    """
    mag = _axis_law(rig)
    p = true_plant(rig)
    n, na = p.n_states, p.n_axes
    z = np.zeros(n + na)
    jac = np.zeros((n + na, n + na))
    jac[:n, n:] = p.b_u
    jac[n:, :n] = p.c_y
    for _ in range(50):
        x, u = z[:n], z[n:]
        i, g = p.c_current @ x, p.c_gap @ x
        f, dfdi, dfdg = magnet_force_and_slopes(mag, i, g)
        res = np.concatenate([p.a @ x + p.b_u @ u + p.b_f @ (f - p.ki * i - p.ks * g) + p.b_c, p.c_y @ x])
        jac[:n, :n] = p.a + p.b_f @ ((dfdi - p.ki)[:, None] * p.c_current + (dfdg - p.ks)[:, None] * p.c_gap)
        step = linalg.solve(jac, -res)
        z = z + step
        if np.max(np.abs(step[:n] @ p.c_gap.T)) < _NEWTON_TOL and np.max(np.abs(step[n:])) < 1e-12:
            break
    else:
        raise ValueError("operating_point: Newton's method did not converge; the magnets cannot carry the "
                         "rotor (check bias_current_a, current_limit_a and the rotor mass)")
    x, u = z[:n], z[n:]
    i, g = p.c_current @ x, p.c_gap @ x
    if np.any(np.abs(u) > rig.current_limit_a):
        raise ValueError(f"operating_point: carrying the rotor needs control currents {u} A, beyond "
                         f"current_limit_a = {rig.current_limit_a} A")
    f, dfdi, dfdg = magnet_force_and_slopes(mag, i, g)
    return OperatingPoint(x, u, g, f, dfdi, dfdg)


def _axis_law(rig: Rig) -> MagnetPair | tuple[MagnetPair, ...]:
    """The true magnets as :func:`magnet_force_and_slopes` takes them: one pair when every axis has the
    same (the radial rig: vectorised), else one per axis."""
    mags = rig.axis_magnets(true=True)
    return mags[0] if all(m == mags[0] for m in mags) else mags


def levitated_plant(rig: Rig) -> tuple[TruePlant, OperatingPoint]:
    """The true rig's affine model linearised at the levitated operating point, and that point."""
    op = operating_point(rig)
    fc = op.force_n - op.ki_n_per_a * op.current_a - op.ks_n_per_m * op.gap_m
    return true_plant(rig, op.ki_n_per_a, op.ks_n_per_m, fc), op


def pade_delay(n_channels: int, delay_s: float, order: int = 2) -> StateSpace:
    """Continuous Pade approximation of exp(-s delay) on each channel (identity for delay 0)."""
    if delay_s <= 0:
        return StateSpace(np.zeros((0, 0)), np.zeros((0, n_channels)), np.zeros((n_channels, 0)),
                          np.eye(n_channels))
    # [order/order] Pade: coefficients of exp(-x) ~ N(x) / N(-x)
    coef = [factorial(2 * order - k) * factorial(order) / (factorial(2 * order) * factorial(k)
                                                            * factorial(order - k)) for k in range(order + 1)]
    num = [c * (-delay_s) ** k for k, c in enumerate(coef)][::-1]
    den = [c * delay_s ** k for k, c in enumerate(coef)][::-1]
    from scipy import signal  # here, not at the top: scipy.signal imports scipy.stats, ~0.6 s on every command
    a1, b1, c1, d1 = signal.tf2ss(num, den)
    a1, t = linalg.matrix_balance(a1, permute=False)  # companion entries span 1/tau^order: rescale
    b1, c1 = linalg.solve(t, b1), c1 @ t
    eye = np.eye(n_channels)
    return StateSpace(np.kron(eye, a1), np.kron(eye, b1), np.kron(eye, c1), np.kron(eye, d1))


def delayed_zoh(a: np.ndarray, b: np.ndarray, dt: float, delay_s: float) -> tuple[np.ndarray, np.ndarray,
                                                                                  np.ndarray]:
    """Exact discretisation of x' = A x + B u(t - tau) with u held per sample, 0 <= tau <= dt.

    Returns
    -------
    (Phi, Gamma1, Gamma0) with x[k+1] = Phi x[k] + Gamma1 u[k] + Gamma0 u[k-1].
    """
    if not 0 <= delay_s <= dt * (1 + 1e-9):
        raise ValueError(f"delayed_zoh: delay {delay_s} s must lie in [0, dt = {dt}] s")
    delay_s = min(delay_s, dt)
    phi, _ = zoh_blocks(a, b, dt)
    e_rest, g1 = zoh_blocks(a, b, dt - delay_s)
    _, g_tau = zoh_blocks(a, b, delay_s)
    return phi, g1, e_rest @ g_tau


def true_linear_model(rig: Rig, discrete: bool = False, pade_order: int = 2, plant: TruePlant | None = None,
                      outputs: np.ndarray | None = None) -> StateSpace:
    """Small-signal model of the true rig at the levitated operating point: u [A] -> y [m].

    The reference every identification accuracy figure is measured against.

    Parameters
    ----------
    rig
        rig parameters.
    discrete
        False gives the continuous model with the extra delay as a
        Pade approximation (``pade_order``); True gives the exact
        zero-order-hold model at rig.dt (the delay exact, na extra states
        u[k-1]) -- what a sampled measurement of the simulator sees.
    pade_order
        order of the delay approximation (continuous only).
    plant
        the affine model to linearise (default :func:`levitated_plant`'s),
        e.g. one with the magnets' slopes at an excitation level.
    outputs
        (q, n) output rows over the plant's states (default ``c_y``,
        the sensors), e.g. ``c_current`` or ``c_gap``.

    Returns
    -------
    StateSpace with na inputs (the layout's u names), na outputs (its y names; q unnamed ones with
    ``outputs``), D = 0.
    """
    p = levitated_plant(rig)[0] if plant is None else plant
    c_out = p.c_y if outputs is None else np.asarray(outputs, dtype=float)
    na = p.n_axes
    names = dict(input_names=p.layout.inputs, input_units=p.layout.units("u"))
    if outputs is None:
        names.update(output_names=p.layout.outputs, output_units=p.layout.units("y"))
    if not discrete:
        cont = StateSpace(p.a, p.b_u, c_out, np.zeros((c_out.shape[0], na)))
        return series(pade_delay(na, p.delay_s, pade_order), cont)._replace(**names)
    phi, g1, g0 = delayed_zoh(p.a, p.b_u, rig.dt, p.delay_s)
    n = p.n_states
    a = np.block([[phi, g0], [np.zeros((na, n + na))]])
    b = np.vstack([g1, np.eye(na)])
    c = np.hstack([c_out, np.zeros((c_out.shape[0], na))])
    return StateSpace(a, b, c, np.zeros((c_out.shape[0], na)), rig.dt, **names)


def true_frf(rig: Rig, freq_hz: np.ndarray) -> np.ndarray:
    """The true rig's sampled small-signal FRF u -> y at ``freq_hz`` (L,) [Hz], shape (L, na, na) [m/A]."""
    return true_linear_model(rig, discrete=True).freqresp(np.asarray(freq_hz, dtype=float))
