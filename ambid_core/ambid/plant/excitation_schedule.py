"""Where a plant's excitation r[k] comes from, sample by sample.

A plant (the simulator's node, or a target) applies r[k] at exactly sample k.
Excitation arrives ahead of time in blocks tagged with their first sample
index; a design announces the range of samples it excites, and the plant
waits at an excited sample until the block holding it has arrived, so where
the excitation lands never depends on message timing. Every other sample
has r = 0.

:class:`ExcitationSchedule` keeps the held blocks and the announced ranges
and answers "r[k], or wait". The block in use (``rows`` for samples
[``first``, ``end``)) and ``free_until`` (before it no sample outside that
block is excited) are what a per-sample loop reads; a subclass may keep
``first``, ``rows`` and ``free_until`` where compiled code reads them
(plant_sim keeps them in its loop kernel's context).
"""

from __future__ import annotations

import bisect

import numpy as np

NO_END = 2**62  # free_until when nothing is announced or held ahead (an int64 for compiled readers)


class ExcitationSchedule:
    """Held excitation blocks and the sample ranges designs excite, for a plant at sample k.

    Parameters
    ----------
    n_channels
        excitation channels per row.

    Attributes
    ----------
    blocks
        first index -> (n, n_channels) rows [A], consumed in order.
    starts
        sorted keys of ``blocks``.
    ranges
        experiment id -> [start, end) of the samples its design excites.
    first, end, rows
        the block in use, rows r[first + i] = rows[i] (zeros while none is).
    free_until
        before it, no sample outside the block in use is excited.
    """

    def __init__(self, n_channels: int) -> None:
        self.zero_rows = np.zeros((1, n_channels))
        self.blocks: dict[int, np.ndarray] = {}
        self.starts: list[int] = []
        self.ranges: dict[str, tuple[int, int]] = {}
        self.first = self.end = 0
        self.rows = self.zero_rows
        self.free_until = 0

    def length(self, first: int) -> int:
        """Samples of the held block starting at ``first``."""
        return len(self.blocks[first])

    def rows_at(self, k: int) -> tuple[np.ndarray, int] | None:
        """(rows, i) with r[k] = rows[i] [A]: the block in use, or zeros where no design excites k;
        None while the block of an excited sample has not arrived. A held block covering k becomes
        the block in use."""
        if self.first <= k < self.end:
            return self.rows, k - self.first
        if k < self.free_until:
            return self.zero_rows, 0
        first = self.held(k)
        if first is not None:
            rows = self.blocks[first]
            self.first, self.end, self.rows = first, first + len(rows), rows
            return rows, k - first
        if self.excited(k):
            return None
        self.refresh(k)
        return self.zero_rows, 0

    def passed(self, k: int) -> None:
        """The plant is at sample k: the block in use is dropped once k reaches its end."""
        if k == self.end and self.first in self.blocks:
            del self.blocks[self.first]
            self.starts.remove(self.first)
            self.refresh(k)

    def add_block(self, first: int, data: np.ndarray, k: int) -> int:
        """Hold the block r[first:first + n] (rows [A]) at plant sample k. Rows already due (before k)
        are dropped; returns how many (all of them: nothing is held)."""
        late = min(max(k - first, 0), len(data))
        if late < len(data):
            first, data = first + late, data[late:]
            self.blocks[first] = np.ascontiguousarray(data, dtype=float)
            bisect.insort(self.starts, first)
            self.refresh(k)
        return late

    def add_design(self, experiment_id: str, start: int, total: int, k: int) -> None:
        """A design excites samples [start, start + total) (total 0 or a range already passed: none);
        ValueError if it moves, starts in the past or overlaps another experiment's range."""
        end = start + total
        for other, (a, b) in list(self.ranges.items()):
            if b <= k:
                del self.ranges[other]  # passed: no longer needed
        known = self.ranges.get(experiment_id)
        if known is not None and known[0] != start:
            raise ValueError(f"excitation/design {experiment_id!r}: start_index changed from {known[0]} to {start}")
        if known is None and total and start < k:
            raise ValueError(f"excitation/design {experiment_id!r}: starts at sample {start}, which the plant has "
                             f"passed (now {k})")
        for other, (a, b) in self.ranges.items():
            if other != experiment_id and a < end and start < b:
                raise ValueError(f"excitation/design {experiment_id!r}: samples [{start}, {end}) overlap "
                                 f"experiment {other!r} [{a}, {b})")
        if total == 0 or end <= k:
            self.ranges.pop(experiment_id, None)
        else:
            self.ranges[experiment_id] = (start, end)
        self.refresh(k)

    def refresh(self, k: int) -> None:
        """free_until from sample k: up to the next excited range or held block no lookup is needed."""
        ahead = [a for a, b in self.ranges.values() if b > k] + [f for f in self.starts if f >= k]
        covering = self.excited(k) or self.held(k) is not None
        self.free_until = k if covering else min([max(a, k) for a in ahead], default=NO_END)

    def excited(self, k: int) -> bool:
        """A design says sample k is excited."""
        return any(a <= k < b for a, b in self.ranges.values())

    def experiment_at(self, k: int) -> str:
        """The id of the experiment exciting sample k, or '?'."""
        return next((e for e, (a, b) in self.ranges.items() if a <= k < b), "?")

    def held(self, k: int) -> int | None:
        """First index of the held block covering sample k, or None."""
        i = bisect.bisect_right(self.starts, k) - 1
        if i >= 0:
            first = self.starts[i]
            if k < first + len(self.blocks[first]):
                return first
        return None
