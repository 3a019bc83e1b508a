"""How far an FRF matrix is from a reference: the relative error per line, one norm for every accuracy figure."""

from __future__ import annotations

import numpy as np

__all__ = ["frf_relative_error"]


def frf_relative_error(frf: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Relative error of an FRF matrix per line, ``||G - G_ref||_F / ||G_ref||_F``.

    The matrix norm keeps the structurally zero x-y couplings of a rotor at
    standstill from dominating, as an element-wise ratio would.

    Parameters
    ----------
    frf
        estimate (L, Ny, Nu).
    reference
        true FRF, same shape.

    Returns
    -------
    (L,) relative error [-]; NaN where the estimate is not finite.
    """
    g, r = np.asarray(frf), np.asarray(reference)
    if g.shape != r.shape or g.ndim != 3:
        raise ValueError(f"frf and reference must both be (L, Ny, Nu), got {g.shape} and {r.shape}")
    finite = np.all(np.isfinite(g), axis=(1, 2))
    if finite.all():
        # the difference as it comes, in memory order: the norms sum the same way for every caller
        return np.linalg.norm(g - r, axis=(1, 2)) / np.linalg.norm(r, axis=(1, 2))
    diff = np.where(finite[:, None, None], g - r, 0.0)
    err = np.linalg.norm(diff, axis=(1, 2)) / np.linalg.norm(r, axis=(1, 2))
    return np.where(finite, err, np.nan)
