"""Closed loops of many plants and one controller, from their frequency responses: fast enough to sit
inside a tuning loop.

Sign convention of :mod:`ambid.control.closed_loop`: ``u = ic + r``, ``ic = K y`` (K carries the minus
sign), so the input sensitivity is ``S = (I - K G)^-1`` (r -> u) and the output sensitivity
``So = (I - G K)^-1``. Channels that neither plant nor controller couple (the x and y planes of a rotor
at standstill, an axial axis) form blocks that are inverted apart: 1 x 1 and 2 x 2 blocks in closed form,
which for tens of thousands of small matrices is far cheaper than a batched LAPACK inverse.
"""

from __future__ import annotations

import numpy as np

__all__ = ["coupled_blocks", "block_inverse", "loop_blocks", "input_sensitivity_frf", "worst_peak", "noise_current_frf",
           "current_noise_rms"]


def coupled_blocks(pattern: np.ndarray) -> list[np.ndarray]:
    """The groups of channels a square coupling ``pattern`` (na, na) bool joins (its connected components),
    each an index array in ascending order."""
    pattern = np.asarray(pattern, dtype=bool)
    pattern = pattern | pattern.T
    na = pattern.shape[0]
    seen = np.zeros(na, dtype=bool)
    out = []
    for i in range(na):
        if seen[i]:
            continue
        comp, todo = [], [i]
        seen[i] = True
        while todo:
            j = todo.pop()
            comp.append(j)
            for k in np.flatnonzero(pattern[j] & ~seen):
                seen[k] = True
                todo.append(int(k))
        out.append(np.array(sorted(comp)))
    return out


def block_inverse(m: np.ndarray, blocks: list[np.ndarray]) -> np.ndarray:
    """The inverse of each matrix of ``m`` (..., na, na), zero outside ``blocks``
    (:func:`coupled_blocks` of its pattern)."""
    out = np.zeros_like(m)
    for b in blocks:
        if b.size == 1:
            i = b[0]
            out[..., i, i] = 1.0 / m[..., i, i]
        elif b.size == 2:
            i, j = b
            det = m[..., i, i] * m[..., j, j] - m[..., i, j] * m[..., j, i]
            out[..., i, i], out[..., j, j] = m[..., j, j] / det, m[..., i, i] / det
            out[..., i, j], out[..., j, i] = -m[..., i, j] / det, -m[..., j, i] / det
        else:
            out[..., b[:, None], b[None, :]] = np.linalg.inv(m[..., b[:, None], b[None, :]])
    return out


def _pattern(controller_frf: np.ndarray, plant_frf: np.ndarray) -> np.ndarray:
    g = np.abs(plant_frf).reshape(-1, *plant_frf.shape[-2:]).max(axis=0)
    k = np.abs(controller_frf)
    k = np.diag(k.max(axis=0)) if k.ndim == 2 else k.max(axis=0)
    # entries 1e-7 of the largest are rounding (a structural zero of a state-space model), not a coupling
    return (g > 1e-7 * g.max()) | (k.T > 1e-7 * max(k.max(), 1e-300))


def loop_blocks(controller_frf: np.ndarray, plant_frf: np.ndarray) -> list[np.ndarray]:
    """The channel groups that the loop of ``controller_frf`` ((L, na) diagonal or (L, na, na)) and the plants
    ``plant_frf`` (..., L, na, na) couple: compute them once for many controllers of one structure."""
    return coupled_blocks(_pattern(np.asarray(controller_frf), plant_frf))


def input_sensitivity_frf(controller_frf: np.ndarray, plant_frf: np.ndarray) -> np.ndarray:
    """``S = (I - K G)^-1`` of every plant, (..., L, na, na).

    Parameters
    ----------
    controller_frf
        (L, na) a decentralised controller's diagonal, or (L, na, na) a full one [A/m],
        minus sign and delay included.
    plant_frf
        (..., L, na, na) plants [m/A].

    Examples
    --------
    >>> import numpy as np
    >>> g = np.array([[[2.0]]])              # one line, one axis: 2 m/A
    >>> input_sensitivity_frf(np.array([[-1.0]]), g)[0, 0, 0]   # 1 / (1 + 2)
    np.float64(0.3333333333333333)
    """
    k = np.asarray(controller_frf)
    kg = k[..., :, None] * plant_frf if k.ndim == 2 else k @ plant_frf
    na = plant_frf.shape[-1]
    return block_inverse(np.eye(na) - kg, coupled_blocks(_pattern(k, plant_frf)))


def worst_peak(controller_frf: np.ndarray, plant_frf: np.ndarray, blocks: list[np.ndarray] | None = None
               ) -> np.ndarray:
    """Peak ``|S_jj|`` per plant over the axes and the grid, (...,) from plants (..., L, na, na) (each loop's
    stability is not checked here).

    Parameters
    ----------
    controller_frf
        (L, na) decentralised controller [A/m].
    plant_frf
        (..., L, na, na) plants [m/A].
    blocks
        :func:`loop_blocks`, when known.
    """
    k = np.asarray(controller_frf)
    if k.ndim != 2:
        s = input_sensitivity_frf(k, plant_frf)
        return np.abs(np.diagonal(s, axis1=-2, axis2=-1)).max(axis=(-2, -1))
    blocks = loop_blocks(k, plant_frf) if blocks is None else blocks
    peak = np.zeros(plant_frf.shape[:-3])
    for b in blocks:
        if b.size > 2:
            m = np.eye(b.size) - k[:, b, None] * plant_frf[..., b[:, None], b[None, :]]
            d = np.abs(np.diagonal(np.linalg.inv(m), axis1=-2, axis2=-1))
        elif b.size == 1:
            d = np.abs(1.0 / (1.0 - k[:, b[0]] * plant_frf[..., b[0], b[0]]))
        else:   # only the diagonal of a 2 x 2 inverse: m_jj / det, m_ii / det
            i, j = b
            mii, mjj = 1.0 - k[:, i] * plant_frf[..., i, i], 1.0 - k[:, j] * plant_frf[..., j, j]
            det = mii * mjj - (k[:, i] * plant_frf[..., i, j]) * (k[:, j] * plant_frf[..., j, i])
            d = np.maximum(np.abs(mjj / det), np.abs(mii / det))
        peak = np.maximum(peak, d.reshape(*d.shape[:len(peak.shape)], -1).max(axis=-1))
    return peak


def noise_current_frf(controller_frf: np.ndarray, plant_frf: np.ndarray, noise_std_m: np.ndarray) -> np.ndarray:
    """The control current each sensor's white noise causes through the loop, ``ic = K (I - G K)^-1 v``, per
    unit of noise std: (L, na currents, na sensors) [A per sample].

    Parameters
    ----------
    controller_frf
        (L, na) decentralised, or (L, na, na) full controller [A/m].
    plant_frf
        (L, na, na) one plant [m/A].
    noise_std_m
        (na,) each sensor's noise std per sample [m].
    """
    k = np.asarray(controller_frf)
    kf = np.einsum("li,ij->lij", k, np.eye(k.shape[1])) if k.ndim == 2 else k
    na = plant_frf.shape[-1]
    so = block_inverse(np.eye(na) - plant_frf @ kf, loop_blocks(k, plant_frf))
    return (kf @ so) * np.asarray(noise_std_m)[None, None, :]


def current_noise_rms(controller_frf: np.ndarray, plant_frf: np.ndarray, noise_std_m: np.ndarray) -> np.ndarray:
    """RMS control current [A] per axis that white sensor noise causes through the loop (Parseval over
    :func:`noise_current_frf` on a uniform grid over (0, Nyquist))."""
    t = noise_current_frf(controller_frf, plant_frf, noise_std_m)
    return np.sqrt(np.mean(np.sum(np.abs(t) ** 2, axis=2), axis=0))
