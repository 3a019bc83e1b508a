"""Data-sheet tolerances of the rig's physical parameters: the priors of model updating.

A rig file states each parameter's nominal value (the fields of :data:`ambid.plant.rig.RIG_FIELDS`,
from which the nominal ki, ks, amplifier bandwidth, bending modes ... are derived) and, under
``tolerances:``, how far the real rig may lie from it, the way a data sheet says it:

* ``"5 %"``: relative, nominal x (1 +- 0.05);
* ``"x3"``: a factor, nominal / 3 .. nominal x 3 (symmetric in the logarithm: damping ratios);
* a number: an absolute half-width in the parameter's SI unit, nominal +- it;
* ``"LOW..HIGH"``: a range in SI units (or in samples with ``sample``: ``"0..1 sample"``); its
  middle replaces the nominal value;
* ``"fixed"``: known; the update keeps the nominal value.

Each tolerance is read as the central 95 % interval of a normal prior, in the parameter (relative,
absolute, range) or in its logarithm (factor). Names are those of the updating model
(:data:`ambid.fit.model_update.PARAMETERS`); ``bending_freq_hz`` and ``bending_damping_ratio`` apply to
every bending mode in the band unless ``bending_<k>_freq_hz`` ... names mode k. :data:`DEFAULT_TOLERANCES`
holds the defaults (docs/default_rig.md, "Tolerances").
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

__all__ = ["Tolerance", "DEFAULT_TOLERANCES", "TOLERANCE_NAMES", "Z95", "parse_tolerance", "parse_tolerances",
           "tolerance_for"]

#: the 0.975 quantile of the standard normal: a tolerance is a 95 % interval, +-Z95 prior standard deviations
Z95 = 1.959963984540054


@dataclass(frozen=True)
class Tolerance:
    """One parameter's tolerance.

    Attributes
    ----------
    kind
        ``relative`` (value: fraction), ``factor`` (value > 1), ``absolute`` (value: half-width
        [SI unit]), ``range`` (low, high [SI unit, or samples with ``in_samples``]) or ``fixed``.
    value
        the fraction, factor or half-width (nan for a range or fixed).
    low, high
        the range (nan otherwise).
    in_samples
        the range is in samples of the rig's sample period.
    """

    kind: str
    value: float = math.nan
    low: float = math.nan
    high: float = math.nan
    in_samples: bool = False

    def to_text(self) -> str:
        """The canonical text of this tolerance (``parse_tolerance(t.to_text()) == t``)."""
        if self.kind == "relative":
            return f"{100 * self.value:.6g} %"
        if self.kind == "factor":
            return f"x{self.value:.6g}"
        if self.kind == "absolute":
            return f"{self.value:.6g}"
        if self.kind == "range":
            return f"{self.low:.6g}..{self.high:.6g}" + (" sample" if self.in_samples else "")
        return "fixed"

    def centre_and_sd(self, nominal: float, dt_s: float) -> tuple[float, float, bool]:
        """(prior mean [parameter unit], prior std, log): the normal prior this tolerance states around
        ``nominal``; with ``log`` the mean and std are of ln(parameter). A fixed one has std 0."""
        if self.kind == "relative":
            return nominal, abs(nominal) * self.value / Z95, False
        if self.kind == "factor":
            return nominal, math.log(self.value) / Z95, True
        if self.kind == "absolute":
            return nominal, self.value / Z95, False
        if self.kind == "range":
            scale = dt_s if self.in_samples else 1.0
            return 0.5 * (self.low + self.high) * scale, 0.5 * (self.high - self.low) * scale / Z95, False
        return nominal, 0.0, False


#: default tolerance of every updating parameter that has one (docs/default_rig.md, "Tolerances")
DEFAULT_TOLERANCES: dict[str, Tolerance] = {
    # manufacturing of the magnets (air gap, pole area, iron): a data sheet's +-5 % and +-10 %
    "ki_n_per_a": Tolerance("relative", 0.05),
    "ks_n_per_m": Tolerance("relative", 0.10),
    # two magnets built to one drawing: each ks +-10 %, their ratio about the same
    "ks_b_over_a": Tolerance("relative", 0.10),
    # eq. 2.24 is a power bandwidth; the current controller's own tuning and the probe electronics differ
    "amplifier_bandwidth_hz": Tolerance("relative", 0.50),
    "sensor_bandwidth_hz": Tolerance("relative", 0.50),
    # the axial bearing (a five-axis rig): its magnet pair, amplifier and probe, built like the radial ones
    "axial_ki_n_per_a": Tolerance("relative", 0.05),
    "axial_ks_n_per_m": Tolerance("relative", 0.10),
    "axial_amplifier_bandwidth_hz": Tolerance("relative", 0.50),
    "axial_sensor_bandwidth_hz": Tolerance("relative", 0.50),
    # a finite-element model of a free-free rotor, and a guess of structural damping
    "bending_freq_hz": Tolerance("relative", 0.05),
    "bending_damping_ratio": Tolerance("factor", 3.0),
    # conversion and PWM update: somewhere within the sample
    "delay_s": Tolerance("range", low=0.0, high=1.0, in_samples=True),
    # the support (housing) mode has no data sheet: it is started at the fitted mode the nominal model
    # lacks, and its prior is only wide enough to keep the problem well posed
    "support_freq_hz": Tolerance("factor", 2.0),
    "support_damping_ratio": Tolerance("factor", 5.0),
    "support_gain_per_kg": Tolerance("factor", 10.0),
}

_BENDING = re.compile(r"^bending_([2-9])_(freq_hz|damping_ratio)$")
#: names a ``tolerances:`` mapping may hold
TOLERANCE_NAMES: tuple[str, ...] = tuple(DEFAULT_TOLERANCES) + tuple(
    f"bending_{k}_{q}" for k in range(2, 9) for q in ("freq_hz", "damping_ratio"))
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_FORMS = ('"5 %" (relative), "x3" (a factor), a number (+- that, SI unit), "LOW..HIGH" (a range, SI unit, '
          'or "0..1 sample") or "fixed"')


def parse_tolerance(name: str, raw: Any) -> Tolerance:
    """One tolerance from its text or number (module docstring); ValueError naming ``name`` and the forms."""
    bad = ValueError(f"rig: tolerances: {name} = {raw!r} is not a tolerance; give {_FORMS}")
    if isinstance(raw, bool) or raw is None:
        raise bad
    if isinstance(raw, (int, float)):
        if not (math.isfinite(raw) and raw > 0):
            raise ValueError(f"rig: tolerances: {name} = {raw!r} must be > 0 (a half-width in SI units); "
                             f"give {_FORMS}")
        return Tolerance("absolute", float(raw))
    text = str(raw).strip().lower()
    if text == "fixed":
        return Tolerance("fixed")
    m = re.fullmatch(rf"({_NUMBER})\s*%", text)
    if m:
        v = float(m.group(1)) / 100
        if not 0 < v < 1:
            raise ValueError(f"rig: tolerances: {name} = {raw!r} must lie between 0 and 100 %")
        return Tolerance("relative", v)
    m = re.fullmatch(rf"[x*]\s*({_NUMBER})", text)
    if m:
        v = float(m.group(1))
        if not (math.isfinite(v) and v > 1):
            raise ValueError(f"rig: tolerances: {name} = {raw!r} must be a factor > 1, e.g. x3")
        return Tolerance("factor", v)
    m = re.fullmatch(rf"({_NUMBER})\s*\.\.\s*({_NUMBER})\s*(samples?)?", text)
    if m:
        lo, hi = float(m.group(1)), float(m.group(2))
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"rig: tolerances: {name} = {raw!r} must be a range LOW..HIGH with LOW < HIGH")
        if m.group(3) and name != "delay_s":
            raise ValueError(f"rig: tolerances: {name} = {raw!r}: only delay_s is given in samples")
        return Tolerance("range", low=lo, high=hi, in_samples=bool(m.group(3)))
    m = re.fullmatch(_NUMBER, text)
    if m:
        return parse_tolerance(name, float(text))
    raise bad


def parse_tolerances(raw: Any) -> dict[str, Tolerance]:
    """A rig file's ``tolerances:`` mapping (already loaded) -> name -> :class:`Tolerance`."""
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise ValueError(f"rig: tolerances must be a mapping of parameter: tolerance, got {type(raw).__name__}; "
                         "e.g. tolerances: {ki_n_per_a: 5 %, bending_damping_ratio: x3}")
    unknown = sorted(str(k) for k in raw if k not in TOLERANCE_NAMES)
    if unknown:
        raise ValueError(f"rig: tolerances: unknown parameter(s) {unknown}; known are: "
                         f"{', '.join(DEFAULT_TOLERANCES)} and bending_<k>_freq_hz, bending_<k>_damping_ratio "
                         "(k = 2..8)")
    return {str(k): parse_tolerance(str(k), v) for k, v in raw.items()}


def tolerance_for(name: str, given: dict[str, Tolerance]) -> Tolerance | None:
    """The tolerance of updating parameter ``name``: the rig file's, else the default; a higher bending
    mode takes the first one's; None for a parameter without one."""
    if name in given:
        return given[name]
    m = _BENDING.match(name)
    if m:
        return tolerance_for(f"bending_{m.group(2)}", given)
    return DEFAULT_TOLERANCES.get(name)
