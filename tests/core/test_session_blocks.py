"""ambid.recording.blocks: hand-written SampleBlock CDR reader against mcap_ros2's encoder and decoder."""

import sys
import time
from pathlib import Path

import numpy as np
import pytest
from ambid.recording import SessionWriter, inspect_session, iter_messages
from ambid.recording.blocks import (SAMPLE_BLOCK_TYPE, block_spans, decode_sample_block, encode_sample_block,
                                  iter_sample_blocks, read_samples, sample_block_session, sample_block_span,
                                  sample_block_topics, sample_index_report)
from mcap_ros2._dynamic import serialize_dynamic

ROOT = Path(__file__).resolve().parents[2]
SEP = "=" * 80
MSG_TEXT = (ROOT / "ambid_msgs" / "msg" / "SampleBlock.msg").read_text()
DEFINITION = (
    MSG_TEXT
    + f"\n{SEP}\nMSG: builtin_interfaces/Time\n"
    + (Path(sys.prefix) / "share" / "builtin_interfaces" / "msg" / "Time.msg").read_text()
)
ENCODE = serialize_dynamic(SAMPLE_BLOCK_TYPE, DEFINITION)[SAMPLE_BLOCK_TYPE]
# the layout before sessions had ids: the same fields without the last one
OLD_ENCODE = serialize_dynamic(SAMPLE_BLOCK_TYPE, DEFINITION.replace(
    next(line for line in MSG_TEXT.splitlines() if line.startswith("uint64 session_id")) + "\n", ""))[SAMPLE_BLOCK_TYPE]
NAMES = ["y_a_x", "y_b_x", "u_a_x"]


def _fields(first, data, experiment_id="", flags=None, stamp=(0, 0), names=NAMES, session_id=0):
    data = np.asarray(data, dtype=float)
    return {
        "stamp": {"sec": stamp[0], "nanosec": stamp[1]}, "experiment_id": experiment_id,
        "first_index": first, "sample_period": 1e-4, "n_samples": data.shape[0],
        "channel_names": list(names), "channel_units": ["m"] * len(names),
        "data": data.ravel().tolist(), "sample_flags": [] if flags is None else list(flags),
        "flags": 0 if flags is None else int(np.bitwise_or.reduce(flags)), "session_id": session_id,
    }


def block(first, data, experiment_id="", flags=None, stamp=(0, 0), names=NAMES, session_id=0):
    return ENCODE(_fields(first, data, experiment_id, flags, stamp, names, session_id))


@pytest.mark.parametrize("experiment_id", ["", "e", "exp", "abcd", "experiment-7"])
@pytest.mark.parametrize("with_flags", [False, True])
def test_decode_matches_what_mcap_ros2_encoded(experiment_id, with_flags):
    rng = np.random.default_rng(len(experiment_id))
    data = rng.normal(size=(7, 3))
    flags = rng.integers(0, 8, size=7).astype(np.uint8) if with_flags else None
    cdr = block(2**40 + 5, data, experiment_id, flags, stamp=(12, 345))
    out = decode_sample_block(cdr)
    assert out.first_index == 2**40 + 5 and out.experiment_id == experiment_id
    assert out.stamp_ns == 12_000_000_345 and out.sample_period_s == 1e-4
    assert out.channel_names == tuple(NAMES) and out.channel_units == ("m", "m", "m")
    assert out.n_samples == 7 and np.array_equal(out.data, data)
    assert np.array_equal(out.sample_flags, flags if with_flags else np.zeros(0, np.uint8))
    assert out.flags == (int(np.bitwise_or.reduce(flags)) if with_flags else 0)
    assert sample_block_span(cdr) == (2**40 + 5, 7)


@pytest.mark.parametrize("session_id", [0, 1, 0x3FA9C01B, 2**64 - 1])
@pytest.mark.parametrize("with_flags", [False, True])
@pytest.mark.parametrize("experiment_id", ["", "exp"])
def test_the_session_id_ends_every_block_as_mcap_ros2_writes_it(session_id, with_flags, experiment_id):
    data = np.arange(21.0).reshape(7, 3)
    flags = np.arange(7, dtype=np.uint8) if with_flags else None
    theirs = block(40, data, experiment_id, flags, session_id=session_id)
    # 8-aligned and last: the message is 4 + 8n bytes, its last 8 the id
    assert (len(theirs) - 4) % 8 == 0 and int.from_bytes(theirs[-8:], "little") == session_id
    assert decode_sample_block(theirs).session_id == session_id == sample_block_session(theirs)
    mine = encode_sample_block(40, 1e-4, NAMES, ["m"] * 3, data, experiment_id, session_id=session_id)
    assert (mine == theirs or with_flags) and decode_sample_block(mine).session_id == session_id  # (rows flags: none)
    # a block recorded before sessions had ids ends after its flags: no session
    old = OLD_ENCODE({k: v for k, v in _fields(40, data, experiment_id, flags).items() if k != "session_id"})
    assert decode_sample_block(old).session_id == 0 == sample_block_session(old)
    assert decode_sample_block(old).first_index == 40 and np.array_equal(decode_sample_block(old).data, data)
    with pytest.raises(ValueError, match="truncated"):
        sample_block_session(theirs[:30])


@pytest.mark.parametrize("experiment_id", ["", "e", "exp", "abcd"])
def test_an_empty_block_has_no_padding_before_its_missing_values(experiment_id):
    for names in (NAMES, NAMES[:1], []):
        cdr = block(9, np.zeros((0, len(names))), experiment_id, flags=np.zeros(0, np.uint8), names=names)
        out = decode_sample_block(cdr)
        assert out.data.shape == (0, len(names)) and out.channel_names == tuple(names)
        assert out.first_index == 9 and out.sample_flags.shape == (0,)


def test_bad_bytes_are_rejected_with_the_reason():
    cdr = block(0, np.ones((4, 3)))
    with pytest.raises(ValueError, match="truncated|claims"):
        decode_sample_block(cdr[:-20])
    with pytest.raises(ValueError, match="little-endian"):
        decode_sample_block(b"\x00\x00" + cdr[2:])
    with pytest.raises(ValueError, match="too short"):
        sample_block_span(b"\x00")
    wrong = ENCODE({"session_id": 0, "first_index": 3, "n_samples": 5, "channel_names": NAMES, "data": [1.0] * 12,
                    "stamp": {"sec": 0, "nanosec": 0}, "experiment_id": "", "sample_period": 1.0,
                    "channel_units": [], "sample_flags": [], "flags": 0})
    with pytest.raises(ValueError, match="12 values, expected n_samples x channels = 5 x 3"):
        decode_sample_block(wrong)


def write_session(path, blocks, names=NAMES, **kw):
    with SessionWriter(path, **kw) as w:
        w.add_topic("/amb/measurement", SAMPLE_BLOCK_TYPE, definition={SAMPLE_BLOCK_TYPE: MSG_TEXT},
                    type_hash="")
        w.add_topic("/amb/excitation", SAMPLE_BLOCK_TYPE, definition={SAMPLE_BLOCK_TYPE: MSG_TEXT},
                    type_hash="")
        for i, (topic, first, data) in enumerate(blocks):
            w.write(topic, block(first, data, names=names), 1_000_000 * (i + 1))


@pytest.fixture
def ament(monkeypatch):
    monkeypatch.setenv("AMENT_PREFIX_PATH", sys.prefix)


def test_gap_report_agrees_with_inspect_session_decoding_every_block(tmp_path, ament):
    rng = np.random.default_rng(1)
    # measurement: 0..99, 100..149, gap of 50, 200..299, overlap 250..259; excitation contiguous
    layout = [("/amb/measurement", 0, 100), ("/amb/excitation", 0, 40), ("/amb/measurement", 100, 50),
              ("/amb/measurement", 200, 100), ("/amb/excitation", 40, 40), ("/amb/measurement", 250, 10)]
    blocks = [(t, f, rng.normal(size=(n, 3))) for t, f, n in layout]
    path = tmp_path / "s.mcap"
    write_session(path, blocks, chunk_size_bytes=4096)
    ref = inspect_session(path, sample_index={SAMPLE_BLOCK_TYPE: lambda m: (m.first_index, m.n_samples)})
    assert sample_block_topics(path) == ["/amb/excitation", "/amb/measurement"]
    fast = sample_index_report(path)
    assert fast == ref["sample_index"]
    meas = fast["/amb/measurement"]
    assert (meas["gap_count"], meas["missing_samples"], meas["overlapping_blocks"], meas["overlapping_samples"]) \
        == (1, 50, 1, 10)
    assert block_spans(path, ["/amb/excitation"])["/amb/excitation"] == [(2_000_000, 0, 40), (5_000_000, 40, 40)]


def test_read_samples_assembles_a_range_across_blocks_and_marks_gaps(tmp_path, ament):
    rng = np.random.default_rng(2)
    parts = [(0, rng.normal(size=(100, 3))), (100, rng.normal(size=(100, 3))), (300, rng.normal(size=(100, 3)))]
    path = tmp_path / "s.mcap"
    write_session(path, [("/amb/measurement", f, d) for f, d in parts], chunk_size_bytes=8192)
    full = np.full((400, 3), np.nan)
    for first, d in parts:
        full[first : first + 100] = d
    out = read_samples(path, "/amb/measurement", 50, 350, channels=["u_a_x", "y_a_x"])
    assert out.first_index == 50 and out.channel_names == ("u_a_x", "y_a_x") and out.sample_period_s == 1e-4
    assert np.array_equal(out.present, ~np.isnan(full[50:350, 0]))
    assert np.array_equal(out.data, full[50:350][:, [2, 0]], equal_nan=True)
    assert not out.present[150:250].any() and out.present[250:].all()
    with pytest.raises(ValueError, match="not in the blocks"):
        read_samples(path, "/amb/measurement", 0, 10, channels=["nope"])
    with pytest.raises(ValueError, match="start_index < stop_index"):
        read_samples(path, "/amb/measurement", 10, 10)
    blocks = list(iter_sample_blocks(path, "/amb/measurement"))
    assert [b.first_index for _, b in blocks] == [0, 100, 300]
    assert all(np.array_equal(b.data, d) for (_, b), (_, d) in zip(blocks, parts))


def test_reading_blocks_costs_little_beyond_reading_the_file(tmp_path, ament):
    # 1000 x 16 blocks as the plant publishes them (y, u, ic, r), in 1 MiB zstd chunks
    rng = np.random.default_rng(3)
    path = tmp_path / "big.mcap"
    n_blocks = 40
    names = [f"c{i}" for i in range(16)]
    write_session(path, [("/amb/measurement", 1000 * k, np.round(rng.normal(size=(1000, 16)), 6))
                         for k in range(n_blocks)], names=names, chunk_size_bytes=1 << 20)

    def bare():
        return sum(len(m.data) for m in iter_messages(path, "/amb/measurement"))

    def decoded():
        return sum(float(b.data[-1, 0]) * 0 + b.n_samples for _, b in iter_sample_blocks(path, "/amb/measurement"))

    best = {}
    for fn in (bare, decoded) * 3:  # interleaved, best of three: the box is shared
        t = time.perf_counter()
        fn()
        best[fn.__name__] = min(best.get(fn.__name__, np.inf), time.perf_counter() - t)
    ratio = best["bare"] / best["decoded"]
    print(f"\n{n_blocks} blocks: bare read {n_blocks / best['bare']:.0f} blocks/s, with decoding "
          f"{n_blocks / best['decoded']:.0f} blocks/s ({100 * ratio:.0f} % of the bare rate)")
    assert ratio >= 0.5
