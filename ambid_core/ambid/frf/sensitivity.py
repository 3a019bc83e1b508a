"""Input sensitivity of the AMB control loop and its ISO 14839-3 zone.

Sign convention: ``u = r - C y`` (the control current is ``ic = -C y``), the
plant is ``y = P u``, so ``u = (I + C P)^-1 r``: the input sensitivity
``S = (I + C P)^-1`` maps the excitation r to the applied current u. It is
measured as ``S = U R^-1`` per line over the experiments, i.e. the pooled
``S_ur S_rr^-1`` (r is noise-free, so noise does not bias it).

ISO 14839-3 judges each control axis by the peak magnitude of its
sensitivity over frequency, as an absolute gain (not dB): zone A if
peak < 3 (9.5 dB), B if < 4 (12 dB), C if < 5 (14 dB), else D. Each axis is
the diagonal element S_ii measured with the other loops closed; the
machine's zone is that of the worst axis.

What a record shows depends on where the excitation entered the loop
(:func:`sensitivity_shown`, per excitation channel r_a on axis a):

* ``current`` (r added to the control current, u = ic + r; ambid's own
  sessions): with the total current u_a measured, ``S_i = u / r`` is the
  input sensitivity, line by line.
* ``reference`` (r added to the controller's position reference, the error
  e = r - y): the loop's sensitivity is ``S_o = e / r = 1 - y_a / r_a``, shown
  only where the record holds the controller's own position sensor y_a in
  the reference's unit. ``u / r`` is then K S_o, the controller times the
  sensitivity, not a sensitivity; accelerometers or probes elsewhere on the
  shaft show the plant, not the loop.
* ``output`` (r added to the sensor signal the controller reads):
  ``S_o = (y + r) / r = 1 + y_a / r_a`` with y_a that sensor before the
  addition, in r's unit; likewise only where the record holds it.

In every case ``y / r = G (u / r)``: the line's FRF from r to y is the
measured plant times the measured u / r.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ambid.frf.estimators import _cross, _matched, _right_divide

__all__ = ["input_sensitivity", "sensitivity_diagonal", "sensitivity_peak", "iso14839_zone", "zone_probabilities",
           "sensitivity_peak_draws",
           "input_sensitivity_from_models", "ZONE_LIMITS", "ZONES", "ShownSensitivity", "sensitivity_shown"]

# Upper peak-gain limits of zones A, B, C (ISO 14839-3); above the last is D.
ZONE_LIMITS: tuple[tuple[str, float], ...] = (("A", 3.0), ("B", 4.0), ("C", 5.0))
#: The zones, best first.
ZONES: tuple[str, ...] = ("A", "B", "C", "D")


def input_sensitivity(u: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Measured input sensitivity ``S = S_ur S_rr^-1`` (r -> u), per line.

    Parameters
    ----------
    u
        applied-input spectra (M, Ne, P, L, Nu).
    r
        excitation spectra (M, Ne, P or 1, L, Nu), Ne >= Nu with an
        invertible reference matrix at every line.

    Returns
    -------
    S (L, Nu, Nu), dimensionless (A/A).
    """
    s = _matched(u=u, r=r)
    return _right_divide(_cross(s["u"], s["r"]), _cross(s["r"], s["r"]), "S_rr")


def sensitivity_diagonal(s: np.ndarray) -> np.ndarray:
    """Per-axis SISO view: the diagonal elements S_ii, shape (L, Nu) from (L, Nu, Nu)."""
    s = np.asarray(s)
    if s.ndim != 3 or s.shape[1] != s.shape[2]:
        raise ValueError(f"s must have shape (L, Nu, Nu), got {s.shape}")
    return np.diagonal(s, axis1=1, axis2=2).copy()


def sensitivity_peak(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Peak magnitude of each axis's sensitivity over the lines.

    Parameters
    ----------
    s
        sensitivity matrices (L, Nu, Nu), or diagonal (L, Nu).

    Returns
    -------
    (peak, index): peak |S_ii| per axis (Nu,) as absolute gain, and the
    line index (Nu,) where it occurs.
    """
    s = np.asarray(s)
    diag = sensitivity_diagonal(s) if s.ndim == 3 else s
    if diag.ndim != 2 or diag.shape[0] == 0:
        raise ValueError(f"s must have shape (L, Nu, Nu) or (L, Nu) with L >= 1, got {s.shape}")
    if not np.all(np.isfinite(diag)):
        raise ValueError("s contains NaN or inf")
    mag = np.abs(diag)
    idx = mag.argmax(axis=0)
    return mag[idx, np.arange(mag.shape[1])], idx


def iso14839_zone(peak: float) -> str:
    """ISO 14839-3 zone of a peak sensitivity (absolute gain): A < 3 <= B < 4 <= C < 5 <= D.

    Examples
    --------
    >>> iso14839_zone(2.5), iso14839_zone(3.5), iso14839_zone(4.5), iso14839_zone(6.0)
    ('A', 'B', 'C', 'D')
    """
    peak = float(peak)
    if not np.isfinite(peak) or peak < 0:
        raise ValueError(f"peak must be a finite gain >= 0 (absolute, not dB), got {peak}")
    for zone, limit in ZONE_LIMITS:
        if peak < limit:
            return zone
    return "D"


def zone_probabilities(peaks: np.ndarray) -> dict[str, float]:
    """The probability of each ISO 14839-3 zone, the share of ``peaks`` (draws of a peak's distribution,
    absolute gain) in it: the zone of :func:`iso14839_zone` with its confidence.

    Examples
    --------
    >>> zone_probabilities(np.array([2.5, 2.9, 3.1, 4.2]))
    {'A': 0.5, 'B': 0.25, 'C': 0.25, 'D': 0.0}
    """
    x = np.asarray(peaks, dtype=float).ravel()
    if x.size == 0 or not np.all(np.isfinite(x)):
        raise ValueError("zone_probabilities needs finite peak draws")
    edges = [limit for _, limit in ZONE_LIMITS]
    counts = np.bincount(np.searchsorted(edges, x, side="right"), minlength=len(ZONES))
    return {z: float(c) / x.size for z, c in zip(ZONES, counts)}


def sensitivity_peak_draws(s: np.ndarray, g: np.ndarray, var_g: np.ndarray, c_jw: np.ndarray,
                           n_draws: int = 1000, rng: np.random.Generator | None = None) -> np.ndarray:
    """Draws of the worst input-sensitivity peak ``max_l max_i |S_ii(l)|`` from the plant FRF's uncertainty.

    At each line the plant is drawn as ``G + dG``, dG circular complex Gaussian with ``E|dG|^2 = var_g``
    per element (independent elements and lines), and the sensitivity moves as the loop closed on it does:
    ``S + (I + C (G + dG))^-1 - (I + C G)^-1`` (exact, not linearised). The centre ``s`` is what is known at
    the line (the measured u / r, or the fitted model's S between the lines).

    Parameters
    ----------
    s
        (L, Nu, Nu) the sensitivity at the lines [A/A].
    g
        (L, Ny, Nu) the plant FRF u -> y there [m/A].
    var_g
        (L, Ny, Nu) its variance [(m/A)^2]; 0 where nothing is known.
    c_jw
        (L, Nu, Ny) the controller y -> -ic there [A/m] (``u = r - C y``).
    n_draws
        number of draws.
    rng
        the generator (None: seed 0).

    Returns
    -------
    (n_draws,) peak draws [-, absolute gain].

    Examples
    --------
    >>> g = np.full((1, 1, 1), 1.0 + 0j); c = np.full((1, 1, 1), -0.7 + 0j)
    >>> d = sensitivity_peak_draws(1.0 / (1.0 + c @ g), g, np.zeros((1, 1, 1)), c, 4)
    >>> np.allclose(d, 1.0 / 0.3)
    True
    """
    s, g, c_jw = (np.asarray(a, dtype=complex) for a in (s, g, c_jw))
    sd = np.sqrt(np.nan_to_num(np.asarray(var_g, dtype=float), nan=0.0) / 2.0)
    rng = np.random.default_rng(0) if rng is None else rng
    dg = sd * (rng.standard_normal((n_draws, *g.shape)) + 1j * rng.standard_normal((n_draws, *g.shape)))
    eye = np.eye(s.shape[1])
    drawn = s + np.linalg.inv(eye + c_jw @ (g + dg)) - np.linalg.inv(eye + c_jw @ g)
    return np.abs(np.diagonal(drawn, axis1=2, axis2=3)).max(axis=(1, 2))


def input_sensitivity_from_models(p_jw: np.ndarray, c_jw: np.ndarray) -> np.ndarray:
    """True input sensitivity ``S = (I + C P)^-1`` from plant and controller FRFs.

    Parameters
    ----------
    p_jw
        plant FRF (L, Ny, Nu) [m/A], u -> y.
    c_jw
        controller FRF (L, Nu, Ny) [A/m], y -> -ic (``u = r - C y``).

    Returns
    -------
    S (L, Nu, Nu).
    """
    p_jw, c_jw = np.asarray(p_jw), np.asarray(c_jw)
    if p_jw.ndim != 3 or c_jw.ndim != 3 or c_jw.shape != (p_jw.shape[0], p_jw.shape[2], p_jw.shape[1]):
        raise ValueError(f"need p_jw (L, Ny, Nu) and c_jw (L, Nu, Ny), got {p_jw.shape} and {c_jw.shape}")
    eye = np.eye(p_jw.shape[2])
    return np.linalg.inv(eye + c_jw @ p_jw)


@dataclass(frozen=True)
class ShownSensitivity:
    """The loop sensitivity one excitation channel shows, or why it shows none.

    Attributes
    ----------
    excitation
        the excitation channel (``r_a_x``).
    injected_at
        'current', 'reference' or 'output'.
    kind
        'input' (S_i = u / r), 'output' (S_o from the controller's sensor), or '' (none).
    values
        (L,) complex S_aa at the lines, or None.
    why
        one line: what it is, or why there is none.
    """

    excitation: str
    injected_at: str
    kind: str
    values: np.ndarray | None
    why: str


def _axis(name: str) -> str:
    return name.split("_", 1)[1] if "_" in name else name


def sensitivity_shown(G: np.ndarray, S_ur: np.ndarray, output_names: Sequence[str], input_names: Sequence[str],
                      injected_at: Mapping[str, str] | None = None, output_units: Sequence[str] | None = None,
                      excitation_units: Sequence[str] | None = None) -> list[ShownSensitivity]:
    """Per excitation channel, the loop sensitivity the measured lines show (module docstring).

    Parameters
    ----------
    G
        (L, Ny, Nu) the FRF u -> y.
    S_ur
        (L, Nu, Nu) the measured u / r (r -> u).
    output_names
        (Ny,) ``y_<name>``; input_names: (Nu,) ``u_<axis>`` (the excitation ``r_<axis>``).
    injected_at
        excitation name -> 'current' | 'reference' | 'output' (missing: current).
    output_units
        (Ny,) the outputs' units (None: all in m).
    excitation_units
        (Nu,) the excitation's units (None: A where injected at the current, m otherwise).

    Returns
    -------
    One :class:`ShownSensitivity` per input, in order.
    """
    injected_at = dict(injected_at or {})
    g, s_ur = np.asarray(G), np.asarray(S_ur)
    out_units = list(output_units) if output_units is not None else ["m"] * len(output_names)
    shown = []
    for j, u in enumerate(input_names):
        axis = _axis(u)
        r = f"r_{axis}"
        where = injected_at.get(r, "current")
        r_unit = (list(excitation_units)[j] if excitation_units is not None else ("A" if where == "current" else "m"))
        if where == "current":
            shown.append(ShownSensitivity(r, where, "input", s_ur[:, j, j],
                                          f"input sensitivity S_i = u/r of {u}: {r} is added to the control current "
                                          "and the total current is measured"))
            continue
        own = f"y_{axis}"
        sign = -1.0 if where == "reference" else 1.0
        formula = "1 - y/r" if where == "reference" else "1 + y/r"
        if own in output_names and out_units[list(output_names).index(own)] == r_unit:
            i = list(output_names).index(own)
            t = np.einsum("lk,lk->l", g[:, i, :], s_ur[:, :, j])    # y_a / r_a = G[a, :] (u / r)[:, a]
            into = "position reference" if sign < 0 else "sensor signal"
            shown.append(ShownSensitivity(r, where, "output", 1.0 + sign * t,
                                          f"sensitivity S_o = {formula} at the controller's own sensor {own} "
                                          f"[{r_unit}]: {r} is added to the {into}"))
            continue
        others = ", ".join(f"{n[2:]} [{un}]" for n, un in zip(output_names, out_units)) or "none"
        place = "the controller's position reference" if where == "reference" else "the sensor signal"
        shown.append(ShownSensitivity(
            r, where, "", None,
            f"no sensitivity for {r}: it is injected at {place} [{r_unit}], where the loop's sensitivity is {formula} "
            f"at the controller's own position sensor {own} in {r_unit}, which this record does not hold "
            f"(its outputs: {others}); u/r here is the controller times the sensitivity, not a sensitivity"))
    return shown


def sensitivity_lines(sens: Mapping | None) -> list[str]:
    """What a summary's ``sensitivity`` says, as the headline prints it: the loop's worst peak with its frequency,
    where it came from (the measured lines, or the fitted model between them) and its ISO 14839-3 zone; then one
    line per excitation channel that shows no sensitivity, saying why."""
    if not sens:
        return []
    lines = []
    loop = sens.get("loop")
    if loop:
        lines.append(f"loop sensitivity peak {loop['peak']:.3g} at {loop['peak_hz']:.4g} Hz ({loop['channel']}, from "
                     f"{loop['source']}): ISO 14839-3 zone {loop['iso_zone']}")
        measured = sens.get("worst_peak")
        if measured is not None and "fitted model" in loop["source"]:
            lines.append(f"  at the measured lines {measured:.3g} (zone {sens.get('iso_zone')})"
                         + ("" if sens.get("true_peak") is None else
                            f"; the true loop {max(sens['true_peak']):.3g} (zone {sens.get('true_iso_zone')})"))
        probs = loop.get("zone_probabilities")
        if probs:
            lines.append("  zone probabilities " + ", ".join(f"{z} {probs[z]:.2f}" for z in ZONES)
                         + " (from the measured and fitted sensitivity's uncertainty)")
    for why in sens.get("none") or []:
        lines.append(why)
    return lines
