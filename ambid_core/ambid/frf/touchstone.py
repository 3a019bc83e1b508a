"""Touchstone (version 1) network-parameter files, as vector network analysers and RF tools write them.

A ``.sNp`` file holds an N-port's S, Y or Z parameters over frequency: an
option line ``# <unit> <parameter> <format> R <z0>`` (defaults ``GHz S MA R
50``), comments after ``!``, then per frequency the frequency and 2 N^2 numbers
(real/imaginary, magnitude/angle in degrees, or dB/angle), a 2-port's in the
order 11, 21, 12, 22 and every other N-port's row by row, over as many lines as
the writer wraps them. A 2-port's noise parameters, which follow its data on
frequencies that start again, are left out with a note.

The parameters become an FRF matrix ``H[k, i, j]`` = parameter ``ij`` at line
``k``: for S, the wave leaving port i over the wave entering port j (outputs
``b1..bN``, inputs ``a1..aN``, dimensionless); for Z, the voltage at port i over
the current into port j (``V1..`` [V] over ``I1..`` [A]); for Y the reverse.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ambid.text_file import read_text

__all__ = ["TOUCHSTONE_FIX", "is_touchstone", "read_touchstone"]

TOUCHSTONE_FIX = ("give a Touchstone version 1 file: '# <Hz|kHz|MHz|GHz> <S|Y|Z> <RI|MA|DB> R <z0>', then per "
                  "frequency the frequency and 2 N^2 numbers")
_SUFFIX = re.compile(r"^\.s(\d{1,2})p$", re.IGNORECASE)
_UNITS = {"HZ": 1.0, "KHZ": 1e3, "MHZ": 1e6, "GHZ": 1e9}
# parameter -> (output name, output unit, input name, input unit, what H is)
_PARAMETERS = {"S": ("b", "", "a", "", "S-parameters"), "Z": ("V", "V", "I", "A", "impedance"),
               "Y": ("I", "A", "V", "V", "admittance")}


def is_touchstone(path: str | Path) -> bool:
    """Whether ``path`` names a Touchstone file by its suffix.

    Parameters
    ----------
    path : str or Path
        A file name.

    Returns
    -------
    bool
        True for ``.s1p``, ``.s2p``, ... ``.s99p`` (any case).
    """
    m = _SUFFIX.match(Path(path).suffix)
    return bool(m) and int(m.group(1)) > 0


def _options(line: str, p: Path) -> tuple[float, str, str, float]:
    """(frequency scale [Hz per unit], parameter, number format, reference impedance [ohm]) of an option line."""
    scale, param, fmt, z0 = 1e9, "S", "MA", 50.0
    tokens = line[1:].split()
    k = 0
    while k < len(tokens):
        t = tokens[k].upper()
        if t in _UNITS:
            scale = _UNITS[t]
        elif t in ("S", "Y", "Z", "H", "G"):
            param = t
        elif t in ("RI", "MA", "DB"):
            fmt = t
        elif t == "R" and k + 1 < len(tokens):
            try:
                z0 = float(tokens[k + 1])
            except ValueError:
                raise ValueError(f"FRF file {p}: the option line's reference impedance '{tokens[k + 1]}' is not a "
                                 f"number; {TOUCHSTONE_FIX}") from None
            k += 1
        else:
            raise ValueError(f"FRF file {p}: '{tokens[k]}' in the option line '{line.strip()}' is no Touchstone "
                             f"option; {TOUCHSTONE_FIX}")
        k += 1
    if param not in _PARAMETERS:
        raise ValueError(f"FRF file {p} holds {param} (hybrid) parameters, which mix voltages and currents; give "
                         "S, Y or Z parameters")
    return scale, param, fmt, z0


def _numbers(text: str, p: Path) -> tuple[str | None, np.ndarray]:
    """The option line (or None) and every number of the data lines, in order."""
    option = None
    values: list[float] = []
    for n, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("!", 1)[0].strip()
        if not line:
            continue
        if line.startswith("#"):
            option = option or line
            continue
        if line.startswith("["):
            raise ValueError(f"FRF file {p} is Touchstone version 2 (keyword '{line.split()[0]}' on line {n}); "
                             f"{TOUCHSTONE_FIX}")
        try:
            values.extend(float(v) for v in line.split())
        except ValueError:
            raise ValueError(f"FRF file {p}: line {n} '{line[:40]}' is not numbers; {TOUCHSTONE_FIX}") from None
    return option, np.asarray(values, dtype=float)


def read_touchstone(path: str | Path):
    """Read a Touchstone v1 file as an FRF matrix (module docstring).

    Parameters
    ----------
    path : str or Path
        A ``.sNp`` file.

    Returns
    -------
    tuple
        ``(freq_hz (L,), H (L, N, N) complex, outputs (N,), inputs (N,), notes, extra)``, ``extra`` holding
        ``output_units``, ``input_units`` and ``form`` for :class:`ambid.frf.frf_file.MeasuredFrf`.

    Raises
    ------
    ValueError
        One line naming the file, the problem and the fix.
    """
    p = Path(path)
    n_ports = int(_SUFFIX.match(p.suffix).group(1))
    option, x = _numbers(read_text(p, "FRF file", TOUCHSTONE_FIX), p)
    if option is None:
        raise ValueError(f"FRF file {p} has no option line ('# GHz S RI R 50'); {TOUCHSTONE_FIX}")
    scale, param, fmt, z0 = _options(option, p)
    width = 1 + 2 * n_ports ** 2
    notes = []
    if n_ports == 2:
        # a 2-port's noise parameters follow on frequencies that start again: the data ends where they begin
        starts = np.arange(0, x.size - width + 1, width)
        f = x[starts]
        back = np.flatnonzero(np.diff(f) <= 0)
        if back.size:
            x = x[:starts[back[0] + 1]]
            notes.append("the 2-port's noise parameters after its data are left out")
    if x.size == 0 or x.size % width:
        raise ValueError(f"FRF file {p} holds {x.size} numbers, not a whole number of rows of {width} (the "
                         f"frequency and {2 * n_ports ** 2} for a {n_ports}-port): cut short, or not a "
                         f".s{n_ports}p; {TOUCHSTONE_FIX}")
    rows = x.reshape(-1, width)
    a, b = rows[:, 1::2], rows[:, 2::2]
    if fmt == "RI":
        v = a + 1j * b
    else:
        mag = a if fmt == "MA" else 10.0 ** (a / 20.0)
        v = mag * np.exp(1j * np.deg2rad(b))
    h = v.reshape(-1, n_ports, n_ports)
    if n_ports == 2:      # Touchstone's 2-port order is 11, 21, 12, 22 (column by column)
        h = h.transpose(0, 2, 1)
    out_name, out_unit, in_name, in_unit, form = _PARAMETERS[param]
    outs = tuple(f"{out_name}{i + 1}" for i in range(n_ports))
    ins = tuple(f"{in_name}{i + 1}" for i in range(n_ports))
    notes.insert(0, f"Touchstone {n_ports}-port {param} parameters ({fmt}, reference impedance {z0:g} ohm): "
                    f"H[{outs[0]}/{ins[0]}] = {param}11")
    extra = dict(output_units=(out_unit,) * n_ports, input_units=(in_unit,) * n_ports, form=form)
    return rows[:, 0] * scale, h, outs, ins, notes, extra
