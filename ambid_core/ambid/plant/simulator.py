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
numpy. The rig's axes (its layout: four radial, or five with the axial
bearing) set every size.

Sensor noise: the noise of sample k is row k of ``default_rng(seed)``'s
standard normal stream (drawn (NOISE_BLOCK, na) at a time) times each
sensor's noise std, whichever of ``output()`` and ``step_output()`` reads
it, and however often.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import linalg

from ambid.compiled import KernelOwner, compiled
from ambid.plant import step_kernel as sk
from ambid.plant.rig import Rig
from ambid.plant.sensors import cubic, noise_std, runout
from ambid.plant.true_rig import OperatingPoint, TruePlant, delayed_zoh, levitated_plant, zoh_blocks

CONTACT_SUBSTEPS = 16
NOISE_BLOCK = 4096
# the magnet law is evaluated at most this close to a pole face (fraction of the air gap)
_GAP_GUARD = 0.98


class PlantSimulator(KernelOwner):
    """The simulated rig: state, one step per sample, measured output.

    Parameters
    ----------
    rig
        rig parameters.
    seed
        seed of the sensor noise.
    nonlinear_magnets
        use the full force law (eq. 2.14) of the true
        magnets instead of its linearisation at the levitated operating
        point.

    Attributes
    ----------
    plant
        the :class:`ambid.plant.true_rig.TruePlant` integrated.
    operating_point
        the levitated equilibrium (ic0, gaps, slopes).
    index
        samples stepped so far (read-only).

    State ``x`` (n,): see :mod:`ambid.plant.true_rig`. The rotor starts at rest on
    the backup bearings (static equilibrium in contact, zero currents).
    """

    _UNPICKLED = ("_plant_step", "_aux", "_v", "_noise", "_yout")  # a copy binds them to its own work vector

    def __init__(self, rig: Rig, seed: int = 0, nonlinear_magnets: bool = False) -> None:
        self.rig = rig
        plant, op = levitated_plant(rig)
        self.plant: TruePlant = plant
        self.operating_point: OperatingPoint = op
        self.layout = plant.layout
        n, na = plant.n_states, plant.n_axes
        self._n, self._na = n, na
        dt = rig.dt
        # free-flight step: x[k+1] = Phi x + G0 u[k-1] + G1 u[k] + Gw [f; r_s] + Gr [cos; sin](theta_k) + gc
        phi, g1, g0 = delayed_zoh(plant.a, plant.b_u, dt, plant.delay_s)
        b_w = np.column_stack([plant.b_f, plant.b_s, plant.b_c])
        _, g_w = zoh_blocks(plant.a, b_w, dt)
        g_rot = _rotating_drive(plant, dt)
        step_rows = np.hstack([phi, g0, g1, g_w[:, :2 * na], g_rot, g_w[:, 2 * na:]])  # (n, n + 4 na + 3)
        self._aux_map = np.vstack([plant.c_y, plant.c_gap, plant.c_current, plant.c_sensor])  # (4 na, n)
        shift = np.zeros((na, n + 4 * na + 3))
        shift[:, n + na:n + 2 * na] = np.eye(na)  # u[k] becomes u[k-1]
        m = np.vstack([step_rows, shift, self._aux_map @ step_rows])  # (n + 5 na, n + 4 na + 3)
        # one work vector holds parameters, aux, v, M and the noise block (ambid.plant.step_kernel)
        s = sk.plant_work(m, na, NOISE_BLOCK)
        self.sensors = rig.axis_sensors()
        axes, groups = sk.plant_offsets.py_func(n, na)[:2]
        words = s[axes:groups].reshape(na, sk.AXIS_WORDS)
        for j, mag in enumerate(rig.axis_magnets(true=True)):
            words[j, sk.AX_KC] = mag.k_magnet * math.cos(mag.pole_angle_rad)
            words[j, sk.AX_IB] = mag.bias_current_a
            words[j, sk.AX_S0] = mag.air_gap_m
            words[j, sk.AX_GUARD] = _GAP_GUARD * mag.air_gap_m
        words[:, sk.AX_FC], words[:, sk.AX_KI], words[:, sk.AX_KS] = plant.force_const, plant.ki, plant.ks
        words[:, sk.AX_LIMIT] = rig.current_limit_a
        words[:, sk.AX_CUBIC] = cubic(self.sensors)  # Sensors.probe_error, compiled
        s[sk.PAR_CUBIC] = float(bool(np.any(words[:, sk.AX_CUBIC])))
        self._backup = rig.backup_bearings()
        for q, (members, clearance) in enumerate(self._backup):
            s[groups + 3 * q:groups + 3 * q + 3] = members[0], members[1] if len(members) > 1 else -1, \
                clearance * clearance
        s[sk.PAR_GROUPS] = len(self._backup)
        s[sk.PAR_NONLINEAR] = float(bool(nonlinear_magnets))
        s[sk.PAR_COS_STEP], s[sk.PAR_SIN_STEP] = math.cos(plant.speed_rad_s * dt), math.sin(plant.speed_rad_s * dt)
        s[sk.PAR_COS] = 1.0  # the rotor angle is 0 at sample 0
        s[sk.PAR_UNBALANCE] = float(plant.b_unbalance is not None)
        if plant.runout is not None:
            table = sk.plant_offsets.py_func(n, na)[2]
            s[sk.PAR_RUNOUT_N] = plant.runout.shape[0]
            s[table:table + plant.runout.size] = plant.runout.ravel()
        self._s = s
        self._bind()
        # contact sub-steps (the delayed input switches at the nearest sub-step)
        h = dt / CONTACT_SUBSTEPS
        self._phi_s, self._gu_s = zoh_blocks(plant.a, plant.b_u, h)
        _, gw_s = zoh_blocks(plant.a, b_w, h)
        self._gf_s, self._gs_s, self._gc_s = gw_s[:, :na], gw_s[:, na:2 * na], gw_s[:, 2 * na]
        self._grot_s = _rotating_drive(plant, h)
        self._delay_substeps = int(round(plant.delay_s / h))
        self._gap_vel = plant.gap_velocity_map()
        self._noise_std = noise_std(self.sensors)
        self._cubic = cubic(self.sensors)
        self._kcon, self._dcon = rig.contact_stiffness_n_per_m, rig.contact_damping_ns_per_m
        self._rng = np.random.default_rng(seed)
        self.draw_noise()  # rows for samples 0 .. NOISE_BLOCK - 1
        self.x = self._rest_state()

    def _bind(self) -> None:
        """The compiled step kernel, and named views into the work vector (the kernel reads and writes it)."""
        self._plant_step = compiled(sk.plant_step_with, sk.plant_step_with_args(self._na))
        s = self._s
        n, na = self._n, self._na
        _, _, _, _, yout, aux, iv, _ = sk.plant_offsets.py_func(n, na)
        self._yout = s[yout:yout + na]  # the y[k+1] it leaves
        self._aux = s[aux:aux + 4 * na]  # y, gap, current, sensor displacement at index
        self._v = s[iv:iv + n + 4 * na + 3]
        self._noise = s[sk.noise_offset(n, na):].reshape(NOISE_BLOCK, na)

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
            self._aux[:self._na] += runout(self.plant.runout, self.rotor_angle_rad)

    @property
    def rotor_angle_rad(self) -> float:
        """Rotor angle theta at the present sample, in [0, 2 pi) [rad] (0 at sample 0)."""
        return float(math.atan2(self._s[sk.PAR_SIN], self._s[sk.PAR_COS]) % (2 * math.pi))

    @property
    def bearing_displacement(self) -> np.ndarray:
        """Rotor minus stator displacement at the bearings [m], (na,) in layout order."""
        na = self._na
        return self._aux[na:2 * na].copy()

    def bearing_radius(self) -> np.ndarray:
        """Rotor-stator displacement at each backup bearing [m]: the radius at a radial one, |z| at an
        axial one, (bearings,) in ``rig.backup_bearings()`` order (A, B, then the axial one)."""
        g = self._aux[self._na:2 * self._na].tolist()
        return np.array([math.hypot(*(g[j] for j in members)) for members, _ in self._backup])

    def output(self) -> np.ndarray:
        """Measured sensor displacements y[k] [m], (na,), with sensor noise, k = ``index``.

        The noise of sample k is row k of the seed's stream (drawn in blocks
        of ``NOISE_BLOCK`` rows): calling ``output()`` twice, or after
        :meth:`step_output`, returns the same y.
        """
        s = self._s
        return self._aux[:self._na] + self._noise[int(s[sk.PAR_INDEX] - s[sk.PAR_NOISE_BASE])]

    def draw_noise(self) -> None:
        """The next NOISE_BLOCK rows of the noise stream; a compiled caller of ``plant_step`` calls it
        when the kernel returns STATUS_NOISE (nothing changed), then calls the kernel again."""
        self._noise[:] = self._rng.standard_normal((NOISE_BLOCK, self._na)) * self._noise_std
        if self._s[sk.PAR_STATUS] == sk.STATUS_NOISE:
            self._s[sk.PAR_NOISE_BASE] += NOISE_BLOCK
            self._s[sk.PAR_STATUS] = 0.0

    def start_levitated(self) -> None:
        """Put the rig at the levitated operating point: x = operating_point.state, the previous
        current reference ic0 (skips the lift-off, e.g. to measure around the operating point)."""
        n = self._n
        self._v[n:n + self._na] = self.operating_point.current_a
        self.x = self.operating_point.state

    # -- forces the affine model lacks -------------------------------------
    def _magnet_residual(self, cur: np.ndarray, gap: np.ndarray) -> np.ndarray:
        """Eq. 2.14 minus its affine linearisation per axis [N], (na,), for currents and gaps (na,)."""
        out = np.empty(self._na)
        sk.magnet_residual(self._s, np.ascontiguousarray(cur, dtype=float), np.ascontiguousarray(gap, dtype=float),
                           out)
        return out

    def _contact_force(self, gap: np.ndarray, gap_vel: np.ndarray) -> np.ndarray:
        """Retainer force on the rotor at the bearings [N], (na,): spring-damper along the radius (a radial
        bearing's x and y together, an axial one along z), push only."""
        f = np.zeros(self._na)
        for members, clearance in self._backup:
            if len(members) == 2:
                j, i = members
                gx, gy = gap[j], gap[i]
                r = math.hypot(gx, gy)
                pen = r - clearance
                if pen > 0:
                    ux, uy = gx / r, gy / r
                    vr = gap_vel[j] * ux + gap_vel[i] * uy
                    fr = max(self._kcon * pen + self._dcon * vr, 0.0)
                    f[j], f[i] = -fr * ux, -fr * uy
            else:
                j = members[0]
                pen = abs(gap[j]) - clearance
                if pen > 0:
                    sign = math.copysign(1.0, gap[j])
                    f[j] = -sign * max(self._kcon * pen + self._dcon * gap_vel[j] * sign, 0.0)
        return f

    def _rest_state(self) -> np.ndarray:
        """Static equilibrium resting on the retainers with zero currents (Newton, numerical Jacobian)."""
        p = self.plant
        n = self._n

        def resid(x: np.ndarray) -> np.ndarray:
            gap = p.c_gap @ x
            f = self._contact_force(gap, np.zeros(self._na))
            if self.nonlinear_magnets:
                f = f + self._magnet_residual(p.c_current @ x, gap)
            rs = self._cubic * (p.c_sensor @ x) ** 3
            return p.a @ x + p.b_f @ f + p.b_s @ rs + p.b_c

        # first guess: the operating point moved rigidly straight down onto the radial retainers (the
        # axial axis carries no weight: it stays where the operating point has it)
        weight = self.rig.rotor_mass_kg * 9.81 / 2
        target = p.c_gap @ self.operating_point.state
        for members, clearance in self._backup:
            if len(members) == 2:
                target[list(members)] = -(clearance + weight / self._kcon) / math.sqrt(2.0)
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
        """Advance one sample with the current reference u = ic + r [A] (na floats) held.

        Returns
        -------
        (clipped, contact): the amplifiers saturated at the current limit
        during this sample; the rotor touched the backup bearings.
        """
        u = tuple(current_ref)   # step_output's path without building the output (the core loops' call)
        clipped, contact = self._plant_step(self._s, u)
        if contact:  # contact, or the noise block is used up
            if self._s[sk.PAR_STATUS] == sk.STATUS_NOISE:
                self.draw_noise()
                return self.step(u)
            self._substeps()
            return clipped, True
        return clipped, False

    def step_output(self, *u: float) -> tuple:
        """``step(u)`` then ``output()`` in one call: the loop's per-sample call.

        Parameters
        ----------
        u
            current reference u = ic + r [A] held over this sample, na floats.

        Returns
        -------
        (y_0, ..., y_na-1, clipped, contact): the next sample's measured
        output y[k+1] [m] with its noise (what ``output()`` returns
        after this call), then as :meth:`step`.
        """
        clipped, contact = self._plant_step(self._s, u)
        if contact:  # contact, or the noise block is used up
            if self._s[sk.PAR_STATUS] == sk.STATUS_NOISE:
                self.draw_noise()
                return self.step_output(*u)
            return (*self.finish_contact_sample(), clipped, True)
        return (*self._yout.tolist(), clipped, False)

    @property
    def work(self) -> np.ndarray:
        """The plant work vector (:mod:`ambid.plant.step_kernel`), for a compiled caller of ``plant_step``
        that handles its STATUS_* returns as :meth:`step_output` does."""
        return self._s

    def finish_contact_sample(self) -> tuple[float, ...]:
        """After ``plant_step`` returned STATUS_CONTACT: the sample in contact sub-steps; returns
        y[k+1] [m] with its noise (na floats)."""
        self._substeps()
        return tuple(self.output().tolist())

    def _substeps(self) -> None:
        """Redo the sample in CONTACT_SUBSTEPS sub-steps from v, with u[k] (clipped) in v's u slot."""
        p = self.plant
        n = self._n
        na = self._na
        v = self._v
        x = v[:n].copy()
        u_new, u_old = v[n + na:n + 2 * na].copy(), v[n:n + na].copy()
        h = self.rig.dt / CONTACT_SUBSTEPS
        theta = self.rotor_angle_rad - p.speed_rad_s * h * CONTACT_SUBSTEPS  # the angle at the sample's start
        for j in range(CONTACT_SUBSTEPS):
            gap = p.c_gap @ x
            f = self._contact_force(gap, self._gap_vel @ x)
            if self.nonlinear_magnets:
                f += self._magnet_residual(p.c_current @ x, gap)
            drive = self._gu_s @ (u_old if j < self._delay_substeps else u_new) + self._gc_s + self._gf_s @ f
            if self._s[sk.PAR_CUBIC]:
                drive += self._gs_s @ (self._cubic * (p.c_sensor @ x) ** 3)
            if p.b_unbalance is not None:
                th = theta + j * p.speed_rad_s * h
                drive += self._grot_s @ np.array([math.cos(th), math.sin(th)])
            x = self._phi_s @ x + drive
        v[:n] = x
        v[n:n + na] = u_new
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
