"""Eigen-analysis, modal reduction and state-space models of a rotor.

Works on the matrices of ``ambid.plant.fem_rotor`` (4 DOFs per node: x, y,
theta_x, theta_y) or any M, K, G with that layout, for

    M q'' + (D + Omega G) q' + K q = F.

Axisymmetric rotors (the (x, theta_y) and (y, -theta_x) planes carry the
same M and K, G couples them) are reduced plane-wise: one set of
mass-normalised plane modes serves both planes, so the reduced
coordinates are

    eta = [eta_x (n_modes), eta_y (n_modes)],  q ~= shapes @ eta,

where x-plane mode j moves x and theta_y only and y-plane mode j is the same
shape in (y, -theta_x). The reduced gyroscopic matrix couples eta_x and
eta_y, and with the complex coordinate eta_x + i eta_y a positive whirl
frequency is forward whirl (orbit in the sense of the spin), a negative one
backward whirl.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.linalg

from ambid.plant.fem_rotor import DOF_RX, DOF_RY, DOF_X, DOF_Y, DOFS_PER_NODE


@dataclass(frozen=True)
class ModalModel:
    """Mass-normalised modal model of an axisymmetric rotor.

    Attributes
    ----------
    freq_hz
        natural frequencies at standstill per plane mode,
        shape (n_modes,) [Hz]; the first ``n_rigid`` are 0.
    n_rigid
        rigid-body modes per plane (2 free-free, 0 when supported).
    shapes
        mode shapes on the full DOFs, shape (n_dof, 2 n_modes),
        columns [x-plane modes, y-plane modes]; shapes.T M shapes = I.
    polar
        reduced polar-inertia matrix Pm = phi_p.T P phi_p, shape
        (n_modes, n_modes) [-]; the reduced gyroscopic matrix is
        [[0, Pm], [-Pm, 0]].
    """

    freq_hz: np.ndarray
    n_rigid: int
    shapes: np.ndarray
    polar: np.ndarray

    @property
    def n_modes(self) -> int:
        """Plane modes kept (rigid + flexible); the model has 2 n_modes coordinates."""
        return self.freq_hz.size

    @property
    def stiffness(self) -> np.ndarray:
        """Reduced stiffness diag(omega^2) over eta, shape (2 n_modes, 2 n_modes) [1/s^2]."""
        w2 = (2 * np.pi * self.freq_hz) ** 2
        return np.diag(np.concatenate([w2, w2]))

    @property
    def gyroscopic(self) -> np.ndarray:
        """Reduced gyroscopic matrix shapes.T G shapes, shape (2 n_modes, 2 n_modes) [-]."""
        z = np.zeros_like(self.polar)
        return np.block([[z, self.polar], [-self.polar, z]])


def undamped_modes(mass: np.ndarray, stiffness: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Generalised eigenproblem K phi = omega^2 M phi (any DOF layout).

    Parameters
    ----------
    mass
        M, symmetric positive definite, shape (n, n).
    stiffness
        K, symmetric positive semi-definite, shape (n, n).

    Returns
    -------
    (freq_hz, shapes): natural frequencies ascending, shape (n,) [Hz]
    (round-off negative eigenvalues of rigid-body modes clipped to 0), and
    mass-normalised shapes, shape (n, n), column j for freq_hz[j].
    """
    m, k = _square(mass, "mass"), _square(stiffness, "stiffness")
    if m.shape != k.shape:
        raise ValueError(f"mass {m.shape} and stiffness {k.shape} must have the same shape")
    lam, vec = scipy.linalg.eigh(k, m)
    return np.sqrt(np.clip(lam, 0.0, None)) / (2 * np.pi), vec


def support_stiffness(n_dof: int, dofs: Sequence[int], stiffness_n_m: float | Sequence[float]) -> np.ndarray:
    """Diagonal spring matrix to add to K for a supported analysis.

    Parameters
    ----------
    n_dof
        size of K.
    dofs
        DOF indices of the springs (give both x and y to keep the rotor
        axisymmetric, as ``plane_modes`` requires).
    stiffness_n_m
        one value or one per DOF [N/m] (or N m/rad on rotations).

    Returns
    -------
    Array of shape (n_dof, n_dof).
    """
    idx = _dofs(dofs, n_dof, "dofs")
    kv = np.broadcast_to(np.asarray(stiffness_n_m, dtype=float), idx.shape)
    if not np.all(np.isfinite(kv)):
        raise ValueError("stiffness_n_m must be finite")
    ks = np.zeros((n_dof, n_dof))
    np.add.at(ks, (idx, idx), kv)
    return ks


def plane_modes(mass: np.ndarray, stiffness: np.ndarray, gyroscopic: np.ndarray | None = None,
                n_flexible: int | None = None, rigid_tol_hz: float = 1.0) -> ModalModel:
    """Modal reduction of an axisymmetric rotor: rigid modes + first flexible modes.

    Parameters
    ----------
    mass
        M, shape (4 n_nodes, 4 n_nodes), layout of ``ambid.plant.fem_rotor``.
    stiffness
        K, same shape, positive semi-definite (free-free, or with
        axisymmetric supports). Add negative magnet stiffness later, in
        ``modal_state_space(input_stiffness_n_m=...)``.
    gyroscopic
        G, same shape; None for a non-rotating analysis.
    n_flexible
        flexible plane modes to keep; None keeps all.
    rigid_tol_hz
        modes below this frequency count as rigid-body modes [Hz].

    Returns
    -------
    ModalModel. Free-free rigid modes come out as translation and tilt
    about the centre of mass (both mass-normalised); flexible shapes are
    signed so their largest translation is positive.

    Raises
    ------
    ValueError
        the planes are coupled or differ (not axisymmetric), or
        shapes do not fit the 4-DOF-per-node layout.
    """
    m, k = _square(mass, "mass"), _square(stiffness, "stiffness")
    n = m.shape[0]
    if k.shape != m.shape or n % DOFS_PER_NODE:
        raise ValueError(f"mass and stiffness must be equal square matrices of size 4 n_nodes, got "
                         f"{m.shape} and {k.shape}")
    g = np.zeros_like(m) if gyroscopic is None else _square(gyroscopic, "gyroscopic")
    if g.shape != m.shape:
        raise ValueError(f"gyroscopic {g.shape} must have the shape of mass {m.shape}")
    xp, yp, t = _plane_index(n)
    for name, a in (("mass", m), ("stiffness", k)):
        _check_axisymmetric(a, xp, yp, t, name)
    scale = max(np.abs(g).max(), 1e-300)
    polar_full = g[np.ix_(xp, yp)] * t
    if (np.abs(g[np.ix_(xp, xp)]).max() > 1e-9 * scale or np.abs(g[np.ix_(yp, yp)]).max() > 1e-9 * scale
            or np.abs(g[np.ix_(yp, xp)] + t[:, None] * polar_full).max() > 1e-9 * scale
            or np.abs(polar_full - polar_full.T).max() > 1e-9 * scale):
        raise ValueError("gyroscopic matrix is not the axisymmetric plane coupling of ambid.plant.fem_rotor "
                         "(G[x-plane, y-plane] = P T with P symmetric, G[y, x] = -T P)")
    mp, kp = m[np.ix_(xp, xp)], k[np.ix_(xp, xp)]
    freq, vec = undamped_modes(mp, kp)
    rigid = freq < rigid_tol_hz
    n_rigid = int(rigid.sum())
    if n_rigid and not np.all(rigid[:n_rigid]):
        raise ValueError("rigid-body modes are not the lowest modes; check rigid_tol_hz")
    freq[:n_rigid] = 0.0
    vec = vec.copy()
    if n_rigid == 2:
        vec[:, :2] = _clean_rigid(mp, vec[:, :2])
    for j in range(n_rigid if n_rigid == 2 else 0, freq.size):
        w = vec[0::2, j]
        if w[np.argmax(np.abs(w))] < 0:
            vec[:, j] *= -1.0
    n_keep = freq.size if n_flexible is None else n_rigid + int(n_flexible)
    if n_flexible is not None and not 0 <= n_flexible <= freq.size - n_rigid:
        raise ValueError(f"n_flexible must lie in [0, {freq.size - n_rigid}], got {n_flexible!r}")
    phi_p = vec[:, :n_keep]
    shapes = np.zeros((n, 2 * n_keep))
    shapes[xp, :n_keep] = phi_p
    shapes[yp, n_keep:] = t[:, None] * phi_p
    polar = phi_p.T @ polar_full @ phi_p
    return ModalModel(freq_hz=freq[:n_keep], n_rigid=n_rigid, shapes=shapes, polar=0.5 * (polar + polar.T))


def modal_state_space(model: ModalModel, input_dofs: Sequence[int], output_dofs: Sequence[int],
                      speed_rad_s: float = 0.0, damping_ratio: float | Sequence[float] = 0.0,
                      input_stiffness_n_m: float | Sequence[float] | None = None,
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous-time state space of the reduced rotor, x' = A x + B u, y = C x.

    States x = [eta (2 n_modes), eta' (2 n_modes)] with eta = [eta_x, eta_y]
    (module docstring); inputs are forces [N] (moments [N m] on rotation DOFs)
    at ``input_dofs``; outputs are displacements [m] (rotations [rad]) at
    ``output_dofs``. Reduced equation:
    eta'' + (diag(2 zeta omega) + Omega Gm) eta' + diag(omega^2) eta = shapes.T F.

    Parameters
    ----------
    model
        from ``plane_modes``.
    input_dofs
        DOF indices of the force inputs, length n_in.
    output_dofs
        DOF indices of the displacement outputs, length n_out.
    speed_rad_s
        spin speed Omega [rad/s].
    damping_ratio
        modal damping ratio, scalar or one per plane mode
        (n_modes,); rigid modes (omega = 0) get none.
    input_stiffness_n_m
        springs from each input DOF to ground, scalar
        or shape (n_in,) [N/m]; added as shapes[in].T diag(k) shapes[in].
        Negative values model the magnets' negative stiffness -ks
        (the modes stay those of ``model``, so keep enough of them).

    Returns
    -------
    (A, B, C) of shapes (4 n_modes, 4 n_modes), (4 n_modes, n_in),
    (n_out, 4 n_modes).
    """
    n_dof, r = model.shapes.shape
    i_in = _dofs(input_dofs, n_dof, "input_dofs")
    i_out = _dofs(output_dofs, n_dof, "output_dofs")
    zeta = _damping(damping_ratio, model.n_modes)
    if not np.isfinite(speed_rad_s):
        raise ValueError(f"speed_rad_s must be finite, got {speed_rad_s!r}")
    w = 2 * np.pi * model.freq_hz
    damp = np.diag(np.tile(2 * zeta * w, 2))
    stiff = model.stiffness
    if input_stiffness_n_m is not None:
        kv = np.broadcast_to(np.asarray(input_stiffness_n_m, dtype=float), i_in.shape)
        if not np.all(np.isfinite(kv)):
            raise ValueError("input_stiffness_n_m must be finite")
        phi_in = model.shapes[i_in, :]
        stiff = stiff + phi_in.T @ (kv[:, None] * phi_in)
    a = np.block([[np.zeros((r, r)), np.eye(r)],
                  [-stiff, -(damp + speed_rad_s * model.gyroscopic)]])
    b = np.vstack([np.zeros((r, i_in.size)), model.shapes[i_in, :].T])
    c = np.hstack([model.shapes[i_out, :], np.zeros((i_out.size, r))])
    return a, b, c


def second_order_state_space(mass: np.ndarray, damping: np.ndarray | None, stiffness: np.ndarray,
                             input_dofs: Sequence[int], output_dofs: Sequence[int],
                             gyroscopic: np.ndarray | None = None, speed_rad_s: float = 0.0,
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unreduced state space of M q'' + (D + Omega G) q' + K q = F.

    States x = [q, q'] (2 n_dof); inputs forces at ``input_dofs``; outputs
    displacements at ``output_dofs``. Any DOF layout.

    Returns
    -------
    (A, B, C) of shapes (2 n, 2 n), (2 n, n_in), (n_out, 2 n).
    """
    m, k = _square(mass, "mass"), _square(stiffness, "stiffness")
    n = m.shape[0]
    d = np.zeros_like(m) if damping is None else _square(damping, "damping")
    if gyroscopic is not None:
        d = d + speed_rad_s * _square(gyroscopic, "gyroscopic")
    if k.shape != m.shape or d.shape != m.shape:
        raise ValueError("mass, damping, stiffness and gyroscopic must have the same shape")
    i_in = _dofs(input_dofs, n, "input_dofs")
    i_out = _dofs(output_dofs, n, "output_dofs")
    minv_k, minv_d = np.linalg.solve(m, k), np.linalg.solve(m, d)
    sel = np.zeros((n, i_in.size))
    sel[i_in, np.arange(i_in.size)] = 1.0
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-minv_k, -minv_d]])
    b = np.vstack([np.zeros((n, i_in.size)), np.linalg.solve(m, sel)])
    c = np.zeros((i_out.size, 2 * n))
    c[np.arange(i_out.size), i_out] = 1.0
    return a, b, c


def whirl_frequencies(model: ModalModel, speed_rad_s: float,
                      damping_ratio: float | Sequence[float] = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Whirl frequencies at a spin speed, from the complex reduced eigenproblem.

    With e = eta_x + i eta_y the model is
    e'' + (diag(2 zeta omega) - i Omega Pm) e' + diag(omega^2) e = 0; each
    eigenvalue s gives the signed whirl frequency Im(s) / 2 pi: positive is
    forward whirl, negative backward. The real system's eigenvalues are these
    s and their conjugates.

    Parameters
    ----------
    model
        from ``plane_modes``.
    speed_rad_s
        spin speed Omega [rad/s] (negative spins the other way).
    damping_ratio
        as in ``modal_state_space``.

    Returns
    -------
    (freq_hz, damping): signed whirl frequencies, shape (2 n_modes,),
    ordered by |freq|, then backward before forward [Hz]; and their
    damping ratios -Re(s)/|s| (0 where s = 0).
    """
    if not np.isfinite(speed_rad_s):
        raise ValueError(f"speed_rad_s must be finite, got {speed_rad_s!r}")
    m = model.n_modes
    zeta = _damping(damping_ratio, m)
    w = 2 * np.pi * model.freq_hz
    a = np.block([[np.zeros((m, m)), np.eye(m)],
                  [-np.diag(w**2), -(np.diag(2 * zeta * w) - 1j * speed_rad_s * model.polar)]])
    s = np.linalg.eigvals(a)
    f = s.imag / (2 * np.pi)
    mag = np.abs(s)
    zeta_out = np.where(mag > 0, -s.real / np.where(mag > 0, mag, 1.0), 0.0)
    order = np.lexsort((f, np.round(np.abs(f), 9)))
    return f[order], zeta_out[order]


def campbell(model: ModalModel, speeds_rad_s: np.ndarray,
             damping_ratio: float | Sequence[float] = 0.0) -> np.ndarray:
    """Signed whirl frequencies over speed (Campbell diagram) [Hz].

    Parameters
    ----------
    model
        from ``plane_modes``.
    speeds_rad_s
        spin speeds, shape (n_speeds,) [rad/s].

    Returns
    -------
    Array (n_speeds, 2 n_modes): row k is ``whirl_frequencies`` at
    speeds_rad_s[k]; sort order is per row (by |freq|), so follow a branch
    by sign and rank.
    """
    speeds = np.atleast_1d(np.asarray(speeds_rad_s, dtype=float))
    return np.array([whirl_frequencies(model, om, damping_ratio)[0] for om in speeds])


def _clean_rigid(mp: np.ndarray, rig: np.ndarray) -> np.ndarray:
    """Rotate a 2-D rigid subspace to translation + tilt about the centre of mass."""
    trans = np.zeros(mp.shape[0])
    trans[0::2] = 1.0
    coef = rig.T @ mp @ trans  # components of the translation in the M-orthonormal basis
    resid = trans - rig @ coef
    if np.linalg.norm(resid) > 1e-6 * np.linalg.norm(trans):
        return rig  # translation is not rigid (supported rotor): keep the eigenvectors
    t = rig @ coef / np.linalg.norm(coef)
    perp = np.array([-coef[1], coef[0]]) / np.linalg.norm(coef)
    tilt = rig @ perp
    if tilt[1::2].sum() < 0:
        tilt = -tilt
    return np.column_stack([t, tilt])


def _plane_index(n_dof: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    nodes = np.arange(n_dof // DOFS_PER_NODE)[:, None] * DOFS_PER_NODE
    xp = (nodes + np.array([DOF_X, DOF_RY])).ravel()
    yp = (nodes + np.array([DOF_Y, DOF_RX])).ravel()
    return xp, yp, np.tile([1.0, -1.0], n_dof // DOFS_PER_NODE)


def _check_axisymmetric(a: np.ndarray, xp: np.ndarray, yp: np.ndarray, t: np.ndarray, name: str) -> None:
    scale = np.abs(a).max()
    axx = a[np.ix_(xp, xp)]
    if (np.abs(a[np.ix_(xp, yp)]).max() > 1e-9 * scale
            or np.abs(a[np.ix_(yp, yp)] - t[:, None] * axx * t).max() > 1e-9 * scale):
        raise ValueError(
            f"{name} is not axisymmetric: the (x, theta_y) and (y, -theta_x) planes must be "
            "uncoupled and equal (add supports to x and y alike); use undamped_modes for the general case")


def _square(a: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(a, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ValueError(f"{name} must be a square matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


def _dofs(dofs: Sequence[int], n_dof: int, name: str) -> np.ndarray:
    idx = np.atleast_1d(np.asarray(dofs))
    if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"{name} must be a 1-D sequence of integer DOF indices, got {dofs!r}")
    if np.any((idx < 0) | (idx >= n_dof)):
        raise ValueError(f"{name} must lie in [0, {n_dof}), got {idx.tolist()}")
    return idx


def _damping(damping_ratio: float | Sequence[float], n_modes: int) -> np.ndarray:
    zeta = np.asarray(damping_ratio, dtype=float)
    if zeta.ndim == 0:
        zeta = np.full(n_modes, float(zeta))
    if zeta.shape != (n_modes,) or not np.all(np.isfinite(zeta)) or np.any(zeta < 0):
        raise ValueError(f"damping_ratio must be a scalar or shape ({n_modes},), finite and >= 0, "
                         f"got {damping_ratio!r}")
    return zeta
