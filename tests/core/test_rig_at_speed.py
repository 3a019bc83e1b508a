"""The true rig at speed: unbalance forces m e Omega^2, runout in y only, the gyroscopic whirl against
the full finite-element eigen-analysis, and levitation with both controllers."""

from pathlib import Path

import numpy as np
import pytest
from ambid.control.closed_loop import check_controller_on_rig
from ambid.control.lqg import lqg_controller
from ambid.control.pid import PidParameters, pid_controller
from ambid.control.stepper import ControllerStepper
from ambid.plant.fem_rotor import assemble_rotor
from ambid.plant.rig import load_rig, make_rig
from ambid.plant.simulator import PlantSimulator
from ambid.plant.true_rig import levitated_plant, true_linear_model
from scipy import linalg

REPO = Path(__file__).resolve().parents[2]
SPEED_RPM = 12_000.0
OMEGA = SPEED_RPM * np.pi / 30


def test_sleeve_unbalance_is_m_e_omega_squared_at_its_bearing():
    """The sleeves sit on the bearings, so their unbalance must drive the rotor exactly like a bearing
    force m e Omega^2 [cos(theta + phi), sin(theta + phi)] with m the sleeve's own mass, by hand."""
    e, phi = 3e-6, np.deg2rad(35.0)
    rig = make_rig({"rotor_speed_rpm": SPEED_RPM, "sleeve_a_eccentricity_m": e,
                    "sleeve_a_unbalance_phase_deg": 35.0})
    v = rig.values
    m = v["density_kg_m3"] * np.pi / 4 * (v["sleeve_diameter_m"] ** 2 - v["shaft_diameter_m"] ** 2) \
        * v["sleeve_length_m"]
    p, _ = levitated_plant(rig)
    nr = p.n_rotor
    for theta in (0.0, 1.1, 4.0):
        force = m * e * OMEGA**2 * np.array([np.cos(theta + phi), 0.0, np.sin(theta + phi), 0.0])  # A x, B x, A y, B y
        drive = p.b_unbalance @ [np.cos(theta), np.sin(theta)]
        np.testing.assert_allclose(drive[:nr], rig.rotor_model().b @ force, rtol=1e-9, atol=1e-12)
        assert not drive[nr:].any()  # the pedestals feel it only through the magnets
        assert np.hypot(force[0], force[2]) == pytest.approx(m * e * OMEGA**2, rel=1e-12)
    # standstill: no unbalance force, however eccentric
    assert levitated_plant(make_rig({"sleeve_a_eccentricity_m": e}))[0].b_unbalance is None


def test_simulator_integrates_the_rotating_unbalance_exactly():
    """Open loop, constant current, no noise: the simulator's samples against the continuous model driven
    by the continuous rotating force, solved here with the rotating phasor as extra states (scipy)."""
    rig = make_rig({"rotor_speed_rpm": SPEED_RPM, "stack_eccentricity_m": 5e-6, "stack_unbalance_phase_deg": 70.0,
                    "sensor_noise_m": 0.0})
    sim = PlantSimulator(rig)
    sim.start_levitated()
    p, u0 = sim.plant, sim.operating_point.current_a
    n, steps = p.n_states, 60
    ys = []
    for _ in range(steps):
        sim.step(u0)
        ys.append(sim.output())
    # augmented: [x; cos theta; sin theta; 1], x' = A x + B_u u0 + b_c + B_unb [cos; sin]
    aug = np.zeros((n + 3, n + 3))
    aug[:n, :n], aug[:n, n:n + 2] = p.a, p.b_unbalance
    aug[:n, n + 2] = p.b_u @ u0 + p.b_c
    aug[n:n + 2, n:n + 2] = [[0.0, -OMEGA], [OMEGA, 0.0]]
    z = np.concatenate([sim.operating_point.state, [1.0, 0.0, 1.0]])
    step = linalg.expm(aug * rig.dt)
    want = []
    for _ in range(steps):
        z = step @ z
        want.append(p.c_y @ z[:n])
    want, ys = np.array(want), np.array(ys)
    assert np.abs(want).max() > 1e-8  # the unbalance moved the rotor measurably
    np.testing.assert_allclose(ys, want, atol=1e-6 * np.abs(want).max())
    assert sim.rotor_angle_rad == pytest.approx((OMEGA * rig.dt * steps) % (2 * np.pi), abs=1e-9)


def test_runout_is_in_y_and_not_in_the_rotor_motion():
    """Same currents with and without runout: identical states, and y differs by the probes' runout as
    written here from the rig file's harmonics (the y probe a quarter turn on, track B turned by beta)."""
    base = {"rotor_speed_rpm": SPEED_RPM, "sensor_noise_m": 0.0, "stack_eccentricity_m": 2e-6}
    ro = {"runout_mech_1x_m": 3e-6, "runout_mech_1x_phase_deg": 30.0, "runout_mech_2x_m": 1e-6,
          "runout_elec_3x_m": 0.5e-6, "runout_elec_3x_phase_deg": -80.0, "runout_b_phase_deg": 40.0}
    sims = [PlantSimulator(make_rig(base)), PlantSimulator(make_rig({**base, **ro}))]
    rng = np.random.default_rng(3)
    us = 0.01 * rng.standard_normal((300, 4))
    for sim in sims:
        sim.start_levitated()
    out = [[], []]
    for u in us:
        for j, sim in enumerate(sims):
            sim.step(sim.operating_point.current_a + u)
            out[j].append((sim.x.copy(), sim.output()))
    beta = np.deg2rad(40.0)
    for k, ((x0, y0), (x1, y1)) in enumerate(zip(*out), start=1):
        np.testing.assert_array_equal(x0, x1)
        th = OMEGA * rig_dt() * k
        want = []
        for track, quarter in ((0, 0), (beta, 0), (0, np.pi / 2), (beta, np.pi / 2)):
            want.append(3e-6 * np.cos(th - quarter + np.deg2rad(30) + track)
                        + 1e-6 * np.cos(2 * (th - quarter + track))
                        + 0.5e-6 * np.cos(3 * (th - quarter + track) - np.deg2rad(80)))
        np.testing.assert_allclose(y1 - y0, want, atol=1e-13)
    # 1X runout reads as a forward circular orbit at probe A: y lags x by a quarter turn
    th = OMEGA * rig_dt() * 5
    assert np.cos(th + np.deg2rad(30) - np.pi / 2) == pytest.approx(np.sin(th + np.deg2rad(30)))


def rig_dt() -> float:
    return make_rig().dt


def test_whirl_frequencies_at_speed_match_the_full_finite_element_eigen_analysis():
    """The rig's reduced rotor at 12,000 rpm against the quadratic eigenproblem of the full finite-element
    matrices, M q'' + Omega G q' + K q = 0 (undamped), and the whirl direction of each bending mode from the
    eigenvector (forward: p = x + j y turns with the spin)."""
    rig = make_rig({"rotor_speed_rpm": SPEED_RPM, "modal_damping_ratio": 0.0})
    fe = assemble_rotor(rig.rotor_geometry)
    n = fe.mass.shape[0]
    minv = np.linalg.inv(fe.mass)
    a_full = np.block([[np.zeros((n, n)), np.eye(n)], [-minv @ fe.stiffness, -OMEGA * minv @ fe.gyroscopic]])
    s_full, v_full = np.linalg.eig(a_full)
    rotor = rig.rotor_model()
    s_red, v_red = np.linalg.eig(rotor.a)
    nb = 2  # the first two bending modes, each split into a backward and a forward whirl

    def bending(s, vecs, c_x, c_y):
        keep = (s.imag > 2 * np.pi * 100) & (s.imag < 2 * np.pi * 1200)
        f = s.imag[keep] / (2 * np.pi)
        px, py = c_x @ vecs[:, keep], c_y @ vecs[:, keep]
        forward = np.abs(px + 1j * py) > np.abs(px - 1j * py)
        order = np.argsort(f)
        return f[order], forward[order]

    from ambid.plant.fem_rotor import DOF_X, DOF_Y, dof_index, node_at
    node = node_at(fe.node_z_m, rig.shaft_length_m / 2 + rig.bearing_a_z_m)
    cx, cy = np.zeros(2 * n), np.zeros(2 * n)
    cx[dof_index(node, DOF_X)], cy[dof_index(node, DOF_Y)] = 1.0, 1.0
    f_full, fw_full = bending(s_full, v_full, cx, cy)
    f_red, fw_red = bending(s_red, v_red, rotor.c_bearing[0], rotor.c_bearing[2])
    assert f_red.size == f_full.size == 2 * nb
    np.testing.assert_allclose(f_red, f_full, rtol=2e-4)
    # each mode splits: the lower of a pair whirls backward, the higher forward
    assert list(fw_full) == list(fw_red) == [False, True] * nb
    standstill = make_rig({"modal_damping_ratio": 0.0}).rotor_model().flexible_freq_hz[:nb]
    assert np.all(f_red[0::2] < standstill) and np.all(f_red[1::2] > standstill)


@pytest.mark.parametrize("kind", ["pid", "lqg"])
def test_the_spinning_rig_with_unbalance_and_runout_levitates(kind):
    rig = load_rig(REPO / "rigs" / "spinning.yaml")
    assert rig.unbalance_planes() and true_linear_model(rig).a.shape  # the file carries unbalance
    model = pid_controller(PidParameters(), rig.dt) if kind == "pid" else lqg_controller(rig)
    check_controller_on_rig(rig, model)
    sim = PlantSimulator(rig, seed=7, nonlinear_magnets=True)
    ctl = ControllerStepper(model, rig.current_limit_a)
    n, last = 12_000, 5_000
    contact = np.zeros(n, bool)
    radius, y_log = np.empty((n, 2)), np.empty((n, 4))
    for k in range(n):
        y = sim.output()
        _, contact[k] = sim.step(ctl.step(y))
        radius[k], y_log[k] = sim.bearing_radius(), y
    assert contact[0] and not contact[-last:].any()
    assert radius[-last:].max() < 0.1 * rig.backup_clearance_m
    # the rotor angle, turned sample by sample (contact sub-steps included), is still Omega t
    assert sim.rotor_angle_rad == pytest.approx((rig.speed_rad_s * rig.dt * n) % (2 * np.pi), abs=1e-10)
    # the synchronous response is there: y carries a 1X line well above the noise
    spec = np.abs(np.fft.rfft(y_log[-last:, 0])) / last
    f = np.fft.rfftfreq(last, rig.dt)
    assert spec[np.argmin(np.abs(f - 200.0))] > 10 * np.median(spec)


def test_an_imported_rotor_cannot_carry_a_stack_unbalance():
    with pytest.raises(ValueError, match="imported rotor"):
        make_rig({"stack_eccentricity_m": 1e-6}, rotor_import=make_rig().rotor_model())
