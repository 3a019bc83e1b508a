"""Finite-element rotor and modal analysis against closed forms."""

import dataclasses

import numpy as np
import pytest
import scipy.linalg
from ambid.plant.fem_rotor import (DOF_RX, DOF_RY, DOF_X, DOF_Y, Disk, LaminationStack, Material, RotorGeometry,
                                   ShaftSection, assemble_rotor, dof_index, mesh_nodes, node_at,
                                   rigid_body_properties, shear_coefficient)
from ambid.plant.modal import (modal_state_space, plane_modes, second_order_state_space, support_stiffness,
                               undamped_modes, whirl_frequencies)
from scipy.optimize import brentq

STEEL = Material()
E, RHO = STEEL.youngs_modulus_pa, STEEL.density_kg_m3
BETA_L = np.array([4.730040745, 7.853204624])  # free-free Euler-Bernoulli roots


def _euler_bernoulli_hz(length, diameter):
    return BETA_L**2 / (2 * np.pi * length**2) * np.sqrt(E * diameter**2 / (16 * RHO))


def _timoshenko_free_free_hz(length, diameter, f_lo, f_hi):
    """First root of the continuous Timoshenko beam, free-free, by transfer matrix.

    State [w, beta, M, Q]: w' = beta + Q/(kGA), beta' = M/EI,
    M' = -w^2 rho I beta - Q, Q' = -w^2 rho A w; free ends: M = Q = 0.
    """
    area, inertia = np.pi * diameter**2 / 4, np.pi * diameter**4 / 64
    kga = shear_coefficient(0.0, STEEL.poisson_ratio) * STEEL.shear_modulus_pa * area

    def det(f):
        w2 = (2 * np.pi * f) ** 2
        a = np.array([[0, 1, 0, 1 / kga], [0, 0, 1 / (E * inertia), 0],
                      [0, -w2 * RHO * inertia, 0, -1], [-w2 * RHO * area, 0, 0, 0]])
        t = scipy.linalg.expm(a * length)
        return np.linalg.det(t[2:4, 0:2])

    grid = np.linspace(f_lo, f_hi, 60)
    vals = np.array([det(f) for f in grid])
    k = np.flatnonzero(np.sign(vals[:-1]) != np.sign(vals[1:]))[0]
    return brentq(det, grid[k], grid[k + 1], xtol=1e-6)


def test_slender_free_free_matches_euler_bernoulli():
    length, diameter = 1.0, 0.02  # L/D = 50: shear and rotary inertia < 0.5 %
    rotor = assemble_rotor(RotorGeometry(sections=(ShaftSection(length, diameter),),
                                         max_element_length_m=0.05))
    model = plane_modes(rotor.mass, rotor.stiffness, n_flexible=2)
    assert model.n_rigid == 2
    ratio = model.freq_hz[2:4] / _euler_bernoulli_hz(length, diameter)
    assert np.all(np.abs(ratio - 1) < 0.01), ratio
    assert np.all(ratio < 1.0)  # Timoshenko is always (slightly) softer


def test_thick_shaft_timoshenko_below_euler_bernoulli():
    length, diameter = 0.3, 0.1  # L/D = 3
    rotor = assemble_rotor(RotorGeometry(sections=(ShaftSection(length, diameter),),
                                         max_element_length_m=0.015))
    f_fem = plane_modes(rotor.mass, rotor.stiffness, n_flexible=1).freq_hz[2]
    f_eb = _euler_bernoulli_hz(length, diameter)[0]
    f_timo = _timoshenko_free_free_hz(length, diameter, 0.5 * f_eb, 0.99 * f_eb)
    assert abs(f_fem / f_timo - 1) < 0.005, (f_fem, f_timo)
    # Shear and rotary inertia cost this short shaft roughly a fifth of its frequency.
    assert 0.10 < 1 - f_fem / f_eb < 0.30, f_fem / f_eb


def _assembly():
    shaft_l, shaft_d = 0.8, 0.06
    disk = Disk.from_geometry(position_m=0.65, width_m=0.03, outer_diameter_m=0.25, inner_diameter_m=shaft_d)
    stack = LaminationStack(start_m=0.3, length_m=0.2, outer_diameter_m=0.12)
    geom = RotorGeometry(sections=(ShaftSection(0.3, shaft_d), ShaftSection(0.2, shaft_d, 0.02),
                                   ShaftSection(0.3, shaft_d)),
                         disks=(disk,), stacks=(stack,), stations_m=(0.1, 0.123456, 0.7),
                         max_element_length_m=0.04)
    return geom, disk, stack, shaft_l, shaft_d


def test_rigid_body_modes_and_properties_by_hand():
    geom, disk, stack, shaft_l, shaft_d = _assembly()
    rotor = assemble_rotor(geom)
    # Hand computation: (mass, centre, own Jt, own Jp) of each piece.
    def tube(z0, length, do, di):
        m = RHO * np.pi / 4 * (do**2 - di**2) * length
        return m, z0 + length / 2, m * (length**2 / 12 + (do**2 + di**2) / 16), m * (do**2 + di**2) / 8
    parts = [tube(0.0, 0.3, shaft_d, 0.0), tube(0.3, 0.2, shaft_d, 0.02), tube(0.5, 0.3, shaft_d, 0.0),
             tube(0.3, 0.2, 0.12, shaft_d),
             (disk.mass_kg, disk.position_m, disk.transverse_inertia_kg_m2, disk.polar_inertia_kg_m2)]
    m = sum(p[0] for p in parts)
    zc = sum(p[0] * p[1] for p in parts) / m
    jt = sum(p[2] + p[0] * (p[1] - zc) ** 2 for p in parts)
    jp = sum(p[3] for p in parts)
    props = rigid_body_properties(rotor)
    assert props.mass_kg == pytest.approx(m, rel=1e-9)
    assert props.center_of_mass_m == pytest.approx(zc, rel=1e-9)
    assert props.transverse_inertia_kg_m2 == pytest.approx(jt, rel=1e-9)
    assert props.polar_inertia_kg_m2 == pytest.approx(jp, rel=1e-9)

    # Full (both planes) eigenproblem: exactly four zero frequencies.
    freq, _ = undamped_modes(rotor.mass, rotor.stiffness)
    assert np.sum(freq < 1.0) == 4 and freq[4] > 50.0
    model = plane_modes(rotor.mass, rotor.stiffness, rotor.gyroscopic, n_flexible=3)
    assert model.n_rigid == 2 and np.all(model.freq_hz[:2] == 0)
    phi = model.shapes
    assert np.allclose(phi.T @ rotor.mass @ phi, np.eye(phi.shape[1]), atol=1e-9)
    n = rotor.node_z_m.size
    # Rigid translation mode = 1/sqrt(m) everywhere; tilt mode = 1/sqrt(Jt) about the centre.
    assert np.allclose(phi[dof_index(np.arange(n), DOF_X), 0], 1 / np.sqrt(m))
    assert np.allclose(phi[dof_index(np.arange(n), DOF_RY), 1], 1 / np.sqrt(jt))
    assert np.allclose(phi[dof_index(np.arange(n), DOF_X), 1], (rotor.node_z_m - zc) / np.sqrt(jt))
    # The y-plane copy: same translation, theta_x = -dy/dz.
    assert np.allclose(phi[dof_index(np.arange(n), DOF_Y), model.n_modes + 1], (rotor.node_z_m - zc) / np.sqrt(jt))
    assert np.allclose(phi[dof_index(np.arange(n), DOF_RX), model.n_modes + 1], -1 / np.sqrt(jt))
    # Reduced gyroscopic matrix equals the projection of the full one.
    assert np.allclose(phi.T @ rotor.gyroscopic @ phi, model.gyroscopic, atol=1e-12)
    assert model.polar[1, 1] == pytest.approx(jp / jt, rel=1e-9)
    # Free-free rigid nutation: the tilt mode whirls forward at Omega Jp / Jt.
    speed = 2 * np.pi * 200.0
    f_whirl, _ = whirl_frequencies(plane_modes(rotor.mass, rotor.stiffness, rotor.gyroscopic, n_flexible=0),
                                   speed)
    assert np.max(f_whirl) == pytest.approx(speed * jp / jt / (2 * np.pi), rel=1e-6)


def test_mesh_contains_stations_and_section_ends():
    geom, *_ = _assembly()
    z = mesh_nodes(geom)
    for pos in (0.0, 0.1, 0.123456, 0.3, 0.5, 0.65, 0.7, 0.8):
        assert abs(z[node_at(z, pos)] - pos) < 1e-12
    assert np.all(np.diff(z) <= geom.max_element_length_m + 1e-12)
    with pytest.raises(ValueError, match="stations_m"):
        node_at(z, 0.111)
    with pytest.raises(ValueError, match="outside the shaft"):
        RotorGeometry(sections=(ShaftSection(0.5, 0.05),), stations_m=(0.6,))
    with pytest.raises(ValueError, match="inner_diameter_m"):
        ShaftSection(0.5, 0.05, 0.06)


def _whirl_closed_form(k, m, id_, ip, speed):
    """Signed whirl frequencies [Hz] of a rigid disk on a massless shaft.

    (k11 - m w^2)(k22 - Id w^2 + Omega Ip w) - k12^2 = 0, w > 0 forward.
    """
    poly = np.polysub(np.polymul([-m, 0, k[0, 0]], [-id_, speed * ip, k[1, 1]]), [k[0, 1] ** 2])
    roots = np.roots(poly)
    assert np.allclose(roots.imag, 0)
    return np.sort(roots.real) / (2 * np.pi)


def test_overhung_disk_whirl_against_closed_form():
    length, diameter = 0.4, 0.03
    disk = Disk(position_m=length, mass_kg=8.0, transverse_inertia_kg_m2=0.06, polar_inertia_kg_m2=0.11)
    nearly_massless = Material(density_kg_m3=1e-3)
    geom = RotorGeometry(sections=(ShaftSection(length, diameter),), disks=(disk,), material=nearly_massless,
                         max_element_length_m=0.1)
    rotor = assemble_rotor(geom)
    keep = slice(4, None)  # clamp node 0 (z = 0): cantilever
    m, k, g = (a[keep, keep] for a in (rotor.mass, rotor.stiffness, rotor.gyroscopic))
    model = plane_modes(m, k, g)
    # Tip compliance of a Timoshenko cantilever (force and moment at the free end).
    ei = E * np.pi * diameter**4 / 64
    kga = shear_coefficient(0.0, 0.3) * STEEL.shear_modulus_pa * np.pi * diameter**2 / 4
    compliance = np.array([[length**3 / (3 * ei) + length / kga, length**2 / (2 * ei)],
                           [length**2 / (2 * ei), length / ei]])
    k_tip = np.linalg.inv(compliance)
    previous = None
    for speed in (0.0, 2 * np.pi * 50, 2 * np.pi * 150):
        exact = _whirl_closed_form(k_tip, disk.mass_kg, disk.transverse_inertia_kg_m2,
                                   disk.polar_inertia_kg_m2, speed)
        backward, forward = -exact[exact < 0][::-1], exact[exact > 0]
        f_fem, zeta = whirl_frequencies(model, speed)
        fem_fwd = np.sort(f_fem[f_fem > 0])[:2]
        fem_bwd = np.sort(-f_fem[f_fem < 0])[:2]
        assert np.allclose(fem_fwd, forward, rtol=2e-3), (fem_fwd, forward)
        assert np.allclose(fem_bwd, backward, rtol=2e-3), (fem_bwd, backward)
        assert np.allclose(zeta, 0, atol=1e-9)
        if speed == 0:
            assert np.allclose(fem_fwd, fem_bwd, rtol=1e-9)
        else:
            assert np.all(fem_fwd > previous[0]) and np.all(fem_bwd < previous[1])
        previous = (fem_fwd, fem_bwd)
    # The real state-space eigenvalues are the same whirl frequencies (both signs).
    a, _, _ = modal_state_space(model, [0], [0], speed_rad_s=speed)
    f_real = np.sort(np.abs(np.linalg.eigvals(a).imag)) / (2 * np.pi)
    assert np.allclose(f_real, np.sort(np.abs(np.concatenate([f_fem, f_fem]))), rtol=1e-8)


def test_modal_state_space_equals_full_model_when_all_modes_kept():
    geom, *_ = _assembly()
    rotor = assemble_rotor(dataclasses.replace(geom, max_element_length_m=0.1))
    z = rotor.node_z_m
    bearings = [node_at(z, 0.1), node_at(z, 0.7)]
    sensors = [node_at(z, 0.0), node_at(z, 0.8)]
    inputs = dof_index(np.repeat(bearings, 2), np.tile([DOF_X, DOF_Y], 2))
    outputs = dof_index(np.repeat(sensors, 2), np.tile([DOF_X, DOF_Y], 2))
    # Supported analysis (springs at the bearings in x and y) at speed.
    ks = support_stiffness(rotor.n_dof, inputs, 2e7)
    speed = 2 * np.pi * 120.0
    model = plane_modes(rotor.mass, rotor.stiffness + ks, rotor.gyroscopic)
    assert model.n_rigid == 0
    a, b, c = modal_state_space(model, inputs, outputs, speed_rad_s=speed)
    af, bf, cf = second_order_state_space(rotor.mass, None, rotor.stiffness + ks, inputs, outputs,
                                          gyroscopic=rotor.gyroscopic, speed_rad_s=speed)
    assert a.shape == (4 * model.n_modes, 4 * model.n_modes) and b.shape[1] == 4 and c.shape[0] == 4
    for f in (10.0, 137.0, 555.0):
        s = 2j * np.pi * f
        h = c @ np.linalg.solve(s * np.eye(a.shape[0]) - a, b)
        hf = cf @ np.linalg.solve(s * np.eye(af.shape[0]) - af, bf)
        assert np.allclose(h, hf, rtol=1e-6, atol=1e-6 * np.abs(hf).max())
        # Gyroscopic coupling: a force in x moves the rotor in y at speed (not at rest).
        assert np.abs(h[1, 0]) > 1e-4 * np.abs(h[0, 0])
    a0, b0, c0 = modal_state_space(model, inputs, outputs, speed_rad_s=0.0)
    h0 = c0 @ np.linalg.solve(2j * np.pi * 137.0 * np.eye(a0.shape[0]) - a0, b0)
    assert np.abs(h0[1, 0]) < 1e-12 * np.abs(h0[0, 0])
    # Free-free modes with the bearing springs added in modal coordinates: same model.
    free = plane_modes(rotor.mass, rotor.stiffness, rotor.gyroscopic)
    assert free.n_rigid == 2
    a2, b2, c2 = modal_state_space(free, inputs, outputs, speed_rad_s=speed, input_stiffness_n_m=2e7)
    assert np.allclose(np.sort(np.linalg.eigvals(a2).imag), np.sort(np.linalg.eigvals(a).imag), rtol=1e-7)
    s = 2j * np.pi * 137.0
    h2 = c2 @ np.linalg.solve(s * np.eye(a2.shape[0]) - a2, b2)
    hf = cf @ np.linalg.solve(s * np.eye(af.shape[0]) - af, bf)
    assert np.allclose(h2, hf, rtol=1e-6, atol=1e-6 * np.abs(hf).max())
    # A few modes reproduce the low-frequency compliance within a few percent.
    small = plane_modes(rotor.mass, rotor.stiffness + ks, rotor.gyroscopic, n_flexible=6)
    a6, b6, c6 = modal_state_space(small, inputs, outputs, speed_rad_s=speed, damping_ratio=0.0)
    s = 2j * np.pi * 10.0
    h6 = c6 @ np.linalg.solve(s * np.eye(a6.shape[0]) - a6, b6)
    hf = cf @ np.linalg.solve(s * np.eye(af.shape[0]) - af, bf)
    assert np.allclose(h6, hf, rtol=0.03, atol=0.03 * np.abs(hf).max())


def test_modal_damping_ratio_reaches_eigenvalues():
    rotor = assemble_rotor(RotorGeometry(sections=(ShaftSection(0.8, 0.06),), max_element_length_m=0.08))
    model = plane_modes(rotor.mass, rotor.stiffness, n_flexible=2)
    zeta = np.array([0.0, 0.0, 0.02, 0.05])
    f, z = whirl_frequencies(model, 0.0, damping_ratio=zeta)
    flex = np.abs(f) > 1.0
    expected = np.repeat(model.freq_hz[2:] * np.sqrt(1 - zeta[2:] ** 2), 2)
    assert np.allclose(np.sort(np.abs(f[flex])), expected, rtol=1e-9)
    assert np.allclose(np.sort(z[flex]), np.repeat(zeta[2:], 2), rtol=1e-9)


def test_bad_inputs_raise():
    rotor = assemble_rotor(RotorGeometry(sections=(ShaftSection(0.5, 0.05),), max_element_length_m=0.1))
    ks = support_stiffness(rotor.n_dof, [0], 1e7)  # x only: no longer axisymmetric
    with pytest.raises(ValueError, match="axisymmetric"):
        plane_modes(rotor.mass, rotor.stiffness + ks)
    model = plane_modes(rotor.mass, rotor.stiffness)
    with pytest.raises(ValueError, match="input_dofs"):
        modal_state_space(model, [rotor.n_dof], [0])
    with pytest.raises(ValueError, match="damping_ratio"):
        modal_state_space(model, [0], [0], damping_ratio=[0.1, 0.2])
    with pytest.raises(ValueError, match="n_flexible"):
        plane_modes(rotor.mass, rotor.stiffness, n_flexible=100)
    with pytest.raises(ValueError, match="NaN"):
        plane_modes(np.full_like(rotor.mass, np.nan), rotor.stiffness)
    with pytest.raises(ValueError, match="density_kg_m3"):
        Material(density_kg_m3=-1.0)
