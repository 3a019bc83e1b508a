"""An excitation design from the user's terms (kind, band, resolution, inputs, peak current, ...).

``build_design`` maps those terms onto the designers of this package for
every kind; the ``excitation_generator`` node, ``ambid design`` and the
identify session all build their designs with it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from ambid.excitation.synchronous import DEFAULT_GUARD_BINS, DEFAULT_HARMONICS

KINDS = ("multisine", "stepped_sine", "swept_sine", "noise", "prbs", "dibs")
DEFAULT_INPUTS = ("u_a_x", "u_b_x", "u_a_y", "u_b_y")
# choices per kind that take them; the first is the kind's default ("" selects it)
GRIDS = {"multisine": ("random_odd", "odd", "full"), "stepped_sine": ("full", "odd"),
         "dibs": ("odd", "random_odd", "full")}
SPACINGS = {"multisine": ("linear", "log"), "stepped_sine": ("linear", "log"),
            "dibs": ("linear", "log"), "swept_sine": ("linear", "log")}
PHASES = {"multisine": ("random", "schroeder", "crest_optimised")}
MIMOS = {"multisine": ("orthogonal", "one_at_a_time"), "swept_sine": ("one_at_a_time", "orthogonal"),
         "noise": ("simultaneous", "one_at_a_time"), "prbs": ("one_at_a_time", "orthogonal"),
         "dibs": ("one_at_a_time", "orthogonal")}
PRBS_MAX_ORDER = 23
# a PRBS holds each bit for d samples; its spectrum falls as sinc(f d / fs): at f = fs / (3 d)
# the loss is 1.65 dB, so the clock divider keeps the band below that
PRBS_BAND_FRACTION = 1.0 / 3.0


def _option(kind: str, name: str, value: str, table: dict[str, tuple[str, ...]]) -> str:
    """The kind's default for "", the value if the kind takes it, else ValueError."""
    if kind not in table:
        if value:
            takers = ", ".join(table)
            raise ValueError(f"{name} {value!r} does not apply to a {kind} design (only to {takers}); "
                             f"leave {name} empty")
        return ""
    allowed = table[kind]
    if not value:
        return allowed[0]
    if value not in allowed:
        raise ValueError(f"{name} of a {kind} design must be one of {allowed}, got {value!r}")
    return value


def prbs_clock(band_hz: tuple[float, float], resolution_hz: float, fs_hz: float) -> tuple[int, int]:
    """(order, clock_divider) of a PRBS for a band and resolution.

    The clock divider d is the largest keeping band_hz[1] <= fs / (3 d)
    (hold loss <= 1.65 dB); the order is the smallest whose period
    d (2^order - 1) samples gives a resolution at least as fine as asked.
    """
    f_hi, res = float(band_hz[1]), float(resolution_hz)
    if not (math.isfinite(f_hi) and math.isfinite(res)) or f_hi <= 0 or res <= 0:
        raise ValueError(f"band upper edge and resolution must be finite and > 0 [Hz], got {f_hi!r}, {res!r}")
    if f_hi >= fs_hz / 2:
        raise ValueError(f"band upper edge {f_hi:g} Hz is not below the Nyquist frequency fs/2 = "
                         f"{fs_hz / 2:g} Hz; lower the band")
    divider = max(1, int(PRBS_BAND_FRACTION * fs_hz / f_hi))
    bits = fs_hz / (res * divider)
    order = max(2, math.ceil(math.log2(bits + 1) - 1e-12))
    if order > PRBS_MAX_ORDER:
        raise ValueError(f"a PRBS with resolution {res:g} Hz needs order {order} > {PRBS_MAX_ORDER}; "
                         "coarsen the resolution")
    return order, divider


def build_design(kind: str, band_hz: tuple[float, float], resolution_hz: float, fs_hz: float,
                 input_names: Sequence[str] = DEFAULT_INPUTS, peak_current_a: float = 0.5,
                 n_periods: int = 4, n_realisations: int = 1, n_transient_periods: int = 1,
                 grid: str = "", spacing: str = "", phases: str = "", mimo: str = "", seed: int = 0,
                 settle_s: float = 0.5, n_cycles: int = 10, speed_rpm: float = 0.0,
                 n_harmonics: int = DEFAULT_HARMONICS, guard_bins: int = DEFAULT_GUARD_BINS):
    """An ExcitationDesign from the user's terms, for any kind.

    Args:
        kind: one of KINDS.
        band_hz: (f_lo, f_hi) band of interest [Hz], f_hi < fs/2.
        resolution_hz: line spacing [Hz] (prbs: the resolution is at least this fine).
        fs_hz: sample rate of the plant [Hz].
        input_names: (Nu,) inputs, e.g. DEFAULT_INPUTS.
        peak_current_a: excitation peak per input [A].
        n_periods, n_realisations, n_transient_periods: P, M, Pt (unused by stepped_sine).
        grid, spacing, phases, mimo: "" = the kind's default (first entry of GRIDS, SPACINGS,
            PHASES, MIMOS); a choice a kind does not take raises ValueError. For swept_sine
            ``spacing`` is the sweep law.
        seed: seed of the random choices.
        settle_s, n_cycles: stepped sine settling wait [s] and measured cycles per line.
        speed_rpm: rotor speed [rpm]; > 0 (multisine only) steers the lines clear of the synchronous
            harmonics 1..n_harmonics, ``guard_bins`` bins each side (:mod:`ambid.excitation.synchronous`).

    Returns:
        ExcitationDesign.

    Raises:
        ValueError naming the bad argument (band above Nyquist, resolution not dividing fs, ...).
    """
    from ambid.excitation import (design_dibs, design_multisine, design_noise, design_prbs, design_stepped_sine,
                                  design_swept_sine)

    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    band = (float(band_hz[0]), float(band_hz[1]))
    grid = _option(kind, "grid", grid, GRIDS)
    spacing = _option(kind, "spacing", spacing, SPACINGS)
    phases = _option(kind, "phases", phases, PHASES)
    mimo = _option(kind, "mimo", mimo, MIMOS)
    if speed_rpm and kind != "multisine":
        raise ValueError(f"a {kind} design cannot steer clear of the synchronous harmonics at speed; use kind "
                         "multisine, or leave out the speed")
    common = dict(input_names=tuple(input_names), peak_current_a=peak_current_a)
    periodic = dict(n_periods=n_periods, n_realisations=n_realisations, n_transient_periods=n_transient_periods)
    if kind == "multisine":
        return design_multisine(band, resolution_hz, fs_hz, **common, **periodic, grid=grid, spacing=spacing,
                                phases=phases, mimo=mimo, seed=seed, speed_rpm=speed_rpm,
                                n_harmonics=n_harmonics, guard_bins=guard_bins)
    if kind == "stepped_sine":
        return design_stepped_sine(band, resolution_hz, fs_hz, **common, settle_s=settle_s, n_cycles=n_cycles,
                                   grid=grid, spacing=spacing)
    if kind == "swept_sine":
        return design_swept_sine(band, resolution_hz, fs_hz, **common, **periodic, law=spacing, mimo=mimo)
    if kind == "noise":
        return design_noise(band, resolution_hz, fs_hz, **common, **periodic, mimo=mimo, seed=seed)
    if kind == "prbs":
        order, divider = prbs_clock(band, resolution_hz, fs_hz)
        return design_prbs(fs_hz, order, **common, clock_divider=divider, **periodic, mimo=mimo, seed=seed)
    return design_dibs(band, resolution_hz, fs_hz, **common, **periodic, grid=grid, spacing=spacing, mimo=mimo,
                       seed=seed)
