"""Did the rotor stay levitated? Streaming figures of a run, memory flat in its length."""

from __future__ import annotations

import numpy as np


class _Window:
    """Displacement statistics of the samples from ``start`` on."""

    __slots__ = ("start", "n", "sum", "sum_sq", "max_abs", "contacts", "end")

    def __init__(self, start: int, width: int) -> None:
        self.start = start
        self.n = 0
        self.sum = np.zeros(width)
        self.sum_sq = np.zeros(width)
        self.max_abs = 0.0
        self.contacts = 0
        self.end = start  # one past the last sample taken

    def add(self, first_index: int, y: np.ndarray, contact: np.ndarray) -> None:
        skip = max(0, min(len(y), self.start - first_index))
        y, contact = y[skip:], contact[skip:]
        if not len(y):
            return
        self.n += len(y)
        self.sum += y.sum(axis=0)
        self.sum_sq += (y * y).sum(axis=0)
        self.max_abs = max(self.max_abs, float(np.abs(y).max()))
        self.contacts += int(contact.sum())
        self.end = first_index + skip + len(y)


class LevitationMonitor:
    """Accumulates displacement statistics after a settling period.

    Parameters
    ----------
    clearance_m
        backup-bearing radial clearance [m].
    settle_samples
        samples ignored at the start (lift-off from the retainer): the run is judged over
        the samples from this index on (the second half of a run of known length).
    after_lift_off
        for a run that ends before ``settle_samples`` (a node died, the session was
        stopped), the samples from this many after the last lift-off on are judged instead; default
        ``settle_samples``. So the figures are true up to wherever the run ended: a rotor that
        levitated for six seconds before its controller was lost reads as such, not as never levitated.

    The rotor counts as levitated when, in the window judged, it never touched the retainer and every
    measured displacement stayed within half the clearance. Feed only the samples the session ran under
    control (leave out a safe state's landing after the run failed): ``end_index`` in :meth:`figures` says
    where the judged samples end.
    """

    def __init__(self, clearance_m: float, settle_samples: int, after_lift_off: int | None = None) -> None:
        self.clearance_m = clearance_m
        self.settle = settle_samples
        self.after_lift_off = settle_samples if after_lift_off is None else after_lift_off
        self.contacts = 0
        self.lift_off_index: int | None = None
        self._width: int | None = None
        self._settled: _Window | None = None     # samples >= settle
        self._since_lift: _Window | None = None  # samples >= last lift-off + after_lift_off
        self.end_index = 0  # one past the last sample added

    def add_block(self, first_index: int, y: np.ndarray, contact: np.ndarray) -> None:
        """Samples first_index.. of measured displacement y [m] (n, k) and retainer contact (n,) bool."""
        y = np.asarray(y, dtype=float)
        contact = np.asarray(contact, dtype=bool)
        if self._width is None:
            self._width = y.shape[1]
            self._settled = _Window(self.settle, self._width)
        touching = np.flatnonzero(contact)
        self.contacts += touching.size
        if touching.size:
            last = touching[-1]
            self.lift_off_index = int(first_index + last + 1) if last + 1 < len(contact) else None
            self._since_lift = None
            if self.lift_off_index is not None:
                self._since_lift = _Window(self.lift_off_index + self.after_lift_off, self._width)
        elif self.lift_off_index is None:
            self.lift_off_index = int(first_index)
        if self._since_lift is None and self.lift_off_index is not None:
            self._since_lift = _Window(self.lift_off_index + self.after_lift_off, self._width)
        self._settled.add(first_index, y, contact)
        if self._since_lift is not None:
            self._since_lift.add(first_index, y, contact)
        self.end_index = max(self.end_index, first_index + len(y))

    @property
    def _judged(self) -> _Window | None:
        """The settled window, or where the run ended before it, the samples since lift-off (if any)."""
        if self._settled is not None and self._settled.n:
            return self._settled
        if self._since_lift is not None and self._since_lift.n:
            return self._since_lift
        return None

    @property
    def n(self) -> int:
        w = self._judged
        return w.n if w is not None else 0

    def levitated(self) -> bool:
        w = self._judged
        return w is not None and w.contacts == 0 and w.max_abs < 0.5 * self.clearance_m

    def figures(self) -> dict:
        """displacement_rms_m (about zero, all channels), per-channel mean and std [m], contacts, and the
        samples judged ``[evaluated_from_index, evaluated_to_index)`` (``samples_evaluated`` 0: none yet)."""
        w = self._judged
        width = self._width or 0
        if w is None:
            mean = var = np.zeros(width)
            rms, max_abs, after, start, end = 0.0, 0.0, 0, None, None
        else:
            mean = w.sum / w.n
            var = np.maximum(w.sum_sq / w.n - mean**2, 0.0)
            rms, max_abs, after = float(np.sqrt(np.mean(w.sum_sq / w.n))), w.max_abs, w.contacts
            start, end = max(w.start, 0), w.end
        return {
            "levitated": self.levitated(),
            "displacement_rms_m": rms,
            "displacement_mean_m": mean.tolist(),
            "displacement_std_m": np.sqrt(var).tolist(),
            "max_abs_displacement_m": max_abs,
            "contact_samples": self.contacts,
            "contact_samples_after_settling": after,
            "lift_off_index": self.lift_off_index,
            "samples_evaluated": w.n if w is not None else 0,
            "evaluated_from_index": start,
            "evaluated_to_index": end,
        }
