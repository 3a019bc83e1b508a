"""Small files of named arrays as users hand them over: ``.npz``, MATLAB ``.mat`` (v5 and v7.3) and YAML.

The one reader behind a rotor model (:mod:`ambid.plant.rotor_import`) and a
controller file (:mod:`ambid.control.user_controller`). Whatever makes a file
unusable (missing, a folder, empty, random bytes, cut short, a pickle, complex
values) is a ``ValueError`` whose message is one line: the file, the problem
and the caller's fix. A time record, which may be larger than memory, has its
own chunked reader (:mod:`ambid.records.readers`).
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ambid.yaml_file import read_yaml

__all__ = ["check_file", "read_arrays"]

_MAT73_MAGIC = b"MATLAB 7.3 MAT-file"
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


def check_file(path: Path, what: str, fix: str) -> None:
    """A file that exists, is no folder and is not empty, or ValueError
    "<what> <path> does not exist|is a folder|is empty; <fix>"."""
    if not path.exists():
        raise ValueError(f"{what} {path} does not exist; {fix}")
    if path.is_dir():
        raise ValueError(f"{what} {path} is a folder; {fix}")
    if path.stat().st_size == 0:
        raise ValueError(f"{what} {path} is empty; {fix}")


def read_arrays(path: str | os.PathLike, what: str, fix: str,
                suffixes: tuple[str, ...] = (".npz", ".mat"), complex_names: tuple[str, ...] = ()) -> dict[str, Any]:
    """The named values in ``path``, read whole.

    Parameters
    ----------
    path
        the file; its suffix (one of ``suffixes``) says the format.
    what
        what the file is, for messages ("rotor file", "controller file").
    fix
        the fix a message ends with ("give A, B, C, D and dt ...").
    suffixes
        the formats accepted, from ``.npz``, ``.mat``, ``.yaml``, ``.yml``.
    complex_names
        the values that may be complex (a measured FRF); any other complex value is refused.

    Returns
    -------
    name -> value: numpy arrays (``.mat``: 2-D as MATLAB holds them, also
    from v7.3), or what YAML holds under each key.

    Raises
    ------
    ValueError
        one line naming the file, what is wrong with it and ``fix``.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in suffixes:
        raise ValueError(f"{what} {path}: '{suffix}' is not a {what} type ({', '.join(suffixes)}); {fix}")
    check_file(path, what, fix)
    try:
        if suffix == ".npz":
            data = _npz(path, what)
        elif suffix == ".mat":
            data = _mat(path, what)
        else:
            data = _yaml(path, what)
    except PermissionError:
        raise ValueError(f"{what} {path} cannot be read (permission denied); make it readable") from None
    except _Refused as exc:
        raise ValueError(f"{exc}; {fix}") from None
    for key, value in data.items():
        if isinstance(value, np.ndarray) and np.iscomplexobj(value) and key not in complex_names:
            raise ValueError(f"{what} {path}: '{key}' is complex; give real values")
    return data


class _Refused(Exception):
    """A file its reader could not use; the message names the file and the problem, the caller adds the fix."""


def _npz(path: Path, what: str) -> dict[str, np.ndarray]:
    if not zipfile.is_zipfile(path):
        raise _Refused(f"{what} {path} is not an .npz file (not a zip archive: other data, or cut short)")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except ValueError as exc:
        if "pickle" in str(exc):
            raise _Refused(f"{what} {path} holds object (pickled) arrays; save plain numeric arrays "
                           "(np.savez of numpy arrays)") from None
        raise _Refused(f"{what} {path} cannot be read as .npz ({exc})") from None
    except (OSError, EOFError, zipfile.BadZipFile) as exc:  # a damaged member: CRC, cut-off stream
        raise _Refused(f"{what} {path} is damaged ({exc})") from None


def _mat(path: Path, what: str) -> dict[str, np.ndarray]:
    with open(path, "rb") as f:
        head = f.read(520)
    if head.startswith(_MAT73_MAGIC) or head[:8] == _HDF5_MAGIC or head[512:520] == _HDF5_MAGIC:
        return _mat73(path, what)
    # scipy.io and h5py are loaded only when a .mat file is read (rare; h5py alone costs ~0.2 s to import)
    from scipy import io as sio
    from scipy.io.matlab import matfile_version

    try:
        matfile_version(str(path))   # v4 (no header, MATLAB's save -v4) or v5; anything else raises
    except Exception:  # noqa: BLE001 - scipy raises ValueError or its own MatReadError
        raise _Refused(f"{what} {path} is not a MATLAB .mat file (no MAT v4, v5 or v7.3 layout)") from None
    try:
        raw = sio.loadmat(path, squeeze_me=False)
    except Exception as exc:  # noqa: BLE001 - scipy's MAT parser raises a zoo of types on a damaged file
        raise _Refused(f"{what} {path} is damaged or cut short ({type(exc).__name__}: {exc})") from None
    return {k: np.asarray(v) for k, v in raw.items() if not k.startswith("__")}


def _mat73(path: Path, what: str) -> dict[str, np.ndarray]:
    import h5py

    out = {}
    try:
        with h5py.File(path, "r") as f:
            for name, ds in f.items():
                if not isinstance(ds, h5py.Dataset) or name.startswith("#"):
                    continue
                cls = ds.attrs.get("MATLAB_class", b"double")
                cls = cls.decode() if isinstance(cls, bytes) else str(cls)
                if cls in ("char", "cell", "struct") or ds.dtype.kind not in "biufcV":
                    continue
                value = np.asarray(ds)
                if value.dtype.names and {"real", "imag"} <= set(value.dtype.names):  # MATLAB's complex
                    value = value["real"] + 1j * value["imag"]
                out[name] = value.T  # MATLAB is column-major: an m x n matrix is an (n, m) dataset
    except OSError as exc:
        raise _Refused(f"{what} {path}: a MAT v7.3 header but no readable HDF5 inside; it is cut short or "
                       f"damaged ({exc})") from None
    return out


def _yaml(path: Path, what: str) -> dict[str, Any]:
    try:
        data = read_yaml(path, what, "")
    except ValueError as exc:
        raise _Refused(str(exc)) from None
    if not isinstance(data, dict):
        raise _Refused(f"{what} {path} holds no mapping of key: value")
    return data
