"""A position controller as its owner has it: a discrete state space or per-axis transfer functions
in a file (.npz, .mat or YAML).

The model maps the na measured displacements y [m] of the rig's axes (its
layout's order, e.g. ``y_a_x y_b_x y_a_y y_b_y``, ``y_z`` last on a five-axis
rig) to the na control currents ic [A] in the same order, minus sign included
(ic = K(z) y), at the rig's sample period. Keys (any case):

* state space: ``A`` (n, n), ``B`` (n, na), ``C`` (na, n), ``D`` (na, na), and
  the sample period ``dt`` (or ``Ts``) [s]; or
* transfer functions in z^-1 powers, the same on every axis (``num``,
  ``den``: 1-D) or one per axis (``num``, ``den``: na rows, zero-padded), and
  ``dt``: axis i maps y_i to ic_i only.

A controller that computes ic[k] from y[k] (D != 0, no computational delay)
is run as given; the usual digital controller, whose output is one sample
late, has D = 0 and lets the loop pipeline (docs/architecture.md).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np
from scipy import io as sio

from ambid.array_file import read_arrays
from ambid.channels import RADIAL, Layout
from ambid.statespace import StateSpace, block_diag

FIX = "give A, B, C, D and dt (or num, den and dt) of a discrete y [m] -> ic [A] controller"


def _read(path: Path) -> dict[str, Any]:
    data = read_arrays(path, "controller file", FIX, (".npz", ".mat", ".yaml", ".yml"))
    return {str(k).lower(): v for k, v in data.items()}


def _matrix(data: dict, key: str, path: Path, ndim: int = 2) -> np.ndarray:
    try:
        m = np.asarray(data[key], dtype=float)
    except KeyError:
        raise ValueError(f"controller file {path} has no '{key.upper()}'; {FIX}") from None
    except (TypeError, ValueError):
        raise ValueError(f"controller file {path}: '{key.upper()}' is not numeric; {FIX}") from None
    if ndim == 2:
        m = np.atleast_2d(m) if m.size else m.reshape(0, 0)
    if not np.all(np.isfinite(m)):
        raise ValueError(f"controller file {path}: '{key.upper()}' holds NaN or Inf; give finite values")
    return m


def _scalar(data: dict, keys: tuple[str, ...], path: Path) -> float:
    for k in keys:
        if k in data:
            try:
                v = np.asarray(data[k], dtype=float).ravel()
            except (TypeError, ValueError):
                v = np.zeros(0)
            if v.size == 1 and np.isfinite(v[0]) and v[0] > 0:
                return float(v[0])
            raise ValueError(f"controller file {path}: '{k}' must be one positive number of seconds")
    raise ValueError(f"controller file {path} has no sample period (dt); {FIX}")


def _from_transfer_functions(data: dict, path: Path, dt: float, na: int) -> StateSpace:
    num, den = _matrix(data, "num", path), _matrix(data, "den", path)
    if num.shape[0] == 1:
        num, den = np.repeat(num, na, axis=0), np.repeat(np.atleast_2d(den), na, axis=0)
    if num.shape[0] != na or den.shape[0] != na:
        raise ValueError(f"controller file {path}: num and den must have 1 row (every axis) or {na} rows (one per "
                         f"axis), got {num.shape[0]} and {den.shape[0]}")
    axes = []
    for i in range(na):
        length = max(num.shape[1], den.shape[1])
        n, d = np.pad(num[i], (0, length - num.shape[1])), np.pad(den[i], (0, length - den.shape[1]))
        while length > 1 and n[length - 1] == 0 and d[length - 1] == 0:  # common z^-k factors of padding
            length -= 1
        n, d = n[:length], d[:length]
        if d[0] == 0:
            raise ValueError(f"controller file {path}: den of axis {i + 1} must start with a non-zero z^0 "
                             "coefficient (a causal filter in powers of z^-1)")
        # equal lengths in z^-1 are the same polynomials in z: b0 z^m + ... over a0 z^m + ...
        from scipy import signal  # here, not at the top: it imports scipy.stats, ~0.5 s in every controller node

        with warnings.catch_warnings():  # b0 = 0 (a sample of delay) is normal here, not badly conditioned
            warnings.simplefilter("ignore", signal.BadCoefficients)
            a, b, c, dd = signal.tf2ss(n, d)
        axes.append(StateSpace(a, b, c, dd, dt))
    return block_diag(*axes)


def load_controller(path: str | Path, dt_s: float, whose: str = "the rig's", layout: Layout = RADIAL) -> StateSpace:
    """The controller in ``path`` as a discrete StateSpace at ``dt_s``, on the axes of ``layout`` (the rig's,
    the record's): na inputs (y) and na outputs (ic).

    ``whose`` names the sample period ``dt_s`` in a refusal ("the rig's", "the record's").

    Raises
    ------
    ValueError
        one line naming the file, what is wrong and the fix (missing, unreadable, a key
        missing, wrong shapes, NaN/Inf, a sample period other than the rig's).
    """
    path = Path(path)
    data = _read(path)
    dt = _scalar(data, ("dt", "ts", "sample_period_s"), path)
    if abs(dt - dt_s) > 1e-9 * dt_s:
        raise ValueError(f"controller file {path}: sample period {dt:g} s differs from {whose} {dt_s:g} s; "
                         f"discretise the controller at {whose} sample rate")
    na = len(layout)
    if "num" in data or "den" in data:
        model = _from_transfer_functions(data, path, dt_s, na)
    else:
        a, b, c, d = (_matrix(data, k, path) for k in ("a", "b", "c", "d"))
        n = a.shape[0]
        shapes = {"A": (a.shape, (n, n)), "B": (b.shape, (n, na)), "C": (c.shape, (na, n)),
                  "D": (d.shape, (na, na))}
        for key, (got, want) in shapes.items():
            if n and got != want or not n and key == "D" and got != want:
                raise ValueError(f"controller file {path}: {key} is {got[0]} x {got[1]}, expected {want[0]} x "
                                 f"{want[1]} ({na} displacements in, {na} currents out, {n} states)")
        if not n:
            b, c = np.zeros((0, na)), np.zeros((na, 0))
        model = StateSpace(a, b, c, d, dt_s)
    return model._replace(input_names=layout.outputs, output_names=layout.inputs,
                          input_units=layout.units("y"), output_units=layout.units("u"))


def save_controller(path: str | Path, model: StateSpace) -> None:
    """Write a discrete controller as ``load_controller`` reads it (.npz or .mat by the suffix)."""
    path = Path(path)
    arrays = {"A": model.a, "B": model.b, "C": model.c, "D": model.d, "dt": np.array(model.dt)}
    if path.suffix.lower() == ".mat":
        sio.savemat(path, arrays)
    else:
        np.savez(path, **arrays)
