"""The rig's parameter tables in Markdown (``docs/default_rig.md`` holds the default rig's)."""

from __future__ import annotations

from ambid.plant.rig import RIG_FIELDS, Rig, make_rig
from ambid.plant.true_rig import operating_point


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def rig_markdown(rig: Rig | None = None) -> str:
    """Markdown tables of a rig: every parameter (value, unit, range, source), the derived values, and
    the true rig's levitated operating point.

    ``docs/default_rig.md`` holds this text for the default rig between the
    markers ``<!-- rig-tables:begin -->`` and ``<!-- rig-tables:end -->``.
    """
    rig = make_rig() if rig is None else rig
    lines = ["| parameter | value | unit | allowed range | source |", "| --- | --- | --- | --- | --- |"]
    for key, f in RIG_FIELDS.items():
        source = f.source.replace("|", "\\|")
        lines.append(f"| `{key}` | {_fmt(rig.values[key])} | {f.unit} | [{_fmt(f.low)}, {_fmt(f.high)}] "
                     f"| {source} |")
    lines += ["", "| derived quantity | value |", "| --- | --- |"]
    lines += [f"| `{k}` | {_fmt(v)} |" for k, v in rig.derived().items()]
    op = operating_point(rig)
    lines += ["", "| true rig, levitated (sensors read 0), bearing A x | value |", "| --- | --- |",
              f"| control current ic0 [A] | {_fmt(op.current_a[0])} |",
              f"| rotor-stator displacement at the bearing [m] | {_fmt(op.gap_m[0])} |",
              f"| magnet force [N] | {_fmt(op.force_n[0])} |",
              f"| ki there [N/A] | {_fmt(op.ki_n_per_a[0])} |",
              f"| ks there [N/m] | {_fmt(op.ks_n_per_m[0])} |"]
    return "\n".join(lines) + "\n"
