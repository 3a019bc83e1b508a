"""An excitation experiment placed on a plant's sample clock and streamed ahead of it in blocks.

:func:`place_experiment` checks a design against the plant it is for (sample
rate, inputs, amplifier headroom, excitation channels) and places it at a
start sample no earlier than is safe; :meth:`Experiment.due_blocks` gives the
blocks whose end lies within a look-ahead of the plant's progress, each
computed on demand by ``design.samples`` so memory stays flat however long
the experiment. The excitation_generator node is this over ROS.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from ambid.excitation.design import ExcitationDesign, check_headroom
from ambid.quantity import quantity

# the controller's peak working current (gravity and regulation) the headroom check assumes unless told [A]:
# the excitation generator's default, and what identify and design check a run against before it starts
WORKING_CURRENT_A = 1.0


@dataclass(frozen=True)
class Streaming:
    """How experiments are streamed ahead of a plant and checked against its amplifier: the excitation
    generator's parameters besides the experiment's terms (:class:`ambid.excitation.spec.DesignSpec`).

    Attributes
    ----------
    block_size, lookahead, start_margin
        samples per block; most samples published ahead of the plant's progress (:meth:`Experiment.due_blocks`);
        samples between the plant's progress and an automatically chosen start (:func:`place_experiment`).
    current_limit_a, working_current_a
        the headroom check's amplifier limit (0: the plant's) and controller's working current [A].
    """

    block_size: int = quantity(1000, "samples per excitation block", "", 1, 1_000_000)
    lookahead: int = quantity(20_000, "most samples published ahead of the plant's progress", "", 2, 100_000_000)
    start_margin: int = quantity(5000, "samples between the plant's progress and an automatically chosen start", "",
                                 0, 100_000_000)
    current_limit_a: float = quantity(0.0, "amplifier current limit for the headroom check; 0 = the plant's "
                                           "(plant/description)", "A", 0.0, 1e3)
    working_current_a: float = quantity(WORKING_CURRENT_A, "controller's peak working current (gravity and "
                                                           "regulation) for the headroom check", "A", 0.0, 1e3)


@dataclass
class Experiment:
    """A running experiment: its design, where it lies on the plant's clock, how far it is published.

    Attributes
    ----------
    experiment_id
        its name.
    design
        the excitation.
    start
        plant sample index of the design's offset 0.
    total
        samples, cut by :meth:`stop`.
    columns
        (Nu,) the excitation channel of each design input.
    next_offset
        first offset not yet published.
    blocks
        blocks published.
    """

    experiment_id: str
    design: ExcitationDesign
    start: int
    total: int
    columns: np.ndarray
    next_offset: int = 0
    blocks: int = 0

    @property
    def end(self) -> int:
        return self.start + self.total

    def due_blocks(self, progress: int, lookahead: int, block_size: int, n_channels: int
                   ) -> Iterator[tuple[int, np.ndarray, bool]]:
        """(first sample index, rows (n, n_channels) [A], final) of each block not yet published whose end
        lies at most ``lookahead`` samples past the plant's ``progress``, in order; each counts as
        published once taken."""
        limit = progress + lookahead
        while self.next_offset < self.total:
            off = self.next_offset
            n = min(block_size, self.total - off)
            if self.start + off + n > limit:
                return
            data = np.zeros((n, n_channels))
            data[:, self.columns] = self.design.samples(off, n)
            self.next_offset += n
            self.blocks += 1
            yield self.start + off, data, off + n == self.total

    def stop(self) -> None:
        """No more blocks: every one published is applied, nothing after it."""
        self.total = self.next_offset


def place_experiment(experiment_id: str, design: ExcitationDesign, *, fs_hz: float, current_names: Sequence[str],
                     current_limit_a: np.ndarray | float, working_current_a: float,
                     excitation_names: Sequence[str], progress: int, start_margin: int, after: int = 0,
                     start_index: int = 0) -> Experiment:
    """``design`` as an experiment on a plant, or ValueError saying why it cannot run there.

    Parameters
    ----------
    fs_hz
        the plant's sample rate [Hz]; the design's must be the same.
    current_names
        the plant's currents; the design's inputs must be among them.
    current_limit_a
        amplifier limit per current (same order) or one for all [A].
    working_current_a
        the controller's peak working current, for the headroom check [A].
    excitation_names
        the excitation channels; input ``u_<axis>`` is excited through ``r_<axis>``.
    progress
        the next sample the plant applies; the experiment starts at least ``start_margin``
        samples later, and not before ``after`` (the previous experiment's end).
    start_index
        the start asked for; 0 = the earliest safe one.
    """
    if abs(design.fs_hz - fs_hz) > 1e-9 * fs_hz:
        raise ValueError(f"the design's sample rate {design.fs_hz:g} Hz differs from the plant's "
                         f"{fs_hz:g} Hz; design it at {fs_hz:g} Hz")
    names = list(current_names)
    missing = [n for n in design.input_names if n not in names]
    if missing:
        raise ValueError(f"the design excites {missing}, which the plant does not have; its currents are {names}")
    limit = np.broadcast_to(np.asarray(current_limit_a, dtype=float), (len(names),))
    check_headroom(design, limit[[names.index(n) for n in design.input_names]], working_current_a)
    columns = np.array([list(excitation_names).index("r_" + n[2:]) if n.startswith("u_")
                        and "r_" + n[2:] in excitation_names else -1 for n in design.input_names])
    if np.any(columns < 0):
        raise ValueError(f"inputs {list(design.input_names)} have no excitation channel among "
                         f"{list(excitation_names)} (u_<axis> is excited by r_<axis>)")
    earliest = max(progress + start_margin, after)
    start = int(start_index) or earliest
    if start < earliest:
        raise ValueError(f"start_index {start} is too early: the plant is at sample {progress} (needs start_margin "
                         f"{start_margin} ahead) and the previous experiment ends at {after}; use {earliest} or later, "
                         "or 0 for the next safe one")
    return Experiment(experiment_id, design, start, design.total_samples, columns)
