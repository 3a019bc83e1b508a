"""A small simulated 2x2 AMB-like closed loop for the FRF tests (shared test helper).

Plant (continuous, ZOH-discretised at 10 kHz): two decoupled rigid axes with
negative magnetic stiffness (unstable real poles at +-32 Hz) plus a lightly
damped bending mode at 350 Hz coupling both axes. Controller: decentralised
PD with a 2 kHz roll-off (Tustin), acting one sample late through the ZOH.
Sign convention as in ambid.frf: u = r - C y, y = P u + v (v: white
measurement noise, fed back through C).
"""

import numpy as np
from scipy import signal

FS = 10_000.0   # sample rate [Hz]


def loop_model(kd: float = 30.0) -> dict:
    """Discrete plant (ap, bp, cp) and controller (ac, bc, cc, dc) matrices."""
    m, ks, ki = 5.0, 2e5, 50.0                       # kg, N/m, N/A
    wf, zf, mf, phi = 2 * np.pi * 350, 0.01, 3.0, np.array([1.0, -0.8])
    a = np.zeros((6, 6))
    a[:3, 3:] = np.eye(3)
    a[3, 0] = a[4, 1] = ks / m
    a[5, 2], a[5, 5] = -wf**2, -2 * zf * wf
    b = np.zeros((6, 2))
    b[3, 0] = b[4, 1] = ki / m
    b[5] = phi * ki / mf
    c = np.zeros((2, 6))
    c[0, 0] = c[1, 1] = 1.0
    c[:, 2] = phi
    ap, bp, cp, _, _ = signal.cont2discrete((a, b, c, np.zeros((2, 2))), 1 / FS, method="zoh")
    kp, wl = 2.9e4, 2 * np.pi * 2000                 # A/m, rad/s
    # C(s) = kp + kd s / (1 + s/wl) per axis, one state each
    c1 = signal.cont2discrete(tuple(np.array([[v]]) for v in (-wl, 1.0, -kd * wl**2, kp + kd * wl)),
                              1 / FS, method="bilinear")[:4]
    ac, bc, cc, dc = (np.kron(np.eye(2), x) for x in c1)
    return dict(ap=ap, bp=bp, cp=cp, ac=ac, bc=bc, cc=cc, dc=dc)


def frf_of(a, b, c, d, freq_hz):
    """Discrete state-space FRF at freq_hz (L,): (L, p, m)."""
    z = np.exp(2j * np.pi * np.asarray(freq_hz) / FS)
    zi_a = z[:, None, None] * np.eye(a.shape[0]) - a
    return c @ np.linalg.solve(zi_a, np.broadcast_to(b, (z.size,) + b.shape)) + d


def plant_frf(loop, freq_hz):
    """P (L, 2, 2) [m/A]."""
    return frf_of(loop["ap"], loop["bp"], loop["cp"], 0.0, freq_hz)


def controller_frf(loop, freq_hz):
    """C (L, 2, 2) [A/m] in the u = r - C y convention."""
    return frf_of(loop["ac"], loop["bc"], loop["cc"], loop["dc"], freq_hz)


def simulate(loop, r, noise_std, seed, cubic=0.0):
    """r (n_seg, n, 2) -> y, u (n_seg, n, 2); each segment from rest.

    The applied current is u + cubic u^3 (static amplifier nonlinearity); u
    (the commanded current) is what is measured."""
    ap, bp, cp, ac, bc, cc, dc = (loop[k] for k in ("ap", "bp", "cp", "ac", "bc", "cc", "dc"))
    nx_p, nx_c = ap.shape[0], ac.shape[0]
    v = noise_std * np.random.default_rng(seed).standard_normal(r.shape)
    k_u = np.hstack([-dc @ cp, -cc])                 # u = k_u x + (r - dc v)
    a0 = np.block([[ap, np.zeros((nx_p, nx_c))], [bc @ cp, ac]])
    b_u = np.vstack([bp, np.zeros((nx_c, 2))])
    u_ext = r - v @ dc.T
    w_v = v @ np.vstack([np.zeros((nx_p, 2)), bc]).T
    a_cl_t, a0_t, k_u_t, b_u_t = (a0 + b_u @ k_u).T, a0.T, k_u.T, b_u.T
    w_lin = np.swapaxes(u_ext @ b_u_t + w_v, 0, 1)
    w_v, u_t = np.swapaxes(w_v, 0, 1), np.swapaxes(u_ext, 0, 1)
    xs = np.empty((r.shape[1], r.shape[0], nx_p + nx_c))
    x = np.zeros(xs.shape[1:])
    for k in range(r.shape[1]):
        xs[k] = x
        if cubic == 0.0:
            x = x @ a_cl_t + w_lin[k]
        else:
            u = x @ k_u_t + u_t[k]
            x = x @ a0_t + (u + cubic * u**3) @ b_u_t + w_v[k]
    xs = np.swapaxes(xs, 0, 1)
    return xs[..., :nx_p] @ cp.T + v, xs @ k_u.T + u_ext
