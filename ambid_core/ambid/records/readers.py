"""Time records a rig's logger wrote, read in row chunks: memory stays flat in the file's length.

Formats (chosen by extension; the content is checked, not trusted):

* ``.csv``: a header row of channel names, then one row per sample; comma,
  semicolon or tab separated (a semicolon or tab file may use the decimal
  comma, as European loggers write it), numbers quoted or not; a time column
  is just another column.
* ``.mat`` v5 (MATLAB ``save -v7`` and older; compressed or not) and v7.3
  (HDF5 with MATLAB's 512-byte user block): one vector per channel, or one
  numeric matrix (rows = samples) beside a cell array or char matrix of its
  column names. v5 is parsed here element by element (zlib streamed), v7.3
  read by slices through h5py; MATLAB stores column-major, so an n x k
  matrix is a (k, n) HDF5 dataset.
* ``.npz``: one array per channel, or a 2-D array beside a string array of
  names; members are read from the zip entry in chunks, never loaded whole.

:func:`open_record` gives a :class:`Record`: its channel names, its number of
rows (known up front except for CSV) and :meth:`Record.chunks`, which yields
``(first_row, values (n, k) float64)`` in file order for the channels asked.
Every refusal is a :class:`RecordError` naming the file, the channel and the
row, and the fix.
"""

from __future__ import annotations

import itertools
import os
import struct
import tempfile
import zipfile
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .lms_struct import read_lms_signals

__all__ = ["CHUNK_ROWS", "FORMATS", "Record", "RecordError", "open_record", "open_records", "record_format"]

#: rows per chunk: ~1 MB of float64 for 16 channels
CHUNK_ROWS = 8192
FORMATS = ("csv", "mat", "npz")
_MAT73_MAGIC = b"MATLAB 7.3 MAT-file"
_DELIMITERS = (",", ";", "\t")
_COMPLEX = "is complex; a rig's record holds real samples: give the real signal"
_NUMERIC_CLASSES = ("double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
                    "logical")


class RecordError(ValueError):
    """A time record ambid cannot use; the message is one line: the problem (file, channel, row) and the fix."""


def record_format(path: str | os.PathLike) -> str:
    """'csv', 'mat' or 'npz' from a file's extension, else :class:`RecordError`."""
    ext = Path(path).suffix.lower().lstrip(".")
    if ext not in FORMATS:
        raise RecordError(f"{path}: '.{ext}' is not a record format ambid reads; give a .csv, .mat or .npz file")
    return ext


# ---------------------------------------------------------------- sources
# A source delivers some channels row by row: read(n) -> (n, k) float64, sequentially from row 0.

class _Source:
    names: tuple[str, ...] = ()
    n_rows: int | None = None

    def read(self, n: int) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def verify(self) -> None:
        """After the last row: raise if the container's own check (a zip member's CRC) fails."""

    def close(self) -> None:
        pass


class _ByteColumns(_Source):
    """k column streams of raw bytes (one reader each) -> (n, k) float64."""

    def __init__(self, names, n_rows, dtype, readers) -> None:
        self.names, self.n_rows, self.dtype, self.readers = tuple(names), n_rows, np.dtype(dtype), readers

    def read(self, n: int) -> np.ndarray:
        out = np.empty((n, len(self.readers)))
        for j, r in enumerate(self.readers):
            raw = r.read(n * self.dtype.itemsize)
            if len(raw) != n * self.dtype.itemsize:
                raise EOFError
            out[:, j] = np.frombuffer(raw, self.dtype)
        return out

    def verify(self) -> None:
        # the last column's reader has read the member from its start (the others by skipping)
        getattr(self.readers[-1], "verify", lambda: None)()

    def close(self) -> None:
        for r in self.readers:
            r.close()


class _ByteRows(_Source):
    """Row-major (n_rows, k) values from one byte stream."""

    def __init__(self, names, n_rows, dtype, reader) -> None:
        self.names, self.n_rows, self.dtype, self.reader = tuple(names), n_rows, np.dtype(dtype), reader

    def read(self, n: int) -> np.ndarray:
        size = n * len(self.names) * self.dtype.itemsize
        raw = self.reader.read(size)
        if len(raw) != size:
            raise EOFError
        return np.frombuffer(raw, self.dtype).reshape(n, len(self.names)).astype(float)

    def verify(self) -> None:
        getattr(self.reader, "verify", lambda: None)()

    def close(self) -> None:
        self.reader.close()


class _ArrayColumns(_Source):
    """Columns already in memory (an LMS / Simcenter struct, read whole) -> (n, k) float64 in row chunks."""

    def __init__(self, names, values: np.ndarray) -> None:
        self.names, self.values, self.n_rows, self.pos = tuple(names), values, len(values), 0

    def read(self, n: int) -> np.ndarray:
        if self.pos + n > self.n_rows:
            raise EOFError
        out = self.values[self.pos:self.pos + n]
        self.pos += n
        return out


class _Inflate:
    """A zlib stream (a MAT v5 miCOMPRESSED element) read forward in pieces, from its own file handle."""

    def __init__(self, path: str, offset: int, nbytes: int, skip: int = 0) -> None:
        self.f = open(path, "rb")
        self.f.seek(offset)
        self.left, self.z, self.buf = nbytes, zlib.decompressobj(), bytearray()
        while skip:
            skip -= len(self.read(min(skip, 1 << 20)))

    def read(self, n: int) -> bytes:
        while len(self.buf) < n:
            data = self.z.unconsumed_tail
            if not data:
                if self.left <= 0:
                    break
                data = self.f.read(min(1 << 20, self.left))
                if not data:
                    break
                self.left -= len(data)
            self.buf += self.z.decompress(data, max(n - len(self.buf), 1 << 16))
        out = bytes(self.buf[:n])
        del self.buf[:n]
        return out

    def close(self) -> None:
        self.f.close()


class _Plain:
    """A file region read forward from its own handle."""

    def __init__(self, path: str, offset: int) -> None:
        self.f = open(path, "rb")
        self.f.seek(offset)

    def read(self, n: int) -> bytes:
        return self.f.read(n)

    def close(self) -> None:
        self.f.close()


# ---------------------------------------------------------------- the record

@dataclass
class Record:
    """An open time record: channel names and a chunked row reader.

    Attributes
    ----------
    path
        the file.
    kind
        'csv', 'mat5', 'mat73' or 'npz'.
    names
        (k,) channel names in the file.
    n_rows
        rows per channel, or None until a CSV has been read through.
    """

    path: str
    kind: str
    names: tuple[str, ...]
    n_rows: int | None
    _sources: list
    _csv: dict | None = None
    unusable: dict[str, str] = field(default_factory=dict)   # variables that cannot be a channel: why
    units: dict[str, str] = field(default_factory=dict)       # channel -> SI unit, where the file says it
    sample_period_s: float | None = None                      # where the file says it (an LMS struct's increment)
    notes: list[str] = field(default_factory=list)            # what was read how, a line each

    def require(self, names: Sequence[str], what: str = "MAP.yaml") -> None:
        """:class:`RecordError` naming the first of ``names`` the file lacks."""
        for n in names:
            if n in self.unusable:
                raise RecordError(f"{self.path}: '{n}' (named in {what}) {self.unusable[n]}")
            if n not in self.names:
                raise RecordError(f"{self.path}: no channel '{n}' (named in {what}); the file has "
                                  f"{', '.join(self.names) or 'none'}; use one of these names")

    def chunks(self, names: Sequence[str], chunk_rows: int = CHUNK_ROWS) -> Iterator[tuple[int, np.ndarray]]:
        """Yield (first_row, values (n, len(names)) float64) over the whole record, in order.

        Values are as stored (no NaN/Inf check here: see ``ambid.records.importer``).

        Raises
        ------
        RecordError
            a row that cannot be read (CSV: wrong field count, not a number),
            channels of different lengths, a file that ends early.
        """
        self.require(names, "the request")
        if self.kind == "csv":
            yield from _csv_chunks(self, names, chunk_rows)
            return
        wanted = list(names)
        opened = []
        try:
            picks = []
            for src_factory in self._sources:
                src = src_factory()
                opened.append(src)
                cols = [j for j, n in enumerate(src.names) if n in wanted]
                if cols:
                    picks.append((src, cols, [wanted.index(src.names[j]) for j in cols]))
            lengths = {src.names[cols[0]]: src.n_rows for src, cols, _ in picks}
            if len(set(lengths.values())) > 1:
                short = min(lengths, key=lengths.get)
                long = max(lengths, key=lengths.get)
                raise RecordError(f"{self.path}: channel '{short}' has {lengths[short]} rows but '{long}' has "
                                  f"{lengths[long]}; record every channel over the same samples (cut them to "
                                  f"{lengths[short]} rows)")
            n_rows = self.n_rows if not lengths else next(iter(lengths.values()))
            for first in range(0, n_rows, chunk_rows):
                n = min(chunk_rows, n_rows - first)
                out = np.empty((n, len(wanted)))
                for src, cols, dest in picks:
                    try:
                        block = src.read(n)
                    except (EOFError, zlib.error, OSError, zipfile.BadZipFile) as exc:   # BadZipFile: a CRC
                        raise RecordError(f"{self.path}: channel '{src.names[cols[0]]}' ends or breaks at row "
                                          f"{first + 1} ({exc or 'truncated'}); the file is truncated or damaged, "
                                          "give the complete file") from None
                    out[:, dest] = block[:, cols]
                yield first, out
            for src, cols, _ in picks:
                try:
                    src.verify()
                except (zipfile.BadZipFile, zlib.error, OSError, EOFError) as exc:
                    raise RecordError(f"{self.path}: channel '{src.names[cols[0]]}' is damaged ({exc}); the file "
                                      "was changed after it was written, give an intact copy") from None
        finally:
            for s in opened:
                s.close()


def open_record(path: str | os.PathLike) -> Record:
    """Open a time record (.csv, .mat v5/v7.3, .npz) and read its channel names (not its data).

    Raises
    ------
    RecordError
        missing, a folder, empty, not of its format, no numeric channels.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise RecordError(f"{path} is a folder; give the record file in it")
    fmt = record_format(path)
    if not os.path.exists(path):
        raise RecordError(f"{path}: no such file; give the path of the rig's record")
    if os.path.getsize(path) == 0:
        raise RecordError(f"{path} is empty; give a record with a header (CSV) or channels (MAT, NPZ)")
    with open(path, "rb") as f:
        head = f.read(128)
    if fmt == "csv":
        return _open_csv(path, head)
    if fmt == "npz":
        return _open_npz(path)
    if head.startswith(_MAT73_MAGIC) or head[:8] == b"\x89HDF\r\n\x1a\n":
        return _open_mat73(path)
    return _open_mat5(path, head)


def open_records(paths: Sequence[str | os.PathLike]) -> Record:
    """Several files of one recording as one record (an acquisition system that exports its signals in more
    than one file): their channels side by side, every file of the same length and sample period.

    Raises
    ------
    RecordError
        as :func:`open_record`; a channel in two files; files of different lengths or rates; CSV
        among several files.
    """
    paths = [os.fspath(p) for p in paths]
    if len(paths) == 1:
        return open_record(paths[0])
    recs = [open_record(p) for p in paths]
    csv = [r.path for r in recs if r.kind == "csv"]
    if csv:
        raise RecordError(f"{csv[0]}: a CSV record is read as one file; give its channels in one CSV, or the other "
                          "files' as .mat or .npz")
    seen: dict[str, str] = {}
    for r in recs:
        for n in r.names:
            if n in seen:
                raise RecordError(f"{r.path}: channel '{n}' is in {seen[n]} too; give every channel in one file")
            seen[n] = r.path
    lengths = {r.path: r.n_rows for r in recs}
    if len(set(lengths.values())) > 1:
        short = min(lengths, key=lengths.get)
        raise RecordError(f"{short} has {lengths[short]} rows but {max(lengths, key=lengths.get)} has "
                          f"{max(lengths.values())}; give files of the same recording (same samples)")
    periods = {r.path: r.sample_period_s for r in recs if r.sample_period_s}
    if len({round(v, 15) for v in periods.values()}) > 1:
        rates = ", ".join(f"{p}: {1 / v:g} Hz" for p, v in periods.items())
        raise RecordError(f"the files are sampled at different rates ({rates}); give files of one recording")
    return Record(" + ".join(paths), recs[0].kind, tuple(seen), recs[0].n_rows,
                  [f for r in recs for f in r._sources], unusable={k: v for r in recs for k, v in r.unusable.items()},
                  units={k: v for r in recs for k, v in r.units.items()},
                  sample_period_s=next(iter(periods.values()), None), notes=[n for r in recs for n in r.notes])


def _matrix_names(path: str, numeric: dict, names: dict) -> list[tuple[str, list[str]]]:
    """(matrix variable, its column names) for each 2-D numeric matrix a names list fits (k names, k columns)."""
    out = []
    for nm, cols in names.items():
        fits = [v for v, (rows, k) in numeric.items() if k == len(cols) and k > 1]
        if len(fits) == 1:
            out.append((fits[0], cols))
    return out


# ---------------------------------------------------------------- CSV

def _open_csv(path: str, head: bytes) -> Record:
    if b"\x00" in head:
        raise RecordError(f"{path} is not a CSV text file (binary bytes at the start); give the logger's CSV "
                          "export with a header row")
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            header = f.readline()
    except UnicodeDecodeError:
        raise RecordError(f"{path} is not a CSV text file (not UTF-8 text); give the logger's CSV export with "
                          "a header row") from None
    delim = max(_DELIMITERS, key=header.count)   # ties: the comma
    fields = header.rstrip("\r\n").split(delim)
    if len(fields) == 1:
        raise RecordError(f"{path}: line 1 is one column ('{header.strip()[:60]}'); ambid reads a CSV whose columns "
                          "are separated by commas, semicolons or tabs: export the record with one of these")
    trailing = len(fields) > 1 and not fields[-1].strip()   # a logger that ends every line with the delimiter
    names = [h.strip().strip('"').strip() for h in (fields[:-1] if trailing else fields)]
    if not header.strip() or any(not n for n in names):
        raise RecordError(f"{path}: line 1 must be a header of channel names, one per column, none empty; "
                          "make the logger write its header row")
    if all(_is_number(n) for n in names):
        raise RecordError(f"{path}: line 1 holds numbers, not channel names; give the file a header row")
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise RecordError(f"{path}: column name '{dup}' appears twice in the header; give every column its "
                          "own name")
    with open(path, encoding="utf-8-sig", newline="", errors="replace") as f:
        f.readline()
        second = f.readline().rstrip("\r\n").split(delim)
    second = second[:-1] if trailing and len(second) > 1 else second
    units_row = len(second) == len(names) and not any(_is_number(v) for v in second)   # "s;V;V;A" under the names
    return Record(path, "csv", tuple(names), None, [], {"delimiter": delim, "trailing": trailing,
                                                        "skip": 2 if units_row else 1})


def _is_number(text: str) -> bool:
    try:
        float(text.replace(",", ".").strip().strip('"'))
    except ValueError:
        return False
    return True


def _csv_chunks(rec: Record, names: Sequence[str], chunk_rows: int) -> Iterator[tuple[int, np.ndarray]]:
    delim, skip = rec._csv["delimiter"], rec._csv["skip"]
    cols = [rec.names.index(n) for n in names]
    k = len(rec.names)
    row = 0
    # errors="replace": a byte that is not UTF-8 becomes U+FFFD, refused below by its line and column
    with open(rec.path, encoding="utf-8-sig", newline="", errors="replace") as f:
        for _ in range(skip):
            f.readline()
        line_no = skip
        while True:
            raw = list(itertools.islice(f, chunk_rows))
            if not raw:
                break
            if rec._csv["trailing"]:
                raw = [ln.rstrip("\r\n").removesuffix(delim) + "\n" for ln in raw]
            lines = [ln for ln in raw if ln.strip()]
            if delim != ",":
                lines = [ln.replace(",", ".") for ln in lines]
            try:
                values = np.loadtxt(lines, delimiter=delim, ndmin=2, dtype=float, comments=None,
                                    quotechar='"') if lines else np.zeros((0, k))
            except ValueError:
                values = None
            if values is None or values.shape[1] != k:
                _csv_bad_line(rec, raw, line_no, row, k, delim)
            line_no += len(raw)
            if values.shape[0]:
                yield row, values[:, cols]
            row += values.shape[0]
    rec.n_rows = row


def _csv_bad_line(rec: Record, lines: list[str], line_no: int, row: int, k: int, delim: str) -> None:
    i = -1
    for n, ln in enumerate(lines):
        if not ln.strip():
            continue
        i += 1
        fields = ln.rstrip("\r\n").split(delim)
        if delim != ",":
            fields = [v.replace(",", ".") for v in fields]
        where = f"{rec.path}: line {line_no + n + 1} (row {row + i + 1})"
        if len(fields) != k:
            raise RecordError(f"{where} has {len(fields)} fields but the header names {k} columns; the columns "
                              "have different lengths there: cut the record before that line or give the "
                              "complete file")
        for j, v in enumerate(fields):
            try:
                float(v.strip().strip('"'))
            except ValueError:
                raise RecordError(f"{where}, column '{rec.names[j]}': '{v.strip()}' is not a number; give "
                                  "numbers only (clean the logger's export)") from None
    raise RecordError(f"{rec.path}: lines {line_no + 1}-{line_no + len(lines)} cannot be read as numbers; "
                      "check the file")


# ---------------------------------------------------------------- NPZ

def _npz_member(z: zipfile.ZipFile, name: str):
    fp = z.open(name)
    version = np.lib.format.read_magic(fp)
    reader = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, fortran, dtype = reader(fp)
    return fp, shape, fortran, dtype


class _ZipReader:
    def __init__(self, path: str, member: str, skip: int = 0) -> None:
        self.z = zipfile.ZipFile(path)
        self.fp, *_ = _npz_member(self.z, member)
        while skip:
            skip -= len(self.fp.read(min(skip, 1 << 20)))

    def read(self, n: int) -> bytes:
        return self.fp.read(n)

    def verify(self) -> None:
        """Read to the member's end: zipfile checks its CRC there (BadZipFile if the bytes were damaged)."""
        while self.fp.read(1 << 20):
            pass

    def close(self) -> None:
        self.fp.close()
        self.z.close()


def _open_npz(path: str) -> Record:
    try:
        z = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError):
        raise RecordError(f"{path} is not an .npz file (not a zip archive); give the file numpy.savez wrote") \
            from None
    sources, numeric, names_lists = [], {}, {}
    with z:
        for member in z.namelist():
            if not member.endswith(".npy"):
                continue
            var = member[:-4]
            try:
                fp, shape, fortran, dtype = _npz_member(z, member)
            except (ValueError, zipfile.BadZipFile, OSError) as exc:
                raise RecordError(f"{path}: member '{var}' cannot be read ({exc}); give the file numpy.savez "
                                  "wrote") from None
            if dtype.kind in "US" and len(shape) == 1:
                names_lists[var] = [str(s) for s in np.load(path, allow_pickle=False)[var]]
            elif dtype.kind in "biuf" and len(shape) in (1, 2):
                rows, k = (shape[0], 1) if len(shape) == 1 else shape
                numeric[var] = (rows, k, fortran, dtype)
            fp.close()
    if not numeric:
        raise RecordError(f"{path}: no numeric arrays; give one array per channel or a matrix with its names")
    matrices = dict(_matrix_names(path, {v: (r, k) for v, (r, k, _, _) in numeric.items()}, names_lists))
    for var, (rows, k, fortran, dtype) in numeric.items():
        member = var + ".npy"
        cols = matrices.get(var)
        if k == 1:
            sources.append((lambda m=member, v=var, r=rows, d=dtype: _ByteRows([v], r, d, _ZipReader(path, m)),
                            [var], rows))
        elif cols is not None and not fortran:
            sources.append((lambda m=member, c=cols, r=rows, d=dtype: _ByteRows(c, r, d, _ZipReader(path, m)),
                            cols, rows))
        elif cols is not None:
            sources.append((lambda m=member, c=cols, r=rows, d=dtype: _ByteColumns(
                c, r, d, [_ZipReader(path, m, j * r * d.itemsize) for j in range(len(c))]), cols, rows))
    return _record(path, "npz", sources)


def _record(path: str, kind: str, sources: list, unusable: dict[str, str] | None = None) -> Record:
    if not sources and unusable:
        name, why = next(iter(unusable.items()))
        raise RecordError(f"{path}: '{name}' {why}")
    if not sources:
        raise RecordError(f"{path}: no channel found (vectors, or one matrix beside a list of its column names); "
                          "give one vector per channel")
    names = [n for _, cols, _ in sources for n in cols]
    dup = [n for n in names if names.count(n) > 1]
    if dup:
        raise RecordError(f"{path}: channel '{dup[0]}' is stored twice; give every channel once")
    rows = [r for _, _, r in sources]
    return Record(path, kind, tuple(names), max(rows), [f for f, _, _ in sources], unusable=unusable or {})


# ---------------------------------------------------------------- MAT v7.3 (HDF5)

class _H5Source(_Source):
    """One MATLAB matrix (or vector) of a v7.3 file, read in whole HDF5 chunks: each is read and inflated once."""

    def __init__(self, path: str, var: str, names, n_rows: int) -> None:
        import h5py  # MAT v7.3 only: loaded when such a file is read

        # no HDF5 chunk cache (it kept what was read: RSS grew with the file); this source buffers one chunk
        self.f = h5py.File(path, "r", rdcc_nbytes=0)
        self.ds, self.names, self.n_rows = self.f[var], tuple(names), n_rows
        self.step = max(self.ds.chunks[1] if self.ds.chunks else 0, CHUNK_ROWS)
        self.buf, self.at, self.pos = np.zeros((0, len(self.names))), 0, 0

    def read(self, n: int) -> np.ndarray:
        out = []
        while n:
            if self.at >= len(self.buf):
                # MATLAB n x k is an HDF5 (k, n) dataset: rows are the last axis
                self.buf = np.asarray(self.ds[:, self.pos:self.pos + self.step], dtype=float).T
                self.pos += len(self.buf)
                self.at = 0
                if not len(self.buf):
                    raise EOFError
            take = min(n, len(self.buf) - self.at)
            out.append(self.buf[self.at:self.at + take])
            self.at += take
            n -= take
        return np.concatenate(out) if len(out) > 1 else out[0]

    def close(self) -> None:
        self.f.close()


def _h5_text(f, ds) -> str:
    data = np.asarray(ds)
    return "".join(chr(c) for c in data.T.ravel() if c)


def _open_mat73(path: str) -> Record:
    import h5py  # MAT v7.3 only

    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise RecordError(f"{path}: a MAT v7.3 header but no readable HDF5 inside ({exc}); give the complete "
                          "file MATLAB saved") from None
    numeric, names_lists, unusable = {}, {}, {}
    with f:
        for var, ds in f.items():
            if not isinstance(ds, h5py.Dataset) or var.startswith("#"):
                continue
            cls = ds.attrs.get("MATLAB_class", b"")
            cls = cls.decode() if isinstance(cls, bytes) else str(cls)
            if cls in _NUMERIC_CLASSES and ds.dtype.names:
                unusable[var] = _COMPLEX
                continue
            if cls in _NUMERIC_CLASSES and ds.ndim == 2 and not ds.attrs.get("MATLAB_empty", 0):
                k, rows = ds.shape
                if rows == 1 and k > 1:   # a MATLAB row vector 1 x n
                    continue
                numeric[var] = (rows, k)
            elif cls == "cell":
                try:
                    names_lists[var] = [_h5_text(f, f[ref]) for ref in np.asarray(ds).T.ravel()]
                except (KeyError, TypeError, ValueError):
                    pass
            elif cls == "char" and ds.ndim == 2:
                data = np.asarray(ds)   # (width, n_names): column-major char matrix
                names_lists[var] = ["".join(chr(c) for c in col if c).strip() for col in data.T]
    matrices = dict(_matrix_names(path, numeric, names_lists))
    sources = []
    for var, (rows, k) in numeric.items():
        cols = [var] if k == 1 else matrices.get(var)
        if cols is not None:
            sources.append((lambda v=var, c=cols, r=rows: _H5Source(path, v, c, r), cols, rows))
    return _record(path, "mat73", sources, unusable)


# ---------------------------------------------------------------- MAT v5

_MI = {1: "i1", 2: "u1", 3: "<i2", 4: "<u2", 5: "<i4", 6: "<u4", 7: "<f4", 9: "<f8", 12: "<i8", 13: "<u8"}
_MI_MATRIX, _MI_COMPRESSED = 14, 15
_MX_NUMERIC = set(range(6, 16))  # double .. uint64 class codes
_MX_CHAR, _MX_CELL, _MX_STRUCT = 4, 1, 2


def _tag(read) -> tuple[int, int, bytes | None]:
    """(type, nbytes, small data or None) of a v5 tag read from ``read``."""
    raw = read(8)
    if len(raw) < 8:
        raise EOFError
    a, b = struct.unpack("<II", raw)
    if a >> 16:  # small data element: type in the low, size in the high half, data in the 4 bytes after
        return a & 0xFFFF, a >> 16, raw[4:4 + (a >> 16)]
    return a, b, None


def _sub(read) -> tuple[int, bytes]:
    t, n, small = _tag(read)
    if small is not None:
        return t, small
    data = read(n + (-n % 8))
    if len(data) < n:
        raise EOFError
    return t, data[:n]


def _matrix_header(read) -> tuple[int, tuple[int, ...], str, int, int]:
    """(class, dims, name, data type, data bytes) of a miMATRIX, leaving ``read`` at its real data."""
    t, flags = _sub(read)
    cls = flags[0] | (0x100 if flags[1] & 0x08 else 0)   # 0x100: MATLAB's complex flag, kept beside the class
    _, dims = _sub(read)
    dims = struct.unpack(f"<{len(dims) // 4}i", dims)
    _, name = _sub(read)
    if cls in _MX_NUMERIC or cls == _MX_CHAR:
        dtype, nbytes, small = _tag(read)
        if small is not None:
            return cls, dims, name.decode("latin-1"), dtype, -1
        return cls, dims, name.decode("latin-1"), dtype, nbytes
    return cls, dims, name.decode("latin-1"), 0, 0


def _mat5_elements(path: str) -> list[tuple[int, int, bool]]:
    """(offset of the element's data, its byte count, compressed) of every top-level element."""
    out = []
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        pos = 128
        while pos + 8 <= size:
            f.seek(pos)
            t, n = struct.unpack("<II", f.read(8))
            if t not in (_MI_MATRIX, _MI_COMPRESSED) or pos + 8 + n > size:
                raise RecordError(f"{path}: element at byte {pos} is cut off or not a MATLAB array; the file is "
                                  "truncated or not a MAT file, give the complete file MATLAB saved")
            out.append((pos + 8, n, t == _MI_COMPRESSED))
            pos += 8 + n + (0 if t == _MI_COMPRESSED else -n % 8)
    return out


def _mat5_reader(path: str, off: int, n: int, compressed: bool, skip: int = 0):
    if compressed:
        return _Inflate(path, off, n, skip)
    return _Plain(path, off - 8 + skip)


def _open_mat5(path: str, head: bytes) -> Record:
    if len(head) < 128 or head[126:128] != b"IM" or not head.startswith(b"MATLAB"):
        raise RecordError(f"{path} is not a MATLAB .mat file (no MAT v5 or v7.3 header); give the file MATLAB "
                          "saved (save -v7 or -v7.3)")
    from scipy.io import loadmat  # MAT v5 only

    numeric, texts, unusable, structs = {}, {}, {}, []
    for off, n, compressed in _mat5_elements(path):
        r = _mat5_reader(path, off, n, compressed)
        try:
            read = r.read
            if not compressed:
                read(8)   # the element's own tag sits before the matrix subelements
            else:
                t, _, _ = _tag(read)
                if t != _MI_MATRIX:
                    continue
            cls, dims, name, dtype, nbytes = _matrix_header(read)
        except (EOFError, zlib.error, struct.error):
            raise RecordError(f"{path}: the array at byte {off - 8} is cut off or damaged; the file is truncated, "
                              "give the complete file MATLAB saved") from None
        finally:
            r.close()
        if cls & 0x100:
            unusable[name] = _COMPLEX
            continue
        if cls in _MX_NUMERIC and len(dims) == 2 and dtype in _MI and nbytes >= 0:
            rows, k = dims
            if rows == 1 and k > 1:
                rows, k = k, 1   # a row vector is a channel too
            numeric[name] = (rows, k, off, n, compressed, dtype, nbytes)
        elif cls in (_MX_CHAR, _MX_CELL):
            texts[name] = None
        elif cls == _MX_STRUCT:
            structs.append(name)
    names_lists = {}
    if texts:
        raw = loadmat(path, variable_names=list(texts), squeeze_me=True, chars_as_strings=True)
        for name in texts:
            v = raw.get(name)
            if v is None:
                continue
            items = np.atleast_1d(v).ravel().tolist()
            if all(isinstance(s, str) for s in items):
                names_lists[name] = [s.strip() for s in items]
    matrices = dict(_matrix_names(path, {v: (r, k) for v, (r, k, *_) in numeric.items()}, names_lists))
    sources = []
    for var, (rows, k, off, n, compressed, dtype, nbytes) in numeric.items():
        cols = [var] if k == 1 else matrices.get(var)
        if cols is None:
            continue
        item = np.dtype(_MI[dtype]).itemsize
        if nbytes != rows * k * item:
            raise RecordError(f"{path}: '{var}' holds {nbytes} bytes for {rows} x {k} values; the file is damaged, "
                              "give the complete file MATLAB saved")

        def make(v=var, c=cols, r=rows, o=off, nb=n, z=compressed, d=_MI[dtype], kk=k):
            head = _header_bytes(path, o, nb, z)
            size = np.dtype(d).itemsize
            if z and kk > 1:
                # a compressed matrix is column-major: inflating it once to disk beats one zlib stream per
                # column, each inflating every column before its own
                return _ByteColumns(c, r, d, _inflated_columns(path, o, nb, head, kk, r * size))
            return _ByteColumns(c, r, d, [_mat5_reader(path, o, nb, z, head + j * r * size) for j in range(kk)])
        sources.append((make, cols, rows))
    units, period, notes = {}, None, []
    if structs:
        # LMS Test.Lab / Simcenter Testlab exports: one struct per signal (x_values, y_values, channel names, units)
        try:
            signals = read_lms_signals(path, structs)
        except ValueError as exc:
            raise RecordError(str(exc)) from None
        for sig in signals:
            sources.append((lambda sig=sig: _ArrayColumns(sig.names, sig.values), sig.names, len(sig.values)))
            units.update(dict.fromkeys(sig.names, sig.unit))
            periods = {round(x.dt_s, 15) for x in signals}
            if len(periods) > 1:
                raise RecordError(f"{path}: the signals are sampled at different rates ("
                                  f"{', '.join(f'{1 / p:g}' for p in sorted(periods))} Hz); give signals of one rate")
            period = sig.dt_s
            shown = f" (shown by Test.Lab in {sig.display})" if sig.display and sig.display != sig.unit else ""
            notes.append(f"{sig.variable}: LMS/Simcenter struct, channels {', '.join(sig.names)} [{sig.unit or '-'}]"
                         f"{shown}, {len(sig.values)} samples at {1 / sig.dt_s:g} Hz")
    rec = _record(path, "mat5", sources, unusable)
    rec.units, rec.sample_period_s, rec.notes = units, period, notes
    return rec


class _PRead:
    """Forward reads at an offset of a shared file descriptor (the spool of an inflated matrix)."""

    def __init__(self, f, offset: int) -> None:
        self.f, self.pos = f, offset

    def read(self, n: int) -> bytes:
        b = os.pread(self.f.fileno(), n, self.pos)
        self.pos += len(b)
        return b

    def close(self) -> None:
        if not self.f.closed:
            self.f.close()


def _inflated_columns(path: str, off: int, nbytes: int, head: int, k: int, col_bytes: int) -> list[_PRead]:
    """Readers of the k columns of a compressed matrix, inflated once into an unnamed temporary file."""
    spool = tempfile.TemporaryFile()
    src = _Inflate(path, off, nbytes, head)
    try:
        left = k * col_bytes
        while left:
            b = src.read(min(left, 1 << 22))
            if not b:
                break
            spool.write(b)
            left -= len(b)
        spool.flush()
    finally:
        src.close()
    return [_PRead(spool, j * col_bytes) for j in range(k)]


def _header_bytes(path: str, off: int, n: int, compressed: bool) -> int:
    """Bytes from the element's start (compressed: of the inflated stream) to its real data."""
    r = _mat5_reader(path, off, n, compressed)
    count = [0]

    def read(k: int) -> bytes:
        b = r.read(k)
        count[0] += len(b)
        return b

    try:
        if compressed:
            _tag(read)
        else:
            read(8)
        _matrix_header(read)
    finally:
        r.close()
    return count[0]
