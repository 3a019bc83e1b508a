"""Did the rotor stay levitated? Streaming figures of a run, memory flat in its length."""

from __future__ import annotations

import numpy as np


class LevitationMonitor:
    """Accumulates displacement statistics after a settling period.

    Args:
        clearance_m: backup-bearing radial clearance [m].
        settle_samples: samples ignored at the start (lift-off from the retainer).

    The rotor counts as levitated when, after settling, it never touched the
    retainer and every measured displacement stayed within half the clearance.
    """

    def __init__(self, clearance_m: float, settle_samples: int) -> None:
        self.clearance_m = clearance_m
        self.settle = settle_samples
        self.n = 0
        self.sum_sq = self.sum = np.zeros(0)  # per channel, sized by the first block
        self.max_abs = 0.0
        self.contacts_after_settle = 0
        self.contacts = 0
        self.lift_off_index: int | None = None

    def add_block(self, first_index: int, y: np.ndarray, contact: np.ndarray) -> None:
        """Samples first_index.. of measured displacement y [m] (n, channels) and retainer contact (n,) bool."""
        contact = np.asarray(contact, dtype=bool)
        touching = np.flatnonzero(contact)
        self.contacts += touching.size
        if touching.size:
            last = touching[-1]
            self.lift_off_index = int(first_index + last + 1) if last + 1 < len(contact) else None
        elif self.lift_off_index is None:
            self.lift_off_index = int(first_index)
        skip = max(0, min(len(y), self.settle - first_index))
        y, contact = y[skip:], contact[skip:]
        if not len(y):
            return
        if self.sum.size == 0:
            self.sum, self.sum_sq = np.zeros(y.shape[1]), np.zeros(y.shape[1])
        self.n += len(y)
        self.sum += y.sum(axis=0)
        self.sum_sq += (y * y).sum(axis=0)
        self.max_abs = max(self.max_abs, float(np.abs(y).max()))
        self.contacts_after_settle += int(contact.sum())

    def levitated(self) -> bool:
        return self.n > 0 and self.contacts_after_settle == 0 and self.max_abs < 0.5 * self.clearance_m

    def figures(self) -> dict:
        """displacement_rms_m (about zero, all channels), per-channel mean and std [m], contacts."""
        n = max(self.n, 1)
        mean = self.sum / n
        var = np.maximum(self.sum_sq / n - mean**2, 0.0)
        return {
            "levitated": self.levitated(),
            "displacement_rms_m": float(np.sqrt(np.mean(self.sum_sq / n))) if self.sum_sq.size else 0.0,
            "displacement_mean_m": mean.tolist(),
            "displacement_std_m": np.sqrt(var).tolist(),
            "max_abs_displacement_m": self.max_abs,
            "contact_samples": self.contacts,
            "contact_samples_after_settling": self.contacts_after_settle,
            "lift_off_index": self.lift_off_index,
            "samples_evaluated": self.n,
        }
