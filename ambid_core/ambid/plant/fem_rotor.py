"""Finite-element model of a horizontal rotor in its two lateral planes.

Timoshenko beam elements (shear deformation and rotary inertia), rigid disks
and lamination stacks, after Friswell, Penny, Garvey & Lees, *Dynamics of
Rotating Machines* (2010), ch. 5. The result is the matrices of eq. 2.25 of
Hynynen (2011)::

    M q'' + (D + Omega G) q' + K q = F

with Omega the spin speed [rad/s] about +z (the shaft axis).

DOF ordering. Node ``n`` (axial position ``node_z_m[n]``, numbered from the
left end, z = 0) owns the four DOFs ``4 n + (0, 1, 2, 3)``:

    0  x        lateral displacement [m]
    1  y        lateral displacement [m]
    2  theta_x  rotation about +x [rad], = -dy/dz for a slender shaft
    3  theta_y  rotation about +y [rad], = +dx/dz for a slender shaft

(Friswell's u, v, theta, psi.) With this choice the (x, theta_y) and
(y, -theta_x) planes carry the same element matrices, and the gyroscopic
matrix of a disk is ``G[theta_x, theta_y] = Ip = -G[theta_y, theta_x]``.
Forces F follow the same ordering (forces [N] and moments [N m]).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

DOF_X, DOF_Y, DOF_RX, DOF_RY = 0, 1, 2, 3
DOFS_PER_NODE = 4

# Positions closer than this are treated as one node [m].
_MERGE_TOL_M = 1e-9


@dataclass(frozen=True)
class Material:
    """Isotropic elastic material; defaults are structural steel.

    Attributes
    ----------
    youngs_modulus_pa
        E [Pa].
    density_kg_m3
        rho [kg/m^3].
    poisson_ratio
        nu [-], sets G = E / (2 (1 + nu)).
    """

    youngs_modulus_pa: float = 211e9
    density_kg_m3: float = 7810.0
    poisson_ratio: float = 0.3

    def __post_init__(self) -> None:
        for name in ("youngs_modulus_pa", "density_kg_m3"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"Material.{name} must be finite and > 0, got {value!r}")
        if not -1.0 < self.poisson_ratio < 0.5:
            raise ValueError(f"Material.poisson_ratio must lie in (-1, 0.5), got {self.poisson_ratio!r}")

    @property
    def shear_modulus_pa(self) -> float:
        """G = E / (2 (1 + nu)) [Pa]."""
        return self.youngs_modulus_pa / (2.0 * (1.0 + self.poisson_ratio))


STEEL = Material()


@dataclass(frozen=True)
class ShaftSection:
    """A uniform (hollow) cylindrical piece of the shaft.

    Attributes
    ----------
    length_m
        axial length [m].
    outer_diameter_m
        outer diameter [m].
    inner_diameter_m
        bore diameter [m], 0 for a solid shaft.
    material
        overrides ``RotorGeometry.material`` for this section.
    """

    length_m: float
    outer_diameter_m: float
    inner_diameter_m: float = 0.0
    material: Material | None = None

    def __post_init__(self) -> None:
        for name in ("length_m", "outer_diameter_m"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"ShaftSection.{name} must be finite and > 0, got {value!r}")
        if not 0.0 <= self.inner_diameter_m < self.outer_diameter_m:
            raise ValueError(
                "ShaftSection.inner_diameter_m must lie in [0, outer_diameter_m), got "
                f"{self.inner_diameter_m!r} with outer {self.outer_diameter_m!r}")


@dataclass(frozen=True)
class Disk:
    """A rigid disk attached at one axial position (the disk's centre of mass).

    Attributes
    ----------
    position_m
        axial position from the left shaft end [m].
    mass_kg
        mass [kg].
    transverse_inertia_kg_m2
        Id, about a diameter through the centre [kg m^2].
    polar_inertia_kg_m2
        Ip, about the shaft axis [kg m^2]; sets the
        gyroscopic coupling.
    """

    position_m: float
    mass_kg: float
    transverse_inertia_kg_m2: float = 0.0
    polar_inertia_kg_m2: float = 0.0

    def __post_init__(self) -> None:
        for name in ("position_m", "mass_kg", "transverse_inertia_kg_m2", "polar_inertia_kg_m2"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"Disk.{name} must be finite and >= 0, got {value!r}")

    @classmethod
    def from_geometry(cls, position_m: float, width_m: float, outer_diameter_m: float,
                      inner_diameter_m: float = 0.0, density_kg_m3: float = STEEL.density_kg_m3) -> Disk:
        """Disk from a hollow-cylinder geometry [m, kg/m^3].

        m = rho pi/4 (Do^2 - Di^2) w, Ip = m (ro^2 + ri^2) / 2,
        Id = m (3 (ro^2 + ri^2) + w^2) / 12 (thick cylinder about its centre).
        The disk adds no stiffness; model a stiff hub as a shaft section.
        """
        if not (width_m > 0 and outer_diameter_m > 0 and 0 <= inner_diameter_m < outer_diameter_m
                and density_kg_m3 > 0):
            raise ValueError(
                "Disk.from_geometry needs width_m > 0, outer_diameter_m > inner_diameter_m >= 0 "
                f"and density_kg_m3 > 0, got {width_m!r}, {outer_diameter_m!r}, "
                f"{inner_diameter_m!r}, {density_kg_m3!r}")
        ro2 = (outer_diameter_m / 2) ** 2
        ri2 = (inner_diameter_m / 2) ** 2
        mass = density_kg_m3 * np.pi * (ro2 - ri2) * width_m
        return cls(position_m=position_m, mass_kg=mass,
                   transverse_inertia_kg_m2=mass * (3 * (ro2 + ri2) + width_m**2) / 12,
                   polar_inertia_kg_m2=mass * (ro2 + ri2) / 2)


@dataclass(frozen=True)
class LaminationStack:
    """A stack of laminations shrunk on the shaft (motor rotor, bearing sleeve).

    Modelled as a tube distributed over the elements it covers: its mass,
    rotary and polar inertia are added in full, its bending and shear
    stiffness only as ``stiffness_fraction`` of a solid tube (insulated
    sheets carry little bending load).

    Attributes
    ----------
    start_m
        axial position of the left end [m].
    length_m
        axial length [m].
    outer_diameter_m
        outer diameter [m].
    inner_diameter_m
        bore [m]; None takes the shaft's outer diameter there.
    density_kg_m3
        effective density including the stacking factor [kg/m^3].
    stiffness_fraction
        share of the tube's E I and kappa G A that adds to
        the shaft, in [0, 1].
    """

    start_m: float
    length_m: float
    outer_diameter_m: float
    inner_diameter_m: float | None = None
    density_kg_m3: float = STEEL.density_kg_m3
    stiffness_fraction: float = 0.0

    def __post_init__(self) -> None:
        for name in ("length_m", "outer_diameter_m", "density_kg_m3"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"LaminationStack.{name} must be finite and > 0, got {value!r}")
        if not np.isfinite(self.start_m) or self.start_m < 0:
            raise ValueError(f"LaminationStack.start_m must be finite and >= 0, got {self.start_m!r}")
        if self.inner_diameter_m is not None and not 0 <= self.inner_diameter_m < self.outer_diameter_m:
            raise ValueError(
                "LaminationStack.inner_diameter_m must lie in [0, outer_diameter_m), got "
                f"{self.inner_diameter_m!r}")
        if not 0.0 <= self.stiffness_fraction <= 1.0:
            raise ValueError(
                f"LaminationStack.stiffness_fraction must lie in [0, 1], got {self.stiffness_fraction!r}")


@dataclass(frozen=True)
class RotorGeometry:
    """Everything needed to mesh and assemble a rotor.

    Attributes
    ----------
    sections
        shaft sections from left (z = 0) to right.
    disks
        rigid disks.
    stacks
        lamination stacks.
    stations_m
        axial positions that must be nodes (bearing and sensor
        centres, probe tracks) [m].
    material
        default shaft material.
    max_element_length_m
        elements are at most this long [m].
    """

    sections: tuple[ShaftSection, ...]
    disks: tuple[Disk, ...] = ()
    stacks: tuple[LaminationStack, ...] = ()
    stations_m: tuple[float, ...] = ()
    material: Material = field(default_factory=Material)
    max_element_length_m: float = 0.05

    def __post_init__(self) -> None:
        if len(self.sections) == 0:
            raise ValueError("RotorGeometry.sections is empty; give at least one ShaftSection")
        if not np.isfinite(self.max_element_length_m) or self.max_element_length_m <= 0:
            raise ValueError(
                f"RotorGeometry.max_element_length_m must be > 0, got {self.max_element_length_m!r}")
        length = self.length_m
        for what, z in ([("disk", d.position_m) for d in self.disks]
                        + [("stack end", s.start_m + s.length_m) for s in self.stacks]
                        + [("station", z) for z in self.stations_m]):
            if not np.isfinite(z) or not -_MERGE_TOL_M <= z <= length + _MERGE_TOL_M:
                raise ValueError(
                    f"{what} at z = {z!r} m lies outside the shaft [0, {length}] m; "
                    "positions are measured from the left shaft end")

    @property
    def length_m(self) -> float:
        """Total shaft length [m]."""
        return float(sum(s.length_m for s in self.sections))


@dataclass(frozen=True)
class RotorMatrices:
    """Assembled finite-element matrices (see the module docstring for DOFs).

    Attributes
    ----------
    node_z_m
        axial node positions, shape (n_nodes,) [m].
    mass
        M, shape (4 n_nodes, 4 n_nodes) [kg, kg m^2].
    stiffness
        K, same shape [N/m, N, N m/rad].
    gyroscopic
        G, same shape, skew-symmetric; multiply by the spin
        speed Omega [rad/s] [kg m^2].
    """

    node_z_m: np.ndarray
    mass: np.ndarray
    stiffness: np.ndarray
    gyroscopic: np.ndarray

    @property
    def n_dof(self) -> int:
        """Number of DOFs, 4 n_nodes."""
        return self.mass.shape[0]


@dataclass(frozen=True)
class RigidBodyProperties:
    """Rigid-body data of the whole rotor.

    Attributes
    ----------
    mass_kg
        total mass [kg].
    center_of_mass_m
        axial position of the centre of mass [m].
    transverse_inertia_kg_m2
        about a diameter through the centre of mass [kg m^2].
    polar_inertia_kg_m2
        about the shaft axis [kg m^2].
    """

    mass_kg: float
    center_of_mass_m: float
    transverse_inertia_kg_m2: float
    polar_inertia_kg_m2: float


def dof_index(node: int | np.ndarray, dof: int | np.ndarray) -> np.ndarray:
    """Global DOF index 4 node + dof.

    Parameters
    ----------
    node
        node index, int or integer array.
    dof
        one of DOF_X, DOF_Y, DOF_RX, DOF_RY (0..3), broadcastable with node.

    Returns
    -------
    Integer array of the broadcast shape.
    """
    node = np.asarray(node)
    dof = np.asarray(dof)
    if np.any((dof < 0) | (dof >= DOFS_PER_NODE)) or np.any(node < 0):
        raise ValueError("dof must be in 0..3 (DOF_X, DOF_Y, DOF_RX, DOF_RY) and node >= 0")
    return (DOFS_PER_NODE * node + dof).astype(int)


def shear_coefficient(inner_over_outer: float, poisson_ratio: float) -> float:
    """Timoshenko shear coefficient kappa of a hollow circular section (Cowper 1966).

    kappa = 6 (1 + nu) (1 + a^2)^2 / ((7 + 6 nu) (1 + a^2)^2 + (20 + 12 nu) a^2),
    a = Di / Do; 0.886 for a solid steel shaft.
    """
    a2 = inner_over_outer**2
    nu = poisson_ratio
    return 6 * (1 + nu) * (1 + a2) ** 2 / ((7 + 6 * nu) * (1 + a2) ** 2 + (20 + 12 * nu) * a2)


def timoshenko_element(length_m: float, rho_a_kg_m: float, rho_i_kg_m: float, ei_n_m2: float,
                       kappa_g_a_n: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass, stiffness and gyroscopic matrices of one Timoshenko element.

    Friswell et al. (2010) eqs. 5.48-5.55 (Nelson 1980), shear parameter
    phi = 12 E I / (kappa G A L^2); kappa_g_a_n = inf gives Euler-Bernoulli.

    Parameters
    ----------
    length_m
        element length L [m].
    rho_a_kg_m
        mass per length rho A [kg/m].
    rho_i_kg_m
        transverse rotary inertia per length rho I [kg m].
        The polar inertia per length is taken as 2 rho I (axisymmetric).
    ei_n_m2
        bending stiffness E I [N m^2].
    kappa_g_a_n
        shear stiffness kappa G A [N].

    Returns
    -------
    (Me, Ke, Ge), each shape (8, 8), DOFs [x1, y1, tx1, ty1, x2, y2, tx2, ty2].
    """
    L = float(length_m)
    if not (L > 0 and rho_a_kg_m >= 0 and rho_i_kg_m >= 0 and ei_n_m2 > 0 and kappa_g_a_n > 0):
        raise ValueError("timoshenko_element needs L > 0, rho A >= 0, rho I >= 0, E I > 0, kappa G A > 0")
    phi = 12.0 * ei_n_m2 / (kappa_g_a_n * L**2)
    p2 = phi * phi
    m1, m2, m3 = 312 + 588 * phi + 280 * p2, 44 + 77 * phi + 35 * p2, 108 + 252 * phi + 140 * p2
    m4, m5, m6 = 26 + 63 * phi + 35 * p2, 8 + 14 * phi + 7 * p2, 6 + 14 * phi + 7 * p2
    # One plane, DOFs (w1, b1, w2, b2) with b = dw/dz in the slender limit.
    mt = rho_a_kg_m * L / (840 * (1 + phi) ** 2) * np.array([
        [m1, m2 * L, m3, -m4 * L],
        [m2 * L, m5 * L**2, m4 * L, -m6 * L**2],
        [m3, m4 * L, m1, -m2 * L],
        [-m4 * L, -m6 * L**2, -m2 * L, m5 * L**2]])
    m7, m8, m9, m10 = 36.0, 3 - 15 * phi, 4 + 5 * phi + 10 * p2, 1 + 5 * phi - 5 * p2
    mr = rho_i_kg_m / (30 * L * (1 + phi) ** 2) * np.array([
        [m7, m8 * L, -m7, m8 * L],
        [m8 * L, m9 * L**2, -m8 * L, -m10 * L**2],
        [-m7, -m8 * L, m7, -m8 * L],
        [m8 * L, -m10 * L**2, -m8 * L, m9 * L**2]])
    kp = ei_n_m2 / (L**3 * (1 + phi)) * np.array([
        [12, 6 * L, -12, 6 * L],
        [6 * L, (4 + phi) * L**2, -6 * L, (2 - phi) * L**2],
        [-12, -6 * L, 12, -6 * L],
        [6 * L, (2 - phi) * L**2, -6 * L, (4 + phi) * L**2]])
    return _planes_to_full(mt + mr, kp, 2.0 * mr)


def _planes_to_full(mass_plane: np.ndarray, stiff_plane: np.ndarray,
                    polar_plane: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Spread single-plane matrices (w, b per node) onto the 4-DOF layout.

    The x plane is (x, theta_y) = (w, b); the y plane is (y, theta_x) = (w, -b),
    hence the sign flip T = diag(1, -1, ...). The gyroscopic matrix couples the
    planes: G[y-plane, x-plane] = -T P and G[x-plane, y-plane] = P T, where P
    is the polar-inertia matrix built on the rotation shape functions.
    """
    n = mass_plane.shape[0] // 2
    xp = (DOFS_PER_NODE * np.arange(n)[:, None] + np.array([DOF_X, DOF_RY])).ravel()
    yp = (DOFS_PER_NODE * np.arange(n)[:, None] + np.array([DOF_Y, DOF_RX])).ravel()
    t = np.tile([1.0, -1.0], n)
    nd = DOFS_PER_NODE * n
    m, k, g = np.zeros((nd, nd)), np.zeros((nd, nd)), np.zeros((nd, nd))
    m[np.ix_(xp, xp)] = mass_plane
    m[np.ix_(yp, yp)] = t[:, None] * mass_plane * t
    k[np.ix_(xp, xp)] = stiff_plane
    k[np.ix_(yp, yp)] = t[:, None] * stiff_plane * t
    g[np.ix_(yp, xp)] = -t[:, None] * polar_plane
    g[np.ix_(xp, yp)] = polar_plane * t
    return m, k, g


def mesh_nodes(geometry: RotorGeometry) -> np.ndarray:
    """Axial node positions [m], shape (n_nodes,), ascending.

    Section ends, disk positions, stack ends and stations are nodes exactly;
    each interval between them is split into equal elements no longer than
    ``geometry.max_element_length_m``.
    """
    ends = np.concatenate([[0.0], np.cumsum([s.length_m for s in geometry.sections])])
    keys = list(ends) + [d.position_m for d in geometry.disks] + list(geometry.stations_m)
    for s in geometry.stacks:
        keys += [s.start_m, s.start_m + s.length_m]
    keys = np.clip(np.sort(np.asarray(keys, dtype=float)), 0.0, ends[-1])
    keys = keys[np.concatenate([[True], np.diff(keys) > _MERGE_TOL_M])]
    nodes = [keys[:1]]
    for z0, z1 in zip(keys[:-1], keys[1:]):
        n_el = int(np.ceil((z1 - z0) / geometry.max_element_length_m - 1e-9))
        nodes.append(np.linspace(z0, z1, n_el + 1)[1:])
    return np.concatenate(nodes)


def node_at(node_z_m: np.ndarray, position_m: float, tol_m: float = 1e-6) -> int:
    """Index of the node at an axial position.

    Parameters
    ----------
    node_z_m
        node positions, shape (n_nodes,) [m].
    position_m
        wanted axial position [m].
    tol_m
        allowed distance to the nearest node [m].

    Raises
    ------
    ValueError
        no node within ``tol_m``; add the position to
        ``RotorGeometry.stations_m`` so the mesh contains it.
    """
    z = np.asarray(node_z_m, dtype=float)
    idx = int(np.argmin(np.abs(z - position_m)))
    if abs(z[idx] - position_m) > tol_m:
        raise ValueError(
            f"no node at z = {position_m} m (nearest {z[idx]} m); add it to RotorGeometry.stations_m")
    return idx


def assemble_rotor(geometry: RotorGeometry) -> RotorMatrices:
    """Assemble M, K and G of the free-free rotor.

    Parameters
    ----------
    geometry
        shaft, disks, stacks and required stations.

    Returns
    -------
    RotorMatrices with node positions and the (4 n_nodes)^2 matrices;
    no supports and no damping (see ``rayleigh_damping`` and ``ambid.plant.modal``).
    """
    z = mesh_nodes(geometry)
    n_nodes = z.size
    n = DOFS_PER_NODE * n_nodes
    m, k, g = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
    ends = np.concatenate([[0.0], np.cumsum([s.length_m for s in geometry.sections])])
    for e in range(n_nodes - 1):
        z0, z1 = z[e], z[e + 1]
        zm = 0.5 * (z0 + z1)
        sec = geometry.sections[min(int(np.searchsorted(ends, zm) - 1), len(geometry.sections) - 1)]
        mat = sec.material or geometry.material
        do, di = sec.outer_diameter_m, sec.inner_diameter_m
        area = np.pi / 4 * (do**2 - di**2)
        inertia = np.pi / 64 * (do**4 - di**4)
        rho_a = mat.density_kg_m3 * area
        rho_i = mat.density_kg_m3 * inertia
        ei = mat.youngs_modulus_pa * inertia
        kga = shear_coefficient(di / do, mat.poisson_ratio) * mat.shear_modulus_pa * area
        for st in geometry.stacks:
            if st.start_m - _MERGE_TOL_M <= zm <= st.start_m + st.length_m + _MERGE_TOL_M:
                sdi = do if st.inner_diameter_m is None else st.inner_diameter_m
                if st.outer_diameter_m <= sdi:
                    raise ValueError(
                        f"LaminationStack at z = {st.start_m} m: outer diameter {st.outer_diameter_m} m "
                        f"must exceed its bore {sdi} m")
                s_area = np.pi / 4 * (st.outer_diameter_m**2 - sdi**2)
                s_inertia = np.pi / 64 * (st.outer_diameter_m**4 - sdi**4)
                rho_a += st.density_kg_m3 * s_area
                rho_i += st.density_kg_m3 * s_inertia
                ei += st.stiffness_fraction * mat.youngs_modulus_pa * s_inertia
                kga += st.stiffness_fraction * shear_coefficient(
                    sdi / st.outer_diameter_m, mat.poisson_ratio) * mat.shear_modulus_pa * s_area
        me, ke, ge = timoshenko_element(z1 - z0, rho_a, rho_i, ei, kga)
        sl = slice(DOFS_PER_NODE * e, DOFS_PER_NODE * (e + 2))
        m[sl, sl] += me
        k[sl, sl] += ke
        g[sl, sl] += ge
    for d in geometry.disks:
        i = node_at(z, d.position_m)
        md, _, gd = _planes_to_full(np.diag([d.mass_kg, d.transverse_inertia_kg_m2]), np.zeros((2, 2)),
                                    np.diag([0.0, d.polar_inertia_kg_m2]))
        sl = slice(DOFS_PER_NODE * i, DOFS_PER_NODE * (i + 1))
        m[sl, sl] += md
        g[sl, sl] += gd
    return RotorMatrices(node_z_m=z, mass=m, stiffness=k, gyroscopic=g)


def rigid_body_properties(rotor: RotorMatrices) -> RigidBodyProperties:
    """Mass, centre of mass and inertias of the rotor, taken from M and G.

    Uses the exact rigid-body fields of the elements: translation
    (x = 1, theta_y = 0) and tilt (x = z - z_c, theta_y = 1).
    """
    z = rotor.node_z_m
    n = z.size
    ix = dof_index(np.arange(n), DOF_X)
    iry = dof_index(np.arange(n), DOF_RY)
    irx = dof_index(np.arange(n), DOF_RX)
    iy = dof_index(np.arange(n), DOF_Y)
    trans = np.zeros(rotor.n_dof)
    trans[ix] = 1.0
    tilt0 = np.zeros(rotor.n_dof)
    tilt0[ix] = z
    tilt0[iry] = 1.0
    mass = trans @ rotor.mass @ trans
    zc = (trans @ rotor.mass @ tilt0) / mass
    tilt_x = tilt0.copy()
    tilt_x[ix] = z - zc
    jt = tilt_x @ rotor.mass @ tilt_x
    tilt_y = np.zeros(rotor.n_dof)  # same tilt in the y plane: y = -(z - zc), theta_x = 1
    tilt_y[iy] = -(z - zc)
    tilt_y[irx] = 1.0
    jp = tilt_y @ rotor.gyroscopic @ tilt_x
    return RigidBodyProperties(mass_kg=float(mass), center_of_mass_m=float(zc),
                               transverse_inertia_kg_m2=float(jt), polar_inertia_kg_m2=float(jp))


def rayleigh_damping(mass: np.ndarray, stiffness: np.ndarray, alpha_per_s: float,
                     beta_s: float) -> np.ndarray:
    """Proportional damping D = alpha M + beta K, shape of M [N s/m].

    A mode at omega [rad/s] gets damping ratio alpha / (2 omega) + beta omega / 2.
    For damping ratios per mode use ``ambid.plant.modal.modal_state_space``.
    """
    if alpha_per_s < 0 or beta_s < 0:
        raise ValueError(f"rayleigh_damping needs alpha, beta >= 0, got {alpha_per_s!r}, {beta_s!r}")
    return alpha_per_s * np.asarray(mass) + beta_s * np.asarray(stiffness)
