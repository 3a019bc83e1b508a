"""Write time records as MATLAB, numpy and a CSV reader take them, streamed in row chunks.

* ``csv``: header row, comma separated, ``%.17g`` (every float64 round-trips);
* ``mat``: MAT v5 (what ``load`` in any MATLAB and ``scipy.io.loadmat`` read),
  one n x 1 double vector per channel, uncompressed so that each chunk goes
  straight to its place in the file;
* ``mat73``: MAT v7.3, HDF5 behind MATLAB's 512-byte user block, one n x 1
  double per channel (an HDF5 (1, n) dataset: MATLAB is column-major) with
  its ``MATLAB_class`` attribute; for records beyond v5's 2 GB per variable;
* ``npz``: ``data`` (n, k) float64 and ``names`` (k,) in one zip, data
  streamed into its entry.

The file appears under its name only when complete (written beside it,
then renamed): a failure leaves nothing half-written.
"""

from __future__ import annotations

import io
import os
import struct
import tempfile
import time
import zipfile
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

__all__ = ["FORMAT_SUFFIX", "WRITE_FORMATS", "write_record", "atomic_path"]

WRITE_FORMATS = ("csv", "mat", "mat73", "npz")
#: the file name ending of each format: the import tells a record's format by it
FORMAT_SUFFIX = {"csv": ".csv", "mat": ".mat", "mat73": ".mat", "npz": ".npz"}


class atomic_path:
    """Context manager giving a temporary path beside ``path``; renamed onto it on success, removed on failure."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)

    def __enter__(self) -> Path:
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".part", dir=self.path.parent or ".")
        os.close(fd)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            # mkstemp made it owner-only (0600); the finished file gets the mode any new file gets here
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(self.tmp, 0o666 & ~umask)
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)


def _mat_header(version: bytes, text: str, size: int, tail: str = "") -> bytes:
    """MATLAB's file header: 116 bytes of text, 8 of subsystem offset, version, endian 'IM'."""
    stamp = time.strftime("%a %b %d %H:%M:%S %Y", time.gmtime())
    head = f"{text}, Platform: GLNXA64, Created on: {stamp}{tail}".ljust(116).encode("ascii")[:116]
    return (head + b"\x00" * 8 + version + b"IM").ljust(size, b"\x00")


def _mat5_layout(names: Sequence[str], n_rows: int) -> tuple[bytes, list[int], int]:
    """(header bytes of every variable, in order with gaps for data; data offsets; file size)."""
    parts, offsets, pos = [], [], 128
    for name in names:
        nm = name.encode("ascii")
        name_el = struct.pack("<II", 1, len(nm)) + nm + b"\x00" * (-len(nm) % 8)
        body = (struct.pack("<II", 6, 8) + struct.pack("<II", 6, 0)    # flags: mxDOUBLE_CLASS
                + struct.pack("<II", 5, 8) + struct.pack("<ii", n_rows, 1)   # dims n x 1
                + name_el + struct.pack("<II", 9, 8 * n_rows))             # miDOUBLE real part
        head = struct.pack("<II", 14, len(body) + 8 * n_rows) + body
        parts.append((pos, head))
        offsets.append(pos + len(head))
        pos += len(head) + 8 * n_rows
    return parts, offsets, pos


def write_record(path: str | os.PathLike, fmt: str, names: Sequence[str], n_rows: int,
                 chunks: Iterable[tuple[int, np.ndarray]]) -> Path:
    """Write channels to ``path`` in format ``fmt`` (:data:`WRITE_FORMATS`).

    Parameters
    ----------
    path
        output file (its extension is not changed).
    fmt
        'csv', 'mat' (v5), 'mat73' or 'npz'.
    names
        (k,) channel names (MATLAB identifiers for the MAT formats).
    n_rows
        total rows the chunks give.
    chunks
        (first_row, values (n, k)) in row order covering [0, n_rows).

    Returns
    -------
    The path written.
    """
    if fmt not in WRITE_FORMATS:
        raise ValueError(f"format {fmt!r} is not one of {WRITE_FORMATS}")
    names = list(names)
    path = Path(path)
    with atomic_path(path) as tmp:
        written = 0
        if fmt == "csv":
            with open(tmp, "w", newline="") as f:
                f.write(",".join(names) + "\n")
                for _, x in chunks:
                    np.savetxt(f, x, fmt="%.17g", delimiter=",")
                    written += len(x)
        elif fmt == "mat":
            parts, offsets, size = _mat5_layout(names, n_rows)
            with open(tmp, "wb") as f:
                f.write(_mat_header(b"\x00\x01", "MATLAB 5.0 MAT-file", 128))
                for pos, head in parts:
                    f.seek(pos)
                    f.write(head)
                for first, x in chunks:
                    for j, off in enumerate(offsets):
                        f.seek(off + 8 * first)
                        f.write(np.ascontiguousarray(x[:, j], dtype="<f8").tobytes())
                    written += len(x)
                f.truncate(size)
        elif fmt == "mat73":
            import h5py  # MAT v7.3 only: loaded when such a file is written

            step = min(max(n_rows, 1), 65536)
            # whole HDF5 chunks at a time and no chunk cache (it kept what was written: RSS grew with the file)
            with h5py.File(tmp, "w", userblock_size=512, rdcc_nbytes=0) as h:
                sets = []
                for name in names:
                    ds = h.create_dataset(name, shape=(1, n_rows), dtype="<f8", chunks=(1, step))
                    ds.attrs["MATLAB_class"] = np.bytes_("double")
                    sets.append(ds)
                pending, at = [], 0

                def put(rows: list) -> int:
                    x = np.concatenate(rows)
                    for j, ds in enumerate(sets):
                        ds[0, at:at + len(x)] = x[:, j]
                    return len(x)

                for _, x in chunks:
                    pending.append(x)
                    written += len(x)
                    if written - at >= step:
                        at += put(pending)
                        pending = []
                if pending:
                    at += put(pending)
            with open(tmp, "r+b") as f:
                f.write(_mat_header(b"\x00\x02", "MATLAB 7.3 MAT-file", 128, " HDF5 schema 1.00 ."))
        else:
            with zipfile.ZipFile(tmp, "w", allowZip64=True) as z:
                with z.open("data.npy", "w", force_zip64=True) as fp:
                    np.lib.format.write_array_header_1_0(
                        fp, {"descr": "<f8", "fortran_order": False, "shape": (n_rows, len(names))})
                    for _, x in chunks:
                        fp.write(np.ascontiguousarray(x, dtype="<f8").tobytes())
                        written += len(x)
                buf = io.BytesIO()
                np.save(buf, np.array(names))
                z.writestr("names.npy", buf.getvalue())
        if written != n_rows:
            raise ValueError(f"{n_rows} rows announced but {written} written")
    return path
