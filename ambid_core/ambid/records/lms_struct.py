"""Signals as Siemens LMS Test.Lab / Simcenter Testlab export them to MATLAB: one struct per signal.

::

    Signal.x_values.start_value, .increment, .number_of_values    the time base [s]
    Signal.y_values.values                                        (n,) or (n, k) samples, in MKS
    Signal.y_values.quantity.label, .unit_transformation.factor    the display unit and its factor
    Signal.y_values.quantity.quantity_terms                        SI base exponents (LENGTH, MASS, TIME, ...)
    Signal.function_record.primary_channel.label                  the channel's name, one per column

A record's channel is named by its ``primary_channel`` label (``Welle:1:+X``),
else by the struct's ``function_record.name``, else ``<variable>[k]``. Its unit
is the SI unit its quantity terms spell (the values are saved in MKS; a display
unit such as g is only a label with a factor). Such exports are small (one
struct per signal, the values stored whole), so a struct is read whole with
scipy; a record of vectors or of a matrix is still read in chunks
(:mod:`ambid.records.readers`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LmsSignal", "is_lms_struct", "read_lms_signals", "si_unit"]

_BASE = ("LENGTH", "MASS", "TIME", "CURRENT", "TEMPERATURE", "ANGLE")
_SYMBOL = {"LENGTH": "m", "MASS": "kg", "TIME": "s", "CURRENT": "A", "TEMPERATURE": "K", "ANGLE": "rad"}
# exponents (LENGTH, MASS, TIME, CURRENT, TEMPERATURE, ANGLE) -> the unit's usual name
_NAMED = {(1, 0, 0, 0, 0, 0): "m", (1, 0, -1, 0, 0, 0): "m/s", (1, 0, -2, 0, 0, 0): "m/s^2",
          (1, 1, -2, 0, 0, 0): "N", (2, 1, -3, -1, 0, 0): "V", (0, 0, 0, 1, 0, 0): "A",
          (-1, 1, -2, 0, 0, 0): "Pa", (0, 0, 1, 0, 0, 0): "s", (0, 0, 0, 0, 0, 1): "rad",
          (0, 0, -1, 0, 0, 1): "rad/s", (0, 0, 0, 0, 0, 0): "-"}


@dataclass(frozen=True)
class LmsSignal:
    """One exported struct.

    Attributes
    ----------
    variable
        the MATLAB variable.
    names
        (k,) channel names, one per column.
    unit
        the SI unit of its values ('' when the file does not say).
    display
        the unit Test.Lab displayed (e.g. 'g'), for the note.
    start_s, dt_s
        the time base [s].
    values
        (n, k) float64.
    """

    variable: str
    names: tuple[str, ...]
    unit: str
    display: str
    start_s: float
    dt_s: float
    values: np.ndarray


def _text(v) -> str:
    a = np.asarray(v)
    if a.dtype.kind in "US":
        return "".join(str(x) for x in a.reshape(-1)).strip() if a.ndim else str(a).strip()
    return ""


def _labels(v) -> list[str]:
    """One name per column: a MATLAB char array (as scipy gives it: one character per element) is one name, a
    cell array one per cell."""
    if v is None:
        return []
    if isinstance(v, str):
        return [v.strip()]
    a = np.asarray(v)
    if a.dtype.kind in "US":
        return ["".join(str(x) for x in a.reshape(-1)).strip()] if all(len(str(x)) <= 1 for x in a.reshape(-1)) \
            else [str(x).strip() for x in a.reshape(-1)]
    return [_text(x) for x in a.reshape(-1)]


def si_unit(terms) -> str:
    """The SI unit spelt by LMS quantity terms (``num``/``den`` exponents per base quantity); '' without terms."""
    exps = dict.fromkeys(_BASE, 0.0)
    seen = False
    for t in np.atleast_1d(terms):
        q = _text(getattr(t, "quantity", ""))
        if q in exps:
            den = float(getattr(t, "den", 1) or 1)
            exps[q] = float(getattr(t, "num", 0)) / den
            seen = True
    if not seen:
        return ""
    key = tuple(int(exps[b]) if float(exps[b]).is_integer() else exps[b] for b in _BASE)
    if key in _NAMED:
        return _NAMED[key]
    return " ".join(f"{_SYMBOL[b]}^{e:g}" if e != 1 else _SYMBOL[b] for b, e in zip(_BASE, key) if e)


def is_lms_struct(value) -> bool:
    """A struct with x_values and y_values (as scipy loads it with struct_as_record=False)."""
    names = getattr(value, "_fieldnames", None) or ()
    return "x_values" in names and "y_values" in names


def read_lms_signals(path: str, variables: list[str]) -> list[LmsSignal]:
    """The LMS structs among ``variables`` of a MAT v5 file (others are left out).

    Raises
    ------
    ValueError
        a struct whose time base or values do not fit (one line: the variable and the fix).
    """
    from scipy.io import loadmat

    raw = loadmat(path, variable_names=variables, squeeze_me=True, struct_as_record=False)
    out = []
    for var in variables:
        s = raw.get(var)
        if not is_lms_struct(s):
            continue
        x, y = s.x_values, s.y_values
        try:
            start, dt, n = float(x.start_value), float(x.increment), int(x.number_of_values)
        except (AttributeError, TypeError, ValueError):
            raise ValueError(f"{path}: '{var}'.x_values has no start_value, increment and number_of_values; give "
                             "the time signal as Test.Lab exports it") from None
        values = np.asarray(getattr(y, "values", None))
        if values.dtype.kind not in "fiu" or values.ndim not in (1, 2) or values.shape[0] != n or not dt > 0:
            kind = "complex (a spectrum or FRF, not a time signal)" if values.dtype.kind == "c" else \
                f"{values.shape} {values.dtype}"
            raise ValueError(f"{path}: '{var}'.y_values.values is {kind} for {n} time values at {dt:g} s; give "
                             "real time signals, one row per sample")
        values = values.reshape(n, -1).astype(float)
        k = values.shape[1]
        fr = getattr(s, "function_record", None)
        pc = getattr(fr, "primary_channel", None)
        labels = _labels(getattr(pc, "label", None)) if pc is not None else []
        if len(labels) != k or not all(labels):
            labels = _labels(getattr(fr, "name", None)) if fr is not None else []
        if len(labels) != k or not all(labels) or len(set(labels)) != k:
            labels = [var] if k == 1 else [f"{var}[{j + 1}]" for j in range(k)]
        q = getattr(y, "quantity", None)
        out.append(LmsSignal(var, tuple(labels), si_unit(getattr(q, "quantity_terms", [])),
                             _text(getattr(q, "label", "")), start, dt, values))
    return out
