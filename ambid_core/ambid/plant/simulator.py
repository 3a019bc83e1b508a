"""Sample-by-sample simulation of the true rig for the lock-step control loop.

The rig is :mod:`ambid.plant.true_rig`'s affine model, linearised at the levitated
operating point, integrated exactly over each sample with the current
reference held (zero-order hold, the extra input delay exact). What the
affine model lacks -- the magnets' deviation from their linearisation
(eq. 2.14), the sensors' probe-curve error, backup-bearing contact -- enters
as forces (and sensor inputs) evaluated at the start of each step and held;
while the rotor touches the retainer, where the contact spring is stiff, the
sample is split into sub-steps (the delayed reference switches at the
nearest sub-step there).

Spinning, the unbalance forces and the probes' runout are known functions
of the rotor angle theta, integrated from the speed sample by sample: the
unbalance drive rotates within a sample (the kernel turns the angle's phasor
by Omega dt per sample, no trigonometry), and its exact integral over the
sample is a fixed matrix times [cos theta_k; sin theta_k]
(:func:`_rotating_drive`); the runout is added to y at theta_k.

One free-flight sample is one fused matrix-vector product,
[x; u; C x][k+1] = M [x; u[k-1]; u[k]; f; r_s; cos theta_k; sin theta_k; 1], run together with the
held forces by the compiled kernel :func:`ambid.plant.step_kernel.plant_step`
(``step_output()`` ~3 us per sample); the rare contact sub-steps run in
numpy.

Sensor noise: the noise of sample k is row k of ``default_rng(seed)``'s
standard normal stream (drawn (NOISE_BLOCK, 4) at a time) times
``sensor_noise_m``, whichever of ``output()`` and ``step_output()`` reads
it, and however often.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import linalg

from ambid.compiled import KernelOwner, compiled
from ambid.plant import step_kernel as sk
from ambid.plant.rig import Rig
from ambid.plant.sensors import Sensors, runout
from ambid.plant.true_rig import OperatingPoint, TruePlant, delayed_zoh, levitated_plant, zoh_blocks

CONTACT_SUBSTEPS = 16
NOISE_BLOCK = 4096
# the magnet law is evaluated at most this close to a pole face (fraction of the air gap)
_GAP_GUARD = 0.98


class PlantSimulator(KernelOwner):
    """The simulated rig: state, one step per sample, measured output.

    Args:
        rig: rig parameters.
        seed: seed of the sensor noise.
        nonlinear_magnets: use the full force law (eq. 2.14) of the true
            magnets instead of its linearisation at the levitated operating
            point.

    Attributes:
        plant: the :class:`ambid.plant.true_rig.TruePlant` integrated.
        operating_point: the levitated equilibrium (ic0, gaps, slopes).
        index: samples stepped so far (read-only).

    State ``x`` (n,): see :mod:`ambid.plant.true_rig`. The rotor starts at rest on
    the backup bearings (static equilibrium in contact, zero currents).
    """

    _UNPICKLED = ("_plant_step", "_aux", "_v", "_noise")  # a copy binds them to its own work vector

    def __init__(self, rig: Rig, seed: int = 0, nonlinear_magnets: bool = False) -> None:
        self.rig = rig
        plant, op = levitated_plant(rig)
        self.plant: TruePlant = plant
        self.operating_point: OperatingPoint = op
        n = plant.n_states
        self._n = n
        dt = rig.dt
        # free-flight step: x[k+1] = Phi x + G0 u[k-1] + G1 u[k] + Gw [f; r_s] + Gr [cos; sin](theta_k) + gc
        phi, g1, g0 = delayed_zoh(plant.a, plant.b_u, dt, plant.delay_s)
        b_w = np.column_stack([plant.b_f, plant.b_s, plant.b_c])
        _, g_w = zoh_blocks(plant.a, b_w, dt)
        g_rot = _rotating_drive(plant, dt)
        step_rows = np.hstack([phi, g0, g1, g_w[:, :8], g_rot, g_w[:, 8:]])  # (n, n + 19)
        self._aux_map = np.vstack([plant.c_y, plant.c_gap, plant.c_current, plant.c_sensor])  # (16, n)
        shift = np.zeros((4, n + sk.N_EXTRA))
        shift[:, n + 4:n + 8] = np.eye(4)  # u[k] becomes u[k-1]
        m = np.vstack([step_rows, shift, self._aux_map @ step_rows])  # (n + 20, n + 19)
        # one work vector holds parameters, aux, v, M and the noise block (ambid.plant.step_kernel)
        s = sk.plant_work(m, NOISE_BLOCK)
        mag = rig.true_magnet
        s[sk.PAR_LIMIT] = rig.current_limit_a
        s[sk.PAR_NONLINEAR] = float(bool(nonlinear_magnets))
        s[sk.PAR_KC] = mag.k_magnet * math.cos(mag.pole_angle_rad)
        s[sk.PAR_IB] = mag.bias_current_a
        s[sk.PAR_S0] = mag.air_gap_m
        s[sk.PAR_GAP_GUARD] = _GAP_GUARD * mag.air_gap_m
        s[sk.PAR_CUBIC] = rig.values["sensor_cubic_per_m2"]  # Sensors.probe_error, compiled
        s[sk.PAR_CLEAR2] = rig.backup_clearance_m * rig.backup_clearance_m
        s[sk.PAR_LIN:sk.PAR_LIN + 12] = np.column_stack([plant.force_const, plant.ki, plant.ks]).ravel()
        s[sk.PAR_COS_STEP], s[sk.PAR_SIN_STEP] = math.cos(plant.speed_rad_s * dt), math.sin(plant.speed_rad_s * dt)
        s[sk.PAR_COS] = 1.0  # the rotor angle is 0 at sample 0
        s[sk.PAR_UNBALANCE] = float(plant.b_unbalance is not None)
        if plant.runout is not None:
            s[sk.PAR_RUNOUT_N] = plant.runout.shape[0]
            s[sk.PAR_RUNOUT:sk.PAR_RUNOUT + plant.runout.size] = plant.runout.ravel()
        self._s = s
        self._bind()
        # contact sub-steps (the delayed input switches at the nearest sub-step)
        h = dt / CONTACT_SUBSTEPS
        self._phi_s, self._gu_s = zoh_blocks(plant.a, plant.b_u, h)
        _, gw_s = zoh_blocks(plant.a, b_w, h)
        self._gf_s, self._gs_s, self._gc_s = gw_s[:, :4], gw_s[:, 4:8], gw_s[:, 8]
        self._grot_s = _rotating_drive(plant, h)
        self._delay_substeps = int(round(plant.delay_s / h))
        self._gap_vel = plant.gap_velocity_map()
        self.sensors = Sensors.from_rig(rig.values)
        self._clear = rig.backup_clearance_m
        self._kcon, self._dcon = rig.contact_stiffness_n_per_m, rig.contact_damping_ns_per_m
        self._rng = np.random.default_rng(seed)
        self.draw_noise()  # rows for samples 0 .. NOISE_BLOCK - 1
        self.x = self._rest_state()

    def _bind(self) -> None:
        """The compiled step kernel, and named views into the work vector (the kernel reads and writes it)."""
        self._plant_step = compiled(sk.plant_step, sk.PLANT_STEP_ARGS)
        s = self._s
        iv, _, iz = sk.plant_offsets.py_func(self._n)
        self._aux = s[sk.AUX:sk.AUX + sk.N_AUX]  # y, gap, current, sensor displacement at index
        self._v = s[iv:iv + self._n + sk.N_EXTRA]
        self._noise = s[iz:].reshape(NOISE_BLOCK, 4)

    # -- state -----------------------------------------------------------
    @property
    def nonlinear_magnets(self) -> bool:
        """The full magnet law (eq. 2.14) is simulated (fixed at construction)."""
        return bool(self._s[sk.PAR_NONLINEAR])

    @property
    def index(self) -> int:
        """Samples stepped so far: the present sample is y[index]."""
        return int(self._s[sk.PAR_INDEX])

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
        self._set_aux(value)

    def _set_aux(self, x: np.ndarray) -> None:
        """aux at the present sample from the state x, the probes' runout at the present rotor angle included."""
        self._aux[:] = self._aux_map @ x
        if self.plant.runout is not None:
            self._aux[0:4] += runout(self.plant.runout, self.rotor_angle_rad)

    @property
    def rotor_angle_rad(self) -> float:
        """Rotor angle theta at the present sample, in [0, 2 pi) [rad] (0 at sample 0)."""
        return float(math.atan2(self._s[sk.PAR_SIN], self._s[sk.PAR_COS]) % (2 * math.pi))

    @property
    def bearing_displacement(self) -> np.ndarray:
        """Rotor minus stator displacement at the bearings [m], (4,) in AXES order."""
        return self._aux[4:8].copy()

    def bearing_radius(self) -> np.ndarray:
        """Radial rotor-stator displacement at bearings A and B [m], (2,)."""
        g = self._aux[4:8].tolist()
        return np.array([math.hypot(g[0], g[2]), math.hypot(g[1], g[3])])

    def output(self) -> np.ndarray:
        """Measured sensor displacements y[k] [m], (4,), with sensor noise, k = ``index``.

        The noise of sample k is row k of the seed's stream (drawn in blocks
        of ``NOISE_BLOCK`` rows): calling ``output()`` twice, or after
        :meth:`step_output`, returns the same y.
        """
        s = self._s
        return self._aux[0:4] + self._noise[int(s[sk.PAR_INDEX] - s[sk.PAR_NOISE_BASE])]

    def draw_noise(self) -> None:
        """The next NOISE_BLOCK rows of the noise stream; a compiled caller of ``plant_step`` calls it
        when the kernel returns STATUS_NOISE (nothing changed), then calls the kernel again."""
        self._noise[:] = self.sensors.draw_noise(self._rng, NOISE_BLOCK)
        if self._s[sk.PAR_STATUS] == sk.STATUS_NOISE:
            self._s[sk.PAR_NOISE_BASE] += NOISE_BLOCK
            self._s[sk.PAR_STATUS] = 0.0

    def start_levitated(self) -> None:
        """Put the rig at the levitated operating point: x = operating_point.state, the previous
        current reference ic0 (skips the lift-off, e.g. to measure around the operating point)."""
        n = self._n
        self._v[n:n + 4] = self.operating_point.current_a
        self.x = self.operating_point.state

    # -- forces the affine model lacks -------------------------------------
    def _magnet_residual(self, cur: np.ndarray, gap: np.ndarray) -> np.ndarray:
        """Eq. 2.14 minus its affine linearisation per axis [N], (4,), for currents and gaps (4,)."""
        out = np.empty(4)
        sk.magnet_residual(self._s, np.ascontiguousarray(cur, dtype=float), np.ascontiguousarray(gap, dtype=float),
                           out)
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
                f = f + self._magnet_residual(p.c_current @ x, gap)
            rs = self.sensors.probe_error(p.c_sensor @ x)
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
        u0, u1, u2, u3 = current_ref
        r = self.step_output(u0, u1, u2, u3)
        return r[4], r[5]

    def step_output(self, u0: float, u1: float, u2: float, u3: float) -> tuple[float, float, float, float, bool, bool]:
        """``step([u0, u1, u2, u3])`` then ``output()`` in one call: the loop's per-sample call.

        Args:
            u0, u1, u2, u3: current reference u = ic + r [A] held over this sample.

        Returns:
            (y0, y1, y2, y3, clipped, contact): the next sample's measured
            output y[k+1] [m] with its noise (what ``output()`` returns
            after this call), then as :meth:`step`.
        """
        r = self._plant_step(self._s, u0, u1, u2, u3)
        if r[5]:  # contact, or the noise block is used up
            if self._s[sk.PAR_STATUS] == sk.STATUS_NOISE:
                self.draw_noise()
                return self.step_output(u0, u1, u2, u3)
            y0, y1, y2, y3 = self.finish_contact_sample()
            return y0, y1, y2, y3, r[4], True
        return r

    @property
    def work(self) -> np.ndarray:
        """The plant work vector (:mod:`ambid.plant.step_kernel`), for a compiled caller of ``plant_step``
        that handles its STATUS_* returns as :meth:`step_output` does."""
        return self._s

    def finish_contact_sample(self) -> tuple[float, float, float, float]:
        """After ``plant_step`` returned STATUS_CONTACT: the sample in contact sub-steps; returns
        y[k+1] [m] with its noise."""
        self._substeps()
        y0, y1, y2, y3 = self.output().tolist()
        return y0, y1, y2, y3

    def _substeps(self) -> None:
        """Redo the sample in CONTACT_SUBSTEPS sub-steps from v, with u[k] (clipped) in v's u slot."""
        p = self.plant
        n = self._n
        v = self._v
        x = v[:n].copy()
        u_new, u_old = v[n + 4:n + 8].copy(), v[n:n + 4].copy()
        h = self.rig.dt / CONTACT_SUBSTEPS
        theta = self.rotor_angle_rad - p.speed_rad_s * h * CONTACT_SUBSTEPS  # the angle at the sample's start
        for j in range(CONTACT_SUBSTEPS):
            gap = p.c_gap @ x
            f = self._contact_force(gap, self._gap_vel @ x)
            if self.nonlinear_magnets:
                f += self._magnet_residual(p.c_current @ x, gap)
            drive = self._gu_s @ (u_old if j < self._delay_substeps else u_new) + self._gc_s + self._gf_s @ f
            if self.sensors.cubic_per_m2:
                drive += self._gs_s @ self.sensors.probe_error(p.c_sensor @ x)
            if p.b_unbalance is not None:
                th = theta + j * p.speed_rad_s * h
                drive += self._grot_s @ np.array([math.cos(th), math.sin(th)])
            x = self._phi_s @ x + drive
        v[:n] = x
        v[n:n + 4] = u_new
        self._set_aux(x)


def _rotating_drive(plant: TruePlant, t: float) -> np.ndarray:
    """(n, 2) G with int_0^t exp(A (t - s)) B_unb [cos; sin](theta_k + Omega s) ds = G [cos; sin](theta_k).

    The rotating phasor w = [cos; sin](theta) obeys w' = S w, S = [[0, -Omega], [Omega, 0]], so G is the
    coupling block of exp([[A, B_unb], [0, S]] t) (zeros without unbalance).
    """
    n = plant.n_states
    if plant.b_unbalance is None:
        return np.zeros((n, 2))
    om = plant.speed_rad_s
    aug = np.zeros((n + 2, n + 2))
    aug[:n, :n], aug[:n, n:] = plant.a, plant.b_unbalance
    aug[n:, n:] = [[0.0, -om], [om, 0.0]]
    return linalg.expm(aug * t)[:n, n:]
