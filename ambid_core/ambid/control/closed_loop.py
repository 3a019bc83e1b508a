"""The feedback loop of plant and controller: closing it, checking it, judging its robustness.

Sign convention: u = ic + r with ic = K y (K carries the minus sign), so the
loop from the excitation r to the plant input u is S_i = (I - K P)^-1, the
input sensitivity. ISO 14839-3 judges each axis by the peak of its diagonal
element S_jj (the other loops closed): zone A < 3, B < 4, C < 5, else D.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from ambid.frf.sensitivity import iso14839_zone
from ambid.plant.analytical import analytical_model
from ambid.plant.true_rig import true_linear_model
from ambid.statespace import StateSpace

# ISO 14839-3 upper limits of the peak sensitivity for zones A, B, C (absolute gain)


def close_loop(plant_d: StateSpace, controller: StateSpace) -> StateSpace:
    """Closed loop r -> [y; u] of a discrete plant (u -> y, D = 0) and controller (y -> ic).

    Returns a discrete StateSpace with inputs r (m) and outputs y (p) then u (m).
    """
    if plant_d.dt <= 0 or abs(plant_d.dt - controller.dt) > 1e-15:
        raise ValueError(f"close_loop: plant and controller must be discrete with one sample period "
                         f"(plant dt={plant_d.dt}, controller dt={controller.dt})")
    if np.any(plant_d.d):
        raise ValueError("close_loop: the discrete plant must be strictly proper (D = 0)")
    ap, bp, cp = plant_d.a, plant_d.b, plant_d.c
    ak, bk, ck, dk = controller.a, controller.b, controller.c, controller.d
    # u = ck xk + dk cp xp + r
    a = np.block([[ap + bp @ dk @ cp, bp @ ck], [bk @ cp, ak]])
    b = np.vstack([bp, np.zeros((ak.shape[0], bp.shape[1]))])
    c = np.vstack([np.hstack([cp, np.zeros((cp.shape[0], ak.shape[0]))]), np.hstack([dk @ cp, ck])])
    d = np.vstack([np.zeros((cp.shape[0], bp.shape[1])), np.eye(bp.shape[1])])
    return StateSpace(a, b, c, d, plant_d.dt, plant_d.input_names,
                      plant_d.output_names + plant_d.input_names)


def _discrete(plant: StateSpace, dt: float) -> StateSpace:
    return plant if plant.dt > 0 else plant.to_discrete(dt)


def check_stability(plant: StateSpace, controller: StateSpace, label: str) -> np.ndarray:
    """Closed-loop poles (z-plane) of ``plant`` (continuous or discrete) with ``controller``.

    Raises
    ------
    ValueError
        naming the unstable poles (as s-plane frequency and damping)
    when
        the loop is unstable.
    """
    loop = close_loop(_discrete(plant, controller.dt), controller)
    poles = loop.poles()
    bad = poles[np.abs(poles) >= 1.0]
    if bad.size:
        bad = bad[np.argsort(-np.abs(bad))]
        # an axisymmetric rotor repeats each pole in x and y, and a conjugate pair is one mode: name each once
        # (with its count) so the message stays one readable line
        seen: dict[str, int] = {}
        for z in bad:
            v = np.log(complex(z)) / controller.dt
            key = (f"z={z.real:.4f}{abs(z.imag):+.4f}j (s={v.real:+.1f}{abs(v.imag):+.1f}j rad/s, "
                   f"{abs(v.imag) / (2 * np.pi):.1f} Hz)")
            seen[key] = seen.get(key, 0) + 1
        desc = ", ".join(k if n == 1 else f"{k} x{n}" for k, n in seen.items())
        raise ValueError(f"{label}: the closed loop is unstable; unstable poles: {desc}. "
                         "Retune the controller or check the rig parameters.")
    return poles


def check_controller_on_rig(rig, controller: StateSpace) -> dict[str, np.ndarray]:
    """Check a controller before a run: stable on the analytical and on the true linearised model.

    Parameters
    ----------
    rig
        :class:`ambid.plant.rig.Rig`.
    controller
        discrete y -> ic model at rig.dt.

    Returns
    -------
    {"analytical": poles, "true": poles}, closed-loop z-plane poles.

    Raises
    ------
    ValueError
        naming the model ("analytical model" or "true rig") and
    its
        unstable poles.
    """

    if abs(controller.dt - rig.dt) > 1e-15:
        raise ValueError(f"controller sample period {controller.dt} s differs from the rig's {rig.dt} s")
    return {"analytical": check_stability(analytical_model(rig), controller, "analytical model"),
            "true": check_stability(true_linear_model(rig, discrete=True), controller, "true rig")}


def _residue_frf(system: StateSpace, freq_hz: np.ndarray, out_idx: np.ndarray, in_idx: np.ndarray
                 ) -> np.ndarray:
    """Elements (out_idx[j], in_idx[j]) of a discrete model's FRF, shape (L, len(out_idx)).

    Pole-residue sum over the eigen-decomposition (cheap on dense grids);
    falls back to ``StateSpace.freqresp`` when A is close to defective.
    """
    z = np.exp(2j * np.pi * np.asarray(freq_hz, dtype=float) * system.dt)
    # diagonal scaling first: states of very different size make the eigenvectors ill-conditioned
    a_bal, scale = linalg.matrix_balance(system.a, permute=False)
    scale = np.diag(scale)
    lam, vec = np.linalg.eig(a_bal)
    if np.linalg.cond(vec) < 1e8:
        left = (system.c[out_idx] * scale) @ vec  # (k, n)
        right = np.linalg.solve(vec, system.b[:, in_idx] / scale[:, None])  # (n, k)
        res = left * right.T  # residues per element and pole
        return (1.0 / (z[:, None] - lam[None, :])) @ res.T + system.d[out_idx, in_idx]
    full = system.freqresp(freq_hz)
    return full[:, out_idx, in_idx]


def residue_freqresp(system: StateSpace, freq_hz: np.ndarray) -> np.ndarray:
    """A model's whole frequency response, (L, p, m), by its poles and residues: for many lines of a model
    of tens of states far cheaper than :meth:`ambid.statespace.StateSpace.freqresp` (the same numbers to
    rounding; it falls back to that where A is close to defective)."""
    if system.n_states == 0:
        return np.broadcast_to(system.d, (np.size(freq_hz),) + system.d.shape).astype(complex)
    p, m = system.n_outputs, system.n_inputs
    rows, cols = np.meshgrid(np.arange(p), np.arange(m), indexing="ij")
    return _residue_frf(system, freq_hz, rows.ravel(), cols.ravel()).reshape(-1, p, m)


def input_sensitivity(plant: StateSpace, controller: StateSpace, freq_hz: np.ndarray) -> np.ndarray:
    """Input sensitivity S_i = (I - K P)^-1 (r -> u) at ``freq_hz`` (L,), shape (L, m, m) [A/A]."""
    loop = close_loop(_discrete(plant, controller.dt), controller)
    p, m = plant.n_outputs, plant.n_inputs
    rows, cols = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    flat = _residue_frf(loop, freq_hz, p + rows.ravel(), cols.ravel())
    return flat.reshape(-1, m, m)


@dataclass(frozen=True)
class LoopRobustness:
    """Robustness figures of a closed loop, per axis (plant input channel).

    Attributes
    ----------
    sensitivity_peak
        max |S_jj| over frequency, (m,) [-].
    peak_freq_hz
        where it occurs, (m,) [Hz].
    zone
        ISO 14839-3 zone of the worst axis ("A".."D").
    gain_margin_low
        largest gain factor < 1 at which axis j's loop
        (others closed) loses stability, (m,) (0 if none).
    gain_margin_high
        smallest such factor > 1, (m,) (inf if none).
    phase_margin_deg
        smallest phase margin over the gain crossovers, (m,) [deg].
    max_singular_peak
        peak of the largest singular value of S_i [-].
    """

    sensitivity_peak: np.ndarray
    peak_freq_hz: np.ndarray
    zone: str
    gain_margin_low: np.ndarray
    gain_margin_high: np.ndarray
    phase_margin_deg: np.ndarray
    max_singular_peak: float


def closed_loop_patches(loop: StateSpace, f_lo_hz: float = 1.0, n_points: int = 81) -> np.ndarray:
    """Frequencies [Hz] about every lightly damped pole of a discrete closed ``loop`` (+-4 half-power widths,
    at least +-0.1 %): where its sensitivity peaks, narrower than any affordable log grid (a 0.5 %-damped
    mode)."""
    nyq = 0.5 / loop.dt
    s = np.log(loop.poles().astype(complex)) / loop.dt
    grid = [np.zeros(0)]
    for v in s:
        f0 = abs(v.imag) / (2 * np.pi)
        if f0 > f_lo_hz and f0 < nyq and -v.real < 0.3 * abs(v):
            half = max(4 * -v.real / (2 * np.pi), 1e-3 * f0)
            grid.append(np.linspace(max(f0 - half, f_lo_hz), min(f0 + half, 0.999 * nyq), n_points))
    return np.unique(np.concatenate(grid))


def robustness_grid(loop: StateSpace, f_lo_hz: float = 1.0, n_grid: int = 4000) -> np.ndarray:
    """Frequency grid [Hz] for peak searches: log-spaced to Nyquist plus dense patches around every
    lightly damped closed-loop pole (:func:`closed_loop_patches`)."""
    nyq = 0.5 / loop.dt
    log = np.logspace(np.log10(f_lo_hz), np.log10(0.999 * nyq), n_grid)
    return np.unique(np.concatenate([log, closed_loop_patches(loop, f_lo_hz)]))


def loop_robustness(plant: StateSpace, controller: StateSpace, f_lo_hz: float = 1.0) -> LoopRobustness:
    """Sensitivity peaks, ISO zone and loop-at-a-time margins of a stable closed loop.

    Parameters
    ----------
    plant
        u -> y model (continuous: discretised with a zero-order hold).
    controller
        discrete y -> ic model.
    f_lo_hz
        lowest frequency considered [Hz].
    """
    loop = close_loop(_discrete(plant, controller.dt), controller)
    if not loop.is_stable():
        raise ValueError("the closed loop of this plant and controller is unstable: it has no sensitivity peak; "
                         "check the plant model or retune the controller")
    f = robustness_grid(loop, f_lo_hz)
    s = input_sensitivity(plant, controller, f)
    diag = np.diagonal(s, axis1=1, axis2=2)
    mag = np.abs(diag)
    idx = mag.argmax(axis=0)
    peak = mag[idx, np.arange(mag.shape[1])]
    # loop j with the others closed, negative-feedback convention: S_jj = 1 / (1 + L_j)
    lj = 1.0 / diag - 1.0
    m = diag.shape[1]
    gm_low, gm_high, pm = np.zeros(m), np.full(m, np.inf), np.full(m, np.inf)
    for j in range(m):
        x = lj[:, j]
        ang = np.angle(x)
        # phase crossings of -180 deg: imaginary part changes sign with negative real part
        cross = np.nonzero((np.sign(x.imag[:-1]) != np.sign(x.imag[1:])) & (x.real[:-1] < 0))[0]
        for k in cross:
            t = x.imag[k] / (x.imag[k] - x.imag[k + 1])
            g = 1.0 / abs(x.real[k] + t * (x.real[k + 1] - x.real[k]))
            if g > 1:
                gm_high[j] = min(gm_high[j], g)
            else:
                gm_low[j] = max(gm_low[j], g)
        gain_cross = np.nonzero(np.sign(np.abs(x[:-1]) - 1) != np.sign(np.abs(x[1:]) - 1))[0]
        for k in gain_cross:
            pm[j] = min(pm[j], 180.0 - abs(np.degrees(ang[k])))
    sv = np.linalg.svd(s, compute_uv=False)[:, 0].max()
    return LoopRobustness(peak, f[idx], iso14839_zone(float(peak.max())), gm_low, gm_high, pm, float(sv))
