"""Directional (complex) FRFs of a rotor: forward and backward whirl told apart.

With the complex coordinates p = x + j y of the displacements and
f = u_x + j u_y of the inputs at each bearing plane (Lee, *Vibration
Analysis of Rotors*, 1993), a real x/y FRF matrix G splits into

    H_f(w) = (G_xx + G_yy + j (G_yx - G_xy)) / 2     forward: p, f turning with the spin
    H_b(w) = (G_xx + G_yy - j (G_yx - G_xy)) / 2     backward: against it

(H_b(w) is the directional FRF at -w, conjugated). A forward whirl mode
peaks in H_f, a backward one in H_b; at standstill, for an isotropic rotor,
the two are equal. The x axis turns into the y axis in the sense of the
spin (as in :mod:`ambid.plant.modal`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ambid.channels import Layout, bearing_of

# a mode whose forward share of the orbit lies between these is called standing (no clear direction)
_STANDING = (0.4, 0.6)


@dataclass(frozen=True)
class DirectionalFrf:
    """Forward and backward directional FRFs between the bearing planes.

    Attributes
    ----------
    freq_hz
        (L,) [Hz].
    forward, backward
        (L, Np, Np) complex, p (outputs) per f (inputs) [m/A].
    var_forward, var_backward
        (L, Np, Np) variances [(m/A)^2] from the x/y variances, the
        elements taken independent; None without them.
    planes
        the bearings of the Np planes (rows), e.g. ("a", "b").
    """

    freq_hz: np.ndarray
    forward: np.ndarray
    backward: np.ndarray
    var_forward: np.ndarray | None = None
    var_backward: np.ndarray | None = None
    planes: tuple[str, ...] = ()


def planes(names: Sequence[str]) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """(x indices, y indices) of the radial bearing planes among channel names of one signal: the bearings
    with both an x and a y channel (``Layout.radial_pairs``), e.g. (0, 1), (2, 3) for y_a_x y_b_x y_a_y y_b_y."""
    pairs = Layout.from_names(names).radial_pairs
    return tuple(x for x, _ in pairs), tuple(y for _, y in pairs)


def has_planes(output_names: Sequence[str], input_names: Sequence[str]) -> bool:
    """Whether both the outputs and the inputs name the x and y of the same bearing planes (>= 1)."""
    try:
        lo, li = Layout.from_names(output_names), Layout.from_names(input_names)
    except ValueError:
        return False
    po, pi = lo.radial_pairs, li.radial_pairs
    return bool(po) and [(lo.axes[x], lo.axes[y]) for x, y in po] == [(li.axes[x], li.axes[y]) for x, y in pi]


def directional_frf(freq_hz: np.ndarray, frf: np.ndarray, var: np.ndarray | None = None,
                    output_names: Sequence[str] = (), input_names: Sequence[str] = ()) -> DirectionalFrf:
    """Forward and backward directional FRFs from an x/y FRF matrix (module docstring).

    Parameters
    ----------
    freq_hz
        (L,) [Hz].
    frf
        (L, Ny, Nu) u -> y [m/A].
    var
        (L, Ny, Nu) variance of each element, or None.
    output_names, input_names
        the channels of the rows and columns (``y_a_x``, ``u_a_x``, ...): the
        planes are their bearings with an x and a y channel (:func:`planes`).

    Returns
    -------
    :class:`DirectionalFrf` with (L, Np, Np) matrices, Np the planes.
    """
    g = np.asarray(frf)
    (xo, yo), (xi, yi) = (tuple(np.asarray(i, dtype=np.int64) for i in planes(n)) for n in (output_names, input_names))
    gxx, gyy = g[:, xo][:, :, xi], g[:, yo][:, :, yi]
    gxy, gyx = g[:, xo][:, :, yi], g[:, yo][:, :, xi]
    fwd = (gxx + gyy + 1j * (gyx - gxy)) / 2
    bwd = (gxx + gyy - 1j * (gyx - gxy)) / 2
    vf = None
    if var is not None:
        v = np.asarray(var, dtype=float)
        vf = (v[:, xo][:, :, xi] + v[:, yo][:, :, yi] + v[:, xo][:, :, yi] + v[:, yo][:, :, xi]) / 4
    lay = Layout.from_names(output_names)
    return DirectionalFrf(np.asarray(freq_hz, dtype=float), fwd, bwd, vf, vf,
                          tuple(bearing_of(lay.axes[x]) for x, _ in lay.radial_pairs))


def whirl(shape: np.ndarray, names: Sequence[str]) -> tuple[str, float]:
    """Whirl direction of a mode from its complex shape at the planes (the response ~ Re(shape e^{j w t})),
    the shape's channels named by ``names`` (the planes as :func:`planes` finds them).

    The orbit p = x + j y of each plane is (s_x + j s_y) / 2 e^{j w t} (forward) plus
    conj(s_x - j s_y) / 2 e^{-j w t} (backward); the forward share is
    sum |s_x + j s_y|^2 / (sum |s_x + j s_y|^2 + sum |s_x - j s_y|^2) over the planes.

    Returns
    -------
    ('forward' | 'backward' | 'standing', forward share in [0, 1]).
    """
    s = np.asarray(shape, dtype=complex)
    x_idx, y_idx = planes(names)
    sx, sy = s[list(x_idx)], s[list(y_idx)]
    f, b = np.sum(np.abs(sx + 1j * sy) ** 2), np.sum(np.abs(sx - 1j * sy) ** 2)
    share = float(f / (f + b)) if f + b > 0 else 0.5
    kind = "forward" if share > _STANDING[1] else "backward" if share < _STANDING[0] else "standing"
    return kind, share


def whirl_of_residue(residue: np.ndarray, output_names: Sequence[str], input_names: Sequence[str],
                     ) -> tuple[str, float]:
    """Whirl direction of a mode from its residue matrix R (Ny, Nu) at the pole with Im > 0, its rows and
    columns the channels named.

    The forward and backward directional FRFs have the residues R_f, R_b (the combinations of
    :func:`directional_frf` applied to R); the forward share is ||R_f||^2 / (||R_f||^2 + ||R_b||^2).
    Unlike a single shape vector this also judges a pair of coincident modes (an isotropic rotor at
    standstill, a rank-2 residue): its share is 1/2, 'standing'.

    Returns
    -------
    ('forward' | 'backward' | 'standing', forward share in [0, 1]).
    """
    r = np.asarray(residue, dtype=complex)[None]
    d = directional_frf([0.0], r, None, output_names, input_names)
    f, b = np.sum(np.abs(d.forward) ** 2), np.sum(np.abs(d.backward) ** 2)
    share = float(f / (f + b)) if f + b > 0 else 0.5
    kind = "forward" if share > _STANDING[1] else "backward" if share < _STANDING[0] else "standing"
    return kind, share
