"""A rig that is not ambid's, and its records as a logger and MATLAB write them (shared test helper).

The plant, the controller, the excitation and the file layouts are written
here with scipy/numpy/h5py only, so an import identified against them is
checked against something ambid did not compute:

* plant: four bearing axes, each a rotor mass on a magnet with negative
  stiffness (one unstable real pole pair per axis), plus two lightly damped
  flexible modes that every axis sees (modal shapes, force and sensor
  collocated), force ki * current, ZOH-discretised at FS;
* controller: a PID per axis (derivative filtered) whose output is one
  sample late, as a digital controller's;
* excitation: an orthogonal random-phase multisine (Dobrowiecki et al.
  2006): Nu experiments per realisation, input i of experiment e weighted by
  exp(-j 2 pi i e / Nu), added to the currents;
* sensor noise: white, seeded, on the measured y only.
"""

from __future__ import annotations

import time

import numpy as np
from scipy import signal

FS = 10_000.0
AXES = ("a_x", "b_x", "a_y", "b_y")
MASS, KS, KI = 2.0, 2.0e5, 50.0            # kg, N/m (negative stiffness), N/A
MODES_HZ = (310.0, 720.0)
MODES_ZETA = (0.006, 0.004)
SHAPES = np.array([[1.0, -0.8, 0.6, -0.5], [0.5, 1.0, -0.7, 0.9]])   # (mode, axis)
KP, KD, KINT = 1.6 * KS / KI, 6.0, 2.0e4   # A/m, A s/m, A/(m s)


def plant_continuous() -> tuple[np.ndarray, ...]:
    """(A, B, C, D): currents (4) [A] -> displacements (4) [m]."""
    n = 8 + 2 * len(MODES_HZ)
    a, b, c = np.zeros((n, n)), np.zeros((n, 4)), np.zeros((4, n))
    for i in range(4):
        a[2 * i, 2 * i + 1] = 1.0
        a[2 * i + 1, 2 * i] = KS / MASS
        b[2 * i + 1, i] = KI / MASS
        c[i, 2 * i] = 1.0
    for k, (f, z) in enumerate(zip(MODES_HZ, MODES_ZETA)):
        w, j = 2 * np.pi * f, 8 + 2 * k
        a[j, j + 1] = 1.0
        a[j + 1, j], a[j + 1, j + 1] = -w * w, -2 * z * w
        b[j + 1] = KI * SHAPES[k] / MASS
        c[:, j] = SHAPES[k]
    return a, b, c, np.zeros((4, 4))


def true_modes() -> list[tuple[float, float]]:
    """(frequency [Hz], damping) of the plant's oscillating poles, from its A."""
    p = np.linalg.eigvals(plant_continuous()[0])
    p = p[p.imag > 1e-6]
    return sorted((abs(s) / (2 * np.pi), -s.real / abs(s)) for s in p)


def multisine(n: int, lines: np.ndarray, amp: float, m: int, nu: int, pt: int, p: int, seed: int) -> np.ndarray:
    """Orthogonal random-phase multisine, realisation-major segments of (pt + p) periods of n: (samples, nu)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    w = np.exp(-2j * np.pi * np.outer(np.arange(nu), np.arange(nu)) / nu)   # W[i, e]
    out = []
    for _ in range(m):
        phases = rng.uniform(0, 2 * np.pi, (nu, lines.size))
        for e in range(nu):
            ph = np.exp(1j * phases) * w[:, e][:, None]
            period = (amp * ph[:, :, None] * np.exp(2j * np.pi * lines[None, :, None] * t / n)).real.sum(axis=1).T
            out.append(np.tile(period, (pt + p, 1)))
    return np.concatenate(out)


def closed_loop(r: np.ndarray, noise_m: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Simulate the PID loop with r (n, 4) [A] added to the currents: (y measured (n, 4) [m], u (n, 4) [A])."""
    a, b, c, d = plant_continuous()
    ad, bd, *_ = signal.cont2discrete((a, b, c, d), 1 / FS, method="zoh")
    dt = 1 / FS
    tau = 1 / (2 * np.pi * 2000.0)                     # derivative filter
    alpha = np.exp(-dt / tau)
    rng = np.random.default_rng(seed)
    noise = noise_m * rng.standard_normal(r.shape)
    n = len(r)
    x = np.zeros(ad.shape[0])
    integ, dfilt, y_prev = np.zeros(4), np.zeros(4), np.zeros(4)
    ic = np.zeros(4)
    ys, us = np.empty((n, 4)), np.empty((n, 4))
    for k in range(n):
        y = c @ x + noise[k]
        u = ic + r[k]
        ys[k], us[k] = y, u
        x = ad @ x + bd @ u
        # the current computed from y[k] is applied from sample k+1 on
        integ += dt * y
        dfilt = alpha * dfilt + (1 - alpha) * (y - y_prev) / dt
        y_prev = y
        ic = -(KP * y + KINT * integ + KD * dfilt)
    return ys, us


def write_logger_csv(path, columns: dict[str, np.ndarray], time_ms: np.ndarray) -> None:
    """A European logger's CSV: semicolon separated, decimal comma, time in ms first."""
    names = ["Zeit [ms]"] + list(columns)
    x = np.column_stack([time_ms] + list(columns.values()))
    with open(path, "w", newline="") as f:
        f.write(";".join(names) + "\r\n")
        for row in x:
            f.write(";".join(f"{v:.12g}".replace(".", ",") for v in row) + "\r\n")


def write_matlab73(path, data: np.ndarray, names: list[str], extra: dict[str, np.ndarray] | None = None) -> None:
    """What MATLAB's ``save(path, 'data', 'names', '-v7.3')`` writes for an n x k double ``data`` and a 1 x k
    cell ``names``: HDF5 behind a 512-byte user block headed 'MATLAB 7.3 MAT-file', column-major (an n x k
    matrix is a (k, n) dataset), MATLAB_class attributes, the cell's strings as uint16 char datasets under
    #refs# referenced from the cell dataset."""
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        ds = f.create_dataset("data", data=np.ascontiguousarray(np.asarray(data, float).T))
        ds.attrs["MATLAB_class"] = np.bytes_("double")
        refs = f.create_group("#refs#")
        ref_list = []
        for i, name in enumerate(names):
            ch = refs.create_dataset(f"n{i}", data=np.array([[ord(c)] for c in name], dtype=np.uint16))
            ch.attrs["MATLAB_class"] = np.bytes_("char")
            ch.attrs["MATLAB_int_decode"] = np.int32(2)
            ref_list.append(ch.ref)
        cell = f.create_dataset("names", data=np.array(ref_list, dtype=h5py.ref_dtype).reshape(len(names), 1))
        cell.attrs["MATLAB_class"] = np.bytes_("cell")
        for key, v in (extra or {}).items():
            e = f.create_dataset(key, data=np.atleast_2d(np.asarray(v, float)))
            e.attrs["MATLAB_class"] = np.bytes_("double")
    header = (f"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: {time.strftime('%a %b %d %H:%M:%S %Y')} "
              "HDF5 schema 1.00 .").ljust(116).encode() + b"\x00" * 8 + b"\x00\x02IM"
    with open(path, "r+b") as f:
        f.write(header)
