"""Load recorded time series for offline FRF estimation (no ROS needed).

Supported files (chosen by extension):

* ``.npz``: each array is a channel, named by its key;
* ``.mat``: each numeric variable is a channel (``scipy.io.loadmat``, MAT
  v4-v7.2; save MATLAB v7.3 files with ``save(..., '-v7')``); row or
  column vectors become 1-D;
* ``.csv``: a header row of channel names, then one row per sample,
  comma separated (an empty field reads as NaN and is then rejected).

A channel is an array whose axis 0 is the sample index: (n_samples,) or
(n_samples, k). Every returned channel must have the same number of
samples, be real and finite.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ["load_arrays", "stack_channels"]


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {k: np.asarray(data[k]) for k in data.files}


def _read_mat(path: Path) -> dict[str, np.ndarray]:
    from scipy.io import loadmat  # only needed for .mat files

    try:
        raw = loadmat(path, squeeze_me=False)
    except NotImplementedError as exc:  # HDF5-based v7.3
        raise ValueError(f"{path}: MAT v7.3 files are not supported; re-save with "
                         "save(..., '-v7')") from exc
    out = {}
    for key, value in raw.items():
        if key.startswith("__") or not isinstance(value, np.ndarray):
            continue
        if value.dtype.kind not in "biufc":
            continue  # structs, cells, strings are not channels
        if value.ndim == 2 and 1 in value.shape:
            value = value.reshape(-1)
        out[key] = value
    return out


def _read_csv(path: Path, delimiter: str) -> dict[str, np.ndarray]:
    with open(path, newline="") as f:
        header = next(csv.reader(f, delimiter=delimiter), None)
    if not header:
        raise ValueError(f"{path}: empty file; expected a header row of channel names")
    names = [h.strip() for h in header]
    if any(not n for n in names) or len(set(names)) != len(names):
        raise ValueError(f"{path}: header names must be non-empty and unique, got {names}")
    try:
        values = np.genfromtxt(path, delimiter=delimiter, skip_header=1, dtype=float,
                               ndmin=2, invalid_raise=True)
    except ValueError as exc:
        raise ValueError(f"{path}: rows must all have {len(names)} numeric fields ({exc})") from exc
    if values.size == 0:
        values = np.empty((0, len(names)))
    if values.shape[1] != len(names):
        raise ValueError(f"{path}: header has {len(names)} names but rows have {values.shape[1]} fields")
    return {n: values[:, i].copy() for i, n in enumerate(names)}


def load_arrays(path: str | Path, channels: Sequence[str] | None = None,
                n_samples: int | None = None, delimiter: str = ",") -> dict[str, np.ndarray]:
    """Load named channels from a .npz, .mat or .csv file.

    Parameters
    ----------
    path
        file path.
    channels
        names to return (all numeric channels if None).
    n_samples
        required number of samples per channel, optional.
    delimiter
        field separator of .csv files.

    Returns
    -------
    dict name -> float array (n_samples,) or (n_samples, k), in file units.

    Raises
    ------
    ValueError
        unknown extension, missing channel, complex data, NaN/inf,
        channels of different lengths or not ``n_samples`` long.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    ext = path.suffix.lower()
    if ext == ".npz":
        data = _read_npz(path)
    elif ext == ".mat":
        data = _read_mat(path)
    elif ext == ".csv":
        data = _read_csv(path, delimiter)
    else:
        raise ValueError(f"{path}: unsupported extension {ext!r}; use .npz, .mat or .csv")
    if channels is None:
        channels = sorted(data)
    else:
        missing = [c for c in channels if c not in data]
        if missing:
            raise ValueError(f"{path}: missing channel(s) {missing}; the file has {sorted(data)}")
    if not channels:
        raise ValueError(f"{path}: no numeric channels found")
    out = {}
    for name in channels:
        a = np.asarray(data[name])
        if a.dtype.kind == "c":
            raise ValueError(f"{path}: channel {name!r} is complex; time series must be real")
        if a.dtype.kind not in "biuf":
            raise ValueError(f"{path}: channel {name!r} is not numeric (dtype {a.dtype})")
        if a.ndim not in (1, 2):
            raise ValueError(f"{path}: channel {name!r} must be (n_samples,) or (n_samples, k), "
                             f"got shape {a.shape}")
        a = a.astype(float)
        bad = ~np.isfinite(a)
        if bad.any():
            first = int(np.argwhere(bad)[0][0])
            raise ValueError(f"{path}: channel {name!r} has {int(bad.sum())} NaN/inf value(s), first "
                             f"at sample {first}; clean or interpolate the data before loading")
        out[name] = a
    lengths = {n: a.shape[0] for n, a in out.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{path}: channels have different lengths {lengths}; all must share the "
                         "sample axis (axis 0)")
    if n_samples is not None and next(iter(lengths.values())) != n_samples:
        raise ValueError(f"{path}: channels have {next(iter(lengths.values()))} samples, expected "
                         f"{n_samples} (the experiment layout's length)")
    return out


def stack_channels(data: dict[str, np.ndarray], names: Sequence[str]) -> np.ndarray:
    """Stack named channels column-wise into (n_samples, n_ch) in the order given."""
    missing = [n for n in names if n not in data]
    if missing:
        raise ValueError(f"missing channel(s) {missing}; available {sorted(data)}")
    cols = [np.asarray(data[n], dtype=float).reshape(len(data[n]), -1) for n in names]
    if len({c.shape[0] for c in cols}) > 1:
        raise ValueError(f"channels {list(names)} have different lengths {[c.shape[0] for c in cols]}")
    return np.concatenate(cols, axis=1)
