"""The five-axis rig (rigs/five_axis.yaml): the axial bearing of chapter 2 by hand, its decoupling from the
radial planes, the simulator's compiled step of five axes against numpy, both controllers lifting the rotor
off on all five axes, and the physical model reproducing the true rig."""

from pathlib import Path

import numpy as np
import pytest
from ambid.channels import FIVE_AXIS, RADIAL
from ambid.control.kinds import checked_design
from ambid.control.stepper import ControllerStepper
from ambid.fit.model_update import nominal_parameters, physical_frf, true_parameters
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import load_rig, make_rig
from ambid.plant.simulator import CONTACT_SUBSTEPS, PlantSimulator
from ambid.plant.true_rig import delayed_zoh, true_linear_model, zoh_blocks

REPO = Path(__file__).resolve().parents[2]
RIG = load_rig(REPO / "rigs" / "five_axis.yaml")
MU0 = 4e-7 * np.pi


def test_the_axial_magnet_amplifier_and_disk_by_hand():
    assert RIG.layout == FIVE_AXIS and make_rig().layout == RADIAL
    nc, aa, s0, ib = 80.0, 4.0e-3, 0.6e-3, 3.0
    k = 0.25 * MU0 * nc**2 * aa                 # eq. 2.12
    ki, ks = 4 * k * ib / s0**2, 4 * k * ib**2 / s0**3   # eqs. 2.16-2.17 with alpha = 0: along the axis
    d = RIG.derived()
    assert d["axial_ki_n_per_a"] == pytest.approx(ki, rel=1e-12) and ki == pytest.approx(268.083, rel=1e-5)
    assert d["axial_ks_n_per_m"] == pytest.approx(ks, rel=1e-12)
    assert d["axial_true_ki_n_per_a"] == pytest.approx(1.02 * ki, rel=1e-12)
    assert d["axial_true_ks_n_per_m"] == pytest.approx(0.96 * ks, rel=1e-12)
    inductance = MU0 * nc**2 * aa / (2 * s0)
    w_bw = np.log(9.0) * 560.0 / (inductance * (ib + 3.0))          # eq. 2.24
    assert d["axial_current_loop_bandwidth_hz"] == pytest.approx(w_bw / (2 * np.pi), rel=1e-12)
    disk = 7810.0 * np.pi / 4 * (0.16**2 - 0.06**2) * 0.02
    assert d["thrust_disk_mass_kg"] == pytest.approx(disk, rel=1e-12)
    assert RIG.rotor_mass_kg == pytest.approx(make_rig().rotor_mass_kg + disk, rel=1e-9)
    # the analytical model's axial instability is sqrt(ks / m) of the whole rotor (a free mass)
    poles = analytical_model(RIG).poles()
    assert np.min(np.abs(poles - np.sqrt(ks / RIG.rotor_mass_kg))) < 1e-6 * np.sqrt(ks / RIG.rotor_mass_kg)


def test_the_axial_axis_is_decoupled_from_the_radial_planes():
    f = np.array([5.0, 40.0, 177.0, 280.0, 850.0])
    for model in (analytical_model(RIG), true_linear_model(RIG, discrete=True)):
        g = model.freqresp(f)
        assert model.input_names[-1] == "u_z" and model.output_names[-1] == "y_z"
        assert np.abs(g[:, 4, :4]).max() < 1e-8 * np.abs(g).max()   # zero but for the rounding of expm
        assert np.abs(g[:, :4, 4]).max() < 1e-8 * np.abs(g).max()
    # with the disk's mass and inertia in the radial rotor, the radial block is the rotor's, not the default's
    radial = analytical_model(make_rig({"thrust_disk_z_m": 0.37})).freqresp(f)
    assert not np.allclose(radial, analytical_model(RIG).freqresp(f)[:, :4, :4])


def _reference_step(sim, x, u_prev, u, nonlinear):
    """One free-flight sample from the plant's continuous model, built here from its blocks (any axes)."""
    rig, p = sim.rig, sim.plant
    u_c = np.clip(u, -rig.current_limit_a, rig.current_limit_a)
    gap, cur = p.c_gap @ x, p.c_current @ x
    f = np.zeros(p.n_axes)
    if nonlinear:  # eq. 2.14 of each axis' own true magnet, minus its affine linearisation
        for j, mag in enumerate(rig.axis_magnets(true=True)):
            f[j] = mag.force(cur[j], gap[j]) - p.force_const[j] - p.ki[j] * cur[j] - p.ks[j] * gap[j]
    phi, g1, g0 = delayed_zoh(p.a, p.b_u, rig.dt, p.delay_s)
    _, gw = zoh_blocks(p.a, np.column_stack([p.b_f, p.b_s, p.b_c]), rig.dt)
    return phi @ x + g0 @ u_prev + g1 @ u_c + gw @ np.concatenate([f, np.zeros(p.n_axes), [1.0]]), u_c


@pytest.mark.parametrize("nonlinear", [False, True])
def test_the_compiled_step_of_five_axes_is_the_numpy_step(nonlinear):
    sim = PlantSimulator(make_rig({"axial_bearing": 1, "sensor_noise_m": 0.0, "axial_sensor_noise_m": 0.0}),
                         seed=1, nonlinear_magnets=nonlinear)
    sim.start_levitated()
    ic0 = sim.operating_point.current_a
    assert ic0[4] == 0.0 and np.all(ic0[:4] > 0.5)   # no gravity along the axis
    rng = np.random.default_rng(3)
    x, u_prev = sim.x.copy(), ic0.copy()
    for k in range(40):
        u = ic0 + 0.1 * rng.standard_normal(5)
        if k == 9:
            u[4] = -9.0   # the axial amplifier clips too
        clipped, contact = sim.step(u.tolist())
        x, u_prev = _reference_step(sim, x, u_prev, u, nonlinear)
        assert clipped == (k == 9) and not contact
        assert np.allclose(sim.x, x, rtol=1e-12, atol=1e-12 * np.abs(x).max())
        assert np.allclose(sim.output(), sim.plant.c_y @ x, rtol=1e-10, atol=1e-16)
    assert abs(sim.output()[4]) > 1e-8   # the axial axis moved


def test_the_disk_lands_on_the_axial_retainer():
    """Pulled along its axis at full current, the rotor lands on the axial retainer (contact sub-steps, push
    only) and rests there, the radial planes undisturbed."""
    rig = make_rig({"axial_bearing": 1, "sensor_noise_m": 0.0, "axial_sensor_noise_m": 0.0})
    sim = PlantSimulator(rig, seed=0, nonlinear_magnets=True)
    sim.start_levitated()
    push = sim.operating_point.current_a.copy()
    push[4] = rig.current_limit_a
    contacts, z = 0, []
    for _ in range(800):
        _, contact = sim.step(push.tolist())
        contacts += contact
        z.append(sim.bearing_displacement[4])
    clearance = rig.axial_backup_clearance_m
    assert contacts > 100 and max(z) < 0.7 * rig.axial_air_gap_m    # never near the magnet's pole face
    assert clearance < z[-1] < clearance + 0.1e-3                   # resting on the retainer, pressed in
    assert np.abs(sim.bearing_displacement[:4]).max() < 0.1 * rig.backup_clearance_m
    assert sim.bearing_radius().shape == (3,) and CONTACT_SUBSTEPS > 1


@pytest.mark.parametrize("kind", ["pid", "lqg"])
def test_both_controllers_levitate_the_five_axis_rotor_from_rest(kind):
    design = checked_design(kind, RIG)   # stable on the analytical and the true model
    assert design.model.input_names == FIVE_AXIS.outputs and design.model.output_names == FIVE_AXIS.controls
    sim = PlantSimulator(RIG, seed=4, nonlinear_magnets=True)
    ctl = ControllerStepper(design.model, design.current_limit_a)
    n, last = 8_000, 3_000
    y_log = np.empty((n, 5))
    contact = np.zeros(n, bool)
    for k in range(n):
        y = sim.output()
        _, contact[k] = sim.step(ctl.step(y))
        y_log[k] = y
    assert contact[0] and not contact[-last:].any()
    assert np.abs(y_log[-last:].mean(axis=0)).max() < 0.3e-6
    assert y_log[-last:, 4].std() < 5 * RIG.axial_sensor_noise_m


def test_the_physical_model_covers_the_five_axes():
    f = np.linspace(10.0, 1000.0, 60)
    nominal = physical_frf(RIG.rotor_model(), nominal_parameters(RIG), f, 0.0)
    assert np.allclose(nominal, analytical_model(RIG).freqresp(f), rtol=1e-7, atol=1e-9 * np.abs(nominal).max())
    true = {k: v for k, v in true_parameters(RIG).items() if not k.endswith(("_centre_n_per_a", "_centre_n_per_m"))}
    g = physical_frf(RIG.rotor_model(), true, f, RIG.dt)
    ref = true_linear_model(RIG, discrete=True).freqresp(f)
    err = np.linalg.norm(g - ref, axis=(1, 2)) / np.linalg.norm(ref, axis=(1, 2))
    assert np.median(err) < 1e-4   # the true rig's bearing A and B slopes differ by < 2 % (one ks_b_over_a)
