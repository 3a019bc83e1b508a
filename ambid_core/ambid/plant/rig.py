"""The AMB rig: its parameters, loading them from a file, and its analytical model.

One table, :data:`RIG_FIELDS`, is the single home of every rig parameter:
its default, unit, allowed range and where the value comes from. Everything
else (rotor mass and modes, ki, ks, coil inductance, amplifier bandwidth) is
derived from it by the properties of :class:`Rig`. The default rig is
documented in ``docs/default_rig.md``, whose tables :func:`rig_markdown`
generates.

Two models of the same rig exist on purpose:

* :func:`analytical_model` -- what an engineer writes down from chapter 2 of
  Hynynen (2011): the finite-element rotor, magnets linearised with the
  nominal ki, ks (eqs. 2.16-2.17) at the centre, first-order amplifiers
  (eq. 2.21 with the power bandwidth of eq. 2.24), ideal sensors at their
  (non-collocated) planes.
* the "true" rig (:mod:`ambid.plant.true_rig`), which the simulator runs: the
  same plus what reality adds (magnet tolerances, the nonlinear force, a
  housing mode, sensor dynamics, an extra delay).

Channel order everywhere: bearing A x, bearing B x, bearing A y, bearing B y
(the axes are turned 45 deg from the vertical), then the axial bearing z when
the rig has one (``axial_bearing``: :attr:`Rig.layout`). Axial positions are
measured from the middle of the shaft, A on the negative side.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from ambid.channels import FIVE_AXIS, RADIAL, Layout
from ambid.plant.amplifier import Amplifier
from ambid.plant.fem_rotor import Disk, LaminationStack, Material, RotorGeometry, ShaftSection
from ambid.plant.magnet import MU0, MagnetPair
from ambid.plant.rigid_rotor import RigidRotor
from ambid.plant.rotor_import import load_rotor
from ambid.plant.rotor_model import RotorModel, fem_rotor_model, rigid_inverse_mass, with_axial
from ambid.plant.sensors import Sensors
from ambid.plant.tolerances import Tolerance, parse_tolerances
from ambid.yaml_file import read_yaml


@dataclass(frozen=True)
class RigField:
    """One rig parameter: default, SI unit, allowed closed range, source; ``integer`` for counts."""

    default: float
    unit: str
    low: float
    high: float
    source: str
    integer: bool = False


_STEEL = Material()

# name -> field. A horizontal steel rotor of ~34 kg, 0.8 m long, on two eight-pole radial AMBs.
RIG_FIELDS: dict[str, RigField] = {
    # control
    "sample_rate_hz": RigField(10_000.0, "Hz", 1_000.0, 100_000.0, "control rate of the design brief"),
    # rotor geometry (finite-element model)
    "shaft_length_m": RigField(0.8, "m", 0.05, 20.0, "solid steel shaft, length"),
    "shaft_diameter_m": RigField(0.060, "m", 0.002, 2.0, "solid steel shaft, diameter"),
    "stack_length_m": RigField(0.20, "m", 0.0, 10.0, "central motor lamination stack, length (0: none)"),
    "stack_diameter_m": RigField(0.120, "m", 0.002, 4.0, "motor lamination stack, outer diameter; adds mass "
                                 "and inertia, no bending stiffness"),
    "sleeve_length_m": RigField(0.040, "m", 0.0, 1.0, "laminated bearing sleeve (AMB rotor stack) at each "
                                "bearing, length; chosen so the rotor weighs ~34 kg"),
    "sleeve_diameter_m": RigField(0.100, "m", 0.002, 4.0, "bearing sleeve, outer diameter"),
    "density_kg_m3": RigField(_STEEL.density_kg_m3, "kg/m^3", 1_000.0, 25_000.0, "structural steel"),
    "youngs_modulus_pa": RigField(_STEEL.youngs_modulus_pa, "Pa", 1e9, 1e12, "structural steel"),
    "bending_modes": RigField(3.0, "-", 0.0, 8.0, "bending modes kept per plane in the modal reduction",
                              integer=True),
    "modal_damping_ratio": RigField(0.005, "-", 0.0, 0.2, "structural damping of the bending modes, 0.5 %"),
    "rotor_speed_rpm": RigField(0.0, "rpm", 0.0, 100_000.0, "spin speed (gyroscopic coupling); 0 = standstill"),
    "bearing_a_z_m": RigField(-0.30, "m", -10.0, 0.0, "bearing A, 0.10 m from the left shaft end"),
    "bearing_b_z_m": RigField(0.30, "m", 0.0, 10.0, "bearing B, 0.10 m from the right shaft end"),
    "sensor_a_z_m": RigField(-0.34, "m", -10.0, 10.0, "sensor A 40 mm outboard of bearing A (non-collocated)"),
    "sensor_b_z_m": RigField(0.34, "m", -10.0, 10.0, "sensor B 40 mm outboard of bearing B"),
    # magnets (nominal, eqs. 2.12-2.17)
    "coil_turns": RigField(200.0, "-", 1.0, 10_000.0, "Nc per magnet"),
    "pole_area_m2": RigField(4.5e-4, "m^2", 1e-6, 1.0, "Aa, pole face 15 mm x 30 mm"),
    "air_gap_m": RigField(0.6e-3, "m", 1e-5, 0.01, "nominal air gap s0"),
    "bias_current_a": RigField(3.0, "A", 0.01, 100.0, "ib, half the coil current range"),
    "pole_angle_deg": RigField(22.5, "deg", 0.0, 45.0, "alpha of an eight-pole bearing"),
    "true_ki_factor": RigField(1.03, "-", 0.5, 2.0, "true ki / nominal ki: manufacturing tolerance (+3 %)"),
    "true_ks_factor": RigField(0.95, "-", 0.5, 2.0, "true ks / nominal ks: manufacturing tolerance (-5 %)"),
    # amplifiers
    "current_limit_a": RigField(3.0, "A", 0.01, 100.0,
                                "|ic + r| <= ib keeps both coil currents ib +- ic non-negative"),
    "dc_link_voltage_v": RigField(560.0, "V", 1.0, 10_000.0, "udc, rectified 400 V three-phase mains"),
    # sensors (true rig; the analytical model assumes ideal ones)
    "sensor_bandwidth_hz": RigField(5_000.0, "Hz", 10.0, 1e6, "eddy-current probe and anti-alias filter, "
                                    "first order"),
    "sensor_gain": RigField(1.0, "m/m", 0.1, 10.0, "calibrated sensitivity (true / nominal)"),
    "sensor_noise_m": RigField(0.2e-6, "m", 0.0, 1e-3, "RMS white noise of an eddy-current sensor at 10 kHz"),
    "sensor_cubic_per_m2": RigField(0.0, "1/m^2", -1e8, 1e8, "static probe-curve error c3 d^3 "
                                    "(optional nonlinearity; 0 = linear)"),
    # housing (true rig only)
    "housing_mass_kg": RigField(20.0, "kg", 0.1, 1e5, "modal mass of each bearing pedestal with its stator"),
    "housing_freq_hz": RigField(180.0, "Hz", 1.0, 1e5, "pedestal (foundation) mode, unmodelled in the "
                                "analytical model"),
    "housing_damping_ratio": RigField(0.02, "-", 0.0, 1.0, "pedestal damping, 2 %"),
    # delay (true rig only)
    "extra_delay_s": RigField(50e-6, "s", 0.0, 0.01, "ADC conversion and PWM update, half a sample; at most "
                              "one sample"),
    # at speed (true rig only; nothing of this acts at standstill)
    "stack_eccentricity_m": RigField(0.0, "m", 0.0, 1e-3, "mass unbalance of the central stack: its centre of "
                                     "mass off the spin axis (1 um ~ ISO 21940 G1.3 at 12,000 rpm); force "
                                     "m e Omega^2"),
    "stack_unbalance_phase_deg": RigField(0.0, "deg", -360.0, 360.0, "angle of the stack's unbalance from the "
                                          "x axis at rotor angle 0, in the sense of the spin"),
    "sleeve_a_eccentricity_m": RigField(0.0, "m", 0.0, 1e-3, "mass unbalance of the bearing sleeve at A"),
    "sleeve_a_unbalance_phase_deg": RigField(0.0, "deg", -360.0, 360.0, "angle of the sleeve A unbalance"),
    "sleeve_b_eccentricity_m": RigField(0.0, "m", 0.0, 1e-3, "mass unbalance of the bearing sleeve at B"),
    "sleeve_b_unbalance_phase_deg": RigField(0.0, "deg", -360.0, 360.0, "angle of the sleeve B unbalance"),
    **{f"runout_{kind}_{h}x_{q}": RigField(0.0, unit, lo, hi, f"{what} runout of the probe tracks, harmonic "
                                           f"{h} of the rotor angle, {desc}")
       for kind, what, hs in (("mech", "mechanical (track out of round, eccentric)", (1, 2)),
                              ("elec", "electrical (conductivity, permeability, residual magnetism)", (1, 2, 3)))
       for h in hs
       for q, unit, lo, hi, desc in (("m", "m", 0.0, 1e-4, "amplitude (API 670 allows 6 um in all)"),
                                     ("phase_deg", "deg", -360.0, 360.0, "phase"))},
    "runout_b_phase_deg": RigField(0.0, "deg", -360.0, 360.0, "the B track's runout profile turned by this "
                                   "angle against the A track's"),
    # backup bearings
    "backup_clearance_m": RigField(0.25e-3, "m", 1e-6, 0.01, "radial retainer clearance, < s0"),
    "contact_stiffness_n_per_m": RigField(5e7, "N/m", 1e3, 1e10, "backup bearing and retainer stiffness"),
    "contact_damping_ns_per_m": RigField(3e3, "N s/m", 0.0, 1e7, "retainer contact damping, little rebound"),
    # the axial bearing (axis z; only with axial_bearing = 1: rigs/five_axis.yaml)
    "axial_bearing": RigField(0.0, "-", 0.0, 1.0, "1: the five-axis machine, a thrust disk on the shaft and an "
                              "axial magnet pair (axis z, decoupled from the radial planes); 0: radial bearings "
                              "only", integer=True),
    "thrust_disk_z_m": RigField(0.37, "m", -10.0, 10.0, "thrust disk centre, outboard of sensor B"),
    "thrust_disk_diameter_m": RigField(0.16, "m", 0.002, 4.0, "solid steel thrust disk, outer diameter (room for "
                                       "an inner and an outer pole ring of the axial stator)"),
    "thrust_disk_thickness_m": RigField(0.02, "m", 0.001, 1.0, "thrust disk, axial thickness"),
    "axial_coil_turns": RigField(80.0, "-", 1.0, 10_000.0, "Nc of each axial magnet (one toroidal coil)"),
    "axial_pole_area_m2": RigField(4.0e-3, "m^2", 1e-6, 1.0, "Aa of each of the two pole rings facing the disk "
                                   "(inner r 35-50 mm, outer r 62-72 mm: equal areas, eq. 2.5)"),
    "axial_air_gap_m": RigField(0.6e-3, "m", 1e-5, 0.01, "nominal axial air gap s0 on each side of the disk"),
    "axial_bias_current_a": RigField(3.0, "A", 0.01, 100.0, "ib of the axial magnets, >= current_limit_a"),
    "axial_true_ki_factor": RigField(1.02, "-", 0.5, 2.0, "true axial ki / nominal: manufacturing tolerance "
                                     "(+2 %)"),
    "axial_true_ks_factor": RigField(0.96, "-", 0.5, 2.0, "true axial ks / nominal: manufacturing tolerance "
                                     "(-4 %)"),
    "axial_sensor_bandwidth_hz": RigField(5_000.0, "Hz", 10.0, 1e6, "axial eddy-current probe on the shaft end "
                                          "face and its anti-alias filter, first order"),
    "axial_sensor_gain": RigField(1.0, "m/m", 0.1, 10.0, "axial probe, calibrated sensitivity (true / nominal)"),
    "axial_sensor_noise_m": RigField(0.3e-6, "m", 0.0, 1e-3, "RMS white noise of the axial probe at 10 kHz "
                                     "(a larger target distance than the radial probes')"),
    "axial_backup_clearance_m": RigField(0.2e-3, "m", 1e-6, 0.01, "axial retainer clearance, a third of the "
                                         "axial s0: the disk lands before the magnet's pull at full current "
                                         "overcomes the retainer's stiffness"),
}

_ROTOR_KEYS = ("shaft_length_m", "shaft_diameter_m", "stack_length_m", "stack_diameter_m", "sleeve_length_m",
               "sleeve_diameter_m", "density_kg_m3", "youngs_modulus_pa", "bending_modes",
               "modal_damping_ratio", "rotor_speed_rpm", "bearing_a_z_m", "bearing_b_z_m", "sensor_a_z_m",
               "sensor_b_z_m", "stack_eccentricity_m", "stack_unbalance_phase_deg", "sleeve_a_eccentricity_m",
               "sleeve_a_unbalance_phase_deg", "sleeve_b_eccentricity_m", "sleeve_b_unbalance_phase_deg")
_UNBALANCE_KEYS = ("stack_eccentricity_m", "sleeve_a_eccentricity_m", "sleeve_b_eccentricity_m")
_AXIAL_ROTOR_KEYS = ("axial_bearing", "thrust_disk_z_m", "thrust_disk_diameter_m", "thrust_disk_thickness_m")
_ROTOR_CACHE: dict[tuple, RotorModel] = {}


@dataclass(frozen=True)
class Rig:
    """A validated set of rig parameters (names and units as in :data:`RIG_FIELDS`).

    Attributes
    ----------
    name
        rig name.
    values
        parameter name -> value (every key of RIG_FIELDS).
    rotor_import
        a user's rotor model replacing the finite-element rotor
        (:mod:`ambid.plant.rotor_import`), or None.
    controller
        the controller the rig's owner runs, as the rig file names
        it (a kind, a file, or a mapping; :func:`ambid.control.kinds.design_controller`
        reads it), or None for the default.
    tolerances
        the rig file's ``tolerances:`` (:mod:`ambid.plant.tolerances`), name ->
        tolerance; the parameters it does not name keep their default tolerance.
    """

    name: str
    values: dict[str, float]
    rotor_import: RotorModel | None = field(default=None, compare=False)
    controller: str | dict | None = field(default=None, compare=False)
    tolerances: dict[str, Tolerance] = field(default_factory=dict, compare=False)

    def __getattr__(self, item: str) -> float:
        values = object.__getattribute__(self, "values")
        if item in values:
            return values[item]
        raise AttributeError(item)

    @property
    def sample_rate_hz(self) -> float:
        """Control rate fs [Hz]: the value the rig holds (code that works in rates reads it, not 1 / dt)."""
        return float(self.values["sample_rate_hz"])

    @property
    def dt(self) -> float:
        """Control period [s]: 1 / :attr:`sample_rate_hz`, the one place the rig's rate becomes a period."""
        return 1.0 / self.values["sample_rate_hz"]

    # -- magnets ---------------------------------------------------------
    @property
    def magnet(self) -> MagnetPair:
        """Nominal magnet pair of one axis (the analytical model's)."""
        v = self.values
        return MagnetPair(v["coil_turns"], v["pole_area_m2"], v["air_gap_m"], v["bias_current_a"],
                          np.deg2rad(v["pole_angle_deg"]))

    @property
    def true_magnet(self) -> MagnetPair:
        """The true magnet pair: ki and ks scaled by ``true_ki_factor``, ``true_ks_factor``.

        Since ks / ki = ib / s0 (eqs. 2.16-2.17), the two factors are one
        effective air gap s0' = s0 fi / fs (iron reluctance, eq. 2.7) and one
        effective pole area Aa' = Aa fi (s0' / s0)^2 (fringing).
        """
        v = self.values
        return _with_tolerance(self.magnet, v["true_ki_factor"], v["true_ks_factor"])

    @property
    def layout(self) -> Layout:
        """The axes the rig controls, in channel order: the two radial bearings' (``RADIAL``), and with
        ``axial_bearing`` the axial one after them (``FIVE_AXIS``)."""
        return FIVE_AXIS if self.values["axial_bearing"] else RADIAL

    @property
    def axial_magnet(self) -> MagnetPair:
        """Nominal magnet pair of the axial bearing: two toroidal magnets facing the thrust disk, each an
        inner and an outer pole ring, so the force acts along the axis (alpha = 0 in eqs. 2.13-2.17)."""
        v = self.values
        return MagnetPair(v["axial_coil_turns"], v["axial_pole_area_m2"], v["axial_air_gap_m"],
                          v["axial_bias_current_a"], 0.0)

    @property
    def axial_true_magnet(self) -> MagnetPair:
        """The true axial magnet pair (``axial_true_ki_factor``, ``axial_true_ks_factor``; as :attr:`true_magnet`)."""
        v = self.values
        return _with_tolerance(self.axial_magnet, v["axial_true_ki_factor"], v["axial_true_ks_factor"])

    def axis_magnets(self, true: bool = False) -> tuple[MagnetPair, ...]:
        """The magnet pair of every axis of :attr:`layout`, nominal or ``true``."""
        radial, axial = (self.true_magnet, self.axial_true_magnet) if true else (self.magnet, self.axial_magnet)
        axial_axes = self.layout.axial
        return tuple(axial if j in axial_axes else radial for j in range(len(self.layout)))

    # -- amplifiers ------------------------------------------------------
    @property
    def coil_inductance_h(self) -> float:
        """L = mu0 Nc^2 Aa / (2 s0) of one magnet at the centre (flux of eq. 2.8 through two gaps) [H]."""
        v = self.values
        return _coil_inductance(v["coil_turns"], v["pole_area_m2"], v["air_gap_m"])

    @property
    def max_coil_current_a(self) -> float:
        """imax = ib + current limit, the largest coil current [A]."""
        return self.values["bias_current_a"] + self.values["current_limit_a"]

    @property
    def amplifier(self) -> Amplifier:
        """One coil's amplifier: L, udc, imax, and a current-loop gain Gp = L omega_BW so that the
        small-signal bandwidth equals the power bandwidth of eq. 2.24 (Lantto's model, eq. 2.21)."""
        return _power_bandwidth_amplifier(self.coil_inductance_h, self.values["dc_link_voltage_v"],
                                          self.max_coil_current_a)

    @property
    def current_loop_bandwidth_hz(self) -> float:
        """Closed current-loop bandwidth omega_BW / 2 pi, omega_BW = ln(9) udc / (L imax) (eq. 2.24) [Hz]."""
        return self.amplifier.bandwidth_hz

    @property
    def axial_coil_inductance_h(self) -> float:
        """L of one axial magnet at the centre, as :attr:`coil_inductance_h` with the axial data [H]."""
        v = self.values
        return _coil_inductance(v["axial_coil_turns"], v["axial_pole_area_m2"], v["axial_air_gap_m"])

    @property
    def axial_amplifier(self) -> Amplifier:
        """An axial coil's amplifier (eq. 2.24 with the axial inductance and imax = axial ib + current limit)."""
        imax = self.values["axial_bias_current_a"] + self.values["current_limit_a"]
        return _power_bandwidth_amplifier(self.axial_coil_inductance_h, self.values["dc_link_voltage_v"], imax)

    @property
    def amplifier_bandwidths_hz(self) -> np.ndarray:
        """The current-loop bandwidth of every axis of :attr:`layout` (eq. 2.24), (na,) [Hz]."""
        radial, axial = self.current_loop_bandwidth_hz, self.axial_amplifier.bandwidth_hz
        return np.array([axial if j in self.layout.axial else radial for j in range(len(self.layout))])

    # -- sensors and backup bearings --------------------------------------
    def axis_sensors(self) -> tuple[Sensors, ...]:
        """The displacement sensor of every axis of :attr:`layout` (the radial probes' data, the axial probe's)."""
        v = self.values
        radial = Sensors.from_rig(v)
        axial = Sensors(v["axial_sensor_bandwidth_hz"], v["axial_sensor_gain"], v["axial_sensor_noise_m"])
        return tuple(axial if j in self.layout.axial else radial for j in range(len(self.layout)))

    def backup_bearings(self) -> tuple[tuple[tuple[int, ...], float], ...]:
        """The retainers: (axes, clearance [m]) of each, a radial bearing's (x, y) axes together (it touches
        when the radius reaches the clearance), an axial one alone."""
        lay, v = self.layout, self.values
        return (tuple((pair, v["backup_clearance_m"]) for pair in lay.radial_pairs)
                + tuple(((j,), v["axial_backup_clearance_m"]) for j in lay.axial))

    # -- rotor -----------------------------------------------------------
    @property
    def speed_rad_s(self) -> float:
        """Spin speed Omega = 2 pi rpm / 60 [rad/s]."""
        return self.values["rotor_speed_rpm"] * np.pi / 30.0

    def unbalance_planes(self) -> tuple[tuple[float, float, float], ...]:
        """The unbalanced planes: (position from the left shaft end [m], m e [kg m], angle [rad]) of the
        central stack and the two bearing sleeves, those with an eccentricity only; m is the stack's own
        mass (the laminations around the shaft)."""
        v = self.values
        half = v["shaft_length_m"] / 2
        rho, d = v["density_kg_m3"], v["shaft_diameter_m"]
        out = []
        for key, phase, z, length, dia in (
                ("stack_eccentricity_m", "stack_unbalance_phase_deg", half, "stack_length_m", "stack_diameter_m"),
                ("sleeve_a_eccentricity_m", "sleeve_a_unbalance_phase_deg", half + v["bearing_a_z_m"],
                 "sleeve_length_m", "sleeve_diameter_m"),
                ("sleeve_b_eccentricity_m", "sleeve_b_unbalance_phase_deg", half + v["bearing_b_z_m"],
                 "sleeve_length_m", "sleeve_diameter_m")):
            mass = rho * np.pi / 4 * (v[dia] ** 2 - d * d) * v[length]
            if v[key] > 0 and mass > 0:
                out.append((float(z), float(mass * v[key]), float(np.deg2rad(v[phase]))))
        return tuple(out)

    @property
    def rotor_geometry(self) -> RotorGeometry:
        """Finite-element geometry of the built-in rotor (z from the left shaft end)."""
        v = self.values
        half = v["shaft_length_m"] / 2
        stacks = []
        if v["stack_length_m"] > 0:
            stacks.append(LaminationStack(half - v["stack_length_m"] / 2, v["stack_length_m"],
                                          v["stack_diameter_m"], density_kg_m3=v["density_kg_m3"]))
        if v["sleeve_length_m"] > 0:
            for zb in (v["bearing_a_z_m"], v["bearing_b_z_m"]):
                stacks.append(LaminationStack(half + zb - v["sleeve_length_m"] / 2, v["sleeve_length_m"],
                                              v["sleeve_diameter_m"], density_kg_m3=v["density_kg_m3"]))
        material = Material(v["youngs_modulus_pa"], v["density_kg_m3"], _STEEL.poisson_ratio)
        stations = tuple(half + v[k] for k in ("bearing_a_z_m", "bearing_b_z_m", "sensor_a_z_m", "sensor_b_z_m"))
        disks = ()
        if v["axial_bearing"]:  # the thrust disk: a rigid disk on the shaft (mass and inertia, no stiffness)
            disks = (Disk.from_geometry(half + v["thrust_disk_z_m"], v["thrust_disk_thickness_m"],
                                        v["thrust_disk_diameter_m"], v["shaft_diameter_m"], v["density_kg_m3"]),)
        return RotorGeometry(sections=(ShaftSection(v["shaft_length_m"], v["shaft_diameter_m"]),),
                             disks=disks, stacks=tuple(stacks), stations_m=stations, material=material,
                             max_element_length_m=min(0.025, v["shaft_length_m"] / 16))

    def rotor_model(self, n_bending: int | None = None) -> RotorModel:
        """The rotor as a state-space block (:class:`ambid.plant.rotor_model.RotorModel`).

        Parameters
        ----------
        n_bending
            bending modes per plane; None takes ``bending_modes``.
            Ignored for an imported rotor (it is used as given).
        """
        v = self.values
        if self.rotor_import is not None:
            # the user's lateral rotor; the axial motion is its rigid mass (sec. 2.3.1)
            return with_axial(self.rotor_import) if v["axial_bearing"] else self.rotor_import
        nb = int(v["bending_modes"] if n_bending is None else n_bending)
        key = tuple(v[k] for k in _ROTOR_KEYS + _AXIAL_ROTOR_KEYS) + (nb,)
        model = _ROTOR_CACHE.get(key)
        if model is None:
            half = v["shaft_length_m"] / 2
            model = fem_rotor_model(self.rotor_geometry, (half + v["bearing_a_z_m"], half + v["bearing_b_z_m"]),
                                    (half + v["sensor_a_z_m"], half + v["sensor_b_z_m"]), nb,
                                    v["modal_damping_ratio"], self.speed_rad_s, self.unbalance_planes())
            if v["axial_bearing"]:
                model = with_axial(model)
            if len(_ROTOR_CACHE) > 16:
                _ROTOR_CACHE.clear()
            _ROTOR_CACHE[key] = model
        return model

    @property
    def rotor(self) -> RigidRotor:
        """Rigid-body view of the rotor (mass, transverse inertia, plane positions from the centre of mass),
        from the low-frequency limit of the rotor model."""
        w = rigid_inverse_mass(self.rotor_model())[:2, :2]
        v = self.values
        d = v["bearing_b_z_m"] - v["bearing_a_z_m"]
        jt = d * d / (w[0, 0] + w[1, 1] - 2 * w[0, 1])
        za = -(w[0, 0] - w[0, 1]) * jt / d
        zc = v["bearing_a_z_m"] - za  # centre of mass from the shaft middle
        mass = 1.0 / (w[0, 1] - za * (za + d) / jt)
        return RigidRotor(mass, jt, (v["bearing_a_z_m"] - zc, v["bearing_b_z_m"] - zc),
                          (v["sensor_a_z_m"] - zc, v["sensor_b_z_m"] - zc))

    @property
    def rotor_mass_kg(self) -> float:
        """Total rotor mass [kg]."""
        return self.rotor_model().mass_kg

    @property
    def rotor_transverse_inertia_kgm2(self) -> float:
        """Transverse moment of inertia about the centre of mass [kg m^2]."""
        return self.rotor.transverse_inertia_kgm2

    def derived(self) -> dict[str, float]:
        """The derived quantities the doc lists: name -> value (SI units in the name)."""
        m, mt = self.magnet, self.true_magnet
        rotor = self.rotor
        model = self.rotor_model()
        out = {
            "rotor_mass_kg": rotor.mass_kg,
            "rotor_transverse_inertia_kgm2": rotor.transverse_inertia_kgm2,
            "magnet_constant_n_m2_per_a2": m.k_magnet,
            "ki_n_per_a": m.ki,
            "ks_n_per_m": m.ks,
            "true_ki_n_per_a": mt.ki,
            "true_ks_n_per_m": mt.ks,
            "true_effective_air_gap_m": mt.air_gap_m,
            "true_effective_pole_area_m2": mt.pole_area_m2,
            "coil_inductance_h": self.coil_inductance_h,
            "max_coil_current_a": self.max_coil_current_a,
            "current_loop_bandwidth_hz": self.current_loop_bandwidth_hz,
            "unstable_pole_hz": float(np.sqrt(2 * m.ks / rotor.mass_kg) / (2 * np.pi)),
            "gravity_current_a": float(rotor.mass_kg * 9.81 / (2 * np.sqrt(2.0)) / m.ki),
            "housing_stiffness_n_per_m": float(self.values["housing_mass_kg"]
                                               * (2 * np.pi * self.values["housing_freq_hz"]) ** 2),
        }
        for j, f in enumerate(model.flexible_freq_hz):
            out[f"free_free_bending_{j + 1}_hz"] = float(f)
        if self.values["axial_bearing"]:
            ma, mat = self.axial_magnet, self.axial_true_magnet
            out.update({
                "thrust_disk_mass_kg": float(self.rotor_geometry.disks[0].mass_kg),
                "axial_magnet_constant_n_m2_per_a2": ma.k_magnet,
                "axial_ki_n_per_a": ma.ki,
                "axial_ks_n_per_m": ma.ks,
                "axial_true_ki_n_per_a": mat.ki,
                "axial_true_ks_n_per_m": mat.ks,
                "axial_coil_inductance_h": self.axial_coil_inductance_h,
                "axial_current_loop_bandwidth_hz": self.axial_amplifier.bandwidth_hz,
                "axial_unstable_pole_hz": float(np.sqrt(ma.ks / model.mass_kg) / (2 * np.pi)),
                "axial_max_force_n": float(ma.force(self.values["current_limit_a"], 0.0)),
            })
        return out

    def to_dict(self) -> dict[str, Any]:
        """name and every parameter value; ``make_rig(rig.to_dict())`` rebuilds the rig
        (with ``rotor_file`` when the rotor was imported from a file)."""
        out: dict[str, Any] = {"name": self.name, **self.values}
        if self.rotor_import is not None and self.rotor_import.source.startswith("file:"):
            out["rotor_file"] = self.rotor_import.source[len("file:"):]
        if self.controller is not None:
            out["controller"] = self.controller
        if self.tolerances:
            out["tolerances"] = {k: t.to_text() for k, t in self.tolerances.items()}
        return out


#: the simulated rig's manufacturing factors on its magnets (true / nominal ki and ks): what the simulation adds
#: to the nominal magnets (:attr:`Rig.true_magnet`), never part of a rig built from what data showed
TRUE_MAGNET_FACTORS = ("true_ki_factor", "true_ks_factor", "axial_true_ki_factor", "axial_true_ks_factor")


def without_true_factors(rig: Rig) -> Rig:
    """``rig`` without its simulated manufacturing factors (each of :data:`TRUE_MAGNET_FACTORS` 1): its true
    magnets are its nominal ones, so a rig whose magnets were set to estimates simulates exactly those.

    Examples
    --------
    >>> rig = without_true_factors(make_rig())
    >>> rig.true_magnet == rig.magnet and rig.axial_true_magnet == rig.axial_magnet
    True
    """
    return replace(rig, values={**rig.values, **dict.fromkeys(TRUE_MAGNET_FACTORS, 1.0)})


def _coil_inductance(turns: float, pole_area_m2: float, air_gap_m: float) -> float:
    """L = mu0 Nc^2 Aa / (2 s0) of one magnet at the centre (flux of eq. 2.8 through two gaps) [H]."""
    return MU0 * turns ** 2 * pole_area_m2 / (2.0 * air_gap_m)


def _power_bandwidth_amplifier(inductance_h: float, udc_v: float, imax_a: float) -> Amplifier:
    """A coil's amplifier whose small-signal bandwidth is the power bandwidth of eq. 2.24,
    omega_BW = ln(9) udc / (L imax) (current-loop gain Gp = L omega_BW, Lantto's model, eq. 2.21)."""
    w_bw = np.log(9.0) * udc_v / (inductance_h * imax_a)
    return Amplifier(inductance_h, 0.0, udc_v, imax_a, inductance_h * w_bw, min_current_a=0.0)


def _with_tolerance(nominal: MagnetPair, ki_factor: float, ks_factor: float) -> MagnetPair:
    """The magnet pair whose ki and ks are the nominal ones times the factors (see :attr:`Rig.true_magnet`)."""
    gap_ratio = ki_factor / ks_factor
    return MagnetPair(nominal.n_turns, nominal.pole_area_m2 * ki_factor * gap_ratio**2,
                      nominal.air_gap_m * gap_ratio, nominal.bias_current_a, nominal.pole_angle_rad)


def _check_value(key: str, f: RigField, raw: Any) -> float:
    try:
        value = float(raw)
    except (TypeError, ValueError):
        raise ValueError(f"rig: {key} must be a number in [{f.low:g}, {f.high:g}] {f.unit}, got {raw!r}") from None
    if isinstance(raw, bool) or not (np.isfinite(value) and f.low <= value <= f.high):
        raise ValueError(f"rig: {key} = {raw!r} is outside its allowed range [{f.low:g}, {f.high:g}] {f.unit}")
    if f.integer and value != int(value):
        raise ValueError(f"rig: {key} = {raw!r} must be a whole number in [{f.low:g}, {f.high:g}]")
    return value


def _check_layout(v: dict[str, float]) -> None:
    half = v["shaft_length_m"] / 2
    if not v["bearing_a_z_m"] < v["bearing_b_z_m"]:
        raise ValueError("rig: bearing_a_z_m must be smaller than bearing_b_z_m")
    if not v["sensor_a_z_m"] < v["sensor_b_z_m"]:
        raise ValueError("rig: sensor_a_z_m must be smaller than sensor_b_z_m")
    for key in ("bearing_a_z_m", "bearing_b_z_m", "sensor_a_z_m", "sensor_b_z_m"):
        if abs(v[key]) > half:
            raise ValueError(f"rig: {key} = {v[key]} m lies outside the shaft (+-shaft_length_m / 2 = "
                             f"+-{half} m from its middle)")
    sl = v["sleeve_length_m"]
    for key in ("bearing_a_z_m", "bearing_b_z_m"):
        if abs(v[key]) + sl / 2 > half:
            raise ValueError(f"rig: the bearing sleeve at {key} = {v[key]} m sticks out of the shaft; shorten "
                             "sleeve_length_m or move the bearing inwards")
        if sl > 0 and abs(v[key]) - sl / 2 < v["stack_length_m"] / 2:
            raise ValueError(f"rig: the bearing sleeve at {key} overlaps the central stack; shorten "
                             "stack_length_m or sleeve_length_m")
    if v["stack_length_m"] > v["shaft_length_m"]:
        raise ValueError("rig: stack_length_m must not exceed shaft_length_m")
    for key in ("stack_diameter_m", "sleeve_diameter_m"):
        if v[key] <= v["shaft_diameter_m"]:
            raise ValueError(f"rig: {key} must exceed shaft_diameter_m (the stack sits on the shaft)")
    if not v["axial_bearing"]:
        return
    zd, wd = v["thrust_disk_z_m"], v["thrust_disk_thickness_m"]
    if abs(zd) + wd / 2 > half:
        raise ValueError(f"rig: the thrust disk at thrust_disk_z_m = {zd} m sticks out of the shaft (+-{half} m "
                         "from its middle); move it inwards or make it thinner")
    for key, length in (("bearing_a_z_m", sl), ("bearing_b_z_m", sl), ("thrust_disk_z_m", v["stack_length_m"])):
        centre = 0.0 if key == "thrust_disk_z_m" else v[key]
        if length > 0 and abs(zd - centre) < (length + wd) / 2:
            what = "central stack" if key == "thrust_disk_z_m" else f"bearing sleeve at {key}"
            raise ValueError(f"rig: the thrust disk at thrust_disk_z_m = {zd} m overlaps the {what}; move it")
    if v["thrust_disk_diameter_m"] <= v["shaft_diameter_m"]:
        raise ValueError("rig: thrust_disk_diameter_m must exceed shaft_diameter_m (the disk sits on the shaft)")
    if v["axial_backup_clearance_m"] >= v["axial_air_gap_m"]:
        raise ValueError("rig: axial_backup_clearance_m must be smaller than axial_air_gap_m, so the disk lands on "
                         "the axial retainer before it touches a magnet")
    if v["current_limit_a"] > v["axial_bias_current_a"]:
        raise ValueError(f"rig: current_limit_a = {v['current_limit_a']} A exceeds axial_bias_current_a = "
                         f"{v['axial_bias_current_a']} A; an axial coil current would turn negative: raise "
                         "axial_bias_current_a or lower current_limit_a")


def make_rig(overrides: dict[str, Any] | None = None, name: str = "ambid-default",
             rotor_import: RotorModel | None = None) -> Rig:
    """Default rig with ``overrides`` applied, every value checked against its range.

    Parameters
    ----------
    overrides
        parameter name -> value (any subset of RIG_FIELDS); may
        also hold ``name``, ``rotor_file`` (a user rotor model, see
        :mod:`ambid.plant.rotor_import`), ``controller`` (see :class:`Rig`) and
        ``tolerances`` (a mapping, :func:`ambid.plant.tolerances.parse_tolerances`).
    name
        rig name unless ``overrides`` gives one.
    rotor_import
        a user rotor model replacing the finite-element rotor.

    Raises
    ------
    ValueError
        naming the field and its allowed range.

    Examples
    --------
    >>> rig = make_rig()                  # the built-in rig
    >>> rig.dt, rig.layout.axes
    (0.0001, ('a_x', 'b_x', 'a_y', 'b_y'))
    >>> round(rig.rotor_mass_kg, 2)
    34.06
    >>> make_rig({"sample_rate_hz": 20_000.0}).dt
    5e-05
    """
    overrides = dict(overrides or {})
    name = str(overrides.pop("name", name))
    rotor_file = overrides.pop("rotor_file", None)
    controller = overrides.pop("controller", None)
    if controller is not None and not isinstance(controller, (str, dict)):
        raise ValueError(f"rig: controller must name a kind or a file, or be a mapping, got {controller!r}")
    tolerances = parse_tolerances(overrides.pop("tolerances", None))
    unknown = sorted(set(overrides) - set(RIG_FIELDS))
    if unknown:
        raise ValueError(f"rig: unknown parameter(s) {unknown}; known are: {', '.join(RIG_FIELDS)}, "
                         "name, rotor_file, controller, tolerances")
    values = {key: _check_value(key, f, overrides.get(key, f.default)) for key, f in RIG_FIELDS.items()}
    if values["backup_clearance_m"] >= values["air_gap_m"]:
        raise ValueError("rig: backup_clearance_m must be smaller than air_gap_m, so the rotor lands on the "
                         "backup bearings before it touches a magnet")
    if values["extra_delay_s"] > 1.0 / values["sample_rate_hz"] + 1e-12:
        raise ValueError(f"rig: extra_delay_s = {values['extra_delay_s']} s must not exceed one sample "
                         f"(1 / sample_rate_hz = {1.0 / values['sample_rate_hz']} s)")
    _check_layout(values)
    if rotor_file is not None:
        if rotor_import is not None:
            raise ValueError("rig: give either rotor_file or rotor_import, not both")

        rotor_import = load_rotor(rotor_file, speed_rpm=values["rotor_speed_rpm"],
                                  damping_ratio=values["modal_damping_ratio"])
    if rotor_import is not None and any(values[k] > 0 for k in _UNBALANCE_KEYS):
        raise ValueError("rig: an imported rotor model has no stack planes to carry an unbalance; set "
                         f"{', '.join(_UNBALANCE_KEYS)} to 0 (or use the finite-element rotor)")
    return Rig(name, values, rotor_import, controller, tolerances)


def _beside(rig_path: Path, name: Any) -> Path:
    p = Path(str(name))
    return p if p.is_absolute() else rig_path.parent / p


def rig_or_default(path: str | Path | None) -> Rig:
    """The rig of the YAML file ``path``, or the built-in rig where ``path`` is empty or None.

    The one home of "this rig file, or the built-in rig": every option and parameter that names a rig file
    (``--rig``, ``rig_file``) is read through it.

    Examples
    --------
    >>> rig_or_default("").name, rig_or_default(None).dt
    ('ambid-default', 0.0001)
    """
    return load_rig(path) if path else make_rig()


def load_rig(path: str | Path) -> Rig:
    """Rig from a YAML file of ``name: value`` pairs (any subset of :data:`RIG_FIELDS`).

    A ``rotor_file`` entry (a relative path is taken from the YAML file's
    folder) replaces the finite-element rotor by a user model; a
    ``controller`` entry names the controller the rig runs (a kind, a file
    beside the YAML, or a mapping, see :class:`Rig`).
    """
    path = Path(path)
    data = read_rig_file(path)
    try:
        return make_rig(data, name=path.stem)
    except ValueError as exc:
        raise ValueError(f"rig file {path}: {exc}") from None


def read_rig_file(path: str | Path) -> dict[str, Any]:
    """A rig file's mapping, the files it names (``rotor_file``, a controller file) made absolute, so that
    the mapping written elsewhere (e.g. with one value changed) names the same rig."""
    path = Path(path)
    fix = "give a YAML file of parameter: value lines like rigs/ideal.yaml, or leave out the rig file for the default"
    data = read_yaml(path, "rig file", fix, allow_empty=False)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f"rig file {path} must hold a mapping of parameter: value, got {type(data).__name__}")
    if "rotor_file" in data:
        rotor_path = Path(str(data["rotor_file"]))
        data["rotor_file"] = str(rotor_path if rotor_path.is_absolute() else path.parent / rotor_path)
    ctrl = data.get("controller")
    # a controller file is named relative to the rig file, like rotor_file
    if isinstance(ctrl, dict) and "file" in ctrl:
        data["controller"] = {**ctrl, "file": str(_beside(path, ctrl["file"]))}
    elif isinstance(ctrl, str) and Path(ctrl).suffix.lower() in (".npz", ".mat", ".yaml", ".yml"):
        data["controller"] = str(_beside(path, ctrl))
    return data
