"""A measured FRF handed over as a file (an analyser's, another tool's): read, checked, named.

Formats, by suffix:

* ``.npz`` or ``.mat`` (MATLAB v5 or v7.3): ``freq_hz`` (n,), ``H`` (n, ny, nu)
  complex, optional ``var`` (n, ny, nu) the variance of each entry
  ``E|H - H0|^2``, optional ``outputs`` (ny,) and ``inputs`` (nu,) names
  (a SISO ``H`` may be (n,));
* ``.csv``: a header row, then one row per frequency: ``freq_hz``,
  ``re(<out>/<in>)`` and ``im(<out>/<in>)`` for every output and input,
  optional ``var(<out>/<in>)`` for all of them;
* ``.uff`` or ``.unv`` (ASCII or binary 58b): Universal File Format datasets
  58 of function type 4 (frequency response function: receptance, mobility,
  accelerance, as the data types of its ordinate and denominator say) or 5
  (transmissibility), one per response/reference pair, all on the same
  abscissa [Hz] as written. A channel is its node and direction (``3+X``), as
  UFF identifies it; entity names are labels only (an analyser often writes
  the test's name on every dataset). Units come from the header (the unit
  labels where written, else the SI unit of the data type). UFF carries no
  variance; the analyser's coherence (function type 6) is read where written;
  a units dataset 164 that is not SI (a file in mm, in, lbf) has its
  factors applied, so the FRF is in SI and says so in a note;
* ``.s1p``, ``.s2p``, ... (Touchstone version 1, as a vector network analyser
  writes it): an N-port's S, Y or Z parameters, one FRF per port pair
  (:mod:`ambid.frf.touchstone`).

A first line at 0 Hz (any format) is left out with a note.

Optional ``output_units`` and ``input_units`` (npz, mat) name each channel's
unit; the fit, the modes and the report carry them.

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
from ambid.frf.touchstone import TOUCHSTONE_FIX, is_touchstone, read_touchstone
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

    Attributes
    ----------
    path
        the file.
    kind
        'npz', 'mat', 'csv', 'uff' or 'touchstone'.
    freq_hz
        (n,) frequencies, increasing [Hz].
    frf
        (n, ny, nu) complex H [the file's unit].
    var
        (n, ny, nu) variance of each entry [unit squared], or None when the file gives none.
    output_names, input_names
        (ny,), (nu,).
    notes
        what was assumed, a line each.
    output_units, input_units
        (ny,), (nu,) each channel's unit as the file says it ('' where it says none).
    form
        what H is: 'FRF', 'receptance', 'mobility', 'accelerance', 'transmissibility', or a network's
        'S-parameters', 'impedance' or 'admittance'.
    coherence
        (n, ny, nu) the analyser's coherence of each response with each reference (UFF function
        type 6; NaN where the file has none), or None.
    """

    path: str
    kind: str
    freq_hz: np.ndarray
    frf: np.ndarray
    var: np.ndarray | None
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]
    notes: list[str] = field(default_factory=list)
    output_units: tuple[str, ...] = ()
    input_units: tuple[str, ...] = ()
    form: str = "FRF"
    coherence: np.ndarray | None = None

    @property
    def unit(self) -> str:
        """H's unit, '<output unit>/<input unit>' where every output and every input share one; else ''."""
        o, i = set(self.output_units), set(self.input_units)
        if len(o) == 1 and len(i) == 1 and all(o | i):
            return f"{o.pop()}/{i.pop()}"
        return ""


def is_frf_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` names an FRF file by its suffix (a session is ``.mcap``)."""
    return Path(path).suffix.lower() in FRF_SUFFIXES or is_touchstone(path)


def read_frf_file(path: str | os.PathLike) -> MeasuredFrf:
    """Read and check an FRF file (module docstring).

    Raises
    ------
    FrfFileError
        one line naming the file, the problem and the fix.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if not is_frf_file(p):
        raise FrfFileError(f"{p}: '{suffix or p.name}' is not an FRF file type ({', '.join(FRF_SUFFIXES)}, .sNp); "
                           "give an .npz, .mat, .csv, UFF 58 or Touchstone file, or a session .mcap")
    fix = TOUCHSTONE_FIX if is_touchstone(p) else _FIX[suffix]
    try:
        check_file(p, "FRF file", fix)
    except ValueError as exc:
        raise FrfFileError(str(exc)) from None
    try:
        if suffix in (".npz", ".mat"):
            freq, h, var, outs, ins, notes, extra = _arrays(p, suffix, fix)
        elif suffix == ".csv":
            freq, h, var, outs, ins, notes = _csv(p, fix)
            extra = {}
        elif is_touchstone(p):
            freq, h, outs, ins, notes, extra = read_touchstone(p)
            var, suffix = None, ".touchstone"
        else:
            freq, h, var, outs, ins, notes, extra = _uff(p, fix)
    except PermissionError:
        raise FrfFileError(f"FRF file {p} cannot be read (permission denied); make it readable") from None
    except FrfFileError:
        raise
    except ValueError as exc:        # the shared readers' one-line messages
        raise FrfFileError(str(exc)) from None
    return _checked(p, suffix.lstrip(".").replace("unv", "uff"), freq, h, var, outs, ins, notes, fix, **extra)


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
    extra = {}
    for key in ("output_units", "input_units"):
        if key in data:
            extra[key] = tuple(str(np.asarray(v).reshape(-1)[0]).strip() if np.asarray(v).size else ""
                               for v in np.asarray(data[key], dtype=object).reshape(-1))
    return freq, h, var, outs, ins, n1 + n2, extra


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
    # each row checked for itself: a file cut short ends in a row that may still parse, only shorter
    x = np.empty((len(body), len(head)))
    for k, ln in enumerate(body):
        values = _floats(ln)
        if values is None:
            raise FrfFileError(f"FRF file {p}: row {k + 2} is not {len(head)} comma-separated numbers; {fix}")
        if len(values) != len(head):
            raise FrfFileError(f"FRF file {p}: row {k + 2} has {len(values)} values for {len(head)} header columns "
                               f"(cut short?); {fix}")
        x[k] = values
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


def _floats(line: str) -> list[float] | None:
    """The comma-separated numbers of ``line``, or None where one is not a number."""
    try:
        return [float(v) for v in line.split(",")]
    except ValueError:
        return None


# UFF dataset 58: function types (record 6, field 1) that are ratios of a response to a reference
_UFF_RATIOS = {4: "FRF", 5: "transmissibility"}
# specific data types (records 8-10, field 1) -> (quantity, SI unit)
_UFF_DATA = {1: ("general", ""), 2: ("stress", "Pa"), 3: ("strain", "m/m"), 5: ("temperature", "K"),
             6: ("heat flux", "W/m^2"), 8: ("displacement", "m"), 9: ("reaction force", "N"), 11: ("velocity", "m/s"),
             12: ("acceleration", "m/s^2"), 13: ("excitation force", "N"), 15: ("pressure", "Pa"),
             16: ("mass", "kg"), 17: ("time", "s"), 18: ("frequency", "Hz"), 19: ("rpm", "rpm"),
             20: ("order", ""), 21: ("sound pressure", "Pa"), 22: ("sound intensity", "W/m^2"),
             23: ("sound power", "W")}
# specific data type -> its dimension as (length, force) exponents, time in s (UFF 164's factors convert L and F)
_UFF_DIMENSION = {2: (-2, 1), 3: (0, 0), 8: (1, 0), 9: (0, 1), 11: (1, 0), 12: (1, 0), 13: (0, 1), 15: (-2, 1),
                  16: (-1, 1), 21: (-2, 1)}
# (response quantity, reference quantity) -> the FRF's name
_FRF_FORMS = {("displacement", "force"): "receptance", ("velocity", "force"): "mobility",
              ("acceleration", "force"): "accelerance"}


def _uff_unit(s: dict, axis: str, si: bool = False) -> tuple[str, str]:
    """(quantity, unit) of one axis of a dataset 58 (``ordinate``, ``orddenom``, ``abscissa``): the unit label the
    header writes where it writes one, else (or where ``si``: the values were converted to SI by dataset 164)
    the SI unit of the specific data type."""
    kind = int(s.get(f"{axis}_spec_data_type", 0) or 0)
    quantity, si_unit = _UFF_DATA.get(kind, ("unknown", ""))
    label = str(s.get(f"{axis}_axis_units_lab", "") or "").strip()
    unit = label if label and label.upper() != "NONE" and not (si and si_unit) else si_unit
    return quantity, unit.replace("m/s2", "m/s^2")


def _uff_units_164(sets: list) -> tuple[float, float, str] | None:
    """(length factor, force factor, description) of the file's units dataset 164, or None where it has none or its
    units are SI. UFF's factors convert the file's units to SI by division (1000 for a length in mm)."""
    for s in sets:
        if isinstance(s, dict) and s.get("type") == 164:
            lf, ff = float(s.get("length", 1.0) or 1.0), float(s.get("force", 1.0) or 1.0)
            if np.isclose(lf, 1.0, rtol=1e-9) and np.isclose(ff, 1.0, rtol=1e-9):
                return None
            return lf, ff, str(s.get("units_description", "") or "").strip()
    return None


def _uff_to_si(s: dict, units164: tuple[float, float, str] | None) -> float | None:
    """The factor turning a dataset 58's ordinate / denominator into SI per dataset 164 (1.0 without one), or None
    where a data type's dimension is unknown (general, unknown) and 164 says the file is not in SI."""
    if units164 is None:
        return 1.0
    lf, ff, _ = units164
    dims = [_UFF_DIMENSION.get(int(s.get(f"{axis}_spec_data_type", 0) or 0)) for axis in ("ordinate", "orddenom")]
    if None in dims:
        return None
    (a_out, b_out), (a_in, b_in) = dims
    return (lf ** a_in * ff ** b_in) / (lf ** a_out * ff ** b_out)


def _uff_channel(s: dict, side: str) -> tuple[str, str]:
    """(channel, label) of a dataset's response or reference: UFF names a channel by its node and direction
    (``3+X``); the entity name is a free label (often the test's name on every dataset)."""
    node, direction = int(s.get(f"{side}_node", 0) or 0), int(s.get(f"{side}_dir", 0) or 0)
    ent = str(s.get(f"{side}_ent_name", "") or "").strip()
    return f"{node}{_DIRECTIONS.get(direction, f'({direction})')}", "" if ent.upper() == "NONE" else ent


def _uff_coherence(sets: list, outs: list[str], ins: list[str], freq: np.ndarray,
                   shape: tuple[int, ...]) -> np.ndarray | None:
    """The analyser's coherence (L, Ny, Nu) of each response with each reference (function type 6), NaN where
    it wrote none; None where it wrote none at all."""
    coh = np.full(shape, np.nan)
    for s in sets:
        if not (isinstance(s, dict) and s.get("type") == 58 and s.get("func_type") == 6):
            continue
        (o, _), (u, _) = _uff_channel(s, "rsp"), _uff_channel(s, "ref")
        x = np.asarray(s.get("x"), dtype=float).reshape(-1)
        if o in outs and u in ins and x.shape == freq.shape and np.allclose(x, freq, rtol=1e-9, atol=0):
            coh[:, outs.index(o), ins.index(u)] = np.abs(np.asarray(s.get("data")).reshape(-1))
    return coh if np.any(np.isfinite(coh)) else None


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
    frf_sets = [s for s in sets if isinstance(s, dict) and s.get("type") == 58 and s.get("func_type") in _UFF_RATIOS]
    if not frf_sets:
        kinds = sorted({f"{s.get('type')}/{s.get('func_type', '-')}" for s in sets if isinstance(s, dict)})
        raise FrfFileError(f"FRF file {p} holds no dataset 58 of function type 4 (FRF) or 5 (transmissibility); "
                           f"found dataset/function types {kinds or 'none'}; {fix}")
    if len({int(s.get("func_type")) for s in frf_sets}) > 1:
        raise FrfFileError(f"FRF file {p} mixes FRFs (function type 4) and transmissibilities (5); give one kind "
                           "per file")
    units164 = _uff_units_164(sets)
    outs: list[str] = []
    ins: list[str] = []
    labels: dict[tuple[str, str], set[str]] = {}
    units: dict[tuple[str, str], str] = {}
    quantities: dict[tuple[str, str], str] = {}
    pairs = {}
    freq = None
    for s in frf_sets:
        (o, lo), (u, lu) = _uff_channel(s, "rsp"), _uff_channel(s, "ref")
        if (o, u) in pairs:
            raise FrfFileError(f"FRF file {p}: two FRF datasets for response {o} / reference {u} (node and "
                               "direction); give one per pair")
        x_kind, x_unit = _uff_unit(s, "abscissa")
        if x_kind not in ("frequency", "unknown", "general") or x_unit not in ("Hz", ""):
            raise FrfFileError(f"FRF file {p}: the dataset {o}/{u} has a {x_kind} abscissa [{x_unit}]; give FRFs "
                               "over frequency in Hz")
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
        for key, lab in ((("response", o), lo), (("reference", u), lu)):
            if lab:
                labels.setdefault(key, set()).add(lab)
        to_si = _uff_to_si(s, units164)
        if to_si is None:
            raise FrfFileError(f"FRF file {p}: dataset 164 gives units '{units164[2]}' (not SI), and the dataset "
                               f"{o}/{u} has a quantity of no known dimension; give data types (displacement, "
                               "velocity, acceleration, force, ...) or write the file in SI")
        data = data * to_si
        for ch, axis, side in ((o, "ordinate", "response"), (u, "orddenom", "reference")):
            q, unit = _uff_unit(s, axis, si=units164 is not None)
            if units.setdefault((side, ch), unit) != unit:
                raise FrfFileError(f"FRF file {p}: {side} {ch} is in {units[(side, ch)]} in one dataset and in "
                                   f"{unit} in another; give one unit per channel")
            quantities.setdefault((side, ch), q)
        pairs[(o, u)] = data
        outs += [o] if o not in outs else []
        ins += [u] if u not in ins else []
    lack = [(o, u) for o in outs for u in ins if (o, u) not in pairs]
    if lack:
        raise FrfFileError(f"FRF file {p}: no FRF for response {lack[0][0]} / reference {lack[0][1]} (the matrix "
                           f"{len(outs)} x {len(ins)} needs every pair); {fix}")
    h = np.array([[pairs[(o, u)] for u in ins] for o in outs]).transpose(2, 0, 1)
    func = _UFF_RATIOS[int(frf_sets[0]["func_type"])]
    q_out = {quantities[("response", o)] for o in outs}
    q_in = {"force" if "force" in quantities[("reference", u)] else quantities[("reference", u)] for u in ins}
    form = func
    if func == "FRF" and len(q_out) == 1 and len(q_in) == 1:
        form = _FRF_FORMS.get((q_out.pop(), q_in.pop()), "FRF")
    def listed(chs, side):
        return ", ".join(f"{c} [{units[(side, c)] or '-'}]" for c in chs)

    notes = [f"UFF 58 {func}s, {form}: outputs {listed(outs, 'response')}; inputs {listed(ins, 'reference')} "
             "(channels by node and direction)"]
    if units164 is not None:
        notes.append(f"dataset 164: the file's units are '{units164[2] or 'user defined'}' (length factor "
                     f"{units164[0]:g}, force factor {units164[1]:g}); the FRFs are converted to SI")
    shared = set.intersection(*labels.values()) if labels and len(labels) == len(outs) + len(ins) else set()
    if shared:
        notes.append(f"entity name {sorted(shared)[0]!r} on every dataset: a label of the test, not a channel")
    coherence = _uff_coherence(sets, outs, ins, freq, h.shape)
    if coherence is not None:
        coh = coherence
        notes.append(f"coherence read for {int(np.sum(np.all(np.isfinite(coh), axis=0)))} of {h.shape[1] * h.shape[2]} "
                     "response/reference pairs")
    return (freq, h, None, tuple(outs), tuple(ins), notes,
            dict(output_units=tuple(units[("response", o)] for o in outs),
                 input_units=tuple(units[("reference", u)] for u in ins), form=form, coherence=coherence))


def _checked(p: Path, kind: str, freq, h, var, outs, ins, notes, fix, output_units=None, input_units=None,
             form: str = "FRF", coherence: np.ndarray | None = None) -> MeasuredFrf:
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
    notes = list(notes)
    if freq.size > 2 and freq[0] == 0:
        # an analyser's first line is often 0 Hz: a static value (or NaN) that no model of the modes describes
        freq, h = freq[1:], h[1:]
        var = None if var is None or np.ndim(var) != 3 else np.asarray(var)[1:]
        coherence = None if coherence is None else coherence[1:]
        notes.append("the 0 Hz line is left out (a static value, often undefined, that no model of the modes "
                     "describes)")
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
    for key, units, names in (("output_units", output_units, outs), ("input_units", input_units, ins)):
        if units is not None and len(units) != len(names):
            raise FrfFileError(f"FRF file {p}: '{key}' holds {len(units)} unit(s) for {len(names)} channels; give one "
                               "unit per channel")
    return MeasuredFrf(path=os.fspath(p), kind=kind, freq_hz=freq, frf=h, var=var, output_names=tuple(outs),
                       input_names=tuple(ins), notes=list(notes),
                       output_units=tuple(output_units or ("",) * len(outs)),
                       input_units=tuple(input_units or ("",) * len(ins)), form=form, coherence=coherence)
