"""The AMB rig: its parameters, loading them from a file, and its linear model.

One table, :data:`RIG_FIELDS`, is the single home of every rig parameter:
its default, unit, allowed range and where the value comes from. The default
rig is documented in ``docs/default_rig.md`` from that table.

Channel order everywhere: bearing A x, bearing B x, bearing A y, bearing B y
(the axes are turned 45 deg from the vertical).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ambid.magnet import MagnetPair
from ambid.rigid_rotor import RigidRotor
from ambid.statespace import StateSpace

AXES = ("a_x", "b_x", "a_y", "b_y")
DISPLACEMENT_NAMES = tuple(f"y_{a}" for a in AXES)
CURRENT_NAMES = tuple(f"u_{a}" for a in AXES)


@dataclass(frozen=True)
class RigField:
    """One rig parameter: default, SI unit, allowed closed range, source."""

    default: float
    unit: str
    low: float
    high: float
    source: str


# name -> field. Values of a horizontal steel rotor of ~29 kg, 0.8 m long.
RIG_FIELDS: dict[str, RigField] = {
    "sample_rate_hz": RigField(10_000.0, "Hz", 1_000.0, 100_000.0, "control rate of the design brief"),
    "rotor_mass_kg": RigField(29.0, "kg", 0.1, 10_000.0,
                              "steel shaft 0.8 m x 60 mm: 7810 kg/m^3 x pi 0.03^2 x 0.8 = 17.6 kg; motor "
                              "stack 5.4 kg at the centre; bearing stacks 2 x 3.0 kg at +-0.30 m"),
    "rotor_transverse_inertia_kgm2": RigField(1.52, "kg m^2", 1e-5, 1e4,
                                              "shaft 17.6 x 0.8^2/12 = 0.94; stacks 2 x 3.0 x 0.30^2 = 0.54; "
                                              "own inertia of the stacks 0.04"),
    "bearing_a_z_m": RigField(-0.30, "m", -10.0, 0.0, "bearing A 0.30 m left of the centre of mass"),
    "bearing_b_z_m": RigField(0.30, "m", 0.0, 10.0, "bearing B 0.30 m right of the centre of mass"),
    "sensor_a_z_m": RigField(-0.34, "m", -10.0, 0.0, "sensor A 40 mm outboard of bearing A (non-collocated)"),
    "sensor_b_z_m": RigField(0.34, "m", 0.0, 10.0, "sensor B 40 mm outboard of bearing B"),
    "coil_turns": RigField(200.0, "-", 1.0, 10_000.0, "Nc per magnet"),
    "pole_area_m2": RigField(4.5e-4, "m^2", 1e-6, 1.0, "Aa, pole face 15 mm x 30 mm"),
    "air_gap_m": RigField(0.6e-3, "m", 1e-5, 0.01, "nominal air gap s0"),
    "bias_current_a": RigField(3.0, "A", 0.01, 100.0, "ib"),
    "pole_angle_deg": RigField(22.5, "deg", 0.0, 45.0, "alpha of an eight-pole bearing"),
    "current_limit_a": RigField(3.0, "A", 0.01, 100.0,
                                "|ic + r| <= ib keeps both coil currents ib +- i non-negative"),
    "current_loop_bandwidth_hz": RigField(1_500.0, "Hz", 10.0, 50_000.0,
                                          "closed current loop 1/(tau_cl s + 1), eq. 2.20"),
    "backup_clearance_m": RigField(0.25e-3, "m", 1e-6, 0.01, "radial retainer clearance, < s0"),
    "contact_stiffness_n_per_m": RigField(5e7, "N/m", 1e3, 1e10, "backup bearing and retainer stiffness"),
    "contact_damping_ns_per_m": RigField(3e3, "N s/m", 0.0, 1e7, "retainer contact damping, little rebound"),
    "sensor_noise_m": RigField(0.2e-6, "m", 0.0, 1e-3, "RMS white noise of an eddy-current sensor at 10 kHz"),
}


@dataclass(frozen=True)
class Rig:
    """A validated set of rig parameters (names and units as in :data:`RIG_FIELDS`)."""

    name: str
    values: dict[str, float]

    def __getattr__(self, item: str) -> float:
        values = object.__getattribute__(self, "values")
        if item in values:
            return values[item]
        raise AttributeError(item)

    @property
    def dt(self) -> float:
        """Control period [s]."""
        return 1.0 / self.values["sample_rate_hz"]

    @property
    def rotor(self) -> RigidRotor:
        v = self.values
        return RigidRotor(v["rotor_mass_kg"], v["rotor_transverse_inertia_kgm2"],
                          (v["bearing_a_z_m"], v["bearing_b_z_m"]), (v["sensor_a_z_m"], v["sensor_b_z_m"]))

    @property
    def magnet(self) -> MagnetPair:
        v = self.values
        return MagnetPair(v["coil_turns"], v["pole_area_m2"], v["air_gap_m"], v["bias_current_a"],
                          np.deg2rad(v["pole_angle_deg"]))

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, **self.values}


def make_rig(overrides: dict[str, Any] | None = None, name: str = "ambid-default") -> Rig:
    """Default rig with ``overrides`` applied, every value checked against its range."""
    overrides = dict(overrides or {})
    name = str(overrides.pop("name", name))
    unknown = sorted(set(overrides) - set(RIG_FIELDS))
    if unknown:
        raise ValueError(f"rig: unknown parameter(s) {unknown}; known are: {', '.join(RIG_FIELDS)}")
    values = {}
    for key, f in RIG_FIELDS.items():
        raw = overrides.get(key, f.default)
        try:
            value = float(raw)
        except (TypeError, ValueError):
            raise ValueError(f"rig: {key} must be a number in [{f.low:g}, {f.high:g}] {f.unit}, got {raw!r}") from None
        if not (np.isfinite(value) and f.low <= value <= f.high):
            raise ValueError(f"rig: {key} = {value!r} is outside its allowed range [{f.low:g}, {f.high:g}] {f.unit}")
        values[key] = value
    if values["backup_clearance_m"] >= values["air_gap_m"]:
        raise ValueError("rig: backup_clearance_m must be smaller than air_gap_m, so the rotor lands on the "
                         "backup bearings before it touches a magnet")
    if values["sensor_a_z_m"] >= values["sensor_b_z_m"]:
        raise ValueError("rig: sensor_a_z_m must be smaller than sensor_b_z_m")
    return Rig(name, values)


def load_rig(path: str | Path) -> Rig:
    """Rig from a YAML file of ``name: value`` pairs (any subset of :data:`RIG_FIELDS`)."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"rig file {path} does not exist") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"rig file {path} is not valid YAML: {exc}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f"rig file {path} must hold a mapping of parameter: value, got {type(data).__name__}")
    try:
        return make_rig(data, name=path.stem)
    except ValueError as exc:
        raise ValueError(f"rig file {path}: {exc}") from None


def analytical_model(rig: Rig) -> StateSpace:
    """Chapter 2's linearised model, continuous time: current reference u [A] -> sensor y [m].

    States: bearing displacements q (4) [m], velocities (4) [m/s], coil control
    currents (4) [A]. Force per axis F = ki i + ks q (eq. 2.18); amplifiers are
    first order with the current-loop bandwidth (eq. 2.20). Gravity is a
    constant offset and not part of the small-signal model.
    """
    w = rig.rotor.inverse_mass()
    ki, ks = rig.magnet.ki, rig.magnet.ks
    tau = 1.0 / (2 * np.pi * rig.current_loop_bandwidth_hz)
    z, i4 = np.zeros((4, 4)), np.eye(4)
    a = np.block([[z, i4, z], [ks * w, z, ki * w], [z, z, -i4 / tau]])
    b = np.vstack([z, z, i4 / tau])
    c = np.hstack([rig.rotor.sensor_map(), z, z])
    return StateSpace(a, b, c, np.zeros((4, 4)), 0.0, CURRENT_NAMES, DISPLACEMENT_NAMES,
                      ("A",) * 4, ("m",) * 4)
