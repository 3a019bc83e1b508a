"""Measurement-time planner and design preview."""

import math

import numpy as np
from ambid.excitation import (describe, design_multisine, design_stepped_sine, format_plan, plan_measurements,
                              plot_design)

NAMES = ("x_a", "y_a", "x_b", "y_b")


def test_planned_times_equal_generated_record_lengths(capsys):
    fs, res, band = 1000.0, 5.0, (5.0, 100.0)
    rows = plan_measurements(band, res, fs, NAMES, 1.0, n_periods=3, n_transient_periods=1,
                             settle_s=0.05, n_cycles=5)
    with capsys.disabled():
        print("\n" + format_plan(rows))
    assert [r.name for r in rows][0] == "stepped sine"
    for r in rows:
        record = sum(blk.shape[0] for _, blk in r.design.blocks(1000))  # stream it all
        assert r.measurement_time_s == record / fs
        assert r.total_samples == record
    n = int(fs / res)
    by_name = {r.name: r for r in rows}
    ortho = by_name["orthogonal multisine"]
    # multisine: Nu experiments x (Pt + P) periods of N samples, by hand
    assert ortho.measurement_time_s == 4 * (1 + 3) * n / fs
    assert by_name["multisine, one input at a time"].measurement_time_s == ortho.measurement_time_s
    assert ortho.excited_share == 1.0
    assert by_name["multisine, one input at a time"].excited_share == 0.25
    # stepped sine on the multisine's lines: per line and input, a settle part of
    # whole periods >= 50 ms and >= 5 measured cycles, the period being
    # N / gcd(N, k) samples; computed here from that definition
    stepped = by_name["stepped sine"]
    assert np.array_equal(stepped.design.excited_lines, ortho.design.excited_lines)
    expected = 0
    for k in ortho.design.excited_lines:
        p = n // math.gcd(n, int(k))
        cycles = k * p // n
        expected += 4 * p * (math.ceil(0.05 * fs / p) + math.ceil(5 / cycles))
    assert stepped.total_samples == expected
    assert stepped.measurement_time_s > 3 * ortho.measurement_time_s


def test_plot_design_writes_png(tmp_path):
    d = design_multisine((2.0, 80.0), 1.0, 400.0, NAMES[:2], [1.0, 0.5], seed=1)
    path = plot_design(d, tmp_path / "ms.png")
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    s = design_stepped_sine((2.0, 40.0), 2.0, 400.0, NAMES[:2], 1.0, settle_s=0.01)
    assert plot_design(s, tmp_path / "sub" / "ss.png").stat().st_size > 10_000


def test_describe_has_the_numbers():
    d = design_multisine((2.0, 80.0), 1.0, 400.0, NAMES[:2], [1.0, 0.5], n_periods=3, seed=1)
    text = describe(d)
    assert f"{d.excited_lines.size} excited lines" in text
    assert "N = 400" in text and "resolution 1 Hz" in text
    assert f"crest factor {d.crest_factor[0]:.3f}" in text
    assert "peak 0.5 A" in text and f"RMS {d.rms_a[1]:.4g} A" in text
    assert f"measurement time {d.measurement_time_s:.6g} s" in text
    assert f"{d.detection_lines_odd.size} odd, {d.detection_lines_even.size} even" in text
