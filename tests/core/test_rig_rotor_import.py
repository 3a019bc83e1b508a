"""A user's rotor model replacing the finite-element rotor: files in, same rig out."""

import numpy as np
import pytest
from ambid.plant.analytical import analytical_model
from ambid.plant.fem_rotor import DOF_X, DOF_Y, assemble_rotor, dof_index, node_at
from ambid.plant.rig import load_rig, make_rig
from ambid.plant.rotor_import import load_rotor, save_rotor

FREQ = np.array([5.0, 60.0, 300.0, 900.0])


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


@pytest.mark.parametrize("ext", [".npz", ".mat"])
def test_state_space_round_trip(tmp_path, ext):
    rig = make_rig()
    path = tmp_path / f"rotor{ext}"
    save_rotor(path, rig.rotor_model())
    loaded = load_rotor(path)
    ref = rig.rotor_model()
    for name in ("a", "b", "c_bearing", "c_sensor", "b_gravity"):
        assert np.array_equal(getattr(loaded, name), getattr(ref, name)), name
    user = make_rig(rotor_import=loaded)
    assert _rel(analytical_model(user).freqresp(FREQ), analytical_model(rig).freqresp(FREQ)) < 1e-12
    assert user.to_dict()["rotor_file"] == str(path)


def test_second_order_matrices_reduce_to_the_built_in_rotor(tmp_path):
    rig = make_rig()
    fem = assemble_rotor(rig.rotor_geometry)
    z, half = fem.node_z_m, rig.shaft_length_m / 2

    def axes(za, zb):
        na, nb = node_at(z, half + za), node_at(z, half + zb)
        return [int(dof_index(na, DOF_X)), int(dof_index(nb, DOF_X)), int(dof_index(na, DOF_Y)),
                int(dof_index(nb, DOF_Y))]

    nodes = np.arange(z.size)
    path = tmp_path / "user_rotor.npz"
    np.savez(path, M=fem.mass, K=fem.stiffness, G=fem.gyroscopic,
             bearing_dofs=axes(rig.bearing_a_z_m, rig.bearing_b_z_m),
             sensor_dofs=axes(rig.sensor_a_z_m, rig.sensor_b_z_m),
             x_dofs=dof_index(nodes, DOF_X), y_dofs=dof_index(nodes, DOF_Y), max_freq_hz=2000.0)
    yaml_path = tmp_path / "user.yaml"
    yaml_path.write_text("rotor_file: user_rotor.npz\nhousing_freq_hz: 150\n")  # relative to the YAML
    user = load_rig(yaml_path)
    assert user.rotor_import is not None and user.housing_freq_hz == 150.0
    assert user.rotor_mass_kg == pytest.approx(rig.rotor_mass_kg, rel=1e-9)
    builtin = make_rig({"housing_freq_hz": 150.0})
    # same modes (2 rigid + 3 bending per plane below 2 kHz), same modal damping: same FRF
    assert _rel(analytical_model(user).freqresp(FREQ), analytical_model(builtin).freqresp(FREQ)) < 1e-6
    # gravity: the same weight on the rotor, so the same levitation current
    from ambid.plant.true_rig import operating_point
    assert operating_point(user).current_a == pytest.approx(operating_point(builtin).current_a, rel=1e-6)


def test_bad_rotor_files_name_the_key(tmp_path):
    path = tmp_path / "r.npz"
    np.savez(path, A=np.zeros((2, 2)), B=np.zeros((2, 4)))
    with pytest.raises(ValueError, match="'C'"):
        load_rotor(path)
    np.savez(path, A=np.zeros((2, 2)), B=np.zeros((2, 3)), C=np.zeros((8, 2)), mass_kg=1.0)
    with pytest.raises(ValueError, match="B .*shape"):
        load_rotor(path)
    np.savez(path, M=np.eye(8), K=np.eye(8), sensor_dofs=[0, 1, 2, 3])
    with pytest.raises(ValueError, match="bearing_dofs"):
        load_rotor(path)
    # a supported (not free-free) rotor has no rigid-body inverse mass at the bearings
    np.savez(path, M=np.eye(8), K=np.eye(8) * 1e6, bearing_dofs=[0, 1, 2, 3], sensor_dofs=[4, 5, 6, 7],
             mass_kg=1.0)
    with pytest.raises(ValueError, match="free-free"):
        load_rotor(path)
