"""Bring your own rotor: a linear rotor model from a ``.npz`` or ``.mat`` file.

The model replaces the built-in finite-element rotor in both the analytical
and the true rig (``rotor_file: my_rotor.npz`` in a rig YAML file, or
``make_rig(..., rotor_import=load_rotor(path))``). It must be free-free: the
magnets are its only supports. Channel order is the rig's: bearing A x,
bearing B x, bearing A y, bearing B y, with x and y the bearing axes (turned
45 deg from the vertical).

Layout 1, state space (keys as written, case-sensitive)::

    A  (n, n)   x' = A x + B f
    B  (n, 4)   f: forces [N] on the rotor at the bearing planes
    C  (8, n)   displacements [m]: bearing planes (4), then sensor planes (4)
    mass_kg     total rotor mass [kg] (scalar)
    D  (8, 4)   optional, must be zero
    b_gravity (n,)  optional: x' caused by gravity; default: the bearing
                forces that give the rigid body gravity's acceleration
                (exact for the rigid motion, no sag)

Layout 2, second order, M q'' + (D + Omega G) q' + K q = F (any DOF layout,
e.g. ROSS's ``rotor.M()``, ``rotor.K(0)``, ``rotor.G()`` of a rotor built
without bearing elements)::

    M, K  (N, N)      mass [kg, kg m^2], stiffness [N/m, ...]
    D     (N, N)      optional damping [N s/m]; default: the rig's
                      ``modal_damping_ratio`` on every flexible mode
    G     (N, N)      optional gyroscopic matrix, times the spin speed [rad/s]
    bearing_dofs (4,) DOF indices of bearing A x, B x, A y, B y
    sensor_dofs  (4,) DOF indices of sensor A x, B x, A y, B y
    x_dofs, y_dofs    optional: every translation DOF along the bearing x
                      (y) axis; then gravity is the consistent load M u_g and
                      the mass is computed; otherwise give mass_kg
    mass_kg           total rotor mass [kg], if x_dofs is not given
    max_freq_hz       optional: modes kept below this frequency (default 5000)

The second-order model is reduced to its undamped modes below
``max_freq_hz`` (the rigid ones included). DOFs that no bearing or sensor
DOF is coupled to through M, K, D or G (the axial and torsional DOFs of a
six-DOF-per-node layout) are dropped first, and so are modes that neither
the bearings nor the sensors see; ``RotorModel.notes`` says what went. K must
be free-free (four lateral rigid-body modes): support springs in it are
named in the error. G is scaled by the rig's ``rotor_speed_rpm``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ambid.array_file import read_arrays
from ambid.plant.modal import undamped_modes
from ambid.plant.rotor_model import GRAVITY_PER_AXIS, N_LATERAL, RotorModel, rigid_inverse_mass

DEFAULT_MAX_FREQ_HZ = 5000.0
_FIX = ("give M, K (+ G, bearing_dofs, sensor_dofs, x_dofs, y_dofs) or A, B, C, mass_kg as "
        "ambid.plant.rotor_import describes, saved by numpy.savez or MATLAB save")
_VECTOR_KEYS = {"b_gravity", "mass_kg", "bearing_dofs", "sensor_dofs", "x_dofs", "y_dofs", "max_freq_hz"}


def _read(path: Path) -> dict[str, np.ndarray]:
    out = {k: np.asarray(v) for k, v in read_arrays(path, "rotor file", _FIX).items()}
    for key in _VECTOR_KEYS & set(out):  # MATLAB stores vectors and scalars as 2-D
        out[key] = out[key].ravel()
    return out


def _matrix(data: dict, key: str, shape: tuple, what: str) -> np.ndarray:
    if key not in data:
        raise ValueError(f"rotor file: key {key!r} ({what}) is missing; see ambid.plant.rotor_import for the layout")
    arr = np.asarray(data[key], dtype=float)
    if any(s is not None and s != a for s, a in zip(shape, arr.shape)) or arr.ndim != len(shape):
        want = tuple("n" if s is None else s for s in shape)
        raise ValueError(f"rotor file: {key} ({what}) must have shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"rotor file: {key} contains NaN or inf")
    return arr


def _symmetric(arr: np.ndarray, key: str, what: str) -> np.ndarray:
    """``arr`` if it is symmetric to round-off, else a ValueError naming the worst entry."""
    asym = np.abs(arr - arr.T)
    if asym.max() > 1e-9 * max(np.abs(arr).max(), np.finfo(float).tiny):
        i, j = np.unravel_index(np.argmax(asym), asym.shape)
        raise ValueError(f"rotor file: {key} ({what}) is not symmetric: {key}[{i}, {j}] = {arr[i, j]:.6g} but "
                         f"{key}[{j}, {i}] = {arr[j, i]:.6g}; give the symmetric {what} the rotordynamics code "
                         "assembled (gyroscopic terms go to G)")
    return arr


def _scalar(data: dict, key: str, what: str) -> float:
    if key not in data:
        raise ValueError(f"rotor file: key {key!r} ({what}) is missing; see ambid.plant.rotor_import for the layout")
    try:
        value = np.asarray(data[key], dtype=float).ravel()
    except (TypeError, ValueError):
        value = np.zeros(0)
    if value.size != 1:
        raise ValueError(f"rotor file: {key} ({what}) must be one number, got {np.asarray(data[key]).tolist()!r}")
    value = float(value[0])
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"rotor file: {key} must be a positive number, got {value}")
    return value


def _indices(data: dict, key: str, n_dof: int, count: int | None = N_LATERAL) -> np.ndarray:
    if key not in data:
        raise ValueError(f"rotor file: key {key!r} (DOF indices) is missing; see ambid.plant.rotor_import")
    idx = np.asarray(data[key]).ravel()
    if idx.dtype.kind == "f" and np.all(idx == np.round(idx)):
        idx = idx.astype(int)
    if idx.dtype.kind not in "iu" or (count is not None and idx.size != count) or np.any((idx < 0) | (idx >= n_dof)):
        need = f"{count} " if count is not None else ""
        raise ValueError(f"rotor file: {key} must hold {need}integer DOF indices in [0, {n_dof}), got {idx.tolist()}")
    return idx.astype(int)


def _lateral(data: dict, idx: np.ndarray, key: str, n_dof: int) -> None:
    """Four distinct DOFs, and (when x_dofs and y_dofs say which DOFs translate along the bearing axes) the
    first two x translations, the last two y translations: an axial or a tilt DOF here cannot be held or seen
    by a radial bearing or sensor, and the loop built on it would fail far from the cause."""
    if np.unique(idx).size != idx.size:
        raise ValueError(f"rotor file: {key} {idx.tolist()} names a DOF twice; give the DOFs of A x, B x, A y, "
                         "B y: four different ones")
    for axis, part in (("x_dofs", idx[:2]), ("y_dofs", idx[2:])):
        if axis in data:
            translations = _indices(data, axis, n_dof, None)
            wrong = [int(i) for i in part if i not in translations]
            if wrong:
                raise ValueError(f"rotor file: {key} {idx.tolist()}: DOF {wrong[0]} is not in {axis}; give A x, "
                                 f"B x (from x_dofs), A y, B y (from y_dofs): translations along the bearing axes, "
                                 "not axial, tilt or torsion DOFs")


def _gravity_from_rigid_body(a: np.ndarray, b: np.ndarray, c_bearing: np.ndarray) -> np.ndarray:
    """b_gravity from bearing forces that give the rigid body gravity's acceleration at both bearings."""
    probe = RotorModel(a, b, c_bearing, c_bearing, np.zeros(a.shape[0]), 1.0)
    w = rigid_inverse_mass(probe)
    if not np.all(np.linalg.eigvalsh(0.5 * (w + w.T)) > 0):
        raise ValueError("rotor model: no positive rigid-body inverse mass at the bearings; the rotor must be "
                         "free-free (no bearing or support stiffness in the model)")
    return b @ np.linalg.solve(w, np.full(N_LATERAL, GRAVITY_PER_AXIS))


def rotor_from_state_space(data: dict, source: str = "") -> RotorModel:
    """RotorModel from layout 1 (module docstring) given as a dict of arrays."""
    a = np.asarray(data.get("A", np.zeros((0, 0))), dtype=float)
    n = a.shape[0] if a.ndim == 2 else 0
    a = _matrix(data, "A", (n, n), "state matrix")
    b = _matrix(data, "B", (n, N_LATERAL), "force input at bearings A x, B x, A y, B y")
    c = _matrix(data, "C", (2 * N_LATERAL, n), "displacements at the 4 bearing then 4 sensor channels")
    if "D" in data and np.any(np.asarray(data["D"], dtype=float)):
        raise ValueError("rotor file: D must be zero (a force cannot move the rotor instantly)")
    mass = _scalar(data, "mass_kg", "total rotor mass")
    if "b_gravity" in data:
        b_g = _matrix(data, "b_gravity", (n,), "state derivative caused by gravity")
    else:
        b_g = _gravity_from_rigid_body(a, b, c[:N_LATERAL])
    return RotorModel(a, b, c[:N_LATERAL], c[N_LATERAL:], b_g, mass, source=source)


def _coupled_to(seeds: np.ndarray, matrices: list[np.ndarray]) -> np.ndarray:
    """(N,) bool: the DOFs that ``seeds`` reach through a non-zero entry of any of ``matrices``.

    A radial bearing holds only the DOFs coupled to its own; the axial and torsional DOFs of a
    rotordynamics code's six-DOF layout are coupled to none of them (decoupled blocks of M, K, G)."""
    n = matrices[0].shape[0]
    link = np.zeros((n, n), dtype=bool)
    for mat in matrices:
        scale = np.max(np.abs(mat))
        if scale > 0:  # round-off in a code's assembly is not a coupling
            link |= np.abs(mat) > 1e-10 * scale
    link |= link.T
    from scipy.sparse import csr_matrix  # scipy.sparse and scipy.io load in ~0.4 s: only for a rotor file
    from scipy.sparse.csgraph import connected_components

    _, label = connected_components(csr_matrix(link), directed=False)
    return np.isin(label, np.unique(label[seeds]))


def _support_springs(k: np.ndarray, data: dict, n_dof: int) -> str:
    """Where a stiffness matrix holds the rotor to ground: the reaction of each DOF to a unit rigid
    translation along the bearing x (and y) axis, which a free-free K gives as zero."""
    found = []
    for axis in ("x_dofs", "y_dofs"):
        if axis not in data:
            continue
        u = np.zeros(n_dof)
        u[_indices(data, axis, n_dof, None)] = 1.0
        reaction = k @ u
        tol = 1e-8 * np.max(np.abs(k))
        found += [f"DOF {i} ({reaction[i]:.3g} N/m)" for i in np.flatnonzero(np.abs(reaction) > tol)]
    return ", ".join(found)


def rotor_from_second_order(data: dict, speed_rad_s: float = 0.0, damping_ratio: float = 0.005,
                            source: str = "") -> RotorModel:
    """RotorModel from layout 2 (module docstring): modal reduction of M, K (D, G).

    DOFs that no bearing or sensor DOF is coupled to (axial and torsional ones) are dropped first,
    then the modes that neither the bearings nor the sensors see; ``RotorModel.notes`` says what went.

    Raises
    ------
    ValueError
        naming the key, or the support springs of a rotor that is not free-free.
    """
    m = np.asarray(data["M"], dtype=float)
    n_dof = m.shape[0] if m.ndim == 2 else 0
    m = _symmetric(_matrix(data, "M", (n_dof, n_dof), "mass matrix"), "M", "mass matrix")
    k = _symmetric(_matrix(data, "K", (n_dof, n_dof), "stiffness matrix"), "K", "stiffness matrix")
    d = _matrix(data, "D", (n_dof, n_dof), "damping matrix") if "D" in data else None
    g = _matrix(data, "G", (n_dof, n_dof), "gyroscopic matrix") if "G" in data else None
    i_b = _indices(data, "bearing_dofs", n_dof)
    i_s = _indices(data, "sensor_dofs", n_dof)
    _lateral(data, i_b, "bearing_dofs", n_dof)
    _lateral(data, i_s, "sensor_dofs", n_dof)
    f_max = _scalar(data, "max_freq_hz", "highest mode kept [Hz]") if "max_freq_hz" in data else DEFAULT_MAX_FREQ_HZ
    notes = []
    held = _coupled_to(np.concatenate([i_b, i_s]), [x for x in (m, k, d, g) if x is not None])
    if not held.all():
        dropped = np.flatnonzero(~held)
        shown = ", ".join(map(str, dropped[:12])) + (", ..." if dropped.size > 12 else "")
        notes.append(f"dropped {dropped.size} of {n_dof} DOFs that no bearing or sensor DOF is coupled to "
                     f"(axial, torsional or other decoupled DOFs: {shown})")
    try:
        freq, shapes = undamped_modes(m[np.ix_(held, held)], k[np.ix_(held, held)])
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ValueError(f"rotor file: M of the DOFs the bearings hold is not positive definite ({exc}); "
                         "check that every kept DOF has mass or inertia") from None
    phi_all = np.zeros((n_dof, freq.size))
    phi_all[held] = shapes
    keep = freq < f_max
    # a mode that neither the bearings nor the sensors see cannot be held or measured
    seen = np.linalg.norm(phi_all[np.concatenate([i_b, i_s])], axis=0)
    unseen = keep & (seen <= 1e-9 * seen.max())
    if unseen.any():
        notes.append(f"dropped {unseen.sum()} mode(s) that neither the bearings nor the sensors see "
                     f"({', '.join(f'{f:.1f} Hz' for f in freq[unseen])})")
    keep &= ~unseen
    if keep.sum() < 2:
        raise ValueError(f"rotor file: no modes below max_freq_hz = {f_max} Hz")
    freq, phi = freq[keep], phi_all[:, keep]
    n_rigid = int(np.sum(freq < 1.0))
    if n_rigid < 4:
        springs = _support_springs(k, data, n_dof)
        where = (f"its stiffness matrix holds support springs at {springs}" if springs else
                 "its stiffness matrix holds the rotor to ground (a support spring or a rotational one)")
        raise ValueError(f"rotor file: the rotor is not free-free: {n_rigid} of the 4 lateral rigid-body modes "
                         f"remain, {where}; give M and K without bearing or support elements (in ROSS: a rotor "
                         "built with its shaft and disk elements only), the magnets are the rig's supports")
    # rigid-body modes are exactly that: round-off leaves them at mHz, which the rigid inverse mass
    # (taken at 1 mHz) and gravity's equilibrium would mistake for a soft support
    freq = np.where(freq < 1.0, 0.0, freq)
    r = freq.size
    w = 2 * np.pi * freq
    damp = phi.T @ d @ phi if d is not None else np.diag(2 * damping_ratio * w)
    # at standstill first: the rigid-body checks and gravity's share hold for the resting rotor
    # (spinning, the gyroscopic coupling turns the rigid tilt into a precession)
    a = np.block([[np.zeros((r, r)), np.eye(r)], [-np.diag(w * w), -damp]])
    b = np.vstack([np.zeros((r, N_LATERAL)), phi[i_b].T])
    c_b = np.hstack([phi[i_b], np.zeros((N_LATERAL, r))])
    c_s = np.hstack([phi[i_s], np.zeros((N_LATERAL, r))])
    if "x_dofs" in data or "y_dofs" in data:
        u_g = np.zeros(n_dof)
        u_g[_indices(data, "x_dofs", n_dof, None)] = GRAVITY_PER_AXIS
        u_g[_indices(data, "y_dofs", n_dof, None)] = GRAVITY_PER_AXIS
        b_g = np.concatenate([np.zeros(r), phi.T @ (m @ u_g)])
        u_x = np.zeros(n_dof)
        u_x[_indices(data, "x_dofs", n_dof, None)] = 1.0
        mass = float(u_x @ m @ u_x)
    else:
        b_g = _gravity_from_rigid_body(a, b, c_b)
        mass = _scalar(data, "mass_kg", "total rotor mass (or give x_dofs and y_dofs)")
    if g is not None and speed_rad_s:
        a[r:, r:] -= speed_rad_s * (phi.T @ g @ phi)
    flexible = freq[freq >= 1.0]
    return RotorModel(a, b, c_b, c_s, b_g, mass, flexible, source, notes=tuple(notes))


def load_rotor(path: str | Path, speed_rpm: float = 0.0, damping_ratio: float = 0.005) -> RotorModel:
    """Load a user rotor model (layout by keys: "M" present -> second order, else state space).

    Parameters
    ----------
    path
        ``.npz`` or ``.mat`` file.
    speed_rpm
        spin speed for the gyroscopic matrix G (second order only) [rpm].
    damping_ratio
        modal damping of the flexible modes when no D is given
        (second order only) [-].

    Returns
    -------
    RotorModel with ``source = "file:<path>"``.

    Raises
    ------
    ValueError
        naming the missing or malformed key.
    """
    path = Path(path)
    data = _read(path)
    source = f"file:{path}"
    if "M" in data:  # checks its own free-free-ness, at standstill
        return rotor_from_second_order(data, speed_rpm * np.pi / 30.0, damping_ratio, source)
    model = rotor_from_state_space(data, source)
    _gravity_from_rigid_body(model.a, model.b, model.c_bearing)  # free-free check
    return model


def save_rotor(path: str | Path, model: RotorModel) -> None:
    """Write a RotorModel in layout 1 (``.npz`` or ``.mat``), so ``load_rotor`` reads it back."""
    path = Path(path)
    data = {"A": model.a, "B": model.b, "C": np.vstack([model.c_bearing, model.c_sensor]),
            "mass_kg": np.array(model.mass_kg), "b_gravity": model.b_gravity}
    if path.suffix == ".npz":
        np.savez(path, **data)
    elif path.suffix == ".mat":
        from scipy import io as sio

        sio.savemat(path, data)
    else:
        raise ValueError(f"save_rotor: unknown extension {path.suffix!r}; use .npz or .mat")
