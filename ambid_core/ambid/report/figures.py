"""The report's figures, one function per concern.

Each function draws one matplotlib Figure (no pyplot state, so it is safe in
any thread and needs no display), writes it as a PNG when ``path`` is given
and returns it. Units: frequencies in Hz, displacements in m (shown in um
where read as numbers), currents in A, FRFs in m/A.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # matplotlib is optional (pip install ambid[report]): the drawing functions import it
    from matplotlib.figure import Figure

    from ambid.excitation.design import ExcitationDesign
    from ambid.fit.order_selection import StabilisationDiagram
    from ambid.frf.levels import LineLevels

__all__ = ["bode_matrix", "noise_distortion", "stabilisation", "excitation", "input_sensitivity", "time_records",
           "frf_error"]

_DPI = 110
_CURVE_STYLE = {
    "fitted model": dict(color="tab:blue", lw=1.3),
    "analytical (nominal) model": dict(color="tab:orange", lw=1.1, ls="--"),
    "updated physical model": dict(color="tab:green", lw=1.1),
    "true rig (simulated)": dict(color="0.35", lw=1.0, ls=":"),
}
_ZONES = (("A", 0.0, 3.0, "tab:green"), ("B", 3.0, 4.0, "gold"), ("C", 4.0, 5.0, "tab:orange"),
          ("D", 5.0, np.inf, "tab:red"))


def _figure(figsize: tuple[float, float]) -> Figure:
    # fixed margins (subplots_adjust) instead of constrained layout or a tight bounding box: on a busy
    # machine those layout passes cost several seconds per figure
    from matplotlib.figure import Figure

    return Figure(figsize=figsize)


def _save(fig: Figure, path: str | Path | None, tight: bool = False) -> Figure:
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=_DPI, bbox_inches="tight" if tight else None)
    return fig


def _log_x(ax) -> None:
    """Log frequency axis with few minor ticks (2 and 5 per decade; every tick costs drawing time)."""
    from matplotlib.ticker import LogLocator, NullFormatter

    ax.set_xscale("log")
    ax.xaxis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))
    ax.xaxis.set_minor_formatter(NullFormatter())


def _db(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return 20 * np.log10(np.abs(x))


def _wrapped_deg(g: np.ndarray) -> np.ndarray:
    """Phase in (-180, 180] deg with NaN inserted at the wraps so lines do not jump across the plot."""
    ph = np.angle(g, deg=True)
    jumps = np.abs(np.diff(ph)) > 180
    out = ph.astype(float).copy()
    out[1:][jumps] = np.nan
    return out


def bode_matrix(freq_hz: np.ndarray, G: np.ndarray, std: np.ndarray | None,
                curves: Mapping[str, tuple[np.ndarray, np.ndarray]], quantity: str = "magnitude",
                path: str | Path | None = None, input_names: Sequence[str] = (),
                output_names: Sequence[str] = (), row_units: Sequence[str] = (),
                col_units: Sequence[str] = ()) -> Figure:
    """Ny x Nu grid of the measured FRF (with a +-2 sigma band) and model curves.

    Parameters
    ----------
    freq_hz
        (L,) measured lines [Hz].
    G
        (L, Ny, Nu) measured FRF [m/A].
    std
        (L, Ny, Nu) standard deviation of G [m/A], or None.
    curves
        label -> (freq (K,) [Hz], FRF (K, Ny, Nu) [m/A]) of models.
    quantity
        'magnitude' (dB re 1 m/A) or 'phase' (deg).
    path
        PNG to write.
    input_names, output_names
        channel labels.
    row_units
        (Ny,) each row's unit (e.g. 'm/s^2/A' for an accelerometer, '' dimensionless); default m/A.
    col_units
        (Nu,) each input's unit (N for a hammer, '' dimensionless); default A.
    """
    if quantity not in ("magnitude", "phase"):
        raise ValueError(f"quantity must be 'magnitude' or 'phase', got {quantity!r}")
    f = np.asarray(freq_hz, dtype=float)
    g = np.asarray(G)
    if g.ndim != 3 or g.shape[0] != f.size:
        raise ValueError(f"G must be (L, Ny, Nu) with L = {f.size}, got {g.shape}")
    ny, nu = g.shape[1:]
    outs = list(output_names) or [f"y{i}" for i in range(ny)]
    ins = list(input_names) or [f"u{j}" for j in range(nu)]
    from matplotlib.ticker import MaxNLocator

    fig = _figure((3.6 * nu + 1, 2.7 * ny + 1.2))
    axes = fig.subplots(ny, nu, sharex=True, squeeze=False)
    fig.subplots_adjust(left=0.07, right=0.99, bottom=0.1, top=0.92, wspace=0.28, hspace=0.18)
    handles = {}
    for i in range(ny):
        for j in range(nu):
            ax = axes[i, j]
            gij = g[:, i, j]
            if quantity == "magnitude":
                if std is not None and np.all(np.isfinite(std[:, i, j])):
                    s2 = 2 * std[:, i, j]
                    lo = np.maximum(np.abs(gij) - s2, np.abs(gij) * 1e-3)
                    handles["measured +-2 sigma"] = ax.fill_between(f, _db(lo), _db(np.abs(gij) + s2),
                                                                    color="0.8", lw=0)
                handles["measured"] = ax.plot(f, _db(gij), "o", ms=2.5, color="k")[0]
            else:
                handles["measured"] = ax.plot(f, np.angle(gij, deg=True), "o", ms=2.5, color="k")[0]
            for label, (fc, gc) in curves.items():
                gc = np.asarray(gc)
                c = gc[:, i, j]
                if np.max(np.abs(c)) <= 1e-9 * np.max(np.abs(gc)):
                    continue  # structurally zero (x -> y at standstill): rounding noise only
                y = _db(c) if quantity == "magnitude" else _wrapped_deg(c)
                handles[label] = ax.plot(fc, y, **_CURVE_STYLE.get(label, {}), label=label)[0]
            _log_x(ax)
            ax.grid(True, which="both", alpha=0.3)
            if quantity == "phase":
                ax.set_ylim(-190, 190)
                ax.set_yticks([-180, -90, 0, 90, 180])
            else:
                ax.yaxis.set_major_locator(MaxNLocator(5))
            if i == 0:
                cu = list(col_units)[j] if j < len(col_units) else "A"
                ax.set_title(f"from {ins[j]} [{cu or '-'}]", fontsize=10)
            if j == 0:
                unit = list(row_units)[i] if i < len(row_units) else "m/A"
                db = f"[dB re 1 {unit}]" if unit else "[dB]"
                ax.set_ylabel(f"{outs[i]}\n" + (f"|G| {db}" if quantity == "magnitude" else "phase [deg]"))
            if i == ny - 1:
                ax.set_xlabel("frequency [Hz]")
    title = "magnitude" if quantity == "magnitude" else "phase"
    fig.suptitle(f"FRF matrix u -> y, {title}: measured and models")
    fig.legend(list(handles.values()), list(handles.keys()), loc="lower center", ncol=len(handles), fontsize=9)
    return _save(fig, path)


def noise_distortion(levels: LineLevels, output_names: Sequence[str] = (), path: str | Path | None = None,
                     odd_db: np.ndarray | None = None, even_db: np.ndarray | None = None) -> Figure:
    """Output amplitude at excited, odd- and even-detection lines against the noise floor, per output.

    Parameters
    ----------
    levels
        :class:`ambid.frf.levels.LineLevels`.
    output_names
        (Ny,) labels.
    path
        PNG to write.
    odd_db, even_db
        (Ny,) distortion levels above the noise [dB] for the titles.
    """
    from matplotlib.ticker import NullLocator

    ny = levels.excited_amp.shape[1]
    outs = list(output_names) or [f"y{i}" for i in range(ny)]
    cols = 2 if ny > 1 else 1
    rows = -(-ny // cols)
    fig = _figure((6.2 * cols, 3.6 * rows + 0.8))
    axes = np.atleast_1d(fig.subplots(rows, cols, sharex=True, squeeze=False)).ravel()
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.08, top=0.9, wspace=0.2, hspace=0.25)
    noise_f = np.concatenate([levels.excited_hz, levels.odd_hz, levels.even_hz])
    order = np.argsort(noise_f)
    for i in range(ny):
        ax = axes[i]
        um = 1e6
        ax.semilogy(levels.excited_hz, levels.excited_amp[:, i] * um, "o", ms=3, color="tab:blue",
                    label="excited lines (signal)")
        if levels.odd_hz.size:
            ax.semilogy(levels.odd_hz, levels.odd_amp[:, i] * um, "v", ms=4, color="tab:red",
                        label="odd detection lines (odd nonlinearity)")
        if levels.even_hz.size:
            ax.semilogy(levels.even_hz, levels.even_amp[:, i] * um, "^", ms=4, color="tab:green",
                        label="even detection lines (even nonlinearity)")
        noise = np.concatenate([levels.excited_noise[:, i], levels.odd_noise[:, i], levels.even_noise[:, i]])
        ax.semilogy(noise_f[order], noise[order] * um, "-", lw=0.9, color="0.5", label="noise floor (std of mean)")
        extra = []
        if odd_db is not None and np.isfinite(odd_db[i]):
            extra.append(f"odd {odd_db[i]:+.1f} dB")
        if even_db is not None and np.isfinite(even_db[i]):
            extra.append(f"even {even_db[i]:+.1f} dB")
        ax.set_title(f"{outs[i]}" + (f" (detection lines vs noise: {', '.join(extra)})" if extra else ""),
                     fontsize=10)
        ax.set_ylabel("line amplitude [um]")
        ax.yaxis.set_minor_locator(NullLocator())
        ax.grid(True, alpha=0.3)
    for ax in axes[ny:]:
        ax.set_visible(False)
    for ax in axes[max(ny - cols, 0):ny]:
        ax.set_xlabel("frequency [Hz]")
    axes[0].legend(fontsize=8)
    fig.suptitle("Output spectra: signal, nonlinear distortion and noise (period means)")
    return _save(fig, path)


def stabilisation(diagram: StabilisationDiagram, freq_hz: np.ndarray, G: np.ndarray, order: int,
                  path: str | Path | None = None, mode_ci95: Sequence[Sequence[float]] = ()) -> Figure:
    """Stabilisation diagram over the CMIF of the measured FRF, the chosen order marked.

    Parameters
    ----------
    diagram
        from :func:`ambid.fit.stabilisation_diagram`.
    freq_hz
        (L,) lines [Hz]; G: (L, Ny, Nu) measured FRF [m/A].
    order
        the chosen model order.
    path
        PNG to write.
    mode_ci95
        [(low, high)] 95 % frequency intervals of the chosen order's modes [Hz], drawn as bars.
    """
    from ambid.fit.order_selection import plot_stabilisation

    chi = dict(zip(diagram.orders.tolist(), diagram.chi2_per_dof.tolist()))
    fig = plot_stabilisation(diagram, G=G, freq_hz=freq_hz,
                             title=f"Stabilisation diagram over the CMIF; chosen order {order} "
                                   f"(chi2/dof {chi.get(order, float('nan')):.3g})")
    ax = fig.axes[0]
    ax.axhline(order, color="tab:purple", lw=1.0, ls="--", label=f"chosen order {order}")
    for k, (lo, hi) in enumerate(mode_ci95):
        # widened to stay visible: a 95 % interval of a lightly damped mode is often < 0.1 Hz
        mid, half = (lo + hi) / 2, max((hi - lo) / 2, 0.002 * (lo + hi) / 2)
        ax.errorbar([mid], [order], xerr=[[half], [half]], fmt="none", ecolor="tab:red", elinewidth=2, capsize=4,
                    label="95 % frequency interval (at least +-0.2 %)" if k == 0 else None)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=3, fontsize="small")
    return _save(fig, path, tight=True)


def excitation(design: ExcitationDesign, path: str | Path | None = None) -> Figure:
    """Amplitude spectrum of one period per input (excited and detection lines) and that period in time.

    The legend gives each input's crest factor, peak and RMS from the design.

    Parameters
    ----------
    design
        the experiment's design.
    path
        PNG to write.
    """
    from matplotlib.ticker import NullLocator

    d = design
    fig = _figure((9.5, 7.0))
    ax_f, ax_t = fig.subplots(2, 1)
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.08, top=0.95, hspace=0.3)
    n, fs = d.n_per_period, d.fs_hz
    t = np.arange(n) / fs
    floor = 1e-4 * float(np.max(d.amplitudes_a)) if d.amplitudes_a.size else 1e-9
    for i, name in enumerate(d.input_names):
        e = i if d.options.get("mimo") == "one_at_a_time" else 0
        start = d.segment_start(0, e) + (d.n_transient_periods * n if d.kind != "stepped_sine" else 0)
        x = d.samples(start, n)[:, i]
        cf = f"crest factor {d.crest_factor[i]:.2f}, peak {d.peak_a[i]:.3g} A, RMS {d.rms_a[i]:.3g} A"
        if d.kind == "stepped_sine":
            line = ax_f.plot(d.freq_hz, np.maximum(d.amplitudes_a[i], floor), "o-", ms=3, label=f"{name}: {cf}")[0]
        else:
            spec = np.abs(np.fft.rfft(x)) * (2 / n)
            line = ax_f.plot(d.freq_hz, np.maximum(spec[d.excited_lines], floor), "o", ms=3,
                             label=f"{name}: {cf}")[0]
        ax_t.plot(t * 1e3, x, lw=0.7, color=line.get_color(), label=name)
    if d.detection_lines_odd.size:
        ax_f.plot(d.detection_lines_odd * fs / n, np.full(d.detection_lines_odd.size, floor), "v", color="tab:red",
                  ms=4, label="odd detection lines (not excited)")
    if d.detection_lines_even.size:
        ax_f.plot(d.detection_lines_even * fs / n, np.full(d.detection_lines_even.size, floor), "^",
                  color="tab:green", ms=3, label="even detection lines (not excited)")
    ax_f.set_yscale("log")
    ax_f.yaxis.set_minor_locator(NullLocator())
    if d.options.get("spacing") == "log":
        _log_x(ax_f)
    ax_f.set_xlabel("frequency [Hz]")
    ax_f.set_ylabel("line amplitude [A]")
    ax_f.set_title(f"Excitation: {d.kind} ({d.options.get('mimo', '')}, {d.options.get('grid', '')}), "
                   f"{d.excited_lines.size} lines, resolution {fs / n:.4g} Hz")
    ax_f.grid(True, alpha=0.3)
    ax_f.legend(fontsize=7)
    ax_t.set_xlabel("time [ms]")
    ax_t.set_ylabel("excitation current r [A]")
    ax_t.set_title(f"one period (N = {n}) of realisation 0; measurement time {d.measurement_time_s:.3g} s")
    ax_t.grid(True, alpha=0.3)
    ax_t.legend(fontsize=7, ncol=4)
    return _save(fig, path)


def input_sensitivity(freq_hz: np.ndarray, S: np.ndarray, input_names: Sequence[str] = (),
                      path: str | Path | None = None) -> Figure:
    """|S_ii| per axis (absolute gain) with the ISO 14839-3 zones A-D shaded (limits 3, 4, 5).

    Parameters
    ----------
    freq_hz
        (L,) lines [Hz].
    S
        (L, Nu, Nu) input sensitivity r -> u [A/A].
    input_names
        (Nu,) labels.
    path
        PNG to write.
    """
    f = np.asarray(freq_hz, dtype=float)
    s = np.abs(np.diagonal(np.asarray(S), axis1=1, axis2=2))
    names = list(input_names) or [f"u{j}" for j in range(s.shape[1])]
    fig = _figure((9.0, 5.2))
    ax = fig.subplots()
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.11, top=0.92)
    top = max(6.0, float(np.nanmax(s)) * 1.15)
    for zone, lo, hi, color in _ZONES:
        ax.axhspan(lo, min(hi, top), color=color, alpha=0.13, lw=0)
        ax.text(f.min(), (lo + min(hi, top)) / 2, f" zone {zone}", va="center", fontsize=9, color="0.3")
    for j, name in enumerate(names):
        k = int(np.argmax(s[:, j]))
        ax.plot(f, s[:, j], "o-", ms=2.5, lw=1.0, label=f"|S| {name}: peak {s[k, j]:.2f} at {f[k]:.4g} Hz")
    _log_x(ax)
    ax.set_ylim(0, top)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("input sensitivity |S_ii| (r -> u) [A/A]")
    worst = float(np.max(s))
    from ambid.frf.sensitivity import iso14839_zone

    ax.set_title(f"Input sensitivity per axis; worst peak {worst:.2f} ({20 * np.log10(worst):.1f} dB): "
                 f"ISO 14839-3 zone {iso14839_zone(worst)}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    return _save(fig, path)


def time_records(t_s: np.ndarray, y: np.ndarray, u: np.ndarray, r: np.ndarray, output_names: Sequence[str] = (),
                 input_names: Sequence[str] = (), path: str | Path | None = None) -> Figure:
    """A short window of the measured displacements, applied currents and excitation.

    Parameters
    ----------
    t_s
        (n,) sample times [s].
    y
        (n, Ny) displacements [m]; u, r: (n, Nu) applied current and
        excitation [A].
    output_names, input_names
        labels.
    path
        PNG to write.
    """
    fig = _figure((9.5, 6.5))
    ax_y, ax_u = fig.subplots(2, 1, sharex=True)
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.09, top=0.94, hspace=0.12)
    t_ms = (np.asarray(t_s) - t_s[0]) * 1e3
    outs = list(output_names) or [f"y{i}" for i in range(y.shape[1])]
    ins = list(input_names) or [f"u{j}" for j in range(u.shape[1])]
    for i, name in enumerate(outs):
        ax_y.plot(t_ms, y[:, i] * 1e6, lw=0.8, label=name)
    for j, name in enumerate(ins):
        line = ax_u.plot(t_ms, u[:, j], lw=0.8, label=f"{name} (applied)")[0]
        ax_u.plot(t_ms, r[:, j], lw=0.6, ls="--", color=line.get_color(), label=f"r of {name} (excitation)")
    ax_y.set_ylabel("displacement y [um]")
    ax_y.set_title(f"Time records from t = {t_s[0]:.4g} s (steady state, {t_ms[-1]:.3g} ms shown)")
    ax_u.set_ylabel("current [A]")
    ax_u.set_xlabel("time since window start [ms]")
    for ax in (ax_y, ax_u):
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, ncol=4)
    return _save(fig, path)


def frf_error(freq_hz: np.ndarray, errors: Mapping[str, np.ndarray], noise_level: np.ndarray | None = None,
              path: str | Path | None = None) -> Figure:
    """Relative FRF-matrix error per line against the true rig, for the measurement and the models.

    Parameters
    ----------
    freq_hz
        (L,) lines [Hz].
    errors
        label -> (L,) ||G - G_true||_F / ||G_true||_F [-].
    noise_level
        (L,) the measurement's 2 sigma relative noise level, or None.
    path
        PNG to write.
    """
    from matplotlib.ticker import NullLocator

    fig = _figure((9.0, 4.8))
    ax = fig.subplots()
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.12, top=0.92)
    for label, e in errors.items():
        ax.loglog(freq_hz, e, "o-" if label == "measured" else "-", ms=2.5, lw=1.0,
                  label=f"{label}: median {np.median(e):.2%}, worst {np.max(e):.2%}")
    if noise_level is not None and np.all(np.isfinite(noise_level)):
        ax.loglog(freq_hz, noise_level, color="0.5", lw=0.9, ls=":", label="measurement noise, 2 sigma")
    _log_x(ax)
    ax.yaxis.set_minor_locator(NullLocator())
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("||G - G_true||_F / ||G_true||_F [-]")
    ax.set_title("FRF error against the true rig (simulated, sampled small-signal model)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)
