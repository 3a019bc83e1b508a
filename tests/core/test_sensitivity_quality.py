"""Where the excitation entered the loop decides which sensitivity the lines show (a closed loop computed here,
independently of ambid's estimators); what spoils a record is found and said in one line each."""

from __future__ import annotations

import numpy as np

from ambid.frf.quality import record_quality
from ambid.frf.sensitivity import sensitivity_shown


def _loop(f):
    """A levitated mass (negative stiffness) under a PD controller: G [m/A], K [A/m], u = r - K y at the current."""
    s = 2j * np.pi * f
    g = 200.0 / (5.0 * s ** 2 - 8e5)
    k = 1.2e4 * (1 + 1e-3 * s) / (1 + 1e-4 * s)
    return g, k


def test_each_injection_point_shows_its_own_sensitivity_or_says_why_not():
    f = np.linspace(5, 500, 200)
    g, k = _loop(f)
    s_true = 1 / (1 + g * k)
    G = g[:, None, None]
    # current: u = r - K y  ->  u / r = S
    shown = sensitivity_shown(G, s_true[:, None, None], ["y_x"], ["u_x"])
    assert shown[0].kind == "input" and np.allclose(shown[0].values, s_true)
    # reference: u = K (r - y)  ->  u / r = K S; the loop's sensitivity is 1 - y/r at the controller's own sensor
    s_ur = (k * s_true)[:, None, None]
    shown = sensitivity_shown(G, s_ur, ["y_x"], ["u_x"], {"r_x": "reference"}, ["m"], ["m"])
    assert shown[0].kind == "output" and np.allclose(shown[0].values, s_true)
    # output: the controller reads y + r  ->  u / r = -K S; S = 1 + y/r
    shown = sensitivity_shown(G, (-k * s_true)[:, None, None], ["y_x"], ["u_x"], {"r_x": "output"}, ["m"], ["m"])
    assert shown[0].kind == "output" and np.allclose(shown[0].values, s_true)
    # at the reference with accelerometers only: none, and one line saying why (u/r is K S, not S)
    acc = -(2 * np.pi * f) ** 2 * g
    shown = sensitivity_shown(np.stack([acc, 0.5 * acc], 1)[:, :, None], s_ur, ["y_acc1", "y_acc2"], ["u_x"],
                              {"r_x": "reference"}, ["m/s^2", "m/s^2"], ["V"])
    assert shown[0].values is None and shown[0].kind == ""
    assert "no sensitivity for r_x" in shown[0].why and "acc1 [m/s^2]" in shown[0].why and "\n" not in shown[0].why


def test_clipping_saturation_dropouts_and_thin_excitation_are_found_with_their_lines():
    rng = np.random.default_rng(3)
    fs, n = 1000.0, 4000
    t = np.arange(n) / fs
    lines = np.arange(5.0, 200.0, 5.0)
    amp = np.where(lines < 150, 1.0, 1e-3)        # the top of the band hardly excited
    r = sum(a * np.cos(2 * np.pi * fl * t + rng.uniform(0, 6.3)) for a, fl in zip(amp, lines))
    y = 0.5 * np.roll(r, 2) + 0.01 * rng.standard_normal(n)
    y_clip = np.clip(y, -0.6 * np.abs(y).max(), 0.5 * np.abs(y).max())
    u = np.clip(r, None, 0.7 * r.max())
    y2 = y.copy()
    y2[1200:1250] = y2[1200]                       # a dropout: 50 samples held
    data = np.column_stack([y_clip, y2, u, r])
    names = ["y_a", "y_b", "u_a", "r_a"]
    coh = np.ones((lines.size, 2))
    coh[lines > 150, 1] = 0.2
    found = record_quality(data, names, fs, lines, coh, ["y_a", "y_b"], ["r_a"], first_row=100)
    kinds = {(q.kind, q.channel) for q in found}
    assert ("clipping", "y_a") in kinds and ("saturation", "u_a") in kinds and ("dropout", "y_b") in kinds
    assert ("clipping", "y_b") not in kinds and ("dropout", "y_a") not in kinds
    low = next(q for q in found if q.kind == "low excitation")
    assert low.lines_hz.min() >= 150 and low.lines_hz.size == int(np.sum(lines >= 150)), low.text
    drop = next(q for q in found if q.kind == "dropout")
    assert "from row 1301" in drop.text                 # rows counted from the record's first, 1-based
    coh_line = next(q for q in found if q.kind == "low coherence")
    assert coh_line.channel == "y_b" and "155-195 Hz" in coh_line.text
    assert all("\n" not in q.text for q in found)
    # a clean record: nothing to say
    assert record_quality(np.column_stack([y, r]), ["y_a", "r_a"], fs, lines[lines < 150]) == []
