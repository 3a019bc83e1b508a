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


def _six_dof_file(tmp_path, **changes):
    from six_dof_rotor import six_dof_rotor

    rotor = {**six_dof_rotor(), **changes}
    path = tmp_path / "ross_like.npz"
    np.savez(path, **rotor)
    return path, rotor


def _lateral(rotor):
    """The test's own lateral-only matrices: the DOFs ux, uy, rx, ry of every node."""
    from six_dof_rotor import RX, RY, UX, UY

    n = rotor["M"].shape[0]
    keep = np.sort(np.concatenate([np.arange(d, n, 6) for d in (UX, UY, RX, RY)]))
    return keep, rotor["M"][np.ix_(keep, keep)], rotor["K"][np.ix_(keep, keep)]


def test_six_dof_layout_drops_the_axial_and_torsional_dofs_and_says_so(tmp_path):
    from scipy import linalg

    path, rotor = _six_dof_file(tmp_path)
    model = load_rotor(path)
    assert len(model.notes) == 1 and "dropped 18 of 54 DOFs" in model.notes[0]
    _, m, k = _lateral(rotor)
    lam = linalg.eigh(k, m, eigvals_only=True)
    own = np.sqrt(lam[lam > 1.0]) / (2 * np.pi)
    own = own[own < 5000.0]
    assert np.allclose(np.sort(model.flexible_freq_hz), own, rtol=1e-9)
    assert model.mass_kg == pytest.approx(np.sum(rotor["M"][np.ix_(rotor["x_dofs"], rotor["x_dofs"])]), rel=1e-12)
    # free-free: the rig levitates it (its operating point exists) and the rigid body has its mass
    from ambid.plant.true_rig import operating_point

    rig = make_rig({"housing_mass_kg": 1e4}, rotor_import=model)
    assert np.all(np.isfinite(operating_point(rig).current_a))


def test_support_springs_in_the_stiffness_are_named(tmp_path):
    from six_dof_rotor import six_dof_rotor

    rotor = six_dof_rotor()
    k = rotor["K"].copy()
    for i in rotor["bearing_dofs"]:  # a ROSS rotor built with its bearing elements
        k[i, i] += 2.5e7
    path, _ = _six_dof_file(tmp_path, K=k)
    with pytest.raises(ValueError, match=r"not free-free: 0 of the 4 lateral rigid-body modes.*"
                                         rf"DOF {rotor['bearing_dofs'][0]} \(2\.5e\+07 N/m\)"):
        load_rotor(path)


def test_gyroscopic_matrix_is_scaled_by_the_rigs_speed(tmp_path):
    """The disk's polar inertia couples the tilts at speed: the import's whirl frequencies against the
    test's own eigen-analysis of the full second-order model M q'' + Omega G q' + K q = 0."""
    from six_dof_rotor import RX, RY, six_dof_rotor

    rotor = six_dof_rotor()
    n = rotor["M"].shape[0]
    g = np.zeros((n, n))
    disk, ip = 6 * 4, 0.30
    g[disk + RX, disk + RY], g[disk + RY, disk + RX] = ip, -ip
    path, rotor = _six_dof_file(tmp_path, G=g, D=np.zeros((n, n)))
    rpm = 12_000.0
    omega = rpm * np.pi / 30
    keep, m, k = _lateral(rotor)
    gl = g[np.ix_(keep, keep)]
    z = np.zeros_like(m)
    first = np.block([[z, np.eye(len(keep))], [-np.linalg.solve(m, k), -omega * np.linalg.solve(m, gl)]])
    own = np.sort(np.abs(np.linalg.eigvals(first).imag)) / (2 * np.pi)
    own = np.unique(np.round(own[(own > 1.0) & (own < 700.0)], 6))
    model = load_rotor(path, speed_rpm=rpm)
    got = np.abs(np.linalg.eigvals(model.a).imag) / (2 * np.pi)
    got = np.unique(np.round(got[(got > 1.0) & (got < 700.0)], 6))
    assert got.size == own.size == 4  # the first two bending modes, each split into backward and forward
    assert np.allclose(got, own, rtol=2e-3)  # modal truncation at 5 kHz
    assert got[1] - got[0] > 1.0  # the split is real
    rig = load_rig(_rig_yaml(tmp_path, path, f"rotor_speed_rpm: {rpm}\n"))
    assert np.allclose(np.linalg.eigvals(rig.rotor_import.a), np.linalg.eigvals(model.a))


def _rig_yaml(tmp_path, rotor_path, extra=""):
    p = tmp_path / "rig.yaml"
    p.write_text(f"rotor_file: {rotor_path.name}\n{extra}")
    return p


def test_the_commands_say_what_the_import_dropped(tmp_path, capsys):
    from ambid_cli.commands.inputs import rig_file

    path, _ = _six_dof_file(tmp_path)
    rig = rig_file(_rig_yaml(tmp_path, path))
    err = capsys.readouterr().err.strip().splitlines()
    assert rig.rotor_import is not None
    assert len(err) == 1 and err[0].startswith("ambid: rotor file: dropped 18 of 54 DOFs")


def _damaged(tmp_path, kind: str, ext: str):
    """A rotor file that cannot be read: the kinds a user's disk and tools produce."""
    from scipy import io as sio
    from six_dof_rotor import six_dof_rotor

    p = tmp_path / f"{kind}{ext}"
    good = tmp_path / f"good{ext}"
    (np.savez if ext == ".npz" else sio.savemat)(good, six_dof_rotor())
    data = good.read_bytes()
    if kind == "folder":
        p.mkdir()
    elif kind == "empty":
        p.write_bytes(b"")
    elif kind == "random":
        p.write_bytes(np.random.default_rng(2).bytes(3000))
    elif kind == "truncated":
        p.write_bytes(data[:len(data) // 2])
    return p


@pytest.mark.parametrize("ext", [".npz", ".mat"])
@pytest.mark.parametrize("kind, message", [
    ("missing", "does not exist"), ("folder", "is a folder"), ("empty", "is empty"),
    ("random", r"is not an \.npz file|is not a MATLAB \.mat file"),
    ("truncated", r"is not an \.npz file|damaged or cut short"),
])
def test_rotor_files_that_cannot_be_read_are_named_with_the_fix(tmp_path, kind, ext, message):
    path = _damaged(tmp_path, kind, ext)
    with pytest.raises(ValueError, match=message) as err:
        load_rotor(path)
    assert str(path) in str(err.value) and "give M, K" in str(err.value) and "\n" not in str(err.value)


def test_a_rotor_file_of_pickled_objects_is_refused(tmp_path):
    path = tmp_path / "objects.npz"
    np.savez(path, M=np.array([{"m": 1}], dtype=object))
    with pytest.raises(ValueError, match="holds object \\(pickled\\) arrays"):
        load_rotor(path)


@pytest.mark.parametrize("key", ["M", "K"])
def test_a_non_symmetric_mass_or_stiffness_matrix_is_named(tmp_path, key):
    from six_dof_rotor import six_dof_rotor

    bad = six_dof_rotor()[key].copy()
    bad[6, 7] += 0.01 * np.abs(bad).max()  # a one-sided entry: a transcription slip, or G put into K
    path, _ = _six_dof_file(tmp_path, **{key: bad})
    with pytest.raises(ValueError, match=rf"{key} \(\w+ matrix\) is not symmetric: {key}\[6, 7\]"):
        load_rotor(path)


@pytest.mark.parametrize("dofs, message", [
    ([6, 6, 7, 43], "names a DOF twice"),
    ([6 + 5, 42, 7, 43], "DOF 11 is not in x_dofs"),   # the torsion DOF of node 1 where its ux belongs
    ([6, 42, 6 + 2, 43], "DOF 8 is not in y_dofs"),    # the axial DOF
])
def test_bearing_dofs_must_be_four_lateral_translations(tmp_path, dofs, message):
    path, _ = _six_dof_file(tmp_path, bearing_dofs=np.array(dofs))
    with pytest.raises(ValueError, match=message):
        load_rotor(path)


def test_a_mat_v73_rotor_file_reads_as_its_npz(tmp_path):
    """MATLAB's -v7.3 is HDF5 behind a 512-byte header, column-major: written here as MATLAB lays it out."""
    import h5py
    from six_dof_rotor import six_dof_rotor

    rotor = six_dof_rotor()
    path = tmp_path / "rotor73.mat"
    with h5py.File(path, "w", userblock_size=512) as f:
        for key, value in rotor.items():
            value = np.atleast_2d(np.asarray(value, dtype=float))
            if value.shape[0] == 1:
                value = value.T   # MATLAB saves a vector as a column, n x 1
            f.create_dataset(key, data=value.T).attrs["MATLAB_class"] = np.bytes_("double")
    with open(path, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(116) + b"\x00" * 8 + b"\x00\x02IM")
    npz, _ = _six_dof_file(tmp_path)
    got, want = load_rotor(path), load_rotor(npz)
    assert np.array_equal(got.a, want.a) and np.array_equal(got.c_sensor, want.c_sensor)
