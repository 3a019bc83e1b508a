"""Which poles of a fitted model are modes of the measured system, and why the others are not.

A common-denominator fit of order n has n poles whatever the data holds: the
poles beyond the system's own model the noise, the misfit and what lies
outside the band. A pole pair is printed as a *mode* only when the data shows
it, by four checks, the first that fails naming the reason:

1. positively damped: a complex pole with negative damping is an unstable
   oscillation, which neither a structure measured in a stable test nor an AMB
   plant has (the plant's only unstable poles are real: the magnets' negative
   stiffness);
2. inside the band the data supports: between the lowest and the highest
   measured line;
3. stable over model orders: found again (frequency within ``tol_freq``,
   damping within a factor of two) at most of the orders fitted from half the
   chosen order up (:func:`ambid.fit.stabilisation_diagram`), as a physical
   pole stays put while the noise's poles wander (with fewer than two such
   orders, as a handful of lines allows, this check cannot judge and is left
   to the next);
4. above the noise: somewhere within its half-power band (and at least the
   nearest lines) the mode's own contribution to the FRF stands out above the
   FRF's noise there by ``min_snr``, summed over the outputs and inputs: its
   standard deviation where the data gives a variance; else the larger of the
   fit's residual about the model and the scatter of the FRF, with the pole's
   own part taken out, about a local quadratic over +-12 lines (a model of high
   order takes the noise into its spurious poles, so its residual alone
   understates the noise; a real mode leaves a smooth remainder; a window of
   25 lines, not a handful, so that a pole fitted to a ripple a few lines wide,
   a VNA's or an analyser's, cannot take up the window's whole scatter).

The common denominator makes a pole shared by every output and input, and the
fourth check is made over all of them together: a mode carried by one entry's
noise alone does not stand out over the matrix's noise.

Real poles are listed apart: an unstable real pole found at most orders is the
plant's own where the FRF is an AMB plant's (u -> y, current in): the magnets'
negative stiffness; in another FRF (a structure's, an analyser's) it is
computational.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ambid.fit.common_denominator import RationalModel
from ambid.fit.modes import _is_real
from ambid.fit.order_selection import StabilisationDiagram

__all__ = ["PoleVerdict", "judge_poles", "NEGATIVE_STIFFNESS"]

NEGATIVE_STIFFNESS = "the plant's unstable real pole: the magnets' negative stiffness"


@dataclass(frozen=True)
class PoleVerdict:
    """One pole of the fitted model and whether the data shows it as a mode.

    Attributes
    ----------
    index
        the pole's index in ``model.poles``.
    freq_hz
        |p| / (2 pi) [Hz]; damping: -Re p / |p| (a real pole: +1 stable, -1 unstable).
    real
        a real pole.
    physical
        printed as a mode (complex) or named as the plant's (real).
    reason
        why not, or what it is (one phrase).
    stable_share
        the share of the orders checked at which it was found again [-] (NaN: too few orders).
    snr
        its largest contribution to the FRF over the noise there [-] (complex poles).
    """

    index: int
    freq_hz: float
    damping: float
    real: bool
    physical: bool
    reason: str
    stable_share: float
    snr: float

    def to_dict(self) -> dict:
        """JSON-safe dict."""
        return dict(freq_hz=self.freq_hz, damping=self.damping, real=self.real, physical=self.physical,
                    reason=self.reason, stable_share=self.stable_share, snr=self.snr)


def _stable_share(p: complex, diagram: StabilisationDiagram, order: int, tol_freq: float) -> float:
    """The share of the diagram's orders from order / 2 up (the chosen one left out) with a pole of the same
    kind within tol_freq in frequency and a factor of two in damping."""
    orders = [int(n) for n in diagram.orders if n >= max(order // 2, 2) and n != order]
    if len(orders) < 2:     # too few orders fitted (a handful of lines) to tell a stable pole from a wandering one
        return float("nan")
    f, z = abs(p), -p.real / abs(p)
    real = bool(_is_real(np.array([p]))[0])
    found = 0
    for n in orders:
        q = diagram.poles_of(n)
        q = q[_is_real(q) == real]
        if q.size == 0:
            continue
        fq, zq = np.abs(q), -q.real / np.abs(q)
        ok = np.abs(fq - f) <= tol_freq * f
        if real:    # an unstable real pole is not found again as a stable one
            ok &= np.sign(q.real) == np.sign(p.real)
        else:
            ok &= (np.sign(zq) == np.sign(z)) & (np.abs(zq) <= 2 * abs(z) + 1e-4) & (np.abs(zq) >= 0.5 * abs(z) - 1e-4)
        found += bool(np.any(ok))
    return found / len(orders)


def _local_scatter(f: np.ndarray, x: np.ndarray, idx: np.ndarray, half: int = 12, deg: int = 2) -> np.ndarray:
    """At the lines ``idx``: the rms scatter of x (L, E) about a local polynomial of degree ``deg`` in frequency over
    +-``half`` lines (degrees of freedom counted), summed over the entries as a norm."""
    out = np.empty(idx.size)
    n_min = deg + 3
    for i, k in enumerate(idx):
        lo, hi = max(0, k - half), min(f.size, k + half + 1)
        if hi - lo < n_min:
            lo, hi = max(0, min(lo, f.size - n_min)), min(f.size, max(hi, n_min))
        t = f[lo:hi] - f[k]
        t = t / max(np.max(np.abs(t)), 1e-300)
        a = np.vander(t, deg + 1)
        coef, *_ = np.linalg.lstsq(a, x[lo:hi], rcond=None)
        r = x[lo:hi] - a @ coef
        out[i] = np.sqrt(np.sum(np.abs(r) ** 2) / max(hi - lo - deg - 1, 1))
    return out


def judge_poles(model: RationalModel, diagram: StabilisationDiagram, order: int, freq_hz: np.ndarray,
                G: np.ndarray, noise_var: np.ndarray | None = None, *, plant_input_current: bool = False,
                tol_freq: float = 0.01, min_stable_share: float = 0.5, min_snr: float = 3.0) -> list[PoleVerdict]:
    """Each pole of ``model`` (complex pairs once, Im > 0, then the real ones) judged by the module's checks.

    Parameters
    ----------
    model
        the fit at ``order``.
    diagram
        the stabilisation diagram the order was chosen on.
    order
        the model's order.
    freq_hz
        (L,) the measured lines [Hz].
    G
        (L, Ny, Nu) the measured FRF.
    noise_var
        (L, Ny, Nu) its variance E|G - G0|^2, or None (the fit's residual stands for the noise).
    plant_input_current
        the FRF is an AMB plant's, current in (an unstable real pole can be its own).
    tol_freq
        relative frequency tolerance of "found again" [-].
    min_stable_share
        share of the orders checked at which a physical pole is found again [-].
    min_snr
        how far a physical mode's contribution stands above the noise [-].

    Returns
    -------
    :class:`PoleVerdict` per pole pair and real pole, complex ones by frequency first.
    """
    f = np.asarray(freq_hz, dtype=float)
    g = np.asarray(G, dtype=complex)
    p_all = model.poles
    lo, hi = float(f.min()), float(f.max())
    fitted = model.freqresp(f)
    resid = np.linalg.norm((g - fitted).reshape(f.size, -1), axis=1)
    if noise_var is not None:
        noise = np.sqrt(np.sum(np.asarray(noise_var, dtype=float).reshape(f.size, -1), axis=1))
    else:
        # the residual about the model, smoothed over +-3 lines: the misfit's level near each line
        k = np.ones(7) / 7
        noise = np.sqrt(np.convolve(resid ** 2, k, mode="same") / np.convolve(np.ones_like(resid), k, mode="same"))
    noise = np.maximum(noise, 1e-300)
    s = 2j * np.pi * f
    out: list[PoleVerdict] = []
    real = _is_real(p_all)     # as the modal summary tells them apart
    complex_idx = [k for k in range(p_all.size) if not real[k] and p_all[k].imag > 0]
    real_idx = [k for k in range(p_all.size) if real[k]]
    for k in sorted(complex_idx, key=lambda k: abs(p_all[k])):
        p = p_all[k]
        fk, zk = abs(p) / (2 * np.pi), -p.real / abs(p)
        share = _stable_share(p, diagram, order, tol_freq)
        r = model.residues[k]
        contrib = (r[None] / (s - p)[:, None, None] + np.conj(r)[None] / (s - np.conj(p))[:, None, None])
        c = np.linalg.norm(contrib.reshape(f.size, -1), axis=1)
        half = max(abs(zk) * fk * 3, 0.0)
        near = np.abs(f - fk) <= half
        if not np.any(near):   # at least the lines on either side of it
            near = np.zeros(f.size, bool)
            near[np.argsort(np.abs(f - fk))[:2]] = True
        level = noise[near]
        if noise_var is None:
            # no variance: the model's residual holds too little of the noise where the order is high (the poles
            # that model the noise take it in), so the scatter of the FRF with this pole's own part taken out,
            # about a local quadratic over +-12 lines, stands for the noise too (Pintelon & Schoukens' local
            # polynomial idea): a real mode leaves a smooth remainder, a pole fitted to ripple leaves the ripple
            # beside it (over +-4 lines a pole fitted to a dip of 2-3 lines left a smooth remainder: a VNA's
            # ring-slot measurement printed two such poles at 103 and 106 GHz)
            level = np.maximum(level, _local_scatter(f, (g - contrib).reshape(f.size, -1), np.flatnonzero(near)))
        snr = float(np.max(c[near] / np.maximum(level, 1e-300)))
        if zk <= 0:
            reason = ("negative damping: an unstable oscillation, which the measured system cannot have (an AMB "
                      "plant's unstable poles are real); computational")
        elif not lo <= fk <= hi:
            reason = f"outside the band the data supports ({lo:g}-{hi:g} Hz); computational"
        elif share < min_stable_share:     # NaN (too few orders to judge) passes: the noise check still applies
            reason = (f"not stable over model orders (found again at {100 * share:.0f} % of the orders from "
                      f"{max(order // 2, 2)} up); computational")
        elif snr < min_snr:
            reason = f"below the noise (its peak {snr:.2g} x the noise there); computational"
        else:
            reason = ""
        out.append(PoleVerdict(int(k), float(fk), float(zk), False, not reason, reason, float(share), snr))
    for k in sorted(real_idx, key=lambda k: p_all[k].real):
        p = complex(p_all[k].real)
        share = _stable_share(p, diagram, order, tol_freq)
        unstable = p.real > 0
        if unstable and plant_input_current and not share < min_stable_share:
            reason, phys = NEGATIVE_STIFFNESS, True
        elif unstable:
            reason, phys = ("an unstable real pole " + ("not stable over model orders" if plant_input_current else
                                                        "in an FRF measured on a stable system") + "; computational"
                            ), False
        else:
            reason, phys = "a real pole (a lag, an amplifier or filter pole, or the fit's own)", False
        out.append(PoleVerdict(int(k), float(abs(p.real) / (2 * np.pi)), 1.0 if p.real < 0 else -1.0, True, phys,
                               reason, float(share), float("nan")))
    return out
