"""A rotor written by the tests, in a layout of its own: six DOFs per node (ux, uy, uz, rx, ry, rz), as
rotordynamics codes such as ROSS hand their matrices over, with axial and torsional DOFs that no radial
bearing holds. Euler-Bernoulli beam elements (consistent mass), axial bar and torsion elements, one disk.

Defaults: 0.8 m steel shaft of 50 mm, 8 elements; a 19 kg disk at mid-span (31 kg in all); bearings at
nodes 1 and 7 (0.6 m apart), sensors at the shaft ends (nodes 0 and 8)."""

from __future__ import annotations

import numpy as np

UX, UY, UZ, RX, RY, RZ = range(6)


def six_dof_rotor(n_el: int = 8, length_m: float = 0.8, diameter_m: float = 0.05, disk_kg: float = 19.0,
                  disk_ip_kgm2: float = 0.30, disk_id_kgm2: float = 0.16, e_pa: float = 211e9,
                  rho: float = 7810.0, nu: float = 0.3, bearing_node: int = 1, sensor_node: int = 0) -> dict:
    """M, K (6 n_nodes square) and the DOF index lists of the rotor above; the bearings sit
    ``bearing_node`` nodes and the sensors ``sensor_node`` nodes in from each shaft end."""
    nn = n_el + 1
    n = 6 * nn
    l = length_m / n_el
    area = np.pi * diameter_m ** 2 / 4
    inertia = np.pi * diameter_m ** 4 / 64
    polar = 2 * inertia
    g_pa = e_pa / (2 * (1 + nu))
    kb = e_pa * inertia / l ** 3 * np.array([[12, 6 * l, -12, 6 * l], [6 * l, 4 * l * l, -6 * l, 2 * l * l],
                                              [-12, -6 * l, 12, -6 * l], [6 * l, 2 * l * l, -6 * l, 4 * l * l]])
    mb = rho * area * l / 420 * np.array([[156, 22 * l, 54, -13 * l], [22 * l, 4 * l * l, 13 * l, -3 * l * l],
                                          [54, 13 * l, 156, -22 * l], [-13 * l, -3 * l * l, -22 * l, 4 * l * l]])
    bar = np.array([[1.0, -1.0], [-1.0, 1.0]])
    bar_m = np.array([[2.0, 1.0], [1.0, 2.0]]) / 6
    m, k = np.zeros((n, n)), np.zeros((n, n))
    for e in range(n_el):
        a, b = 6 * e, 6 * (e + 1)
        # bending in the x-z plane (ux, ry) and in the y-z plane (uy, -rx): the same element
        for u, r, sign in ((UX, RY, 1.0), (UY, RX, -1.0)):
            idx = [a + u, a + r, b + u, b + r]
            t = np.diag([1.0, sign, 1.0, sign])
            k[np.ix_(idx, idx)] += t @ kb @ t
            m[np.ix_(idx, idx)] += t @ mb @ t
        for dof, stiff, mass in ((UZ, e_pa * area / l, rho * area * l), (RZ, g_pa * polar / l, rho * polar * l)):
            idx = [a + dof, b + dof]
            k[np.ix_(idx, idx)] += stiff * bar
            m[np.ix_(idx, idx)] += mass * bar_m
    d = 6 * (nn // 2)
    for dof, value in ((UX, disk_kg), (UY, disk_kg), (UZ, disk_kg), (RX, disk_id_kgm2), (RY, disk_id_kgm2),
                       (RZ, disk_ip_kgm2)):
        m[d + dof, d + dof] += value
    node = lambda i, dof: 6 * i + dof  # noqa: E731
    b, s = bearing_node, sensor_node
    return dict(M=m, K=k, bearing_dofs=np.array([node(b, UX), node(nn - 1 - b, UX), node(b, UY), node(nn - 1 - b, UY)]),
                sensor_dofs=np.array([node(s, UX), node(nn - 1 - s, UX), node(s, UY), node(nn - 1 - s, UY)]),
                x_dofs=np.arange(UX, n, 6), y_dofs=np.arange(UY, n, 6))


def lateral_modes_with_magnets(rotor: dict, ks_n_per_m: float) -> np.ndarray:
    """Frequencies [Hz] of the rotor's flexible lateral modes with the magnets' negative stiffness -ks at the
    four bearing DOFs: the generalised eigenproblem written here (each appears twice: x and y)."""
    from scipy import linalg

    k = rotor["K"].copy()
    for i in rotor["bearing_dofs"]:
        k[i, i] -= ks_n_per_m
    lam = linalg.eigh(k, rotor["M"], eigvals_only=True)
    return np.sqrt(lam[lam > (2 * np.pi * 1.0) ** 2]) / (2 * np.pi)
