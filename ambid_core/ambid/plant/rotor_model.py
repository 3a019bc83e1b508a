"""The rotor as a linear state-space block: bearing forces in, displacements out.

Every rotor the rig can carry (the built-in finite-element rotor, or a model a
user brings, see :mod:`ambid.plant.rotor_import`) is reduced to one
:class:`RotorModel`::

    x' = A x + B f + b_gravity
    q_bearing = C_bearing x,   q_sensor = C_sensor x

f are the forces [N] on the rotor at the bearing axes, q the displacements [m]
at the bearing and sensor axes, all in the rig's channel order (its
:class:`ambid.channels.Layout`, ``RotorModel.layout``): the lateral axes
bearing A x, bearing B x, bearing A y, bearing B y (the x and y axes are the
bearing axes, turned 45 deg from the vertical, so gravity acts on both with
-g / sqrt(2)), and with an axial bearing the axial axis z last
(:func:`with_axial`: the rotor's rigid axial motion, decoupled from the
lateral planes as chapter 2 models it, sec. 2.3.1). The rotor must be
free-free: the magnets (and, on contact, the backup bearings) are its only
supports.

Spinning at Omega with mass unbalance, the rotor also feels the synchronous
forces m e Omega^2 of its unbalanced planes, rotating with the rotor angle
theta = Omega t (forward, from x towards y)::

    x' = ... + Omega^2 B_unbalance [cos theta; sin theta]
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ambid.channels import RADIAL, Layout
from ambid.plant.fem_rotor import DOF_X, DOF_Y, RotorGeometry, assemble_rotor, dof_index, node_at, rigid_body_properties
from ambid.plant.modal import modal_state_space, plane_modes

GRAVITY = 9.81  # standard gravity [m/s^2]
# gravity per bearing axis: both axes are turned 45 deg from the vertical
GRAVITY_PER_AXIS = -GRAVITY / np.sqrt(2.0)
# the lateral rotor's channels: bearing (and sensor) planes A and B, x and y each, in RADIAL's order
# (the axial axis, when the rig has one, is appended by with_axial)
N_LATERAL = len(RADIAL)


@dataclass(frozen=True)
class RotorModel:
    """Linear free-free rotor, force at the bearings -> displacement (module docstring).

    Attributes
    ----------
    a
        (n, n) state matrix.
    b
        (n, na) force input [N] at the bearing axes, ``layout`` order.
    c_bearing
        (na, n) displacement [m] at the bearing axes.
    c_sensor
        (na, n) displacement [m] at the sensor axes.
    b_gravity
        (n,) state derivative caused by gravity (both 45-deg axes).
    mass_kg
        total rotor mass [kg].
    flexible_freq_hz
        free-free bending frequencies kept in the model,
        one per plane mode at standstill [Hz] (empty if unknown).
    source
        where the model comes from (for reports).
    b_unbalance
        (n, 2) state derivative per Omega^2 [1/s^2 -> state units]
        of the unbalance forces, for [cos theta, sin theta] (module
        docstring); None: no unbalance.
    notes
        what the import changed in the model the user gave (DOFs or
        modes dropped), one sentence each, for the commands to say.
    layout
        the axes of the force inputs and displacement outputs (na of them).
    """

    a: np.ndarray
    b: np.ndarray
    c_bearing: np.ndarray
    c_sensor: np.ndarray
    b_gravity: np.ndarray
    mass_kg: float
    flexible_freq_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))
    source: str = ""
    b_unbalance: np.ndarray | None = None
    notes: tuple[str, ...] = ()
    layout: Layout = RADIAL

    def __post_init__(self) -> None:
        a = np.asarray(self.a, dtype=float)
        n = a.shape[0] if a.ndim == 2 else -1
        na = len(self.layout)
        shapes = {"a": (n, n), "b": (n, na), "c_bearing": (na, n), "c_sensor": (na, n), "b_gravity": (n,)}
        for name, shape in shapes.items():
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != shape:
                raise ValueError(f"RotorModel.{name} must have shape {shape} (n = states, {na} = bearing axes "
                                 f"{', '.join(self.layout.axes)}), got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"RotorModel.{name} contains NaN or inf")
            object.__setattr__(self, name, arr)
        if self.b_unbalance is not None:
            bu = np.asarray(self.b_unbalance, dtype=float)
            if bu.shape != (n, 2) or not np.all(np.isfinite(bu)):
                raise ValueError(f"RotorModel.b_unbalance must be finite with shape ({n}, 2), got {bu.shape}")
            object.__setattr__(self, "b_unbalance", bu)
        if not (np.isfinite(self.mass_kg) and self.mass_kg > 0):
            raise ValueError(f"RotorModel.mass_kg must be > 0, got {self.mass_kg!r}")
        object.__setattr__(self, "flexible_freq_hz", np.asarray(self.flexible_freq_hz, dtype=float).ravel())

    @property
    def n_states(self) -> int:
        return self.a.shape[0]

    def bearing_velocity_map(self) -> np.ndarray:
        """(na, n) map from the state to the bearing-axis velocities [m/s] (C_bearing A; C_bearing B = 0)."""
        return self.c_bearing @ self.a


def with_axial(model: RotorModel, axis: str = "z") -> RotorModel:
    """The rotor with its axial rigid-body motion added as the last axis: a free mass ``mass_kg``, force
    [N] on the axis in, axial displacement [m] at the bearing and the sensor out (the axial probe reads
    the shaft's end face; the rotor is rigid along its axis), decoupled from the lateral planes.

    In the modal layout of :func:`ambid.plant.modal.modal_state_space` (x = [eta, eta']) the axial
    displacement joins the coordinates and its velocity the velocities, as one more rigid mode, so
    the layout stays modal; any other state order gets [z, z'] appended.
    """
    if axis in model.layout.axes:
        raise ValueError(f"with_axial: the rotor already has an axis {axis!r}")
    n, na = model.n_states, len(model.layout)
    r = n // 2
    modal = n % 2 == 0 and np.allclose(model.a[:r, :r], 0.0) and np.allclose(model.a[:r, r:], np.eye(r))
    iz, iv = (r, n + 1) if modal else (n, n + 1)
    old = [i for i in range(n + 2) if i not in (iz, iv)]  # where the lateral states go
    a = np.zeros((n + 2, n + 2))
    a[np.ix_(old, old)] = model.a
    a[iz, iv] = 1.0
    b = np.zeros((n + 2, na + 1))
    b[old, :na] = model.b
    b[iv, na] = 1.0 / model.mass_kg
    c_b, c_s = np.zeros((na + 1, n + 2)), np.zeros((na + 1, n + 2))
    c_b[:na, old], c_s[:na, old] = model.c_bearing, model.c_sensor
    c_b[na, iz] = c_s[na, iz] = 1.0
    b_g = np.zeros(n + 2)
    b_g[old] = model.b_gravity  # a horizontal rotor: no gravity along the axis
    b_unb = None
    if model.b_unbalance is not None:
        b_unb = np.zeros((n + 2, 2))
        b_unb[old] = model.b_unbalance
    return RotorModel(a, b, c_b, c_s, b_g, model.mass_kg, model.flexible_freq_hz,
                      model.source + ", axial rigid mass", b_unb, model.notes,
                      Layout(model.layout.axes + (axis,)))


def fem_rotor_model(geometry: RotorGeometry, bearing_z_m: tuple[float, float], sensor_z_m: tuple[float, float],
                    n_bending: int, damping_ratio: float, speed_rad_s: float = 0.0,
                    unbalance: tuple[tuple[float, float, float], ...] = ()) -> RotorModel:
    """Finite-element rotor reduced to its rigid and first bending modes.

    Parameters
    ----------
    geometry
        shaft, stacks and disks; ``stations_m`` must contain the
        bearing and sensor positions.
    bearing_z_m
        bearing A, B positions from the left shaft end [m].
    sensor_z_m
        sensor A, B positions from the left shaft end [m].
    n_bending
        bending modes kept per plane (besides the 2 rigid ones).
    damping_ratio
        modal damping of the bending modes [-].
    speed_rad_s
        spin speed Omega [rad/s] (gyroscopic coupling).
    unbalance
        unbalanced planes (position from the left shaft end [m],
        mass times eccentricity m e [kg m], angle from x at theta = 0
        [rad]); each acts at the node nearest its position.

    Returns
    -------
    RotorModel with 4 (2 + n_bending) states; gravity is the consistent
    distributed load M g (so the rotor also sags).
    """
    rotor = assemble_rotor(geometry)
    modal = plane_modes(rotor.mass, rotor.stiffness, rotor.gyroscopic, n_flexible=int(n_bending))
    if modal.n_rigid != 2:
        raise ValueError(f"the rotor must be free-free (2 rigid modes per plane), found {modal.n_rigid}")
    z = rotor.node_z_m
    nodes_b = [node_at(z, p) for p in bearing_z_m]
    nodes_s = [node_at(z, p) for p in sensor_z_m]

    def axes_dofs(nodes: list[int]) -> list[int]:
        return [int(dof_index(nodes[0], DOF_X)), int(dof_index(nodes[1], DOF_X)),
                int(dof_index(nodes[0], DOF_Y)), int(dof_index(nodes[1], DOF_Y))]

    zeta = np.where(modal.freq_hz > 0, damping_ratio, 0.0)
    a, b, c = modal_state_space(modal, axes_dofs(nodes_b), axes_dofs(nodes_b) + axes_dofs(nodes_s),
                                speed_rad_s=speed_rad_s, damping_ratio=zeta)
    # consistent gravity load M u_g, u_g = g/sqrt(2) on every x and y translation
    u_g = np.zeros(rotor.n_dof)
    all_nodes = np.arange(z.size)
    u_g[dof_index(all_nodes, DOF_X)] = GRAVITY_PER_AXIS
    u_g[dof_index(all_nodes, DOF_Y)] = GRAVITY_PER_AXIS
    r = modal.shapes.shape[1]
    b_g = np.concatenate([np.zeros(r), modal.shapes.T @ (rotor.mass @ u_g)])
    props = rigid_body_properties(rotor)
    b_unb = None
    if unbalance:
        b_unb = np.zeros((a.shape[0], 2))
        for z_m, me, phase in unbalance:
            node = int(np.argmin(np.abs(z - z_m)))
            dofs = [int(dof_index(node, DOF_X)), int(dof_index(node, DOF_Y))]
            _, b_node, _ = modal_state_space(modal, dofs, dofs, speed_rad_s=speed_rad_s, damping_ratio=zeta)
            # F = m e Omega^2 [cos(theta + phase); sin(theta + phase)] = m e Omega^2 R(phase) [cos; sin]
            cp, sp = np.cos(phase), np.sin(phase)
            b_unb += me * b_node @ np.array([[cp, -sp], [sp, cp]])
    return RotorModel(a, b, c[:N_LATERAL], c[N_LATERAL:], b_g, props.mass_kg, modal.freq_hz[modal.n_rigid:],
                      "finite-element rotor (ambid.plant.fem_rotor), modal reduction", b_unb)


def rigid_inverse_mass(model: RotorModel, probe_hz: float = 1e-3) -> np.ndarray:
    """Rigid-body inverse mass W (na, na) [1/kg]: bearing accelerations per bearing force.

    The low-frequency limit of s^2 C_bearing (s I - A)^-1 B of a free-free
    rotor, evaluated at ``probe_hz`` (far below any bending mode).
    """
    s = 2j * np.pi * probe_hz
    g = model.c_bearing @ np.linalg.solve(s * np.eye(model.n_states) - model.a, model.b)
    return (s * s * g).real
