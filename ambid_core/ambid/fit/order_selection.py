"""Order-selection aids: stabilisation diagram and CMIF, as data and figures.

Stabilisation diagram: the model is fitted for a range of orders; each pole
of order n is compared with the nearest pole (s-plane distance, same kind:
complex pair or real pole) of the previous order fitted, and marked stable
in frequency (|df| <= tol_freq f), in damping (|dzeta| <= tol_damping
|zeta|), both, or new. Physical poles stay put as the order grows; spurious
ones (noise modelling) wander.

CMIF (complex mode indicator function): singular values of G per line;
peaks of the first one mark modes, and a second curve peaking at the same
line flags close or repeated modes (e.g. the x and y planes of a rotor).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ambid.fit.blas_threads import single_threaded_blas
from ambid.fit.common_denominator import RationalModel, _fit

if TYPE_CHECKING:  # matplotlib is imported by the plot functions only
    from matplotlib.figure import Figure

__all__ = ["STATUS_LABELS", "StabilisationDiagram", "stabilisation_diagram", "cmif", "plot_stabilisation",
           "plot_cmif"]

#: Meaning of :attr:`StabilisationDiagram.status` codes 0..3.
STATUS_LABELS = ("new", "stable in frequency", "stable in damping", "stable in frequency and damping")


@dataclass(frozen=True)
class StabilisationDiagram:
    """Poles of the fits of increasing order, flattened over the orders.

    One row per complex pair (the Im > 0 pole) and per real pole.

    Attributes
    ----------
    order
        (K,) model order of each row.
    pole_rad_s
        (K,) complex s-plane pole [rad/s].
    freq_hz
        (K,) |p| / (2 pi) [Hz].
    damping
        (K,) -Re(p) / |p| (real poles: +1 stable, -1 unstable).
    status
        (K,) int, index into :data:`STATUS_LABELS`; the first order
        fitted is all 0 (nothing to compare with).
    orders
        (M,) the orders fitted, ascending.
    chi2_per_dof
        (M,) 2 V / (N - p) of each fit (with ``var``; else the
        cost V itself).
    band_hz
        (2,) lowest and highest line of the data [Hz].
    """

    order: np.ndarray
    pole_rad_s: np.ndarray
    freq_hz: np.ndarray
    damping: np.ndarray
    status: np.ndarray
    orders: np.ndarray
    chi2_per_dof: np.ndarray
    band_hz: np.ndarray

    def poles_of(self, order: int) -> np.ndarray:
        """Rows of one order: the poles (k,) complex [rad/s]."""
        return self.pole_rad_s[self.order == order]


def _classify(p: np.ndarray, prev: np.ndarray, tol_freq: float, tol_damping: float) -> np.ndarray:
    status = np.zeros(p.size, dtype=int)
    if prev.size == 0:
        return status
    is_real = p.imag == 0
    prev_real = prev.imag == 0
    for i, pi in enumerate(p):
        cand = prev[prev_real == is_real[i]]
        if cand.size == 0:
            continue
        q = cand[np.argmin(np.abs(cand - pi))]
        f, fq = abs(pi), abs(q)
        z, zq = -pi.real / f, -q.real / fq
        stable_f = abs(f - fq) <= tol_freq * fq
        stable_z = abs(z - zq) <= tol_damping * abs(zq)
        status[i] = int(stable_f) + 2 * int(stable_z)
    return status


def stabilisation_diagram(freq_hz: np.ndarray, G: np.ndarray, var: np.ndarray | None = None, *,
                          orders: Iterable[int], tol_freq: float = 0.01, tol_damping: float = 0.05,
                          refine: bool = False, relative_degree: int = 0, delay_s: float = 0.0,
                          n_vf_iterations: int = 30) -> StabilisationDiagram:
    """Fit every order in ``orders`` and mark the poles that stay.

    Parameters
    ----------
    freq_hz, G, var
        the data as for
        :func:`~ambid.fit.common_denominator.fit_common_denominator`.
    orders
        iterable of model orders (e.g. ``range(10, 31, 2)``).
    tol_freq
        relative frequency change still called stable [-].
    tol_damping
        relative damping change still called stable [-].
    refine
        also run the ML refinement for each order (slower).
    relative_degree, delay_s, n_vf_iterations
        passed to the fit.

    Returns
    -------
    :class:`StabilisationDiagram`.
    """
    ords = np.unique(np.asarray(list(orders), dtype=int))
    if ords.size == 0 or ords.min() < 1:
        raise ValueError(f"orders must hold positive integers, got {list(orders)}")
    if not (tol_freq > 0 and tol_damping > 0):
        raise ValueError(f"tol_freq and tol_damping must be > 0, got {tol_freq}, {tol_damping}")
    rows_o, rows_p, rows_s, chi = [], [], [], []
    prev = np.zeros(0, dtype=complex)
    with single_threaded_blas():
        for n in ords:
            res = _fit(freq_hz, G, var, int(n), relative_degree, delay_s, None, n_vf_iterations, refine, 100,
                       ((), (), (), ()))
            p = res.model.poles
            p = p[p.imag >= 0]
            rows_o.append(np.full(p.size, n))
            rows_p.append(p)
            rows_s.append(_classify(p, prev, tol_freq, tol_damping))
            chi.append(res.chi2_per_dof if res.weighted else res.cost)
            prev = p
    pole = np.concatenate(rows_p)
    mag = np.abs(pole)
    f = np.asarray(freq_hz, dtype=float)
    return StabilisationDiagram(order=np.concatenate(rows_o), pole_rad_s=pole, freq_hz=mag / (2 * np.pi),
                                damping=-pole.real / np.where(mag > 0, mag, 1.0),
                                status=np.concatenate(rows_s), orders=ords, chi2_per_dof=np.asarray(chi),
                                band_hz=np.array([f.min(), f.max()]))


def cmif(G: np.ndarray) -> np.ndarray:
    """Singular values of G per line, descending.

    Parameters
    ----------
    G
        (L, Ny, Nu) complex FRF.

    Returns
    -------
    (L, min(Ny, Nu)) [unit of G].
    """
    g = np.asarray(G)
    if g.ndim != 3:
        raise ValueError(f"G must be (L, Ny, Nu), got shape {g.shape}")
    return np.linalg.svd(g, compute_uv=False)


_STYLE = ((dict(marker="o", facecolors="none", edgecolors="0.6", s=14)),
          (dict(marker="^", facecolors="none", edgecolors="tab:blue", s=22)),
          (dict(marker="v", facecolors="none", edgecolors="tab:orange", s=22)),
          (dict(marker="s", facecolors="tab:green", edgecolors="tab:green", s=20)))


def plot_stabilisation(diagram: StabilisationDiagram, path: str | None = None, *,
                       G: np.ndarray | None = None, freq_hz: np.ndarray | None = None,
                       freq_range_hz: tuple[float, float] | None = None, unit: str = "m/A",
                       title: str = "Stabilisation diagram") -> Figure:
    """Stabilisation diagram figure, with the CMIF behind it if G is given.

    Parameters
    ----------
    diagram
        from :func:`stabilisation_diagram`.
    path
        write a PNG there if given.
    G, freq_hz
        (L, Ny, Nu) FRF and its lines [Hz] for the CMIF overlay.
    freq_range_hz
        x-axis limits [Hz]; default half the lowest line to
        twice the highest.
    unit
        unit of G for the CMIF axis label.
    title
        figure title.

    Returns
    -------
    The matplotlib Figure.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 5.5))
    ax = fig.add_subplot()
    lo, hi = freq_range_hz if freq_range_hz is not None else (diagram.band_hz[0] / 2, diagram.band_hz[1] * 2)
    lo = max(lo, 1e-3)
    if G is not None:
        if freq_hz is None:
            raise ValueError("plot_stabilisation: give freq_hz with G for the CMIF overlay")
        ax2 = ax.twinx()
        sv = cmif(G)
        for k in range(sv.shape[1]):
            ax2.loglog(freq_hz, sv[:, k], color="0.75", lw=0.8, zorder=0)
        ax2.set_ylabel(f"CMIF singular values [{unit}]")
        ax.set_zorder(ax2.get_zorder() + 1)
        ax.patch.set_visible(False)
    inside = (diagram.freq_hz >= lo) & (diagram.freq_hz <= hi)
    for code, style in enumerate(_STYLE):
        sel = inside & (diagram.status == code)
        ax.scatter(diagram.freq_hz[sel], diagram.order[sel], label=STATUS_LABELS[code], **style)
    rhp = inside & (diagram.pole_rad_s.real > 0)
    ax.scatter(diagram.freq_hz[rhp], diagram.order[rhp], marker="x", color="tab:red", s=18,
               label="right-half-plane (unstable) pole")
    ax.set_xscale("log")
    ax.set_xlim(lo, hi)
    ax.set_xlabel("natural frequency |p| / 2\u03c0 [Hz]")
    ax.set_ylabel("model order [-]")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=3, fontsize="small")
    if path is not None:
        fig.savefig(path, dpi=120, bbox_inches="tight")
    return fig


def plot_cmif(freq_hz: np.ndarray, G: np.ndarray, path: str | None = None, *,
              model: RationalModel | np.ndarray | None = None, unit: str = "m/A",
              title: str = "CMIF") -> Figure:
    """CMIF figure of measured data, with a model's CMIF dashed if given.

    Parameters
    ----------
    freq_hz
        (L,) lines [Hz].
    G
        (L, Ny, Nu) measured FRF.
    path
        write a PNG there if given.
    model
        a :class:`RationalModel` or its FRF (L, Ny, Nu) at ``freq_hz``.
    unit
        unit of G for the axis label.
    title
        figure title.

    Returns
    -------
    The matplotlib Figure.
    """
    f = np.asarray(freq_hz, dtype=float)
    sv = cmif(G)
    if sv.shape[0] != f.size:
        raise ValueError(f"plot_cmif: G has {sv.shape[0]} lines, freq_hz {f.size}")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 5))
    ax = fig.add_subplot()
    colors = [f"C{k}" for k in range(sv.shape[1])]
    for k in range(sv.shape[1]):
        ax.loglog(f, sv[:, k], color=colors[k], lw=1.0, label=f"measured \u03c3{k + 1}")
    if model is not None:
        gm = model.freqresp(f) if isinstance(model, RationalModel) else np.asarray(model)
        svm = cmif(gm)
        for k in range(svm.shape[1]):
            ax.loglog(f, svm[:, k], color=colors[k], lw=1.2, ls="--", label=f"model \u03c3{k + 1}")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(f"singular value of G [{unit}]")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize="small", ncol=2)
    if path is not None:
        fig.savefig(path, dpi=120, bbox_inches="tight")
    return fig
