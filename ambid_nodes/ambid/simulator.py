"""Sample-by-sample simulation of the true rig for the lock-step control loop.

The rig is :mod:`ambid.true_rig`'s affine model, linearised at the levitated
operating point, integrated exactly over each sample with the current
reference held (zero-order hold, the extra input delay exact). What the
affine model lacks -- the magnets' deviation from their linearisation
(eq. 2.14), the sensors' probe-curve error, backup-bearing contact -- enters
as forces (and sensor inputs) evaluated at the start of each step and held;
while the rotor touches the retainer, where the contact spring is stiff, the
sample is split into sub-steps (the delayed reference switches at the
nearest sub-step there).

One free-flight sample is one fused matrix-vector product,
[x; u; C x][k+1] = M [x; u[k-1]; u[k]; f; r_s; 1], so ``step() + output()``
costs ~20 us in Python.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import linalg

from ambid.rig import Rig
from ambid.true_rig import OperatingPoint, TruePlant, delayed_zoh, levitated_plant, zoh_blocks

CONTACT_SUBSTEPS = 16
NOISE_BLOCK = 4096
# the magnet law is evaluated at most this close to a pole face (fraction of the air gap)
_GAP_GUARD = 0.98


class PlantSimulator:
    """The simulated rig: state, one step per sample, measured output.

    Args:
        rig: rig parameters.
        seed: seed of the sensor noise.
        nonlinear_magnets: use the full force law (eq. 2.14) of the true
            magnets instead of its linearisation at the levitated operating
            point.

    Attributes:
        plant: the :class:`ambid.true_rig.TruePlant` integrated.
        operating_point: the levitated equilibrium (ic0, gaps, slopes).
        index: samples stepped so far.

    State ``x`` (n,): see :mod:`ambid.true_rig`. The rotor starts at rest on
    the backup bearings (static equilibrium in contact, zero currents).
    """

    def __init__(self, rig: Rig, seed: int = 0, nonlinear_magnets: bool = False) -> None:
        self.rig = rig
        self.nonlinear_magnets = bool(nonlinear_magnets)
        plant, op = levitated_plant(rig)
        self.plant: TruePlant = plant
        self.operating_point: OperatingPoint = op
        n = plant.n_states
        self._n = n
        dt = rig.dt
        # free-flight step: x[k+1] = Phi x + G0 u[k-1] + G1 u[k] + Gw [f; r_s; 1]
        phi, g1, g0 = delayed_zoh(plant.a, plant.b_u, dt, plant.delay_s)
        b_w = np.column_stack([plant.b_f, plant.b_s, plant.b_c])
        _, g_w = zoh_blocks(plant.a, b_w, dt)
        step_rows = np.hstack([phi, g0, g1, g_w])  # (n, n + 17)
        self._aux_map = np.vstack([plant.c_y, plant.c_gap, plant.c_current, plant.c_sensor])  # (16, n)
        shift = np.zeros((4, n + 17))
        shift[:, n + 4:n + 8] = np.eye(4)  # u[k] becomes u[k-1]
        self._m = np.vstack([step_rows, shift, self._aux_map @ step_rows])
        self._v = np.zeros(n + 17)
        self._v[-1] = 1.0
        # contact sub-steps (the delayed input switches at the nearest sub-step)
        h = dt / CONTACT_SUBSTEPS
        self._phi_s, self._gu_s = zoh_blocks(plant.a, plant.b_u, h)
        _, gw_s = zoh_blocks(plant.a, b_w, h)
        self._gf_s, self._gs_s, self._gc_s = gw_s[:, :4], gw_s[:, 4:8], gw_s[:, 8]
        self._delay_substeps = int(round(plant.delay_s / h))
        self._gap_vel = plant.gap_velocity_map()
        # magnet law, as plain floats for the per-sample residual
        mag = rig.true_magnet
        self._res_consts = (mag.k_magnet * math.cos(mag.pole_angle_rad), mag.bias_current_a, mag.air_gap_m,
                            _GAP_GUARD * mag.air_gap_m)
        self._lin = [(float(fc), float(ki), float(ks)) for fc, ki, ks in zip(plant.force_const, plant.ki, plant.ks)]
        self._cubic = rig.sensor_cubic_per_m2
        self._limit = rig.current_limit_a
        self._clear = rig.backup_clearance_m
        self._clear2 = self._clear * self._clear
        self._kcon, self._dcon = rig.contact_stiffness_n_per_m, rig.contact_damping_ns_per_m
        self._noise_std = rig.sensor_noise_m
        self._rng = np.random.default_rng(seed)
        self._noise = np.empty((0, 4))
        self._noise_pos = 0
        self.index = 0
        self.x = self._rest_state()

    # -- state -----------------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        """State (n,) (a view; assign to ``x`` to set it)."""
        return self._v[:self._n]

    @x.setter
    def x(self, value: np.ndarray) -> None:
        value = np.asarray(value, dtype=float)
        if value.shape != (self._n,) or not np.all(np.isfinite(value)):
            raise ValueError(f"PlantSimulator.x must be finite with shape ({self._n},), got {value.shape}")
        self._v[:self._n] = value
        self._set_aux(self._aux_map @ value)

    def _set_aux(self, aux: np.ndarray) -> None:
        self._y = aux[0:4]
        vals = aux[4:16].tolist()
        self._gap, self._cur, self._sd = vals[0:4], vals[4:8], vals[8:12]
        self._touch = self._touching(self._gap)

    @property
    def bearing_displacement(self) -> np.ndarray:
        """Rotor minus stator displacement at the bearings [m], (4,) in AXES order."""
        return np.array(self._gap)

    def bearing_radius(self) -> np.ndarray:
        """Radial rotor-stator displacement at bearings A and B [m], (2,)."""
        g = self._gap
        return np.array([math.hypot(g[0], g[2]), math.hypot(g[1], g[3])])

    def output(self) -> np.ndarray:
        """Measured sensor displacements y[k] [m], (4,), with sensor noise."""
        if self._noise_pos >= len(self._noise):
            self._noise = self._rng.standard_normal((NOISE_BLOCK, 4)) * self._noise_std
            self._noise_pos = 0
        y = self._y + self._noise[self._noise_pos]
        self._noise_pos += 1
        return y

    def start_levitated(self) -> None:
        """Put the rig at the levitated operating point: x = operating_point.state, the previous
        current reference ic0 (skips the lift-off, e.g. to measure around the operating point)."""
        n = self._n
        self._v[n:n + 4] = self.operating_point.current_a
        self.x = self.operating_point.state

    # -- forces the affine model lacks -------------------------------------
    def _touching(self, g: list[float]) -> bool:
        c2 = self._clear2
        return g[0] * g[0] + g[2] * g[2] > c2 or g[1] * g[1] + g[3] * g[3] > c2

    def _magnet_residual(self, cur: list[float], gap: list[float]) -> list[float]:
        """Eq. 2.14 minus its affine linearisation per axis [N] (plain floats: this runs every sample).

        Free flight keeps |gap| below the retainer clearance, < s0; in contact
        the gap is clamped short of the pole face.
        """
        kc, ib, s0, lim = self._res_consts
        out = []
        for j in range(4):
            i, g = cur[j], gap[j]
            if not -lim < g < lim:
                g = lim if g > 0 else -lim
            a, b, ip, im = s0 - g, s0 + g, ib + i, ib - i
            fc, ki, ks = self._lin[j]
            out.append(kc * (ip * ip / (a * a) - im * im / (b * b)) - fc - ki * i - ks * g)
        return out

    def _contact_force(self, gap: np.ndarray, gap_vel: np.ndarray) -> np.ndarray:
        """Retainer force on the rotor at the bearings [N], (4,): spring-damper along the radius, push only."""
        f = np.zeros(4)
        for j in (0, 1):  # bearing A, B: axes j (x) and j + 2 (y)
            gx, gy = gap[j], gap[j + 2]
            r = math.hypot(gx, gy)
            pen = r - self._clear
            if pen > 0:
                ux, uy = gx / r, gy / r
                vr = gap_vel[j] * ux + gap_vel[j + 2] * uy
                fr = max(self._kcon * pen + self._dcon * vr, 0.0)
                f[j], f[j + 2] = -fr * ux, -fr * uy
        return f

    def _rest_state(self) -> np.ndarray:
        """Static equilibrium resting on the retainers with zero currents (Newton, numerical Jacobian)."""
        p = self.plant
        n = self._n

        def resid(x: np.ndarray) -> np.ndarray:
            gap = p.c_gap @ x
            f = self._contact_force(gap, np.zeros(4))
            if self.nonlinear_magnets:
                f = f + np.array(self._magnet_residual((p.c_current @ x).tolist(), gap.tolist()))
            rs = self._cubic * (p.c_sensor @ x) ** 3
            return p.a @ x + p.b_f @ f + p.b_s @ rs + p.b_c

        # first guess: the operating point moved rigidly straight down onto the retainers
        weight = self.rig.rotor_mass_kg * 9.81 / 2
        target = np.full(4, -(self._clear + weight / self._kcon) / math.sqrt(2.0))
        x = self.operating_point.state.copy()
        x[p.c_current.argmax(axis=1)] = 0.0
        x[:p.n_rotor] += linalg.lstsq(p.c_gap[:, :p.n_rotor], target - p.c_gap @ x)[0]
        scale = np.maximum(np.abs(x), 1e-9)
        for _ in range(30):
            r = resid(x)
            jac = np.empty((n, n))
            for j in range(n):
                e = np.zeros(n)
                e[j] = 1e-7 * scale[j]
                jac[:, j] = (resid(x + e) - r) / e[j]
            dx = linalg.lstsq(jac, -r)[0]
            x = x + dx
            if np.max(np.abs(p.c_gap @ dx)) < 1e-13:
                return x
        raise ValueError("PlantSimulator: no resting equilibrium on the backup bearings found; check the "
                         "contact and magnet parameters")

    # -- stepping ----------------------------------------------------------
    def step(self, current_ref) -> tuple[bool, bool]:
        """Advance one sample with the current reference u = ic + r [A] (4 floats) held.

        Returns:
            (clipped, contact): the amplifiers saturated at the current limit
            during this sample; the rotor touched the backup bearings.
        """
        lim = self._limit
        u0, u1, u2, u3 = current_ref
        u = [u0, u1, u2, u3]
        clipped = not (-lim <= u0 <= lim and -lim <= u1 <= lim and -lim <= u2 <= lim and -lim <= u3 <= lim)
        if clipped:
            u = [lim if c > lim else -lim if c < -lim else c for c in u]
        v = self._v
        n = self._n
        if self.nonlinear_magnets:
            v[n + 4:n + 12] = u + self._magnet_residual(self._cur, self._gap)
        else:
            v[n + 4:n + 8] = u
        if self._cubic:
            c3 = self._cubic
            v[n + 12:n + 16] = [c3 * d * d * d for d in self._sd]
        if self._touch:
            self._substeps(u)
            contact = True
        else:
            out = self._m @ v
            vals = out[n + 8:].tolist()  # gap (4), current (4), sensor displacement (4) at k + 1
            c2 = self._clear2
            contact = vals[0] * vals[0] + vals[2] * vals[2] > c2 or vals[1] * vals[1] + vals[3] * vals[3] > c2
            if contact:  # entering contact during this step: redo it finely
                self._substeps(u)
            else:
                v[:n + 4] = out[:n + 4]
                self._y = out[n + 4:n + 8]
                self._gap, self._cur, self._sd = vals[0:4], vals[4:8], vals[8:12]
        self.index += 1
        return clipped, contact

    def _substeps(self, u: list[float]) -> None:
        p = self.plant
        n = self._n
        v = self._v
        x = v[:n].copy()
        u_new, u_old = np.array(u), v[n:n + 4].copy()
        for j in range(CONTACT_SUBSTEPS):
            gap = p.c_gap @ x
            f = self._contact_force(gap, self._gap_vel @ x)
            if self.nonlinear_magnets:
                f += self._magnet_residual((p.c_current @ x).tolist(), gap.tolist())
            drive = self._gu_s @ (u_old if j < self._delay_substeps else u_new) + self._gc_s + self._gf_s @ f
            if self._cubic:
                drive += self._gs_s @ (self._cubic * (p.c_sensor @ x) ** 3)
            x = self._phi_s @ x + drive
        v[:n] = x
        v[n:n + 4] = u_new
        self._set_aux(self._aux_map @ x)
