"""The rig's parameter tables in Markdown (``docs/default_rig.md`` holds the default rig's)."""

from __future__ import annotations

import numpy as np

from ambid.plant.rig import RIG_FIELDS, Rig, make_rig
from ambid.plant.true_rig import operating_point


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def rig_markdown(rig: Rig | None = None) -> str:
    """Markdown tables of a rig: every parameter (value, unit, range, source), the derived values, and
    the true rig's levitated operating point.

    ``docs/default_rig.md`` holds this text for the default rig between the
    markers ``<!-- rig-tables:begin -->`` and ``<!-- rig-tables:end -->``.
    Without an axial bearing the last tables give what ``axial_bearing: 1``
    adds (rigs/five_axis.yaml): the axial magnet's derived values and the
    five-axis rig's levitated operating point.
    """
    rig = make_rig() if rig is None else rig
    lines = ["| parameter | value | unit | allowed range | source |", "| --- | --- | --- | --- | --- |"]
    for key, f in RIG_FIELDS.items():
        source = f.source.replace("|", "\\|")
        lines.append(f"| `{key}` | {_fmt(rig.values[key])} | {f.unit} | [{_fmt(f.low)}, {_fmt(f.high)}] "
                     f"| {source} |")
    lines += ["", "| derived quantity | value |", "| --- | --- |"]
    lines += [f"| `{k}` | {_fmt(v)} |" for k, v in rig.derived().items()]
    lines += _operating_point_table(rig, "true rig, levitated (sensors read 0)")
    if not rig.values["axial_bearing"]:
        five = make_rig({**{k: v for k, v in rig.values.items()}, "axial_bearing": 1})
        extra = {k: v for k, v in five.derived().items() if k not in rig.derived() or k.startswith("axial")
                 or k == "thrust_disk_mass_kg"}
        changed = [k for k, v in five.derived().items() if k in rig.derived() and v != rig.derived()[k]]
        lines += ["", "| with the axial bearing (`axial_bearing: 1`, rigs/five_axis.yaml) | value |", "| --- | --- |"]
        lines += [f"| `{k}` | {_fmt(v)} |" for k, v in extra.items()]
        lines += [f"| `{k}` (with the thrust disk) | {_fmt(five.derived()[k])} |" for k in changed]
        lines += _operating_point_table(five, "five-axis true rig, levitated")
    return "\n".join(lines) + "\n"


def _operating_point_table(rig: Rig, title: str) -> list[str]:
    """The levitated operating point at bearing A x (and at bearing B x and the axial axis where they differ)."""
    op = operating_point(rig)
    lay = rig.layout
    shown = [0] + [j for j in (lay.index("b_x"),) + lay.axial
                   if not np.isclose(op.current_a[j], op.current_a[0], rtol=1e-6, atol=1e-12)
                   or not np.isclose(op.ks_n_per_m[j], op.ks_n_per_m[0], rtol=1e-6)]
    out = []
    for j in shown:
        out += ["", f"| {title}, axis {lay.axes[j]} | value |", "| --- | --- |",
                f"| control current ic0 [A] | {_fmt(op.current_a[j])} |",
                f"| rotor-stator displacement at the bearing [m] | {_fmt(op.gap_m[j])} |",
                f"| magnet force [N] | {_fmt(op.force_n[j])} |",
                f"| ki there [N/A] | {_fmt(op.ki_n_per_a[j])} |",
                f"| ks there [N/m] | {_fmt(op.ks_n_per_m[j])} |"]
    return out
