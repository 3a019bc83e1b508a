"""Issue 20's end-to-end case: a rotor in a six-DOF-per-node layout of the test's own (axial and torsional
DOFs included, as rotordynamics codes such as ROSS hand it over), imported from its M and K, identified
under the LQG and under a state-space controller the test writes itself; the fitted flexible modes against
the test's own eigen-analysis of that rotor with the magnets' negative stiffness."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
from six_dof_rotor import lateral_modes_with_magnets, six_dof_rotor  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
DT = 1e-4


def site_controller(kp=12_000.0, ti=0.05, td=1.5e-3, n=10.0, lowpass_hz=5_000.0) -> dict:
    """The site's own controller, as its owner would hand it over: per axis a PID with a filtered
    derivative and a low-pass, ic = -C(s) y, discretised (Tustin) with one sample of computational delay,
    as one discrete state space y (4) -> ic (4)."""
    num = kp * (np.poly1d([ti, 1.0]) * np.poly1d([td / n, 1.0]) + np.poly1d([ti * td, 0.0, 0.0]))
    den = np.poly1d([ti, 0.0]) * np.poly1d([td / n, 1.0]) * np.poly1d([1 / (2 * np.pi * lowpass_hz), 1.0])
    bz, az, _ = signal.cont2discrete((-num.coeffs, den.coeffs), DT, method="bilinear")
    bz = np.atleast_1d(np.squeeze(bz))
    a, b, c, d = signal.tf2ss(bz, np.concatenate([az, [0.0]]))  # z^-1: the computational delay
    assert np.all(d == 0)
    axes = np.eye(4)
    return dict(A=np.kron(axes, a), B=np.kron(axes, b), C=np.kron(axes, c), D=np.kron(axes, d), dt=DT)


def operating_point_ks(rotor_mass_kg: float, true_ki_factor: float = 1.03, true_ks_factor: float = 0.95) -> float:
    """The true magnets' ks [N/m] where the rotor levitates (eqs. 2.12-2.17 of the seed, the rig's default
    magnet data): ks (1 + (ic0 / ib)^2), each bearing axis carrying m g / (2 sqrt 2) of a symmetric rotor."""
    k = 4e-7 * np.pi * 200**2 * 4.5e-4 / 4
    ib, s0, c = 3.0, 0.6e-3, np.cos(np.radians(22.5))
    ki, ks = true_ki_factor * 4 * k * ib * c / s0**2, true_ks_factor * 4 * k * ib**2 * c / s0**3
    ic0 = rotor_mass_kg * 9.81 / (2 * np.sqrt(2)) / ki
    return ks * (1 + (ic0 / ib) ** 2)


@pytest.fixture(scope="module")
def rig_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("own_rotor")
    # 16 elements of 60 mm shaft, a 19 kg disk mid-span, bearings 0.15 m and sensors 0.10 m from the
    # ends; a heavy foundation (no pedestal mode), so the rotor on its magnets is all there is to find
    rotor = six_dof_rotor(n_el=16, diameter_m=0.06, bearing_node=3, sensor_node=2)
    np.savez(d / "rotor.npz", **rotor)
    np.savez(d / "site_controller.npz", **site_controller())
    (d / "rig.yaml").write_text("name: own-rotor\nrotor_file: rotor.npz\nhousing_mass_kg: 1.0e4\n")
    return d, rotor


@pytest.mark.parametrize("controller", ["lqg", "site_controller.npz"])
def test_own_rotor_identified_under_its_controller(rig_dir, ros_env, controller):
    d, rotor = rig_dir
    mass = float(np.sum(rotor["M"][np.ix_(rotor["x_dofs"], rotor["x_dofs"])]))
    expected = np.unique(np.round(lateral_modes_with_magnets(rotor, operating_point_ks(mass)), 6))[:2]
    spec = controller if controller == "lqg" else str(d / controller)
    out = d / f"run_{controller}"
    proc = subprocess.run([sys.executable, "-m", "ambid_cli.cli", "identify", "--rig", str(d / "rig.yaml"),
                           "--controller", spec, "--out", str(out), "--band", "20", "800", "--resolution", "5",
                           "--periods", "2", "--realisations", "1", "--transient-periods", "1", "--no-progress",
                           "--no-report"],
                          env=ros_env, cwd=REPO, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "ambid: rotor file: dropped 34 of 102 DOFs" in proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["controller"]["kind"] == ("lqg" if controller == "lqg" else "file")
    modes = sorted(m["freq_hz"] for m in summary["fit"]["modes"] if m["stable"] and m["freq_hz"] > 100.0)
    assert len(modes) == 2, summary["fit"]["modes"]
    assert np.allclose(modes, expected, rtol=5e-3), (modes, expected)
    damping = [m["damping"] for m in summary["fit"]["modes"] if m["freq_hz"] > 100.0]
    assert np.allclose(damping, 0.005, rtol=0.2)  # the rig's modal damping of the free-free modes
