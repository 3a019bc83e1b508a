"""A Foxglove layout for the live view, made from the session's channels.

:func:`foxglove_layout` returns the layout as the JSON the Foxglove app
imports (*Layouts, Import from file*): tabs of panels on the live view's
topics (:mod:`ambid.live.frames`):

* **Bode magnitude** and **Bode phase**: an Ny x Nu grid of Plot panels, one
  per FRF entry, drawn against frequency (x axis the message path
  ``.freq_hz[:]`` of the latest message), with the +-2 sigma band and, for
  the magnitude, the noise and total (noise + distortion) levels;
* **Orbits and signals**: an x-y plot per bearing with both radial axes
  (:attr:`ambid.channels.Layout.radial_pairs`), the displacements and the
  currents over time;
* **Noise and distortion**: per output, the level at the detection lines
  against the noise floor there;
* **Status**: the live view's progress, the FRF consumer's and the plant's
  status, and the session's events (Log panel).

``docs/foxglove_layout.json`` is this layout for the default rig
(``python -m ambid.live.layout > docs/foxglove_layout.json`` writes it again).
"""

from __future__ import annotations

import json
import sys

from ambid.channels import RADIAL, Layout, bearing_of
from ambid.live.server import DEFAULT_PREFIX

__all__ = ["foxglove_layout"]


def _split(items: list, direction: str):
    """A balanced mosaic tree of panel ids (or subtrees) side by side in ``direction``."""
    if len(items) == 1:
        return items[0]
    half = len(items) // 2
    return {"first": _split(items[:half], direction), "second": _split(items[half:], direction),
            "direction": direction, "splitPercentage": 100.0 * half / len(items)}


def _plot(title: str, series: list[tuple[str, str]], x_path: str | None = None) -> dict:
    """A Plot panel's config: ``series`` (message path, label); against ``x_path`` (the latest message's
    array) or, without it, against time."""
    cfg = {"title": title,
           "paths": [{"value": v, "enabled": True, "timestampMethod": "receiveTime", "label": label}
                     for v, label in series],
           "showXAxisLabels": True, "showYAxisLabels": True, "showLegend": True, "legendDisplay": "floating",
           "showPlotValuesInLegend": False, "isSynced": False, "sidebarDimension": 240}
    if x_path is None:
        cfg.update(xAxisVal="timestamp", followingViewWidth=2.0)
    else:
        cfg.update(xAxisVal="currentCustom", xAxisPath={"value": x_path, "enabled": True})
    return cfg


def _raw(topic: str) -> dict:
    return {"topicPath": topic, "diffEnabled": False, "diffMethod": "custom", "diffTopicPath": "",
            "showFullMessageForDiff": False}


def foxglove_layout(layout: Layout = RADIAL, prefix: str = DEFAULT_PREFIX) -> dict:
    """The live view's Foxglove layout for a session's channels.

    Parameters
    ----------
    layout
        the session's axes (outputs y_<axis>, inputs u_<axis>; the FRF is Ny x Nu over them).
    prefix
        the live view's topic prefix (``<namespace>/live``).

    Returns
    -------
    The layout, JSON-safe (``configById``, ``layout``, ``globalVariables``, ...).
    """
    p = "/" + prefix.strip("/")
    configs: dict[str, dict] = {}

    def panel(kind: str, key: str, cfg: dict) -> str:
        pid = f"{kind}!{key}"
        configs[pid] = cfg
        return pid

    def grid(rows: list[list[str]]):
        return _split([_split(r, "row") for r in rows], "column")

    mag_rows, phase_rows = [], []
    for out in layout.outputs:
        mags, phases = [], []
        for inp in layout.inputs:
            t = f"{p}/frf/{out}/{inp}"
            key = f"{out}__{inp}"
            mags.append(panel("Plot", f"mag__{key}", _plot(f"|G| {out} / {inp} [dB re 1 m/A]", [
                (f"{t}.magnitude_db[:]", "|G|"), (f"{t}.magnitude_db_lower[:]", "-2 sigma"),
                (f"{t}.magnitude_db_upper[:]", "+2 sigma"), (f"{t}.noise_db[:]", "noise"),
                (f"{t}.total_db[:]", "noise + distortion")], f"{t}.freq_hz[:]")))
            phases.append(panel("Plot", f"phase__{key}", _plot(f"phase {out} / {inp} [deg]", [
                (f"{t}.phase_deg[:]", "phase"), (f"{t}.phase_deg_lower[:]", "-2 sigma"),
                (f"{t}.phase_deg_upper[:]", "+2 sigma")], f"{t}.freq_hz[:]")))
        mag_rows.append(mags)
        phase_rows.append(phases)
    orbit_panels = []
    for xi, yi in layout.radial_pairs:
        b = bearing_of(layout.axes[xi])
        t = f"{p}/orbit/{b}"
        orbit_panels.append(panel("Plot", f"orbit__{b}", _plot(
            f"orbit, bearing {b}: {layout.outputs[yi]} against {layout.outputs[xi]} [m]",
            [(f"{t}.y_m[:]", layout.outputs[yi])], f"{t}.x_m[:]")))
    signals = [panel("Plot", "signals__y", _plot("displacements [m]",
                                                 [(f"{p}/signals.{n}", n) for n in layout.outputs])),
               panel("Plot", "signals__u", _plot("currents [A]", [(f"{p}/signals.{n}", n) for n in layout.inputs]))]
    levels = [panel("Plot", f"levels__{out}", _plot(f"{out} at the detection lines [dB re 1 m]", [
        (f"{p}/levels/{out}.level_db[:]", "level"), (f"{p}/levels/{out}.noise_db[:]", "noise floor")],
        f"{p}/levels/{out}.freq_hz[:]")) for out in layout.outputs]
    status = [panel("RawMessages", "progress", _raw(f"{p}/progress")),
              panel("RawMessages", "frf_consumer", _raw(f"{p}/status/frf_consumer")),
              panel("RawMessages", "plant", _raw(f"{p}/status/plant_sim")),
              panel("Log", "events", {"searchTerms": [], "minLogLevel": 1, "topicToRender": f"{p}/events"})]
    tabs = [("Bode magnitude", grid(mag_rows)), ("Bode phase", grid(phase_rows)),
            ("Orbits and signals", _split([_split(orbit_panels, "row")] + signals, "column")
             if orbit_panels else _split(signals, "column")),
            ("Noise and distortion", _split(levels, "row")),
            ("Status", _split([_split(status[:3], "row"), status[3]], "column"))]
    root = panel("Tab", "live", {"activeTabIdx": 0, "tabs": [{"title": t, "layout": m} for t, m in tabs]})
    return {"configById": configs, "globalVariables": {}, "userNodes": {}, "linkedGlobalVariables": [],
            "playbackConfig": {"speed": 1}, "layout": root}


if __name__ == "__main__":
    json.dump(foxglove_layout(), sys.stdout, indent=1)
    sys.stdout.write("\n")
