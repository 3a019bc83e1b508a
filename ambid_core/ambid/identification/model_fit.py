"""Stage 3, the fit: the common-denominator model of an FRF, its order chosen on a stabilisation diagram.

Order-selection rule (:func:`select_order`): the order with the smallest
information criterion ``2 V + penalty * p * N / (N - p - 1)`` (Akaike's with
its small-sample correction, AICc, for penalty 2; 2 V is chi^2 = chi^2/dof *
(N - p), N real residuals, p real parameters; the correction matters only where
p is a fair share of N, as in a short FRF file: 101 lines of a VNA's S11 chose
order 58 without it, and its poles followed the ripple) among the
orders whose in-band lightly damped complex poles (damping ratio below
``max_damping`` in magnitude) all have positive damping and are stable in
frequency in the diagram (found again within its tol_freq at the next lower
order fitted); if no order qualifies, the smallest criterion of all. The
plant's only unstable poles are real (the magnets' negative stiffness), so
a lightly damped unstable pair marks a spurious pole.

:func:`fit_frf` fits with a known delay of half a sample (the zero-order
hold of a sampled measurement), weighted by the FRF's variance (total with
M >= 2 realisations, else noise) averaged over the inputs of each output, and
returns the modes (frequency, damping, their intervals, whirl) and real poles; the variances are the
FRF stage's (:func:`ambid.identification.session_frf.frf_variances`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np
from scipy import special  # not scipy.stats: ~0.6 s to import on the path of `ambid fit`

from ambid.channels import split_name
from ambid.fit import FitResult, StabilisationDiagram, fit_common_denominator, modal_summary, stabilisation_diagram
from ambid.fit.physical_modes import judge_poles
from ambid.frf.directional import has_planes, whirl_of_residue
from ambid.frf.streaming import FrfResult
from ambid.identification.result import ComputationalPole, ModeInterval, ModeRow, RealPole
from ambid.identification.session_frf import FrfVariances, frf_variances

__all__ = ["select_order", "FrfFit", "fit_frf", "mode_interval", "split_modes"]


def select_order(diagram: StabilisationDiagram, band_hz: tuple[float, float], n_lines: int, n_entries: int,
                 weighted: bool = True, penalty: float = 2.0, max_damping: float = 0.3) -> int:
    """The model order by the rule of the module docstring.

    Parameters
    ----------
    diagram
        from :func:`ambid.fit.stabilisation_diagram`, fitted with
        relative degree 0 (a feed-through term).
    band_hz
        (low, high) band whose poles count [Hz].
    n_lines
        L lines of the data; n_entries: Ny * Nu.
    weighted
        the fits were weighted by the noise variance (then
        ``diagram.chi2_per_dof`` is chi^2/dof); False when unweighted
        (then it holds the cost V, scaled here by the smallest V / dof).
    penalty
        criterion weight per parameter (2: AIC, ln N: MDL/BIC).
    max_damping
        complex poles more damped than this are not checked [-].

    Returns
    -------
    The chosen order.
    """
    if not (penalty >= 0 and n_lines >= 1 and n_entries >= 1):
        raise ValueError(f"need penalty >= 0, n_lines >= 1, n_entries >= 1; got {penalty}, {n_lines}, {n_entries}")
    orders = np.asarray(diagram.orders)
    n_res = 2 * n_lines * n_entries
    n_par = orders + n_entries * (orders + 1)  # poles + numerators and feed-through (fit_common_denominator)
    dof = np.maximum(n_res - n_par, 1)
    chi = np.asarray(diagram.chi2_per_dof, dtype=float)
    chi2 = chi * dof if weighted else 2 * chi
    if not weighted:
        chi2 = chi2 / np.nanmin(chi2 / dof)   # noise level from the best fit per degree of freedom
    # the small-sample correction of Akaike's criterion (AICc, Hurvich & Tsai): where the parameters are a fair
    # share of the data (a short FRF file), each costs more, so the noise a high order takes in is not a better fit
    crit = np.where(np.isfinite(chi2), chi2 + penalty * n_par * n_res / np.maximum(n_res - n_par - 1, 1), np.inf)
    if not np.any(np.isfinite(crit)):
        raise ValueError("the stabilisation diagram has no finite cost values")
    lo, hi = band_hz
    clean = []
    for n in orders:
        sel = diagram.order == n
        p, status, f, z = diagram.pole_rad_s[sel], diagram.status[sel], diagram.freq_hz[sel], diagram.damping[sel]
        checked = (p.imag > 0) & (f >= lo) & (f <= hi) & (np.abs(z) < max_damping)
        clean.append(n != orders[0] and bool(np.all(z[checked] > 0) and np.all(np.isin(status[checked], (1, 3)))))
    clean = np.array(clean)
    pick = np.where(clean, crit, np.inf) if np.any(clean & np.isfinite(crit)) else crit
    return int(orders[int(np.argmin(pick))])


def mode_interval(fit: FitResult, freq_hz: float, damping: float) -> ModeInterval | None:
    """The standard deviations and 95 % intervals of a fitted mode, or None: normal (1.96 sigma), or
    Student's t where the variance came from the realisations' scatter (few degrees of freedom)."""
    sd = fit.mode_interval(freq_hz, damping)
    if sd is None:
        return None
    q = float(special.stdtrit(sd[2], 0.975)) if np.isfinite(sd[2]) else 1.96
    return ModeInterval(freq_hz_std=sd[0], freq_hz_ci95=[freq_hz - q * sd[0], freq_hz + q * sd[0]],
                        damping_std=sd[1], damping_ci95=[damping - q * sd[1], damping + q * sd[1]],
                        ci_dof=sd[2] if np.isfinite(sd[2]) else None, noise_only=False)


def split_modes(fit: FitResult, diagram: StabilisationDiagram, order: int, freq_hz: np.ndarray, G: np.ndarray,
                noise_var: np.ndarray | None, *, plant_input_current: bool = False
                ) -> tuple[list, list[ModeRow], list[RealPole], list[ComputationalPole]]:
    """The fit's poles parted into the modes the data shows and the computational ones
    (:func:`ambid.fit.physical_modes.judge_poles`), for ``ambid fit`` of a session and of an FRF file alike.

    Returns
    -------
    (modes: the physical :class:`ambid.fit.Mode` by frequency; their rows: freq_hz, damping, stable (found
    again within 1 % at the next lower order), the 95 % intervals; the real poles' rows: pole_hz (signed,
    > 0 unstable), unstable, reason; the computational complex poles' rows: freq_hz, damping, reason).
    """
    summary_modes = modal_summary(fit.model)
    prev = diagram.orders[diagram.orders < order]
    prev_poles = diagram.poles_of(int(prev[-1])) if prev.size else np.zeros(0, complex)
    verdicts = {v.index: v for v in judge_poles(fit.model, diagram, order, freq_hz, G, noise_var,
                                                plant_input_current=plant_input_current)}
    poles = fit.model.poles

    def index(pole: complex) -> int:   # the model's pole the summary's is (real poles: their real part)
        return int(np.argmin(np.abs(poles - pole)))

    modes, rows, computational = [], [], []
    for m in summary_modes.modes:
        v = verdicts[index(m.pole_rad_s)]
        if not v.physical:
            computational.append(ComputationalPole(freq_hz=m.freq_hz, damping=m.damping, reason=v.reason,
                                                   stable_share=v.stable_share, snr=v.snr))
            continue
        modes.append(m)
        rows.append(ModeRow(freq_hz=m.freq_hz, damping=m.damping,
                            stable=bool(prev_poles.size and np.min(np.abs(np.abs(prev_poles) / (2 * np.pi) - m.freq_hz))
                                        <= 0.01 * m.freq_hz), interval=mode_interval(fit, m.freq_hz, m.damping)))
    real_rows = []
    for r in summary_modes.real_poles:
        v = verdicts[index(r.pole_rad_s)]
        real_rows.append(RealPole(pole_hz=r.pole_rad_s / (2 * np.pi), unstable=r.unstable, physical=v.physical,
                                  reason=v.reason))
    return modes, rows, real_rows, computational


def _is_current(name: str) -> bool:
    """A channel of the applied current (``u_<axis>``)."""
    try:
        return split_name(name)[0] == "u"
    except ValueError:
        return False


@dataclass(frozen=True)
class FrfFit:
    """The common-denominator model of an FRF as identify fits it, and what the fit was weighted by.

    Attributes
    ----------
    fit
        the fit at the chosen order (:class:`ambid.fit.FitResult`).
    order, order_rule
        the order and how it was chosen.
    diagram
        the stabilisation diagram the order was chosen on.
    band_hz
        (low, high) of the FRF's lines [Hz].
    delay_s
        the known delay fitted with the model: half a sample (the zero-order hold) [s].
    modes
        the in-band complex pole pairs (:class:`ambid.fit.Mode`), by frequency.
    mode_rows
        per mode, what identify prints and records (:class:`ambid.identification.result.ModeRow`):
        frequency, damping, stable (found again within 1 % at the next lower order), their 95 %
        intervals, and, where the channels hold a radial bearing's x and y, whirl and forward_share.
    real_rows
        the real poles (:class:`ambid.identification.result.RealPole`).
    computational
        the fit's complex poles that are not modes of the data, each with its reason
        (:func:`split_modes`).
    variances
        what the fit was weighted by and its intervals are read from
        (:class:`ambid.identification.session_frf.FrfVariances`).
    """

    fit: FitResult
    order: int
    order_rule: str
    diagram: StabilisationDiagram
    band_hz: tuple[float, float]
    delay_s: float
    modes: list
    mode_rows: list[ModeRow]
    real_rows: list[RealPole]
    computational: list[ComputationalPole]
    variances: FrfVariances

    def stable_modes(self) -> list:
        """The modes found again at the next lower order (physical-looking)."""
        return [m for m, row in zip(self.modes, self.mode_rows) if row.stable]

    def physical_modes(self) -> list[tuple[float, float]]:
        """(frequency [Hz], damping [-]) of the stable, positively damped modes; all modes when none is."""
        physical = [(m.freq_hz, m.damping) for m, row in zip(self.modes, self.mode_rows)
                    if row.stable and m.damping > 0]
        return physical or [(m.freq_hz, m.damping) for m in self.modes]


def fit_frf(frf: FrfResult, sample_rate_hz: float, order: int | None = None, *, max_order: int = 32,
            order_penalty: float = 2.0, units: Mapping[str, str] | None = None,
            variances: FrfVariances | None = None) -> FrfFit:
    """The common-denominator fit of an FRF, as :func:`ambid.identification.identify_session` makes it
    (module docstring): order selection on the stabilisation diagram unless ``order`` is given, a known
    delay of half a sample, the weights and interval covariance of the FRF's variance.

    Parameters
    ----------
    frf
        the estimate (:func:`ambid.frf.offline.frf_from_session`).
    sample_rate_hz
        the measurement's sample rate [Hz].
    order
        model order; None selects it (:func:`select_order`).
    max_order
        highest order in the stabilisation diagram.
    order_penalty
        criterion weight per parameter of the order rule (2: Akaike).
    units
        channel -> unit where the record says (an imported record's outputs of any kind); default m
        for outputs, A for inputs.
    variances
        the FRF's variances (:func:`ambid.identification.session_frf.frf_variances`), when the
        caller has them; default computed here.

    Raises
    ------
    ValueError
        too few lines for a parametric fit.
    """
    f = frf.freq_hz
    band = (float(f.min()), float(f.max()))
    v = frf_variances(frf) if variances is None else variances
    fit_delay = (1.0 / sample_rate_hz) / 2  # the zero-order hold: half a sample
    units = dict(units or {})
    labels = dict(input_names=frf.input_names, output_names=frf.output_names,
                  input_units=tuple(units.get(n, "A") for n in frf.input_names),
                  output_units=tuple(units.get(n, "m") for n in frf.output_names))
    top = min(max_order, f.size - 1)
    orders = list(range(2, top + 1, 2))
    if not orders:
        raise ValueError(f"{f.size} lines are too few for a parametric fit; excite more lines")
    diagram = stabilisation_diagram(f, frf.frf, v.weights, orders=orders, delay_s=fit_delay)
    rule = (f"smallest chi2 + {order_penalty:g} p N/(N - p - 1) (AICc) among orders with stable, positively damped "
            "in-band modes")
    if order is None:
        order = select_order(diagram, band, f.size, frf.frf.shape[1] * frf.frf.shape[2], v.weights is not None,
                             order_penalty)
    else:
        rule = "given"
    fit: FitResult = fit_common_denominator(f, frf.frf, v.weights, order=int(order), delay_s=fit_delay,
                                            row_covariance=v.row_cov, realisations=v.realisations, **labels)
    current_in = all(_is_current(n) for n in frf.input_names)
    modes, rows, real_rows, computational = split_modes(fit, diagram, int(order), f, frf.frf, v.var,
                                                        plant_input_current=current_in)
    # the radial bearing planes among the channels (x and y of a bearing): forward and backward whirl told apart
    if has_planes(frf.output_names, frf.input_names):
        for i, m in enumerate(modes):
            k = int(np.argmin(np.abs(fit.model.poles - m.pole_rad_s)))
            whirl, share = whirl_of_residue(fit.model.residues[k], frf.output_names, frf.input_names)
            rows[i] = replace(rows[i], whirl=whirl, forward_share=share)
    return FrfFit(fit, int(order), rule, diagram, band, fit_delay, modes, rows, real_rows, computational, v)
