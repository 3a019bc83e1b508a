"""A closed loop written for the tests (scipy only, nothing of ambid's plant): an AMB-like rotor per plane.

Each plane (x, y) of a rigid rotor with one bending mode hangs in two magnetic
bearings A and B: the magnets' negative stiffness makes it unstable; a
decentralised PD controller with a derivative filter holds it. Sensors sit at
the bearings and add white noise. The x and y planes differ (other masses and
bending modes), so every mode in the band is distinct.

:func:`plant` is the continuous plant u [A] -> y [m] (4 x 4, axes
``a_x b_x a_y b_y``); :func:`true_modes` its lightly damped modes;
:func:`simulate` runs the sampled closed loop (zero-order hold) driven by an
excitation r added to the control currents and by the sensor noise.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

AXES = ("a_x", "b_x", "a_y", "b_y")
FS = 2000.0                     # sample rate [Hz]
NOISE_M = 0.03e-6               # sensor noise, RMS [m]
KI, KS = 40.0, 4.0e5            # magnet force/current [N/A], negative stiffness [N/m]
PLANES = {                      # mass [kg], inertia [kg m^2], bending mode [Hz], its damping [-], modal mass [kg]
    "x": dict(m=8.0, j=0.25, fb=180.0, zb=0.02, mb=2.0, fb2=520.0, zb2=0.01, mb2=1.5),
    "y": dict(m=8.0, j=0.22, fb=240.0, zb=0.015, mb=2.2, fb2=610.0, zb2=0.012, mb2=1.8),
}
LA, LB = -0.2, 0.25             # bearing positions from the centre of mass [m]
SHAPE_A, SHAPE_B = (0.8, 0.6), (-0.9, 0.5)   # the two bending modes' shapes at A and B


def _plane(p: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous (A, B, C) of one plane: states [q_t, q_r, q_b1, q_b2] and their rates; u (2,) [A], y (2,) [m]."""
    # output map q -> y at A, B: translation, tilt, two bending modes
    cq = np.array([[1.0, LA, SHAPE_A[0], SHAPE_A[1]], [1.0, LB, SHAPE_B[0], SHAPE_B[1]]])
    mass = np.diag([p["m"], p["j"], p["mb"], p["mb2"]])
    wb, wb2 = 2 * np.pi * p["fb"], 2 * np.pi * p["fb2"]
    stiff = np.diag([0.0, 0.0, p["mb"] * wb ** 2, p["mb2"] * wb2 ** 2]) - KS * cq.T @ cq   # magnets: -ks y
    damp = np.diag([0.0, 0.0, 2 * p["zb"] * p["mb"] * wb, 2 * p["zb2"] * p["mb2"] * wb2])
    minv = np.linalg.inv(mass)
    a = np.block([[np.zeros((4, 4)), np.eye(4)], [-minv @ stiff, -minv @ damp]])
    b = np.vstack([np.zeros((4, 2)), minv @ cq.T * KI])
    c = np.hstack([cq, np.zeros((2, 4))])
    return a, b, c


def plant() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Continuous (A, B, C, D) of the whole plant, inputs u_a_x u_b_x u_a_y u_b_y [A], outputs y_* [m]."""
    ax, bx, cx = _plane(PLANES["x"])
    ay, by, cy = _plane(PLANES["y"])
    z = np.zeros
    a = np.block([[ax, z((8, 8))], [z((8, 8)), ay]])
    b = np.block([[bx, z((8, 2))], [z((8, 2)), by]])
    c = np.block([[cx, z((2, 8))], [z((2, 8)), cy]])
    return a, b, c, np.zeros((4, 4))


def true_modes(band_hz: tuple[float, float] = (0.0, np.inf)) -> list[tuple[float, float]]:
    """The plant's lightly damped modes [(frequency [Hz], damping ratio [-])], ascending."""
    p = np.linalg.eigvals(plant()[0])
    p = p[p.imag > 1e-6]
    f, z = np.abs(p) / (2 * np.pi), -p.real / np.abs(p)
    return sorted((float(fi), float(zi)) for fi, zi in zip(f, z) if band_hz[0] <= fi <= band_hz[1])


def frf(freq_hz: np.ndarray, sampled: bool = True) -> np.ndarray:
    """(L, 4, 4) plant FRF u -> y [m/A]; ``sampled``: the zero-order-hold model the loop runs."""
    a, b, c, d = plant()
    if sampled:
        ad, bd, cd, dd, _ = signal.cont2discrete((a, b, c, d), 1 / FS, "zoh")
        z = np.exp(2j * np.pi * np.asarray(freq_hz) / FS)
        return np.array([cd @ np.linalg.solve(zz * np.eye(ad.shape[0]) - ad, bd) + dd for zz in z])
    s = 2j * np.pi * np.asarray(freq_hz)
    return np.array([c @ np.linalg.solve(ss * np.eye(a.shape[0]) - a, b) + d for ss in s])


def _controller() -> tuple[np.ndarray, ...]:
    """Discrete PD per axis with a first-order derivative filter: ic = -(kp y + kd dy/dt)."""
    kp, kd, tf = 2.0 * KS / KI, 20.0, 1 / (2 * np.pi * 2500.0)
    num = [-(kp * tf + kd), -kp]               # -(kp + kd s / (tf s + 1)) = -((kp tf + kd) s + kp) / (tf s + 1)
    den = [tf, 1.0]
    ad, bd, cd, dd, _ = signal.cont2discrete(signal.tf2ss(num, den), 1 / FS, "bilinear")
    eye = np.eye(4)
    return np.kron(eye, ad), np.kron(eye, bd), np.kron(eye, cd), np.kron(eye, dd)


def closed_loop() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Discrete closed loop, inputs [r (4); n (4)] (excitation [A], sensor noise [m]), outputs [y (4); u (4)].

    y = C x + n; the controller sees y and answers ic in the same sample (its D term); u = ic + r is held over
    the next sample.
    """
    a, b, c, d = plant()
    ap, bp, cp, _, _ = signal.cont2discrete((a, b, c, d), 1 / FS, "zoh")
    ac, bc, cc, dc = _controller()
    n_p, n_c = ap.shape[0], ac.shape[0]
    # u = cc xc + dc (cp xp + n) + r
    u_x = np.hstack([dc @ cp, cc])
    u_in = np.hstack([np.eye(4), dc])
    a_cl = np.block([[ap, np.zeros((n_p, n_c))], [bc @ cp, ac]]) + np.vstack([bp, np.zeros((n_c, 4))]) @ u_x
    b_cl = np.vstack([bp @ u_in, np.hstack([np.zeros((n_c, 4)), bc])])
    c_cl = np.vstack([np.hstack([cp, np.zeros((4, n_c))]), u_x])
    d_cl = np.vstack([np.hstack([np.zeros((4, 4)), np.eye(4)]), u_in])
    return a_cl, b_cl, c_cl, d_cl


def band_noise(n: int, band_hz: tuple[float, float], rms_a: float, seed: int) -> np.ndarray:
    """(n, 4) independent band-limited Gaussian noise, never repeating (8th-order Butterworth band-pass) [A]."""
    rng = np.random.default_rng(seed)
    sos = signal.butter(8, band_hz, btype="bandpass", fs=FS, output="sos")
    x = signal.sosfilt(sos, rng.standard_normal((n + 4000, 4)), axis=0)[4000:]
    return x * (rms_a / x.std(axis=0))


def simulate(r: np.ndarray, seed: int, noise_m: float = NOISE_M) -> tuple[np.ndarray, np.ndarray]:
    """Run the closed loop from rest with the excitation r (n, 4) [A]; returns y (n, 4) [m], u (n, 4) [A]."""
    a, b, c, d = closed_loop()
    if np.max(np.abs(np.linalg.eigvals(a))) >= 1:
        raise AssertionError("the test's closed loop is unstable")
    noise = noise_m * np.random.default_rng(seed + 1000).standard_normal(r.shape)
    _, out, _ = signal.dlsim((a, b, c, d, 1 / FS), np.hstack([r, noise]))
    return out[:, :4], out[:, 4:]


def multisine_segments(n_per: int, n_periods: int, lines: np.ndarray, seed: int = 3,
                       rms_a: float = 0.25) -> np.ndarray:
    """(4 P N, 4) excitation of four segments of P periods, one input at a time, each a random-phase multisine at
    ``lines`` (bins of the N-sample period) [A]; the segments follow one another without settling periods."""
    rng = np.random.default_rng(seed)
    segs = []
    for e in range(4):
        spec = np.zeros(n_per // 2 + 1, complex)
        spec[lines] = np.exp(2j * np.pi * rng.random(lines.size))
        per = np.fft.irfft(spec, n_per)
        r = np.zeros((n_periods * n_per, 4))
        r[:, e] = np.tile(per / per.std() * rms_a, n_periods)
        segs.append(r)
    return np.vstack(segs)


def run_states(r: np.ndarray, noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The closed loop from rest driven by r (n, 4) [A] and sensor noise (n, 4) [m]: outputs [y; u] (n, 8) and
    states (n, n_x), the state at each sample before its update."""
    a, b, c, d = closed_loop()
    _, out, states = signal.dlsim((a, b, c, d, 1 / FS), np.hstack([r, noise]))
    return out, states


def segment_transients(r: np.ndarray, states: np.ndarray, n_per: int, n_periods: int,
                       lines: np.ndarray) -> np.ndarray:
    """(S, L, 8) the transient of [y; u] at the bins P l of each segment's unscaled DFT, in closed form.

    A segment starts in state x0 where its periodic steady state starts in x_s = (I - A^N)^-1 x_N (x_N: one
    period's response from rest). Its output minus the steady state is the free response C A^t (x0 - x_s), whose
    DFT over the n = P N samples is ``C (I - zeta A)^-1 (I - A^n) (x0 - x_s)``, zeta = exp(-2j pi k / n).
    """
    a, b, c, d = closed_loop()
    nx = a.shape[0]
    n_seg_samples = n_periods * n_per
    an, a_seg = np.linalg.matrix_power(a, n_per), np.linalg.matrix_power(a, n_seg_samples)
    zeta = np.exp(-2j * np.pi * n_periods * np.asarray(lines) / n_seg_samples)
    out = []
    for s in range(r.shape[0] // n_seg_samples):
        rs = r[s * n_seg_samples:s * n_seg_samples + n_per + 1]
        _, _, xz = signal.dlsim((a, b, c, d, 1 / FS), np.hstack([rs, np.zeros_like(rs)]), x0=np.zeros(nx))
        x_s = np.linalg.solve(np.eye(nx) - an, xz[n_per])
        e = (np.eye(nx) - a_seg) @ (states[s * n_seg_samples] - x_s)
        out.append(np.array([c @ np.linalg.solve(np.eye(nx) - z * a, e) for z in zeta]))
    return np.array(out)


def g_and_variance(spectra: np.ndarray, noise_cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """G = Y U^-1 over the four one-input segments at each line and its first-order noise variance.

    ``var G_ij = sum_e (a_i C_e a_i^H) |(U^-1)_ej|^2`` with ``a_i = [e_i, -G_i]`` (the error of row i is
    ``a_i V U^-1``, the experiments' noises independent).

    Args:
        spectra: (4, L, 8) transient-free line spectra [y; u] of the segments.
        noise_cov: (4, L, 8, 8) their noise covariances.

    Returns:
        G (L, 4, 4) [m/A] and its variance (L, 4, 4) [(m/A)^2].
    """
    y, u = np.moveaxis(spectra[..., :4], 0, -1), np.moveaxis(spectra[..., 4:], 0, -1)   # (L, 4, Ne)
    m = np.linalg.inv(u)
    g = y @ m
    a = np.concatenate([np.broadcast_to(np.eye(4), g.shape), -g], axis=2)
    out_var = np.real(np.einsum("lia,leab,lib->lie", a, np.moveaxis(noise_cov, 0, 1), a.conj()))
    return g, np.einsum("lie,lej->lij", out_var, np.abs(m) ** 2)
