"""The model file of the C reference target (``ambid_core/target_c/``, docs/target_c.md).

A plain text file the C program reads without a library: the true rig's
small-signal model sampled with zero-order hold (:func:`ambid.plant.true_rig.true_linear_model`,
discrete; its delay exact), the discrete position controller, the current
limits and the sensor noise. Whitespace-separated tokens, ``#`` comments,
numbers with 17 significant digits (exact round trip)::

    ambid_target_model 1
    dt 0.0001                        sample period [s]
    current_limit 3                  amplifier limit on |ic + r| [A]
    controller_limit 3               saturation of the controller output ic [A]
    noise_std s1 s2 s3 s4            sensor noise std per output [m]
    plant_states n                   then plant_A (n x n), plant_B (n x 4), plant_C (4 x n), plant_D (4 x 4, zero)
    controller_states m              then controller_A, _B, _C, _D likewise (y [m] -> ic [A])
    end

Matrices are row-major, each named before its values. The plant runs
x[k+1] = A x[k] + B u[k], y[k] = C x[k] + noise; the controller
xc[k+1] = A xc + B y[k], ic[k] = C xc + D y[k].
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ambid.control.kinds import checked_design
from ambid.plant.rig import make_rig
from ambid.plant.sensors import Sensors
from ambid.plant.true_rig import true_linear_model
from ambid.statespace import StateSpace
from ambid.text_file import read_text

FORMAT = "ambid_target_model"
VERSION = 1


@dataclass(frozen=True)
class TargetModel:
    """What the C target runs.

    Attributes:
        plant: discrete u (4) [A] -> y (4) [m], D = 0.
        controller: discrete y (4) [m] -> ic (4) [A].
        current_limit_a: amplifier limit on |ic + r| [A].
        controller_limit_a: saturation of ic [A].
        noise_std_m: (4,) sensor noise std [m].
    """

    plant: StateSpace
    controller: StateSpace
    current_limit_a: float
    controller_limit_a: float
    noise_std_m: np.ndarray

    @property
    def dt(self) -> float:
        return float(self.plant.dt)


def rig_target_model(rig=None, controller: str = "") -> TargetModel:
    """The true rig's small-signal model and the controller ``controller`` (a kind or file; "" = the rig
    file's, else pid) as the C target runs them.

    Raises:
        ValueError: the controller cannot be designed or does not hold the rig.
    """
    rig = rig if rig is not None else make_rig()
    design = checked_design(controller or None, rig)
    noise = Sensors.from_rig(rig.values).noise_std_m
    return TargetModel(true_linear_model(rig, discrete=True), design.model, float(rig.current_limit_a),
                       float(design.current_limit_a), np.broadcast_to(np.asarray(noise, dtype=float), (4,)).copy())


def _matrix(name: str, m: np.ndarray) -> str:
    rows = [" ".join(f"{v:.17g}" for v in row) for row in np.atleast_2d(m)]
    return f"{name}\n" + "\n".join(rows) + "\n"


def write_target_model(path: str | os.PathLike, model: TargetModel) -> None:
    """Write ``model`` to ``path`` (complete or not at all: written beside it, then renamed)."""
    p, c = model.plant, model.controller
    for what, ss in (("plant", p), ("controller", c)):
        if ss.dt <= 0 or ss.n_inputs != 4 or ss.n_outputs != 4:
            raise ValueError(f"the {what} must be discrete with 4 inputs and 4 outputs")
    if abs(c.dt - p.dt) > 1e-12 * p.dt:
        raise ValueError(f"plant dt {p.dt} s and controller dt {c.dt} s differ")
    if np.any(p.d != 0):
        raise ValueError("the plant must have D = 0 (y[k] is measured before u[k] is applied)")
    text = [f"# ambid C target model: true rig small-signal model (ZOH, delay exact) and position controller\n",
            f"{FORMAT} {VERSION}\n", f"dt {p.dt:.17g}\n", f"current_limit {model.current_limit_a:.17g}\n",
            f"controller_limit {model.controller_limit_a:.17g}\n",
            "noise_std " + " ".join(f"{v:.17g}" for v in model.noise_std_m) + "\n"]
    for prefix, ss in (("plant", p), ("controller", c)):
        text.append(f"{prefix}_states {ss.n_states}\n")
        for name, m in (("A", ss.a), ("B", ss.b), ("C", ss.c), ("D", ss.d)):
            text.append(_matrix(f"{prefix}_{name}", np.asarray(m, dtype=float).reshape(
                {"A": (ss.n_states, ss.n_states), "B": (ss.n_states, 4), "C": (4, ss.n_states), "D": (4, 4)}[name])))
    text.append("end\n")
    tmp = f"{os.fspath(path)}.part"
    with open(tmp, "w") as f:
        f.write("".join(text))
    os.replace(tmp, path)


def read_target_model(path: str | os.PathLike) -> TargetModel:
    """The model in a file :func:`write_target_model` wrote (the C program is the strict reader of what it
    runs; this one refuses a file it cannot read: ValueError naming the file and what is wrong)."""
    toks = [t for line in read_text(path).splitlines() for t in line.split("#", 1)[0].split()]
    if toks[:2] != [FORMAT, str(VERSION)]:
        raise ValueError(f"{path} is not an {FORMAT} {VERSION} file")
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
    word("current_limit")
    limit = float(nums(1)[0])
    word("controller_limit")
    climit = float(nums(1)[0])
    word("noise_std")
    noise = nums(4)
    models = []
    for prefix in ("plant", "controller"):
        word(f"{prefix}_states")
        n = int(nums(1)[0])
        mats = []
        for name, shape in (("A", (n, n)), ("B", (n, 4)), ("C", (4, n)), ("D", (4, 4))):
            word(f"{prefix}_{name}")
            mats.append(nums(shape[0] * shape[1]).reshape(shape))
        models.append(StateSpace(*mats, dt))
    word("end")
    return TargetModel(models[0], models[1], limit, climit, noise)


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
