"""Radial electromagnet pair: nonlinear force and its linearisation.

Eqs. 2.11-2.18 of Hynynen (2011). A radial bearing axis is a differential
pair of horseshoe magnets; with bias current ``ib`` and control current
``ic`` the upper magnet carries ``ib + ic`` and the lower ``ib - ic``.
Iron magnetisation is neglected (mu_r >> 1, eq. 2.8).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MU0 = 4e-7 * np.pi  # vacuum permeability [H/m]


@dataclass(frozen=True)
class MagnetPair:
    """Physical data of one differential magnet pair (one bearing axis).

    Attributes
    ----------
    n_turns
        coil turns per magnet Nc [-].
    pole_area_m2
        air-gap area of one pole Aa [m^2].
    air_gap_m
        nominal air gap s0 [m].
    bias_current_a
        bias current ib [A].
    pole_angle_rad
        half angle between the poles of one magnet, alpha
        [rad] (22.5 deg for an eight-pole bearing).

    Examples
    --------
    A pair of 200 turns, 4.5 cm^2 poles, 0.6 mm gap and 3 A bias: current and position stiffness.

    >>> pair = MagnetPair(200, 4.5e-4, 6e-4, 3.0)
    >>> round(float(pair.ki), 1), round(float(pair.ks) / 1e3, 1)    # [N/A], [kN/m]
    (174.1, 870.7)
    """

    n_turns: float
    pole_area_m2: float
    air_gap_m: float
    bias_current_a: float
    pole_angle_rad: float = np.deg2rad(22.5)

    def __post_init__(self) -> None:
        for name in ("n_turns", "pole_area_m2", "air_gap_m", "bias_current_a"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"MagnetPair.{name} must be finite and > 0, got {value!r}")
        if not 0 <= self.pole_angle_rad < np.pi / 2:
            raise ValueError(
                f"MagnetPair.pole_angle_rad must lie in [0, pi/2), got {self.pole_angle_rad!r}")

    @property
    def k_magnet(self) -> float:
        """Magnet constant k = mu0 Nc^2 Aa / 4 [N m^2 / A^2] (eq. 2.12)."""
        return 0.25 * MU0 * self.n_turns**2 * self.pole_area_m2

    @property
    def ki(self) -> float:
        """Force-current factor ki = 4 k ib cos(alpha) / s0^2 [N/A] (eqs. 2.15-2.16)."""
        return 4.0 * self.k_magnet * self.bias_current_a * np.cos(self.pole_angle_rad) / self.air_gap_m**2

    @property
    def ks(self) -> float:
        """Force-displacement factor [N/m], positive: F = ki ic + ks x (eq. 2.15).

        Eq. 2.17 writes the same magnitude with the opposite sign convention;
        here ks > 0 means the magnet pulls the rotor further off centre
        (a negative mechanical stiffness -ks).
        """
        return 4.0 * self.k_magnet * self.bias_current_a**2 * np.cos(self.pole_angle_rad) / self.air_gap_m**3

    def force(self, control_current_a: np.ndarray, displacement_m: np.ndarray) -> np.ndarray:
        """Nonlinear force of the pair, eq. 2.14 [N].

        Parameters
        ----------
        control_current_a
            control current ic [A], any shape.
        displacement_m
            rotor displacement x towards the upper magnet [m],
            broadcastable with ``control_current_a``; |x| must stay below s0.

        Returns
        -------
        Force towards the upper magnet [N], broadcast shape. The current of
        each magnet is ib +/- ic; a magnet cannot push, so a negative coil
        current acts like its magnitude (force ~ i^2).
        """
        ic = np.asarray(control_current_a, dtype=float)
        x = np.asarray(displacement_m, dtype=float)
        s0, ib = self.air_gap_m, self.bias_current_a
        if np.any(np.abs(x) >= s0):
            raise ValueError(
                f"displacement reaches the magnet (|x| >= s0 = {s0} m); keep the rotor within "
                "the backup-bearing clearance, which must be smaller than the air gap")
        return self.k_magnet * np.cos(self.pole_angle_rad) * (
            (ib + ic) ** 2 / (s0 - x) ** 2 - (ib - ic) ** 2 / (s0 + x) ** 2)


    def slopes(self, control_current_a: np.ndarray, displacement_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Partial derivatives of :meth:`force` (eq. 2.14) at (ic, x).

        Returns
        -------
        (dF/dic [N/A], dF/dx [N/m]), broadcast shape. At x = 0 they are
        ki (for any ic) and ks (1 + ic^2 / ib^2); at (0, 0) exactly ki, ks.
        """
        ic = np.asarray(control_current_a, dtype=float)
        x = np.asarray(displacement_m, dtype=float)
        s0, ib = self.air_gap_m, self.bias_current_a
        if np.any(np.abs(x) >= s0):
            raise ValueError(f"displacement reaches the magnet (|x| >= s0 = {s0} m)")
        kc = 2.0 * self.k_magnet * np.cos(self.pole_angle_rad)
        dfdi = kc * ((ib + ic) / (s0 - x) ** 2 + (ib - ic) / (s0 + x) ** 2)
        dfdx = kc * ((ib + ic) ** 2 / (s0 - x) ** 3 + (ib - ic) ** 2 / (s0 + x) ** 3)
        return dfdi, dfdx
