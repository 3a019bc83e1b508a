"""The model file of the C reference target (``ambid_core/target_c/``, docs/target_c.md).

A plain text file the C program reads without a library: the true rig's
small-signal model sampled with zero-order hold (:func:`ambid.plant.true_rig.true_linear_model`,
discrete; its delay exact), the discrete position controller, the current
limits and the sensor noise. Whitespace-separated tokens, ``#`` comments,
numbers with 17 significant digits (exact round trip)::

    ambid_target_model 2
    dt 0.0001                        sample period [s]
    axes 5 a_x b_x a_y b_y z         na, then the axes' names: the channel order of everything below
    current_limit 3                  amplifier limit on |ic + r| [A]
    controller_limit 3               saturation of the controller output ic [A]
    noise_std s1 ... s_na            sensor noise std per output [m]
    plant_states n                   then plant_A (n x n), plant_B (n x na), plant_C (na x n), plant_D (na x na, zero)
    controller_states m              then controller_A, _B, _C, _D likewise (y [m] -> ic [A])
    end

Matrices are row-major, each named before its values. The plant runs
x[k+1] = A x[k] + B u[k], y[k] = C x[k] + noise; the controller
xc[k+1] = A xc + B y[k], ic[k] = C xc + D y[k]. Version 1 (no ``axes`` line)
is the four radial axes of the default rig; it is still read.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ambid.channels import RADIAL, Layout
from ambid.control.kinds import checked_design
from ambid.plant.rig import make_rig
from ambid.plant.sensors import noise_std
from ambid.plant.true_rig import true_linear_model
from ambid.statespace import StateSpace
from ambid.text_file import read_text

FORMAT = "ambid_target_model"
VERSION = 2
V1_LAYOUT = RADIAL  # a version 1 file names no axes: the default rig's four radial ones


@dataclass(frozen=True)
class TargetModel:
    """What the C target runs.

    Attributes:
        plant: discrete u (na) [A] -> y (na) [m], D = 0, its inputs and outputs named for the axes.
        controller: discrete y (na) [m] -> ic (na) [A].
        current_limit_a: amplifier limit on |ic + r| [A].
        controller_limit_a: saturation of ic [A].
        noise_std_m: (na,) sensor noise std [m].
    """

    plant: StateSpace
    controller: StateSpace
    current_limit_a: float
    controller_limit_a: float
    noise_std_m: np.ndarray

    @property
    def dt(self) -> float:
        return float(self.plant.dt)

    @property
    def layout(self) -> Layout:
        """The axes, from the plant's input names (``u_<axis>``)."""
        return Layout.from_names(self.plant.input_names)


def rig_target_model(rig=None, controller: str = "") -> TargetModel:
    """The true rig's small-signal model and the controller ``controller`` (a kind or file; "" = the rig
    file's, else pid) as the C target runs them.

    Raises:
        ValueError: the controller cannot be designed or does not hold the rig.
    """
    rig = rig if rig is not None else make_rig()
    design = checked_design(controller or None, rig)
    return TargetModel(true_linear_model(rig, discrete=True), design.model, float(rig.current_limit_a),
                       float(design.current_limit_a), noise_std(rig.axis_sensors()))


def _matrix(name: str, m: np.ndarray) -> str:
    rows = [" ".join(f"{v:.17g}" for v in row) for row in np.atleast_2d(m)]
    return f"{name}\n" + "\n".join(rows) + "\n"


def write_target_model(path: str | os.PathLike, model: TargetModel) -> None:
    """Write ``model`` to ``path`` (complete or not at all: written beside it, then renamed)."""
    p, c = model.plant, model.controller
    lay = model.layout
    na = len(lay)
    for what, ss in (("plant", p), ("controller", c)):
        if ss.dt <= 0 or ss.n_inputs != na or ss.n_outputs != na:
            raise ValueError(f"the {what} must be discrete with {na} inputs and {na} outputs (the axes "
                             f"{' '.join(lay.axes)})")
    if np.shape(model.noise_std_m) != (na,):
        raise ValueError(f"noise_std_m must give one std per axis ({na}), got shape {np.shape(model.noise_std_m)}")
    if abs(c.dt - p.dt) > 1e-12 * p.dt:
        raise ValueError(f"plant dt {p.dt} s and controller dt {c.dt} s differ")
    if np.any(p.d != 0):
        raise ValueError("the plant must have D = 0 (y[k] is measured before u[k] is applied)")
    text = [f"# ambid C target model: true rig small-signal model (ZOH, delay exact) and position controller\n",
            f"{FORMAT} {VERSION}\n", f"dt {p.dt:.17g}\n", f"axes {na} {' '.join(lay.axes)}\n",
            f"current_limit {model.current_limit_a:.17g}\n",
            f"controller_limit {model.controller_limit_a:.17g}\n",
            "noise_std " + " ".join(f"{v:.17g}" for v in model.noise_std_m) + "\n"]
    for prefix, ss in (("plant", p), ("controller", c)):
        text.append(f"{prefix}_states {ss.n_states}\n")
        for name, m in (("A", ss.a), ("B", ss.b), ("C", ss.c), ("D", ss.d)):
            text.append(_matrix(f"{prefix}_{name}", np.asarray(m, dtype=float).reshape(
                {"A": (ss.n_states, ss.n_states), "B": (ss.n_states, na), "C": (na, ss.n_states),
                 "D": (na, na)}[name])))
    text.append("end\n")
    tmp = f"{os.fspath(path)}.part"
    with open(tmp, "w") as f:
        f.write("".join(text))
    os.replace(tmp, path)


def read_target_model(path: str | os.PathLike) -> TargetModel:
    """The model in a file :func:`write_target_model` wrote (the C program is the strict reader of what it
    runs; this one refuses a file it cannot read: ValueError naming the file and what is wrong)."""
    toks = [t for line in read_text(path).splitlines() for t in line.split("#", 1)[0].split()]
    if len(toks) < 2 or toks[0] != FORMAT or toks[1] not in ("1", str(VERSION)):
        raise ValueError(f"{path} is not an {FORMAT} file of version 1 or {VERSION}")
    try:
        return _parse(path, toks)
    except IndexError:
        raise ValueError(f"{path} ends early, after {len(toks)} words: it is cut short") from None


def _parse(path, toks: list[str]) -> TargetModel:
    pos = 2

    def word(w: str) -> None:
        nonlocal pos
        if toks[pos] != w:
            raise ValueError(f"{path}: expected {w!r}, found {toks[pos]!r}")
        pos += 1

    def nums(n: int) -> np.ndarray:
        nonlocal pos
        if pos + n > len(toks):
            raise IndexError
        try:
            out = np.array(toks[pos:pos + n], dtype=float)
        except ValueError:
            at = pos + next(i for i, t in enumerate(toks[pos:pos + n]) if not _is_float(t))
            raise ValueError(f"{path}: word {at + 1} is '{toks[at]}' where a number belongs") from None
        pos += n
        return out

    word("dt")
    dt = float(nums(1)[0])
    lay = V1_LAYOUT
    if toks[1] != "1":
        word("axes")
        na = int(nums(1)[0])
        if not 1 <= na <= 64:
            raise ValueError(f"{path}: axes {na} is not a count of axes (1 to 64)")
        names, pos = toks[pos:pos + na], pos + na
        try:
            lay = Layout(tuple(names))
        except ValueError as exc:
            raise ValueError(f"{path}: the axes {names}: {exc}") from None
    na = len(lay)
    word("current_limit")
    limit = float(nums(1)[0])
    word("controller_limit")
    climit = float(nums(1)[0])
    word("noise_std")
    noise = nums(na)
    models = []
    names = {"plant": (lay.inputs, lay.outputs, lay.units("u"), lay.units("y")),
             "controller": (lay.outputs, lay.controls, lay.units("y"), lay.units("ic"))}
    for prefix in ("plant", "controller"):
        word(f"{prefix}_states")
        n = int(nums(1)[0])
        mats = []
        for name, shape in (("A", (n, n)), ("B", (n, na)), ("C", (na, n)), ("D", (na, na))):
            word(f"{prefix}_{name}")
            mats.append(nums(shape[0] * shape[1]).reshape(shape))
        models.append(StateSpace(*mats, dt, *names[prefix]))
    word("end")
    return TargetModel(models[0], models[1], limit, climit, noise)


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
