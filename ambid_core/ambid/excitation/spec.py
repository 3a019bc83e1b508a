"""An excitation experiment in the user's terms, and the one home of its defaults.

:class:`DesignSpec` holds the terms (kind, band, resolution, inputs, peak
current, periods, ...) and maps them onto the designers of this package for
every kind (:meth:`DesignSpec.build`). Its defaults are the experiment
``ambid identify`` runs, so ``ambid design`` with no options previews exactly
that experiment: ``ambid identify``, ``ambid design``, ``ambid validate``,
``ambid campaign``, the identify session (``ambid_nodes.running.plan.SessionConfig``)
and the ``excitation_generator`` node (its parameters and
``ambid_nodes/config/excitation_generator.yaml``) all take their defaults from
here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

from ambid.channels import RADIAL
from ambid.quantity import quantity

from ambid.excitation.design import ExcitationDesign
from ambid.excitation.designers import (design_dibs, design_multisine, design_noise, design_prbs,
                                        design_stepped_sine, design_swept_sine)
from ambid.excitation.lines import band_bins, n_per_period
from ambid.excitation.synchronous import DEFAULT_GUARD_BINS, DEFAULT_HARMONICS

KINDS = ("multisine", "stepped_sine", "swept_sine", "noise", "prbs", "dibs")
# choices per kind that take them; the first is the kind's default ("" selects it)
GRIDS = {"multisine": ("random_odd", "odd", "full"), "stepped_sine": ("full", "odd"),
         "dibs": ("odd", "random_odd", "full")}
SPACINGS = {"multisine": ("linear", "log"), "stepped_sine": ("linear", "log"),
            "dibs": ("linear", "log"), "swept_sine": ("linear", "log")}
# a multisine's default phases are crest-optimised: 2.3x the RMS of random phases under the same peak
PHASES = {"multisine": ("crest_optimised", "random", "schroeder")}
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

    Examples
    --------
    >>> prbs_clock((10.0, 1000.0), 5.0, 10_000.0)     # (register order, clock divider)
    (10, 3)
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


@dataclass(frozen=True, kw_only=True)
class DesignSpec:
    """An excitation experiment in the user's terms; the defaults are ``ambid identify``'s session.

    Defaults: an orthogonal random-odd multisine with crest-optimised phases on
    every current of the rig (four radial, five with an axial bearing),
    10-1000 Hz at 5 Hz resolution, 0.4 A peak, M = 3 realisations of 3
    transient + 4 steady-state periods, seed 1.

    Attributes
    ----------
    kind
        one of :data:`KINDS`.
    band_hz
        (f_lo, f_hi) band of interest [Hz], f_hi < fs/2.
    resolution_hz
        line spacing fs/N [Hz] (prbs: the resolution is at least this fine).
    input_names
        (Nu,) excited plant currents; empty: every current of the plant (the ``inputs``
        :meth:`build` is given: the rig layout's u_<axis>).
    peak_current_a
        excitation peak per input [A].
    n_periods, n_realisations, n_transient_periods
        P, M, Pt (unused by stepped_sine).
    grid, spacing, phases, mimo
        "" = the kind's default (first entry of :data:`GRIDS`,
        :data:`SPACINGS`, :data:`PHASES`, :data:`MIMOS`; a multisine's: random_odd, linear,
        crest_optimised, orthogonal); a choice a kind does not take raises ValueError at
        :meth:`build`. For swept_sine ``spacing`` is the sweep law.
    seed
        seed of the random choices (phases, grid, noise); an identify session seeds its sensor
        noise with it too.
    settle_s, n_cycles
        stepped sine settling wait [s] and measured cycles per line.
    n_harmonics, guard_bins
        at speed, the synchronous harmonics 1..n_harmonics a multisine keeps
        clear of, ``guard_bins`` bins each side (:mod:`ambid.excitation.synchronous`).
    """

    kind: str = quantity("multisine", "excitation kind: " + " | ".join(KINDS))
    band_hz: tuple[float, float] = quantity((10.0, 1000.0), "band of interest (lower, upper edge), the upper below "
                                                            "fs/2", "Hz")
    resolution_hz: float = quantity(5.0, "frequency resolution fs/N; fs/resolution must be an integer", "Hz",
                                    1e-6, 1e6)
    input_names: tuple[str, ...] = quantity((), "excited inputs (plant current names; [auto]: every current of the "
                                                "plant); u_<axis> is excited through channel r_<axis>", empty="auto")
    # 0.4 A keeps the magnets' odd distortion within ~3 dB of the noise (at 0.5 A it biased the
    # housing-mode damping by 11 %)
    peak_current_a: float = quantity(0.4, "excitation peak per input", "A", 1e-6, 1e3)
    n_periods: int = quantity(4, "steady-state periods P per experiment", "", 1, 1_000_000)
    # three realisations bring the worst excited line under 8 % and give the total variance its scatter
    n_realisations: int = quantity(3, "realisations M (random phases, noise records)", "", 1, 100_000)
    n_transient_periods: int = quantity(3, "periods Pt discarded ahead of each experiment", "", 0, 100_000)
    grid: str = quantity("", "line grid: random_odd | odd | full; empty = the kind's default")
    spacing: str = quantity("", "line spacing (swept sine: sweep law): linear | log; empty = the kind's default")
    phases: str = quantity("", "multisine phases: crest_optimised | random | schroeder; empty = the kind's default "
                               "(crest_optimised)")
    mimo: str = quantity("", "orthogonal | one_at_a_time | simultaneous; empty = the kind's default")
    seed: int = quantity(1, "seed of the random choices (phases, grid, noise)", "", 0, 2**31 - 1)
    settle_s: float = quantity(0.5, "stepped sine: settling wait per line", "s", 0.0, 3600.0)
    n_cycles: int = quantity(10, "stepped sine: measured cycles per line", "", 1, 1_000_000)
    # the synchronous harmonics matter only at speed, which a node's default design does not have:
    # plain fields, no node parameters
    n_harmonics: int = DEFAULT_HARMONICS
    guard_bins: int = DEFAULT_GUARD_BINS

    def to_dict(self) -> dict:
        """The terms as plain JSON values (tuples as lists)."""
        d = asdict(self)
        d["band_hz"], d["input_names"] = list(self.band_hz), list(self.input_names)
        return d

    def check(self, fs_hz: float) -> None:
        """ValueError naming a term that cannot make a design at ``fs_hz`` [Hz] (a kind, choice, band or
        resolution), found without designing anything: :meth:`build` may take a while (crest-factor
        optimisation), so a node checks its parameters with this at start-up and designs when asked."""
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")
        for name, table in (("grid", GRIDS), ("spacing", SPACINGS), ("phases", PHASES), ("mimo", MIMOS)):
            _option(self.kind, name, getattr(self, name), table)
        if self.kind == "prbs":
            prbs_clock(self.band_hz, self.resolution_hz, fs_hz)
        else:
            band_bins(self.band_hz, float(fs_hz), n_per_period(fs_hz, self.resolution_hz))

    def build(self, fs_hz: float, speed_rpm: float = 0.0,
              inputs: Sequence[str] = RADIAL.inputs) -> ExcitationDesign:
        """The ExcitationDesign of these terms at the plant's sample rate ``fs_hz`` [Hz].

        ``speed_rpm`` [rpm] > 0 (multisine only) steers the lines clear of the synchronous harmonics.
        ``inputs``: the plant's currents, excited when ``input_names`` is empty (the rig's
        ``layout.inputs``; the default rig's four radial ones unless given).
        Raises ValueError naming the bad term (band above Nyquist, resolution not dividing fs, ...).

        Examples
        --------
        The default experiment narrowed to 10-100 Hz with one realisation, built for one input at 1 kHz:

        >>> spec = DesignSpec(band_hz=(10.0, 100.0), n_realisations=1, n_transient_periods=1)
        >>> d = spec.build(1000.0, inputs=("u_a_x",))
        >>> d.kind, d.n_per_period, d.input_names, d.total_samples
        ('multisine', 200, ('u_a_x',), 1000)
        """
        kind = self.kind
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
        band = (float(self.band_hz[0]), float(self.band_hz[1]))
        res = self.resolution_hz
        grid = _option(kind, "grid", self.grid, GRIDS)
        spacing = _option(kind, "spacing", self.spacing, SPACINGS)
        phases = _option(kind, "phases", self.phases, PHASES)
        mimo = _option(kind, "mimo", self.mimo, MIMOS)
        if speed_rpm and kind != "multisine":
            raise ValueError(f"a {kind} design cannot steer clear of the synchronous harmonics at speed; use kind "
                             "multisine, or leave out the speed")
        common = dict(input_names=tuple(self.input_names or inputs), peak_current_a=self.peak_current_a)
        periodic = dict(n_periods=self.n_periods, n_realisations=self.n_realisations,
                        n_transient_periods=self.n_transient_periods)
        seed = self.seed
        if kind == "multisine":
            return design_multisine(band, res, fs_hz, **common, **periodic, grid=grid, spacing=spacing,
                                    phases=phases, mimo=mimo, seed=seed, speed_rpm=speed_rpm,
                                    n_harmonics=self.n_harmonics, guard_bins=self.guard_bins)
        if kind == "stepped_sine":
            return design_stepped_sine(band, res, fs_hz, **common, settle_s=self.settle_s, n_cycles=self.n_cycles,
                                       grid=grid, spacing=spacing)
        if kind == "swept_sine":
            return design_swept_sine(band, res, fs_hz, **common, **periodic, law=spacing, mimo=mimo)
        if kind == "noise":
            return design_noise(band, res, fs_hz, **common, **periodic, mimo=mimo, seed=seed)
        if kind == "prbs":
            order, divider = prbs_clock(band, res, fs_hz)
            return design_prbs(fs_hz, order, **common, clock_divider=divider, **periodic, mimo=mimo, seed=seed)
        return design_dibs(band, res, fs_hz, **common, **periodic, grid=grid, spacing=spacing, mimo=mimo,
                           seed=seed)


def build_design(kind: str, band_hz: tuple[float, float], resolution_hz: float, fs_hz: float, *,
                 speed_rpm: float = 0.0, **terms) -> ExcitationDesign:
    """``DesignSpec(kind=kind, band_hz=band_hz, resolution_hz=resolution_hz, **terms).build(fs_hz, speed_rpm)``
    (inputs: the default rig's currents unless ``input_names`` names them).

    ``terms`` are :class:`DesignSpec`'s other fields by name; what is left out is its default.
    """
    return DesignSpec(kind=kind, band_hz=band_hz, resolution_hz=resolution_hz, **terms).build(fs_hz, speed_rpm)
