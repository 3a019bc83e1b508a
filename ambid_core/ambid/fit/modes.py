"""Modes and a state-space realisation of a fitted common-denominator model.

Each complex pole pair p, p* is a mode: natural frequency |p| / (2 pi) [Hz],
damping ratio -Re(p) / |p| (negative for an unstable pair), and shapes from
the dominant singular triplet of its residue matrix, R ~ sigma_1 u v^H
(u: output / mode shape at the sensors, v^H: input participation). Real poles
(AMB negative-stiffness poles, amplifier and filter poles) are listed apart
with their s-plane value.

The realisation is Gilbert's: every pole gets rank(R_k) states, in real
2x2 blocks for complex pairs, so its FRF equals the rational model's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ambid.fit.common_denominator import RationalModel
from ambid.statespace import StateSpace

__all__ = ["Mode", "RealPole", "ModalSummary", "modal_summary", "to_statespace"]

_REAL_TOL = 1e-9


@dataclass(frozen=True)
class Mode:
    """One complex pole pair of the fitted model.

    Attributes
    ----------
    pole_rad_s
        the pole with Im > 0 [rad/s].
    freq_hz
        undamped natural frequency |p| / (2 pi) [Hz].
    damping
        damping ratio -Re(p) / |p| [-]; < 0 for an unstable pair.
    damped_freq_hz
        Im(p) / (2 pi) [Hz].
    output_shape
        (Ny,) complex unit vector u (largest entry real > 0).
    input_shape
        (Nu,) complex participation v^H, so R ~ sigma_1 u v^H.
    residue_singular_values
        (min(Ny, Nu),) singular values of R
        [unit of G * rad/s]; sigma_2 / sigma_1 << 1 means a clean,
        single mode.
    """

    pole_rad_s: complex
    freq_hz: float
    damping: float
    damped_freq_hz: float
    output_shape: np.ndarray
    input_shape: np.ndarray
    residue_singular_values: np.ndarray

    def to_dict(self) -> dict:
        """JSON-safe dict (complex numbers as [re, im])."""
        return dict(pole_rad_s=[self.pole_rad_s.real, self.pole_rad_s.imag], freq_hz=self.freq_hz,
                    damping=self.damping, damped_freq_hz=self.damped_freq_hz,
                    output_shape=_pairs(self.output_shape), input_shape=_pairs(self.input_shape),
                    residue_singular_values=self.residue_singular_values.tolist())


@dataclass(frozen=True)
class RealPole:
    """One real pole of the fitted model.

    Attributes
    ----------
    pole_rad_s
        s-plane value [rad/s]; > 0 is unstable.
    unstable
        pole in the right half plane.
    corner_freq_hz
        |p| / (2 pi) [Hz].
    output_shape, input_shape, residue_singular_values
        as in :class:`Mode`
        (real vectors here).
    """

    pole_rad_s: float
    unstable: bool
    corner_freq_hz: float
    output_shape: np.ndarray
    input_shape: np.ndarray
    residue_singular_values: np.ndarray

    def to_dict(self) -> dict:
        """JSON-safe dict."""
        return dict(pole_rad_s=self.pole_rad_s, unstable=self.unstable, corner_freq_hz=self.corner_freq_hz,
                    output_shape=np.real(self.output_shape).tolist(),
                    input_shape=np.real(self.input_shape).tolist(),
                    residue_singular_values=self.residue_singular_values.tolist())


@dataclass(frozen=True)
class ModalSummary:
    """Modes sorted by frequency and real poles sorted by value."""

    modes: tuple[Mode, ...]
    real_poles: tuple[RealPole, ...]

    def to_dict(self) -> dict:
        """JSON-safe dict with lists ``modes`` and ``real_poles``."""
        return dict(modes=[m.to_dict() for m in self.modes], real_poles=[r.to_dict() for r in self.real_poles])


def _pairs(x: np.ndarray) -> list[list[float]]:
    return [[float(v.real), float(v.imag)] for v in np.asarray(x, dtype=complex)]


def _is_real(p: np.ndarray) -> np.ndarray:
    return np.abs(p.imag) <= _REAL_TOL * np.maximum(np.abs(p), 1e-300)


def _shapes(residue: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    u, sv, vh = np.linalg.svd(residue)
    out, inp = u[:, 0], vh[0]
    # fix the free phase: largest output entry real and positive
    k = np.argmax(np.abs(out))
    ph = np.exp(-1j * np.angle(out[k])) if abs(out[k]) > 0 else 1.0
    out, inp = out * ph, inp / ph
    out[k] = abs(out[k])
    return out, inp, sv


def modal_summary(model: RationalModel) -> ModalSummary:
    """Natural frequencies, damping ratios, real poles and shapes of a model.

    Parameters
    ----------
    model
        a fitted :class:`RationalModel`.

    Returns
    -------
    :class:`ModalSummary`.
    """
    p = model.poles
    real = _is_real(p)
    modes = []
    for k in np.flatnonzero(~real & (p.imag > 0)):
        out, inp, sv = _shapes(model.residues[k])
        wn = abs(p[k])
        modes.append(Mode(pole_rad_s=complex(p[k]), freq_hz=float(wn / (2 * np.pi)),
                          damping=float(-p[k].real / wn), damped_freq_hz=float(p[k].imag / (2 * np.pi)),
                          output_shape=out, input_shape=inp, residue_singular_values=sv))
    reals = []
    for k in np.flatnonzero(real):
        out, inp, sv = _shapes(model.residues[k].real)
        reals.append(RealPole(pole_rad_s=float(p[k].real), unstable=bool(p[k].real > 0),
                              corner_freq_hz=float(abs(p[k].real) / (2 * np.pi)),
                              output_shape=out.real, input_shape=inp.real, residue_singular_values=sv))
    modes.sort(key=lambda m: m.freq_hz)
    reals.sort(key=lambda r: r.pole_rad_s)
    return ModalSummary(modes=tuple(modes), real_poles=tuple(reals))


def to_statespace(model: RationalModel, rank_tol: float = 1e-12) -> StateSpace:
    """Real block-diagonal (modal) realisation of the rational model.

    Each pole p with residue R = U S V^H gets r states, r the number of
    singular values above ``rank_tol`` times the largest residue norm: a real pole
    the block p I_r, a complex pair r blocks [[Re p, -Im p], [Im p, Re p]].
    B and C share sqrt(S) for balance. The pure delay of the model, if any,
    is not in the realisation (see ``model.delay_s``).

    Parameters
    ----------
    model
        the model.
    rank_tol
        relative singular-value threshold; the default keeps every
        direction that is not numerically zero, so the FRF is the
        model's; larger values give a smaller, approximate model.

    Returns
    -------
    Continuous :class:`StateSpace` (dt = 0) with the model's labels.
    """
    if not (np.isfinite(rank_tol) and 0 <= rank_tol < 1):
        raise ValueError(f"rank_tol must be in [0, 1), got {rank_tol}")
    p = model.poles
    ny, nu = model.n_outputs, model.n_inputs
    real = _is_real(p)
    s_all = np.linalg.norm(model.residues.reshape(p.size, -1), axis=1)
    floor = rank_tol * max(s_all.max(initial=0.0), 1e-300)
    a_blocks, b_rows, c_cols = [], [], []
    for k in np.flatnonzero(real | (p.imag > 0)):
        if real[k]:
            u, sv, vh = np.linalg.svd(model.residues[k].real)
        else:
            u, sv, vh = np.linalg.svd(model.residues[k])
        for j in np.flatnonzero(sv > floor):
            c = u[:, j] * np.sqrt(sv[j])
            b = np.sqrt(sv[j]) * vh[j]
            if real[k]:
                a_blocks.append(np.array([[p[k].real]]))
                b_rows.append(b.real[None, :])
                c_cols.append(c.real[:, None])
            else:
                sig, om = p[k].real, p[k].imag
                a_blocks.append(np.array([[sig, -om], [om, sig]]))
                b_rows.append(np.vstack([b.real, b.imag]))
                c_cols.append(np.column_stack([2 * c.real, -2 * c.imag]))
    n = sum(blk.shape[0] for blk in a_blocks)
    a = np.zeros((n, n))
    i = 0
    for blk in a_blocks:
        m = blk.shape[0]
        a[i:i + m, i:i + m] = blk
        i += m
    b = np.vstack(b_rows) if b_rows else np.zeros((0, nu))
    c = np.hstack(c_cols) if c_cols else np.zeros((ny, 0))
    return StateSpace(a, b, c, model.feedthrough, 0.0, model.input_names, model.output_names,
                      model.input_units, model.output_units)
