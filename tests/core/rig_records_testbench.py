"""A rig that is not ambid's, and its records as a logger and MATLAB write them (shared test helper).

The plant, the controller, the excitation and the file layouts are written
here with scipy/numpy/h5py only, so an import identified against them is
checked against something ambid did not compute:

* plant: bearing axes, each a rotor mass on a magnet with negative
  stiffness (one unstable real pole pair per axis), plus two lightly damped
  flexible modes that every radial axis sees (modal shapes, force and sensor
  collocated), force ki * current, ZOH-discretised at FS. Any set of the
  axes ``x`` (a one-axis rig), ``a_x b_x a_y b_y`` (radial) and ``z`` (an
  axial axis: its own mass and magnet, no flexible mode, decoupled);
  the default is the four radial axes;
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
# each axis' mass [kg], negative stiffness [N/m], force per current [N/A], and its share of the two modes
AXIS = {"x": (MASS, KS, KI, (1.0, 0.5)), "a_x": (MASS, KS, KI, (1.0, 0.5)), "b_x": (MASS, KS, KI, (-0.8, 1.0)),
        "a_y": (MASS, KS, KI, (0.6, -0.7)), "b_y": (MASS, KS, KI, (-0.5, 0.9)), "z": (5.0, 3.5e5, 70.0, (0.0, 0.0))}
KP, KD, KINT = 1.6 * KS / KI, 6.0, 2.0e4   # A/m, A s/m, A/(m s)


def gains(axes=AXES) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The PID's (kp [A/m], kd [A s/m], ki [A/(m s)]) per axis: kp = 1.6 ks / ki of the axis' magnet, kd and
    the integral gain scaled with its mass."""
    m, ks, ki = (np.array([AXIS[a][i] for a in axes]) for i in range(3))
    return 1.6 * ks / ki, KD * m / MASS * KI / ki, KINT * m / MASS * KI / ki


def plant_continuous(axes=AXES) -> tuple[np.ndarray, ...]:
    """(A, B, C, D): currents (na) [A] -> displacements (na) [m] of the axes named."""
    na = len(axes)
    n = 2 * na + 2 * len(MODES_HZ)
    a, b, c = np.zeros((n, n)), np.zeros((n, na)), np.zeros((na, n))
    for i, axis in enumerate(axes):
        mass, ks, ki, _ = AXIS[axis]
        a[2 * i, 2 * i + 1] = 1.0
        a[2 * i + 1, 2 * i] = ks / mass
        b[2 * i + 1, i] = ki / mass
        c[i, 2 * i] = 1.0
    for k, (f, z) in enumerate(zip(MODES_HZ, MODES_ZETA)):
        w, j = 2 * np.pi * f, 2 * na + 2 * k
        shape = np.array([AXIS[axis][3][k] for axis in axes])
        a[j, j + 1] = 1.0
        a[j + 1, j], a[j + 1, j + 1] = -w * w, -2 * z * w
        b[j + 1] = np.array([AXIS[axis][2] for axis in axes]) * shape / MASS
        c[:, j] = shape
    return a, b, c, np.zeros((na, na))


def true_modes(axes=AXES) -> list[tuple[float, float]]:
    """(frequency [Hz], damping) of the plant's oscillating poles that the axes see, from its A."""
    a, b, c, _ = plant_continuous(axes)
    s, v = np.linalg.eig(a)
    seen = (s.imag > 1e-6) & (np.abs(c @ v).max(axis=0) > 0) & (np.abs(np.linalg.solve(v, b)).max(axis=1) > 0)
    return sorted((abs(p) / (2 * np.pi), -p.real / abs(p)) for p in s[seen])


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


def closed_loop(r: np.ndarray, noise_m: float, seed: int, axes=AXES) -> tuple[np.ndarray, np.ndarray]:
    """Simulate the PID loop with r (n, na) [A] added to the currents: (y measured (n, na) [m], u (n, na) [A])."""
    a, b, c, d = plant_continuous(axes)
    ad, bd, *_ = signal.cont2discrete((a, b, c, d), 1 / FS, method="zoh")
    kp, kd, kint = gains(axes)
    na = len(axes)
    dt = 1 / FS
    tau = 1 / (2 * np.pi * 2000.0)                     # derivative filter
    alpha = np.exp(-dt / tau)
    rng = np.random.default_rng(seed)
    noise = noise_m * rng.standard_normal(r.shape)
    n = len(r)
    x = np.zeros(ad.shape[0])
    integ, dfilt, y_prev = np.zeros(na), np.zeros(na), np.zeros(na)
    ic = np.zeros(na)
    ys, us = np.empty((n, na)), np.empty((n, na))
    for k in range(n):
        y = c @ x + noise[k]
        u = ic + r[k]
        ys[k], us[k] = y, u
        x = ad @ x + bd @ u
        # the current computed from y[k] is applied from sample k+1 on
        integ += dt * y
        dfilt = alpha * dfilt + (1 - alpha) * (y - y_prev) / dt
        y_prev = y
        ic = -(kp * y + kint * integ + kd * dfilt)
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
