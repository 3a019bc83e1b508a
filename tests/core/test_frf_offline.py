"""Offline FRF (ambid.frf.offline): user arrays, files and recorded MCAP sessions.

Every path must give exactly (bit for bit) what the streaming estimator -- the
one the frf_consumer node runs -- gives on the same samples.
"""

import json
import struct

import ambid.frf.offline as offline
import ambid.recording.blocks as blocks
import numpy as np
import pytest
from ambid.excitation import design_multisine
from ambid.frf.offline import frf_from_arrays, frf_from_files, frf_from_session, session_designs
from ambid.frf.streaming import FrfStream
from ambid.recording import iter_decoded
from ambid.recording.blocks import SampleBlockReader
from frf_testbench import FS, loop_model, simulate
from scipy.io import savemat
from session_testbench import SAMPLE_BLOCK, block_message, design_message, encoder, write_session

OUT, IN, REF = ("y_1", "y_2"), ("u_1", "u_2"), ("r_1", "r_2")
CHANNELS = OUT + IN + ("ic_1", "ic_2") + REF         # as a plant would record them (ic unused)
PRE = 300
KW = dict(outputs=OUT, inputs=IN, references=REF)


@pytest.fixture(scope="module")
def rec():
    d = design_multisine((20.0, 600.0), 20.0, FS, IN, 0.3, n_periods=2, n_realisations=2,
                         n_transient_periods=1, seed=9)
    r = np.zeros((PRE + d.total_samples + 200, 2))
    r[PRE:PRE + d.total_samples] = d.samples(0, d.total_samples)
    y, u = simulate(loop_model(), r[None], 1e-7, seed=2)
    x = np.hstack([y[0], u[0], r - u[0], r])          # ic = u - r
    data = {n: x[:, i].copy() for i, n in enumerate(CHANNELS)}
    return dict(design=d, x=x, data=data)


def _equal(a, b):
    for k in ("freq_hz", "frf", "var_noise", "var_total", "coherence", "sensitivity", "noise_std",
              "sensitivity_peak", "sensitivity_peak_hz"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    assert (a.distortion is None) == (b.distortion is None)
    if a.distortion is not None:
        np.testing.assert_array_equal(a.distortion.odd_db, b.distortion.odd_db)
    assert (a.iso_zone, a.n_periods, a.n_realisations, a.gaps) == (b.iso_zone, b.n_periods,
                                                                   b.n_realisations, b.gaps)


def _streamed(rec, blocks, total=None, start=PRE):
    s = FrfStream(rec["design"], OUT, IN, REF, start_index=start, total_samples=total)
    cols = s.columns(CHANNELS)
    for first, data in blocks:
        s.add(first, data[:, cols])
    return s.estimate()


def _blocks(x, size, drop=()):
    return [(k, x[k:k + size]) for k in range(0, len(x), size) if k // size not in drop]


def test_arrays_give_the_streaming_result(rec):
    res = frf_from_arrays(rec["data"], rec["design"], start_row=PRE, **KW)
    _equal(res, _streamed(rec, _blocks(rec["x"], 1000)))
    assert res.complete and res.n_realisations == 2 and res.estimator == "indirect"
    h1 = frf_from_arrays(rec["data"], rec["design"], estimator="h1", start_row=PRE, **KW)
    assert not np.array_equal(h1.frf, res.frf)


def test_files_and_design_json(rec, tmp_path):
    design_file = tmp_path / "design.json"
    design_file.write_text(json.dumps(rec["design"].to_dict()))
    ref = frf_from_arrays(rec["data"], rec["design"], start_row=PRE, **KW)
    np.savez(tmp_path / "run.npz", **rec["data"])
    savemat(tmp_path / "run.mat", rec["data"])
    np.savetxt(tmp_path / "run.csv", rec["x"], delimiter=",", header=",".join(CHANNELS), comments="",
               fmt="%.17g")
    for name in ("run.npz", "run.mat", "run.csv"):
        _equal(frf_from_files(tmp_path / name, design_file, start_row=PRE, **KW), ref)
    with pytest.raises(ValueError, match="missing channel"):
        frf_from_arrays({k: v for k, v in rec["data"].items() if k != "r_2"}, design_file,
                        start_row=PRE, **KW)
    with pytest.raises(FileNotFoundError, match="no design file"):
        frf_from_arrays(rec["data"], tmp_path / "nope.json", **KW)
    short = {k: v[:PRE + rec["design"].segment_start(1, 0) - 1] for k, v in rec["data"].items()}
    with pytest.raises(ValueError, match="no complete realisation"):
        frf_from_arrays(short, rec["design"], start_row=PRE, **KW)


def _write_session(path, rec, blocks, designs):
    """designs: [(log_time_ns, total_samples)] of ExcitationDesign messages for one experiment."""
    write_session(path, blocks, CHANNELS, [(t_ns, design_message(rec["design"], PRE, total))
                                           for t_ns, total in designs], 1 / FS)


def test_session_gives_the_streaming_result_with_its_gap(rec, tmp_path):
    blocks = _blocks(rec["x"], 1000, drop={3})           # one lost measurement block
    path = tmp_path / "session.mcap"
    _write_session(path, rec, blocks, [(0, rec["design"].total_samples)])
    # the fast block reader agrees with the generic CDR decoder
    for (msg, dec), (first, data) in zip(iter_decoded(path, "/amb/measurement"), blocks):
        f, dt, names, arr = SampleBlockReader()(msg.data)
        assert (f, dt, names) == (dec.first_index, dec.sample_period, list(dec.channel_names))
        np.testing.assert_array_equal(arr, np.reshape(dec.data, (dec.n_samples, -1)))
        np.testing.assert_array_equal(arr, data)
    res = frf_from_session(path, **KW)
    _equal(res, _streamed(rec, blocks))
    assert len(res.gaps) == 1 and res.gaps[0].start_index == 3000 and res.gaps[0].n_samples == 1000
    # samples 3000..3999 hold the end of (m=0, e=1, p=1) and the start of (m=1, e=0, p=0)
    assert res.gaps[0].periods == ((0, 1, 1), (1, 0, 0)) and res.n_periods == 2
    with pytest.raises(ValueError, match="no experiment 'exp2'"):
        frf_from_session(path, experiment_id="exp2", **KW)


def test_session_of_an_experiment_stopped_early(rec, tmp_path):
    d = rec["design"]
    blocks = _blocks(rec["x"], 1000)
    cut = d.segment_start(1, 0) + 10                     # stopped early in realisation 1
    path = tmp_path / "stopped.mcap"
    _write_session(path, rec, blocks, [(0, d.total_samples), (int(0.5e9), cut)])
    res = frf_from_session(path, recover=True, **KW)     # also read front to back
    _equal(res, _streamed(rec, blocks, total=cut))
    assert res.n_realisations == 1 and res.complete


def _second_passes(monkeypatch):
    """Count the re-reads of a session's blocks (frf_from_session reads once unless it must)."""
    calls = []
    original = offline._session_blocks

    def counted(*args, **kwargs):
        calls.append(args[1])
        return original(*args, **kwargs)

    monkeypatch.setattr(offline, "_session_blocks", counted)
    return calls


@pytest.mark.parametrize("case", ["stop_before_the_cut", "stop_after_the_cut", "late_design", "two_experiments"])
def test_one_pass_or_a_second_read_give_the_same_result(rec, tmp_path, monkeypatch, case):
    """The single pass follows the experiment while reading; where it cannot be exact it re-reads.

    Either way the result is the stream of the final design message fed every block.
    """
    d, x = rec["design"], rec["x"]
    blocks = _blocks(x, 1000)
    cut = d.segment_start(1, 0) + 10                     # stopped early in realisation 1
    t_ns = lambda index: int(index / FS * 1e9)           # noqa: E731 - blocks are logged at first / FS + 1 ns
    full = design_message(d, PRE)
    if case == "stop_before_the_cut":                    # republished before any block reaches the cut
        designs, expect, passes = [(0, full), (t_ns(3000), design_message(d, PRE, cut))], cut, 1
    elif case == "stop_after_the_cut":                   # blocks beyond the cut came before the stop
        designs, expect, passes = [(0, full), (t_ns(4000), design_message(d, PRE, cut))], cut, 2
    elif case == "late_design":                          # the design after blocks of its experiment
        designs, expect, passes = [(t_ns(2000), full)], None, 2
    else:                                                # the last experiment is another one, started late
        other = design_message(d, PRE, experiment_id="exp2")
        designs, expect, passes = [(0, full), (t_ns(1000), other)], None, 2
    path = tmp_path / f"{case}.mcap"
    write_session(path, blocks, CHANNELS, designs, 1 / FS)
    calls = _second_passes(monkeypatch)
    res = frf_from_session(path, **KW)
    _equal(res, _streamed(rec, blocks, total=expect))
    assert 1 + len(calls) == passes and all(t == "/amb/measurement" for t in calls)
    if case == "two_experiments":                        # the one the pass followed when asked for
        first = frf_from_session(path, experiment_id="exp1", **KW)
        _equal(first, res)
        assert 1 + len(calls) == passes
        assert [e["experiment_id"] for e in session_designs(path)] == ["exp1", "exp2"]
    if case == "stop_before_the_cut":
        _equal(frf_from_session(path, recover=True, **KW), res)   # front to back, also one pass
        assert 1 + len(calls) == passes


def test_blocks_of_other_namespaces_and_bad_blocks_are_left_alone(rec, tmp_path):
    """Only the chosen experiment's measurement topic is estimated; an unreadable block elsewhere is not fatal,
    one on that topic is reported."""
    d, x = rec["design"], rec["x"]
    blocks = _blocks(x, 1000)
    path = tmp_path / "two_namespaces.mcap"
    from ambid.recording import SessionWriter
    from session_testbench import DEFS, EXCITATION_DESIGN

    def block_bytes(first, data):
        return encoder(SAMPLE_BLOCK)(block_message(first, data, CHANNELS, 1 / FS))

    with SessionWriter(path, compression="zstd", chunk_size_bytes=100_000) as w:
        for topic, type_name in (("/amb/excitation/design", EXCITATION_DESIGN), ("/amb/measurement", SAMPLE_BLOCK),
                                 ("/other/measurement", SAMPLE_BLOCK)):
            w.add_topic(topic, type_name, definition=DEFS, type_hash="")
        w.write("/amb/excitation/design", encoder(EXCITATION_DESIGN)(design_message(d, PRE)), 0)
        w.write("/other/measurement", b"\x00\x01\x00\x00\x01", 1)         # not a SampleBlock
        for first, data in blocks:
            w.write("/amb/measurement", block_bytes(first, data), int(first / FS * 1e9) + 2)
            w.write("/other/measurement", block_bytes(first, 2 * data), int(first / FS * 1e9) + 2)
    _equal(frf_from_session(path, **KW), _streamed(rec, blocks))
    # a truncated block on the experiment's own topic: the error of the block reader
    broken = tmp_path / "broken.mcap"
    with SessionWriter(broken, compression="none") as w:
        w.add_topic("/amb/excitation/design", EXCITATION_DESIGN, definition=DEFS, type_hash="")
        w.add_topic("/amb/measurement", SAMPLE_BLOCK, definition=DEFS, type_hash="")
        w.write("/amb/excitation/design", encoder(EXCITATION_DESIGN)(design_message(d, PRE)), 0)
        for k, (first, data) in enumerate(blocks):
            payload = block_bytes(first, data)
            w.write("/amb/measurement", payload[:-800] if k == 2 else payload, int(first / FS * 1e9) + 1)
    with pytest.raises(ValueError, match="SampleBlock: 8000 values"):
        frf_from_session(broken, **KW)


def test_block_reader_reuses_the_layout_only_when_it_is_the_same(rec, monkeypatch):
    """Blocks of one topic share their channel layout, but serialisers leave the alignment padding
    uninitialised: the layout is reused across other padding bytes, parsed anew for other names."""
    x = rec["x"]
    enc = encoder(SAMPLE_BLOCK)
    first = enc(block_message(0, x[:500], CHANNELS, 1 / FS))
    body = memoryview(first)[4:]
    at = 12 + struct.unpack_from("<I", body, 8)[0]
    at += -at % 8 + 16                                           # n_samples, after first_index, sample_period
    (_, _, _, data_at), spans = blocks._sample_block_layout(body, at)
    padding = sorted(set(range(at, data_at)) - {i for a, b in spans for i in range(a, b)})
    assert padding                                               # 'y_1' etc.: 3 padding bytes after each
    noisy = bytearray(enc(block_message(500, x[500:1000], CHANNELS, 1 / FS)))
    for i in padding:
        noisy[4 + i] = 0xA5
    renamed = [n.replace("_1", "_9") for n in CHANNELS]          # same lengths, other bytes
    other = enc(block_message(1000, x[1000:1500], renamed, 1 / FS))
    parses = []
    original = blocks._sample_block_layout
    monkeypatch.setattr(blocks, "_sample_block_layout", lambda *a: parses.append(1) or original(*a))
    read = SampleBlockReader()
    for buf, names, n_parses in ((first, CHANNELS, 1), (bytes(noisy), CHANNELS, 1), (other, renamed, 2),
                                 (first, CHANNELS, 3)):
        f, dt, got_names, data = read(buf)
        assert got_names == list(names) and len(parses) == n_parses and dt == 1 / FS
        np.testing.assert_array_equal(data, x[f:f + 500])
