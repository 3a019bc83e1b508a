"""The logic the plant and generator nodes run, as plain Python: where the plant's r[k] comes from
(ambid.plant.excitation_schedule) and an experiment placed and streamed ahead of a plant
(ambid.excitation.experiment)."""

from __future__ import annotations

import numpy as np
import pytest

from ambid.excitation import design_multisine
from ambid.excitation.experiment import place_experiment
from ambid.plant.excitation_schedule import NO_END, ExcitationSchedule

EXC = ("r_a_x", "r_b_x", "r_a_y", "r_b_y")
CURRENTS = ("u_a_x", "u_b_x", "u_a_y", "u_b_y")


def test_schedule_waits_for_an_announced_block_and_steps_past_the_rest():
    s = ExcitationSchedule(4)
    assert s.rows_at(0) == (s.zero_rows, 0) and s.free_until == NO_END  # nothing announced: r = 0
    s.add_design("exp-1", 100, 50, k=10)
    assert s.free_until == 100 and s.experiment_at(120) == "exp-1" and s.experiment_at(99) == "?"
    assert s.rows_at(99)[0] is s.zero_rows
    assert s.rows_at(100) is None  # announced and not here: the plant waits
    block = np.arange(200.0).reshape(50, 4)
    assert s.add_block(100, block, k=100) == 0
    rows, i = s.rows_at(120)
    assert np.array_equal(rows[i], block[20]) and (s.first, s.end) == (100, 150)
    s.passed(150)  # used up: dropped
    assert s.blocks == {} and s.starts == []


def test_schedule_drops_late_rows_and_refuses_moved_or_overlapping_designs():
    s = ExcitationSchedule(2)
    assert s.add_block(10, np.ones((5, 2)), k=12) == 2  # rows for 10 and 11 are already due
    assert list(s.blocks) == [12] and s.length(12) == 3
    assert s.add_block(20, np.ones((3, 2)), k=30) == 3 and 20 not in s.blocks  # all late: nothing held
    s.add_design("a", 100, 100, k=0)
    with pytest.raises(ValueError, match="start_index changed from 100 to 101"):
        s.add_design("a", 101, 100, k=0)
    with pytest.raises(ValueError, match="overlap experiment 'a'"):
        s.add_design("b", 150, 100, k=0)
    with pytest.raises(ValueError, match="which the plant has passed"):
        s.add_design("c", 5, 10, k=50)
    s.add_design("a", 100, 0, k=0)  # stopped before it began: no longer excited
    assert s.ranges == {}


def _design(inputs=("u_a_x", "u_b_y"), peak=0.3):
    return design_multisine((50.0, 2000.0), 10.0, 10_000.0, inputs, peak, n_periods=2, n_transient_periods=0,
                            seed=7)


def test_experiment_streams_its_design_within_the_lookahead_in_the_right_channels():
    d = _design()
    exp = place_experiment("exp-0001", d, fs_hz=10_000.0, current_names=CURRENTS, current_limit_a=3.0,
                           working_current_a=1.0, excitation_names=EXC, progress=200, start_margin=1500, after=0)
    assert (exp.start, exp.total) == (1700, d.total_samples) and exp.columns.tolist() == [0, 3]
    blocks = list(exp.due_blocks(progress=200, lookahead=3000, block_size=500, n_channels=4))
    assert [b[0] for b in blocks] == [1700, 2200, 2700]  # ends within 200 + 3000
    first, data, final = blocks[1]
    assert not final and np.array_equal(data[:, [0, 3]], d.samples(500, 500)) and not data[:, [1, 2]].any()
    rest = list(exp.due_blocks(progress=10**6, lookahead=3000, block_size=500, n_channels=4))
    assert rest[-1][2] and rest[-1][0] + len(rest[-1][1]) == exp.end and exp.blocks == 3 + len(rest)
    exp.total = 0
    exp.next_offset = 1000
    exp.stop()
    assert exp.total == 1000


@pytest.mark.parametrize("change, words", [
    (dict(fs_hz=5000.0), "differs from the plant's 5000 Hz"),
    (dict(current_names=("u_a_x",)), "does not have"),
    (dict(current_limit_a=1.2), "exceeds the 1.2 A limit"),
    (dict(excitation_names=("r_a_x",)), "no excitation channel"),
    (dict(start_index=1000), "too early"),
])
def test_experiment_placement_refuses_what_the_plant_cannot_run(change, words):
    kw = dict(fs_hz=10_000.0, current_names=CURRENTS, current_limit_a=3.0, working_current_a=1.0,
              excitation_names=EXC, progress=200, start_margin=1500, after=0)
    with pytest.raises(ValueError, match=words):
        place_experiment("x", _design(), **{**kw, **change})


def test_recording_counts_follows_block_ends_keeps_log_time_and_writes_changed_facts(tmp_path):
    from ambid.recording import iter_messages, read_metadata
    from ambid.recording.blocks import encode_sample_block
    from ambid.recording.in_progress import Recording

    rec = Recording(str(tmp_path / "s" / "r.mcap"), chunk_size=1 << 20, flush_period_s=1.0, compression="zstd",
                    fsync=False, overwrite=False)
    rec.track("/amb/measurement", sample_blocks=True)
    rec.add_topic("/amb/measurement", "std_msgs/msg/String", [])  # the recording keeps bytes, not types
    assert rec.log_time(1000) == (1000, 0) and rec.log_time(400) == (1000, 600)  # held, never back
    for first in (0, 100):
        rec.write("/amb/measurement", encode_sample_block(first, 1e-4, ["y"], ["m"], np.zeros((100, 1))), 1000)
    assert rec.counts == {"/amb/measurement": 2} and rec.block_end == {"/amb/measurement": 200}
    assert rec.write_facts({"rig": "{}"}) and not rec.write_facts({"rig": "{}"})  # a latched message again
    facts = rec.design_facts("exp-1", {"kind": "multisine"})
    assert facts == {"excitation": {"exp-1": {"kind": "multisine"}}}
    rec.close()
    assert rec.figures()["state"] == "done" and rec.figures()["messages"] == 2
    assert len(list(iter_messages(rec.path))) == 2 and "ambid.session" in read_metadata(rec.path)


def test_bridge_commands_wait_for_announcements_resend_and_give_up():
    from ambid.hardware import bridge_protocol as bp
    from ambid.hardware.bridge_link import CommandQueue

    q = CommandQueue(retry_s=0.1, retries=2)
    exp = q.queue(bp.CommandCode.EXPERIMENT, 100, 50, 1)
    start = q.queue(bp.CommandCode.START)
    send, failed = q.due(0.0)
    assert [cid for cid, _ in send] == [exp] and not failed  # START waits for the announcement's ACK
    assert q.due(0.05) == ([], [])  # not yet due again
    assert q.acknowledged(exp).args == (100, 50, 1) and q.acknowledged(exp) is None
    assert [cid for cid, _ in q.due(0.06)[0]] == [start]
    assert [cid for cid, _ in q.due(0.2)[0]] == [start]  # again: no ACK
    send, failed = q.due(0.4)
    assert not send and [c.code for c in failed] == [bp.CommandCode.START] and not q.pending


def test_bridge_excitation_chunks_are_held_until_applied_and_resent_where_missing():
    from ambid.hardware.bridge_link import ExcitationChunks

    c = ExcitationChunks(chunk=40)
    assert c.add(1000, np.ones((100, 4))) == [1000, 1040, 1080] and c.length(1080) == 20
    for first in c.firsts:
        assert not c.sent(first, now=0.0)[1]
    assert c.to_resend(1045, now=0.05, min_age_s=0.1) == []  # just sent
    assert c.to_resend(1045, now=0.5, min_age_s=0.1) == [1040, 1080]
    assert c.sent(1040, now=0.5)[1]  # a re-send
    c.applied(1080)
    assert c.firsts == [1080]


def test_bridge_flag_runs_are_reported_once_when_they_end():
    from ambid.hardware.bridge_link import FlagRuns

    runs = FlagRuns()
    assert runs.feed(0, np.array([0, 1, 1, 0, 1], bool), bit=8) == [(1, 3)]
    assert runs.feed(5, np.array([1, 1, 0], bool), bit=8) == [(4, 7)]  # a run across two blocks, once
    assert runs.feed(8, np.array([1], bool), bit=8) == [] and runs.close(8, 10) == (8, 10)
    assert runs.close(8, 11) is None
