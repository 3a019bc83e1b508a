"""Time-record readers and writers against second implementations: scipy.io (MAT v5), h5py laid out as
MATLAB writes v7.3, numpy (NPZ) and the csv module; the chunked reads give the same numbers whatever the
chunk size, and a SampleBlock encoded here reads back through the .msg-driven CDR codec."""

from __future__ import annotations

import csv

import h5py
import numpy as np
import pytest
import scipy.io as sio
from ambid.records import open_record, write_record
from ambid.recording.blocks import decode_sample_block, encode_sample_block
from rig_records_testbench import write_logger_csv, write_matlab73
from session_testbench import SAMPLE_BLOCK, block_message, encoder

RNG = np.random.default_rng(7)
X = RNG.standard_normal((12_345, 4)) * np.array([1e-5, 1.0, 3.0, 1e3])
NAMES = ["t", "y_a_x", "u_a_x", "r_a_x"]


def _read(path, names, chunk):
    rec = open_record(path)
    parts = list(rec.chunks(names, chunk))
    assert [p[0] for p in parts] == list(range(0, len(X), chunk))
    return rec, np.vstack([p[1] for p in parts])


@pytest.mark.parametrize("chunk", [1000, 4096, 20_000])
def test_files_as_matlab_numpy_and_loggers_write_them(tmp_path, chunk):
    sio.savemat(tmp_path / "v5c.mat", {"data": X, "names": np.array(NAMES, dtype=object), "extra": X[:, 1]},
                do_compression=True)
    sio.savemat(tmp_path / "v5u.mat", {n: X[:, [i]] for i, n in enumerate(NAMES)}, do_compression=False)
    write_matlab73(tmp_path / "v73.mat", X, NAMES)
    np.savez(tmp_path / "vec.npz", **{n: X[:, i] for i, n in enumerate(NAMES)})
    np.savez_compressed(tmp_path / "mat.npz", data=X, names=np.array(NAMES))
    write_logger_csv(tmp_path / "eu.csv", {n: X[:, i] for i, n in enumerate(NAMES)}, np.arange(len(X)) * 0.1)
    with open(tmp_path / "us.csv", "w", newline="") as f:   # what Python's csv module writes
        w = csv.writer(f)
        w.writerow(NAMES)
        w.writerows(X.tolist())
    want = X[:, [3, 0, 2]]
    for name, kind in [("v5c.mat", "mat5"), ("v5u.mat", "mat5"), ("v73.mat", "mat73"), ("vec.npz", "npz"),
                       ("mat.npz", "npz"), ("us.csv", "csv")]:
        rec, got = _read(tmp_path / name, ["r_a_x", "t", "u_a_x"], chunk)
        assert rec.kind == kind
        np.testing.assert_array_equal(got, want, err_msg=name)
    rec, got = _read(tmp_path / "eu.csv", ["Zeit [ms]", "u_a_x"], chunk)
    np.testing.assert_allclose(got, np.column_stack([np.arange(len(X)) * 0.1, X[:, 2]]), rtol=1e-11)


@pytest.mark.parametrize("fmt", ["csv", "mat", "mat73", "npz"])
def test_writers_are_read_by_the_other_side(tmp_path, fmt):
    path = tmp_path / f"out.{'npz' if fmt == 'npz' else 'csv' if fmt == 'csv' else 'mat'}"
    write_record(path, fmt, NAMES, len(X), ((a, X[a:a + 999]) for a in range(0, len(X), 999)))
    if fmt == "csv":
        rows = list(csv.reader(open(path)))
        assert rows[0] == NAMES
        got = np.array(rows[1:], dtype=float)
    elif fmt == "mat":
        m = sio.loadmat(path)
        assert m["y_a_x"].shape == (len(X), 1)
        got = np.column_stack([m[n][:, 0] for n in NAMES])
    elif fmt == "mat73":
        assert open(path, "rb").read(19) == b"MATLAB 7.3 MAT-file"
        with h5py.File(path, "r") as f:
            assert f["y_a_x"].shape == (1, len(X)) and f["y_a_x"].attrs["MATLAB_class"] == b"double"
            got = np.column_stack([f[n][0] for n in NAMES])
    else:
        z = np.load(path)
        assert list(z["names"]) == NAMES
        got = z["data"]
    np.testing.assert_array_equal(got, X)   # %.17g and binary formats: every float64 round-trips
    assert [p.name for p in tmp_path.iterdir()] == [path.name]   # no temporary left


def test_sample_block_encoder_matches_the_msg_codec():
    x = RNG.standard_normal((37, 3))
    names, units = ["y_a_x", "u_a_x", "r_a_x"], ["m", "A", "A"]
    mine = decode_sample_block(encode_sample_block(4321, 1e-4, names, units, x, "exp7", 2_500_000_000))
    theirs = decode_sample_block(encoder(SAMPLE_BLOCK)(
        {**block_message(4321, x, names, 1e-4, units, "exp7"), "stamp": {"sec": 2, "nanosec": 500_000_000}}))
    for field in ("stamp_ns", "experiment_id", "first_index", "sample_period_s", "channel_names", "channel_units"):
        assert getattr(mine, field) == getattr(theirs, field)
    np.testing.assert_array_equal(mine.data, theirs.data)


def test_csv_as_loggers_vary_it(tmp_path):
    """A units row under the names, a delimiter closing every line, CRLF, a BOM, blank lines."""
    body = "\r\n".join(f"{i * 0.5:g};{x:.10g};{-x:.10g};".replace(".", ",") for i, x in enumerate(X[:50, 1]))
    (tmp_path / "a.csv").write_text("\ufefft;x1;x2;\r\ns;V;V;\r\n" + body + "\r\n\r\n", encoding="utf-8")
    rec, got = open_record(tmp_path / "a.csv"), None
    assert rec.names == ("t", "x1", "x2")
    got = np.vstack([c for _, c in rec.chunks(["x2", "t"], 7)])
    np.testing.assert_allclose(got, np.column_stack([-X[:50, 1], np.arange(50) * 0.5]), rtol=1e-9)
    (tmp_path / "b.csv").write_text("1,2,3\n4,5,6\n")
    with pytest.raises(ValueError, match="line 1 holds numbers"):
        open_record(tmp_path / "b.csv")
