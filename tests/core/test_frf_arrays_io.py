"""Loading user arrays from .npz, .mat and .csv (ambid.frf.arrays_io)."""

import numpy as np
import pytest
from ambid.frf import load_arrays, stack_channels
from scipy.io import savemat


@pytest.fixture
def channels():
    rng = np.random.default_rng(0)
    return {"y1": rng.standard_normal(50), "y2": rng.standard_normal(50), "r1": rng.standard_normal(50)}


def _write(path, data):
    if path.suffix == ".npz":
        np.savez(path, **data)
    elif path.suffix == ".mat":
        savemat(path, data)               # 1-D arrays are saved as (1, n) rows
    else:
        names = list(data)
        body = np.column_stack([data[n] for n in names])
        np.savetxt(path, body, delimiter=",", header=",".join(names), comments="")


@pytest.mark.parametrize("ext", [".npz", ".mat", ".csv"])
def test_round_trip(tmp_path, channels, ext):
    path = tmp_path / f"rec{ext}"
    _write(path, channels)
    data = load_arrays(path, ["y2", "r1"], n_samples=50)
    assert list(data) == ["y2", "r1"]
    np.testing.assert_allclose(data["y2"], channels["y2"], rtol=1e-15 if ext != ".csv" else 1e-8)
    assert set(load_arrays(path)) == set(channels)
    stacked = stack_channels(data, ["r1", "y2"])
    assert stacked.shape == (50, 2)
    np.testing.assert_allclose(stacked[:, 0], data["r1"])


@pytest.mark.parametrize("ext", [".npz", ".mat", ".csv"])
def test_missing_channel_and_nan(tmp_path, channels, ext):
    path = tmp_path / f"rec{ext}"
    _write(path, channels)
    with pytest.raises(ValueError, match=r"missing channel.*'u1'.*has \['r1', 'y1', 'y2'\]"):
        load_arrays(path, ["y1", "u1"])
    bad = dict(channels)
    bad["y1"] = bad["y1"].copy()
    bad["y1"][7] = np.nan
    _write(path, bad)
    with pytest.raises(ValueError, match="'y1' has 1 NaN/inf value.*sample 7"):
        load_arrays(path)


def test_length_errors(tmp_path, channels):
    path = tmp_path / "rec.npz"
    np.savez(path, y1=channels["y1"], y2=channels["y2"][:40])
    with pytest.raises(ValueError, match="different lengths"):
        load_arrays(path)
    np.savez(path, y1=channels["y1"])
    with pytest.raises(ValueError, match="expected 64"):
        load_arrays(path, n_samples=64)


def test_multicolumn_channel_and_mat_matrix(tmp_path):
    y = np.arange(20.0).reshape(10, 2)
    savemat(tmp_path / "m.mat", {"y": y, "r": np.arange(10.0)[:, None]})
    data = load_arrays(tmp_path / "m.mat")
    assert data["y"].shape == (10, 2) and data["r"].shape == (10,)
    assert stack_channels(data, ["y", "r"]).shape == (10, 3)


def test_bad_files(tmp_path):
    (tmp_path / "a.txt").write_text("1,2\n")
    with pytest.raises(ValueError, match="unsupported extension"):
        load_arrays(tmp_path / "a.txt")
    with pytest.raises(FileNotFoundError):
        load_arrays(tmp_path / "missing.npz")
    (tmp_path / "b.csv").write_text("y1,y2\n1,2\n3\n")
    with pytest.raises(ValueError, match="2 numeric fields"):
        load_arrays(tmp_path / "b.csv")
    (tmp_path / "c.csv").write_text("y1,y1\n1,2\n")
    with pytest.raises(ValueError, match="unique"):
        load_arrays(tmp_path / "c.csv")
    (tmp_path / "d.csv").write_text("y1,y2\n1,\n3,4\n")
    with pytest.raises(ValueError, match="'y2' has 1 NaN"):
        load_arrays(tmp_path / "d.csv")
    np.savez(tmp_path / "e.npz", z=np.ones(3) * 1j)
    with pytest.raises(ValueError, match="complex"):
        load_arrays(tmp_path / "e.npz")
