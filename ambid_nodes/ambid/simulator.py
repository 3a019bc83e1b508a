"""Sample-by-sample simulation of the rig for the lock-step control loop.

The linear part (rotor, linearised magnets, amplifiers) is integrated exactly
over each sample with the current reference held (zero-order hold); the
forces the linear model lacks (the magnets' nonlinearity, backup-bearing
contact) are evaluated at the start of each step and held, with sub-steps
while the rotor touches the retainer, where the contact spring is stiff.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from ambid.rig import Rig, analytical_model

CONTACT_SUBSTEPS = 16
NOISE_BLOCK = 4096


def _zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    # exact discretisation via the augmented matrix exponential
    n, m = b.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n], aug[:n, n:] = a, b
    e = expm(aug * dt)
    return e[:n, :n], e[:n, n:]


class PlantSimulator:
    """The simulated rig: state, one step per sample, measured output.

    Args:
        rig: rig parameters.
        seed: seed of the sensor noise.
        nonlinear_magnets: use the full force law (eq. 2.14) instead of the
            linearisation (eq. 2.18).

    State x (12,): bearing displacements [m], velocities [m/s], coil control
    currents [A] (see :func:`ambid.rig.analytical_model`). The rotor starts at
    rest on the backup bearings.
    """

    def __init__(self, rig: Rig, seed: int = 0, nonlinear_magnets: bool = False) -> None:
        self.rig = rig
        self.nonlinear_magnets = nonlinear_magnets
        model = analytical_model(rig)
        w = rig.rotor.inverse_mass()
        n = model.n_states
        # extra inputs: bearing forces [N] (4) and gravity (1)
        b_force = np.zeros((n, 4))
        b_force[4:8] = w
        b_grav = np.zeros((n, 1))
        b_grav[4:8, 0] = rig.rotor.gravity_acceleration()
        b_all = np.hstack([model.b, b_force, b_grav])
        self._c = model.c
        self._a_d, bd = _zoh(model.a, b_all, rig.dt)
        self._b_u, self._b_f, self._b_g = bd[:, :4], bd[:, 4:8], bd[:, 8]
        # one mat-vec per free-flight step: x[k+1] = [Ad Bu bg] [x; u; 1]
        self._m = np.hstack([self._a_d, self._b_u, self._b_g[:, None]])
        self._v = np.zeros(n + 5)
        self._v[-1] = 1.0
        self._a_s, bds = _zoh(model.a, b_all, rig.dt / CONTACT_SUBSTEPS)
        self._b_us, self._b_fs, self._b_gs = bds[:, :4], bds[:, 4:8], bds[:, 8]
        self._magnet = rig.magnet
        self._ki, self._ks = self._magnet.ki, self._magnet.ks
        self._limit = rig.current_limit_a
        self._clear = rig.backup_clearance_m
        self._kc, self._dc = rig.contact_stiffness_n_per_m, rig.contact_damping_ns_per_m
        self._noise_std = rig.sensor_noise_m
        self._rng = np.random.default_rng(seed)
        self._noise = np.empty((0, 4))
        self._noise_pos = 0
        self.index = 0
        # resting on the retainer: straight down, i.e. -1/sqrt(2) on both 45-deg axes
        load = rig.rotor_mass_kg * 9.81 / 2
        r0 = self._clear + load / self._kc
        self.x = np.zeros(n)
        self.x[:4] = -r0 / np.sqrt(2.0)

    @property
    def bearing_displacement(self) -> np.ndarray:
        """Rotor displacement at the bearings [m], (4,) in AXES order."""
        return self.x[:4]

    def bearing_radius(self) -> np.ndarray:
        """Radial displacement at bearings A and B [m], (2,)."""
        q = self.x
        return np.hypot(q[0:2], q[2:4])

    def output(self) -> np.ndarray:
        """Measured sensor displacements y[k] [m], (4,), with sensor noise."""
        if self._noise_pos >= len(self._noise):
            self._noise = self._rng.standard_normal((NOISE_BLOCK, 4)) * self._noise_std
            self._noise_pos = 0
        y = self._c @ self.x + self._noise[self._noise_pos]
        self._noise_pos += 1
        return y

    def _contact_force(self, x: np.ndarray) -> np.ndarray | None:
        q, v = x[:4], x[4:8]
        r = np.hypot(q[0:2], q[2:4])
        pen = r - self._clear
        if np.all(pen <= 0):
            return None
        f = np.zeros(4)
        for j in (0, 1):  # bearing A, B
            if pen[j] > 0:
                ux, uy = q[j] / r[j], q[j + 2] / r[j]
                vr = v[j] * ux + v[j + 2] * uy
                fr = max(self._kc * pen[j] + self._dc * vr, 0.0)  # the retainer can only push
                f[j] -= fr * ux
                f[j + 2] -= fr * uy
        return f

    def _magnet_residual(self, x: np.ndarray) -> np.ndarray:
        q, i = x[:4], x[8:12]
        return self._magnet.force(i, q) - self._ki * i - self._ks * q

    def _touching(self, x: np.ndarray) -> bool:
        xa, xb, ya, yb = x[:4].tolist()
        c2 = self._clear * self._clear
        return xa * xa + ya * ya > c2 or xb * xb + yb * yb > c2

    def step(self, current_ref) -> tuple[bool, bool]:
        """Advance one sample with the current reference u = ic + r [A] (4 floats) held.

        Returns:
            (clipped, contact): the amplifiers saturated at the current limit
            during this sample; the rotor touched the backup bearings.
        """
        lim = self._limit
        u = list(current_ref)
        clipped = False
        for j in range(4):
            if not -lim <= u[j] <= lim:
                clipped = True
                u[j] = lim if u[j] > lim else -lim
        x = self.x
        v = self._v
        v[:12] = x
        v[12:16] = u
        if self._touching(x):
            x_new, contact = self._substeps(x, np.asarray(u)), True
        else:
            x_new = self._m @ v
            if self.nonlinear_magnets:
                x_new += self._b_f @ self._magnet_residual(x)
            contact = self._touching(x_new)
            if contact:  # entering contact during this step: redo it finely
                x_new = self._substeps(x, np.asarray(u))
        self.x = x_new
        self.index += 1
        return clipped, contact

    def _substeps(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        drive = self._b_us @ u + self._b_gs
        for _ in range(CONTACT_SUBSTEPS):
            f = self._contact_force(x)
            if f is None:
                f = np.zeros(4)
            if self.nonlinear_magnets:
                f = f + self._magnet_residual(x)
            x = self._a_s @ x + drive + self._b_fs @ f
        return x
