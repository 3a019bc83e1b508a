"""Rigid 4-DOF rotor on two radial bearings (Hynynen 2011, sec. 2.3.1).

Coordinates are the rotor displacements at the two bearing planes,
q = [x_a, x_b, y_a, y_b] [m], so that bearing forces act directly on them
and backup-bearing contact is checked where it happens. The x and y axes are
the bearing axes, turned 45 deg from the vertical, so gravity acts on both
(-g / sqrt(2) each). Non-rotating (no gyroscopic coupling): the flexible
model carries the speed-dependent terms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GRAVITY = 9.81  # standard gravity [m/s^2]


@dataclass(frozen=True)
class RigidRotor:
    """Mass data and axial positions of a rigid rotor.

    Attributes
    ----------
    mass_kg
        rotor mass m [kg].
    transverse_inertia_kgm2
        moment of inertia about a transverse axis
        through the centre of mass J_t [kg m^2].
    bearing_z_m
        axial positions of bearings A and B from the centre of
        mass [m], shape (2,), z_a < z_b.
    sensor_z_m
        axial positions of sensors A and B from the centre of
        mass [m], shape (2,) (non-collocated: differ from bearing_z_m).
    """

    mass_kg: float
    transverse_inertia_kgm2: float
    bearing_z_m: tuple[float, float]
    sensor_z_m: tuple[float, float]

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mass_kg) and self.mass_kg > 0):
            raise ValueError(f"RigidRotor.mass_kg must be > 0, got {self.mass_kg}")
        if not (np.isfinite(self.transverse_inertia_kgm2) and self.transverse_inertia_kgm2 > 0):
            raise ValueError(f"RigidRotor.transverse_inertia_kgm2 must be > 0, got {self.transverse_inertia_kgm2}")
        za, zb = self.bearing_z_m
        if not za < zb:
            raise ValueError(f"RigidRotor.bearing_z_m must be ordered z_a < z_b, got {self.bearing_z_m}")

    def _plane_map(self, z: tuple[float, float]) -> np.ndarray:
        # displacement at axial positions z from (centre displacement, tilt)
        return np.array([[1.0, z[0]], [1.0, z[1]]])

    def inverse_mass(self) -> np.ndarray:
        """W with q'' = W F for bearing forces F [N] (4,), shape (4, 4) [1/kg].

        Per plane W = T Mc^-1 T^T, T mapping (centre, tilt) to bearing
        displacements, Mc = diag(m, J_t).
        """
        t = self._plane_map(self.bearing_z_m)
        w = t @ np.diag([1.0 / self.mass_kg, 1.0 / self.transverse_inertia_kgm2]) @ t.T
        return np.kron(np.eye(2), w)

    def sensor_map(self) -> np.ndarray:
        """S with y_sensor = S q: sensor-plane displacements from bearing ones, (4, 4)."""
        s = self._plane_map(self.sensor_z_m) @ np.linalg.inv(self._plane_map(self.bearing_z_m))
        return np.kron(np.eye(2), s)

    def gravity_acceleration(self) -> np.ndarray:
        """q'' caused by gravity [m/s^2], shape (4,): -g/sqrt(2) on every coordinate."""
        return np.full(2 * len(self.bearing_z_m), -GRAVITY / np.sqrt(2.0))   # x and y at each bearing

    def rigid_mode_frequencies_hz(self, ks_n_per_m: float, kb_n_per_m: float) -> np.ndarray:
        """Cylindrical and conical frequencies of one plane on springs kb [N/m] at both
        bearings with magnet negative stiffness ks [N/m] (kb > ks), shape (2,) ascending."""
        k = (kb_n_per_m - ks_n_per_m) * np.eye(2)
        w = self.inverse_mass()[:2, :2]
        lam = np.sort(np.linalg.eigvals(w @ k).real)
        return np.sqrt(lam) / (2 * np.pi)
