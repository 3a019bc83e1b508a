"""A measured FRF handed over as a file (an analyser's, another tool's): read, checked, named.

Formats, by suffix:

* ``.npz`` or ``.mat`` (MATLAB v5 or v7.3): ``freq_hz`` (n,), ``H`` (n, ny, nu)
  complex, optional ``var`` (n, ny, nu) the variance of each entry
  ``E|H - H0|^2``, optional ``outputs`` (ny,) and ``inputs`` (nu,) names
  (a SISO ``H`` may be (n,));
* ``.csv``: a header row, then one row per frequency: ``freq_hz``,
  ``re(<out>/<in>)`` and ``im(<out>/<in>)`` for every output and input,
  optional ``var(<out>/<in>)`` for all of them;
* ``.uff`` or ``.unv``: Universal File Format datasets 58 of function type 4
  (frequency response function), one per response/reference pair, all on
  the same abscissa [Hz]; a pair's names are its entity names, else node and
  direction (``3+X``). UFF carries no variance.

Whatever makes a file unusable (missing, a folder, empty, random bytes, cut
short, another kind of file, wrong shapes, NaN) is a :class:`FrfFileError`
whose message is one line: the file, the problem and the fix.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ambid.array_file import check_file, read_arrays
from ambid.text_file import read_text

__all__ = ["FRF_SUFFIXES", "FrfFileError", "MeasuredFrf", "read_frf_file", "is_frf_file"]

FRF_SUFFIXES = (".npz", ".mat", ".csv", ".uff", ".unv")
_FIX = {
    ".npz": "give freq_hz (n,), H (n, ny, nu) complex, optional var (n, ny, nu), outputs and inputs (numpy.savez)",
    ".mat": "give freq_hz (n,), H (n, ny, nu) complex, optional var (n, ny, nu), outputs and inputs (MATLAB save)",
    ".csv": "give a header freq_hz, re(<out>/<in>), im(<out>/<in>) [, var(<out>/<in>)] and one row per frequency",
    ".uff": "give Universal File Format datasets 58 of function type 4 (FRF), one per output/input pair",
}
_FIX[".unv"] = _FIX[".uff"]
_COLUMN = re.compile(r"^(re|im|var)\((.+)/(.+)\)$")
_DIRECTIONS = {1: "+X", 2: "+Y", 3: "+Z", 4: "+RX", 5: "+RY", 6: "+RZ", -1: "-X", -2: "-Y", -3: "-Z", -4: "-RX",
               -5: "-RY", -6: "-RZ", 0: ""}


class FrfFileError(ValueError):
    """An FRF file that cannot be used; the message is one line: the file, the problem, the fix."""


@dataclass(frozen=True)
class MeasuredFrf:
    """An FRF read from a file.

    Attributes:
        path: the file.
        kind: 'npz', 'mat', 'csv' or 'uff'.
        freq_hz: (n,) frequencies, increasing [Hz].
        frf: (n, ny, nu) complex H [the file's unit].
        var: (n, ny, nu) variance of each entry [unit squared], or None when the file gives none.
        output_names, input_names: (ny,), (nu,).
        notes: what was assumed, a line each.
    """

    path: str
    kind: str
    freq_hz: np.ndarray
    frf: np.ndarray
    var: np.ndarray | None
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]
    notes: list[str] = field(default_factory=list)


def is_frf_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` names an FRF file by its suffix (a session is ``.mcap``)."""
    return Path(path).suffix.lower() in FRF_SUFFIXES


def read_frf_file(path: str | os.PathLike) -> MeasuredFrf:
    """Read and check an FRF file (module docstring).

    Raises:
        FrfFileError: one line naming the file, the problem and the fix.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in FRF_SUFFIXES:
        raise FrfFileError(f"{p}: '{suffix or p.name}' is not an FRF file type ({', '.join(FRF_SUFFIXES)}); give an "
                           ".npz, .mat, .csv or UFF 58 file, or a session .mcap")
    fix = _FIX[suffix]
    try:
        check_file(p, "FRF file", fix)
    except ValueError as exc:
        raise FrfFileError(str(exc)) from None
    try:
        if suffix in (".npz", ".mat"):
            freq, h, var, outs, ins, notes = _arrays(p, suffix, fix)
        elif suffix == ".csv":
            freq, h, var, outs, ins, notes = _csv(p, fix)
        else:
            freq, h, var, outs, ins, notes = _uff(p, fix)
    except PermissionError:
        raise FrfFileError(f"FRF file {p} cannot be read (permission denied); make it readable") from None
    except FrfFileError:
        raise
    except ValueError as exc:        # the shared readers' one-line messages
        raise FrfFileError(str(exc)) from None
    return _checked(p, suffix.lstrip(".").replace("unv", "uff"), freq, h, var, outs, ins, notes, fix)


def _names(value, n: int, default: str, key: str, p: Path, fix: str) -> tuple[tuple[str, ...], list[str]]:
    if value is None:
        return tuple(f"{default}{i + 1}" for i in range(n)), [f"no '{key}' names in the file: {default}1..{default}{n}"]
    a = np.asarray(value, dtype=object).reshape(-1)
    names = []
    for v in a:
        v = np.asarray(v).reshape(-1)          # a MATLAB cell holds a char array
        names.append("".join(str(x) for x in v) if v.dtype.kind in "US" and v.size > 1 else str(v[0]).strip()
                     if v.size else "")
    if len(names) != n or len(set(names)) != n or not all(names):
        raise FrfFileError(f"FRF file {p}: '{key}' holds {len(names)} name(s) {names[:6]} for {n} "
                           f"{'outputs' if key == 'outputs' else 'inputs'} of H; {fix}")
    return tuple(names), []


def _arrays(p: Path, suffix: str, fix: str):
    data = read_arrays(p, "FRF file", fix, suffixes=(suffix,), complex_names=("H",))
    for key in ("freq_hz", "H"):
        if key not in data:
            raise FrfFileError(f"FRF file {p} has no '{key}' (it holds {sorted(data) or 'nothing'}); {fix}")
    freq = np.asarray(data["freq_hz"])
    h = np.asarray(data["H"])
    if freq.ndim == 2 and 1 in freq.shape:       # MATLAB keeps vectors 2-D
        freq = freq.reshape(-1)
    if h.ndim == 2 and 1 in h.shape and freq.ndim == 1 and h.size == freq.size:   # a SISO FRF as a MATLAB vector
        h = h.reshape(-1)
    if h.ndim == 1:
        h = h[:, None, None]
    var = data.get("var")
    if var is not None:
        var = np.asarray(var)
        if var.ndim == 1 or (var.ndim == 2 and 1 in var.shape and var.size == h.shape[0]):
            var = var.reshape(-1, 1, 1)
    if h.ndim == 3:
        outs, n1 = _names(data.get("outputs"), h.shape[1], "y", "outputs", p, fix)
        ins, n2 = _names(data.get("inputs"), h.shape[2], "u", "inputs", p, fix)
    else:
        outs, ins, n1, n2 = (), (), [], []
    return freq, h, var, outs, ins, n1 + n2


def _csv(p: Path, fix: str):
    text = read_text(p, "FRF file", fix)
    rows = [ln for ln in text.splitlines() if ln.strip()]
    if not rows:
        raise FrfFileError(f"FRF file {p} holds no rows; {fix}")
    head = [c.strip().strip('"') for c in rows[0].split(",")]
    if "freq_hz" not in head:
        raise FrfFileError(f"FRF file {p}: the header {head[:6]} has no 'freq_hz' column; {fix}")
    cols: dict[tuple[str, str, str], int] = {}
    outs: list[str] = []
    ins: list[str] = []
    for i, name in enumerate(head):
        if name == "freq_hz":
            continue
        m = _COLUMN.match(name)
        if not m:
            raise FrfFileError(f"FRF file {p}: column '{name}' is not re(<out>/<in>), im(<out>/<in>) or "
                               f"var(<out>/<in>); {fix}")
        kind, o, u = m.group(1), m.group(2).strip(), m.group(3).strip()
        if (kind, o, u) in cols:
            raise FrfFileError(f"FRF file {p}: column '{name}' appears twice; give each column once")
        cols[(kind, o, u)] = i
        outs += [o] if o not in outs else []
        ins += [u] if u not in ins else []
    if not outs:
        raise FrfFileError(f"FRF file {p}: the header has no re(<out>/<in>) columns; {fix}")
    body = rows[1:]
    if not body:
        raise FrfFileError(f"FRF file {p} has a header but no rows under it; {fix}")
    try:
        x = np.array([[float(v) for v in ln.split(",")] for ln in body])
    except ValueError:
        bad = next((k for k, ln in enumerate(body) if not _floats(ln)), None)
        if bad is not None:
            raise FrfFileError(f"FRF file {p}: row {bad + 2} is not {len(head)} comma-separated numbers; "
                               f"{fix}") from None
        x = np.zeros((0, 0))  # numbers, in rows of unequal length (numpy refuses a ragged array): said below
    if x.ndim != 2 or x.shape[1] != len(head):
        widths = {len(ln.split(",")) for ln in body}
        raise FrfFileError(f"FRF file {p}: rows have {sorted(widths)} values for {len(head)} header columns (cut "
                           f"short?); {fix}")
    missing = [f"{k}({o}/{u})" for o in outs for u in ins for k in ("re", "im") if (k, o, u) not in cols]
    if missing:
        raise FrfFileError(f"FRF file {p}: no column {missing[0]} (every output/input pair needs re and im); {fix}")
    h = np.empty((len(body), len(outs), len(ins)), complex)
    for i, o in enumerate(outs):
        for j, u in enumerate(ins):
            h[:, i, j] = x[:, cols[("re", o, u)]] + 1j * x[:, cols[("im", o, u)]]
    have_var = [(o, u) for o in outs for u in ins if ("var", o, u) in cols]
    var = None
    if have_var:
        if len(have_var) != len(outs) * len(ins):
            lack = next(f"var({o}/{u})" for o in outs for u in ins if (o, u) not in have_var)
            raise FrfFileError(f"FRF file {p}: var columns for some pairs but not {lack}; give var for every pair "
                               "or for none")
        var = np.empty(h.shape)
        for i, o in enumerate(outs):
            for j, u in enumerate(ins):
                var[:, i, j] = x[:, cols[("var", o, u)]]
    return x[:, head.index("freq_hz")], h, var, tuple(outs), tuple(ins), []


def _floats(line: str) -> bool:
    try:
        [float(v) for v in line.split(",")]
    except ValueError:
        return False
    return True


def _uff(p: Path, fix: str):
    try:
        import pyuff
    except ImportError:
        raise FrfFileError(f"FRF file {p}: reading UFF needs pyuff; install ambid with its 'uff' extra "
                           "(pip install 'ambid[uff]')") from None
    try:
        sets = pyuff.UFF(str(p)).read_sets()
    except Exception as exc:  # noqa: BLE001 - pyuff raises a zoo of types on a file it cannot parse
        raise FrfFileError(f"FRF file {p} is not a readable Universal File ({type(exc).__name__}); {fix}") from None
    if isinstance(sets, dict):
        sets = [sets]
    frf_sets = [s for s in sets if isinstance(s, dict) and s.get("type") == 58 and s.get("func_type") == 4]
    if not frf_sets:
        kinds = sorted({f"{s.get('type')}/{s.get('func_type', '-')}" for s in sets if isinstance(s, dict)})
        raise FrfFileError(f"FRF file {p} holds no dataset 58 of function type 4 (FRF); found dataset/function "
                           f"types {kinds or 'none'}; {fix}")

    def name(s: dict, side: str) -> str:
        ent = str(s.get(f"{side}_ent_name", "")).strip()
        if ent and ent.upper() != "NONE":
            return ent
        return f"{int(s.get(f'{side}_node', 0))}{_DIRECTIONS.get(int(s.get(f'{side}_dir', 0)), '?')}"

    outs: list[str] = []
    ins: list[str] = []
    pairs = {}
    freq = None
    for s in frf_sets:
        o, u = name(s, "rsp"), name(s, "ref")
        if (o, u) in pairs:
            raise FrfFileError(f"FRF file {p}: two FRF datasets for response {o} / reference {u}; give one per pair")
        x = np.asarray(s.get("x"), dtype=float).reshape(-1)
        data = np.asarray(s.get("data")).reshape(-1)
        if x.size != data.size or x.size == 0:
            raise FrfFileError(f"FRF file {p}: the dataset {o}/{u} has {x.size} frequencies for {data.size} values "
                               f"(cut short?); {fix}")
        if freq is None:
            freq = x
        elif x.shape != freq.shape or not np.allclose(x, freq, rtol=1e-9, atol=0):
            raise FrfFileError(f"FRF file {p}: the dataset {o}/{u} is on other frequencies than the first; give "
                               "every pair on the same frequencies")
        pairs[(o, u)] = data
        outs += [o] if o not in outs else []
        ins += [u] if u not in ins else []
    lack = [(o, u) for o in outs for u in ins if (o, u) not in pairs]
    if lack:
        raise FrfFileError(f"FRF file {p}: no FRF for response {lack[0][0]} / reference {lack[0][1]} (the matrix "
                           f"{len(outs)} x {len(ins)} needs every pair); {fix}")
    h = np.array([[pairs[(o, u)] for u in ins] for o in outs]).transpose(2, 0, 1)
    return freq, h, None, tuple(outs), tuple(ins), []


def _checked(p: Path, kind: str, freq, h, var, outs, ins, notes, fix) -> MeasuredFrf:
    if freq.ndim != 1 or freq.size < 2:
        raise FrfFileError(f"FRF file {p}: freq_hz has shape {freq.shape}; give a vector of n >= 2 frequencies")
    if h.ndim != 3 or h.shape[0] != freq.size or 0 in h.shape:
        raise FrfFileError(f"FRF file {p}: H has shape {h.shape} for {freq.size} frequencies; give H as "
                           f"(n, ny, nu) = ({freq.size}, outputs, inputs)")
    if not (np.issubdtype(freq.dtype, np.number) and np.issubdtype(h.dtype, np.number)):
        raise FrfFileError(f"FRF file {p}: freq_hz and H must be numbers; {fix}")
    if not np.iscomplexobj(h):
        raise FrfFileError(f"FRF file {p}: H is real; give the complex FRF (real + 1j * imaginary part), not its "
                           "magnitude")
    freq = freq.astype(float)
    h = h.astype(complex)
    for key, a in (("freq_hz", freq), ("H", h)):
        bad = np.argwhere(~np.isfinite(a))
        if bad.size:
            raise FrfFileError(f"FRF file {p}: {key} is {a[tuple(bad[0])]} at index {tuple(int(i) for i in bad[0])}; "
                               "give finite values (leave that frequency out)")
    if freq[0] <= 0 or np.any(np.diff(freq) <= 0):
        k = 0 if freq[0] <= 0 else int(np.argmax(np.diff(freq) <= 0)) + 1
        raise FrfFileError(f"FRF file {p}: freq_hz[{k}] = {freq[k]:g} Hz; give positive frequencies in increasing "
                           "order")
    if var is not None:
        var = np.asarray(var)
        if var.shape != h.shape or not np.issubdtype(var.dtype, np.number) or np.iscomplexobj(var):
            raise FrfFileError(f"FRF file {p}: var has shape {var.shape} ({var.dtype}); give the real variance of "
                               f"each entry of H, shape {h.shape}")
        var = var.astype(float)
        bad = np.argwhere(~(np.isfinite(var) & (var > 0)))
        if bad.size:
            raise FrfFileError(f"FRF file {p}: var is {var[tuple(bad[0])]} at index {tuple(int(i) for i in bad[0])}; "
                               "give finite variances > 0 (or leave var out)")
    return MeasuredFrf(path=os.fspath(p), kind=kind, freq_hz=freq, frf=h, var=var, output_names=tuple(outs),
                       input_names=tuple(ins), notes=list(notes))
