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


def test_a_record_excited_at_the_reference_shows_the_loops_sensitivity_at_its_own_sensor(tmp_path):
    """A levitated mass under a PD controller, simulated here (scipy only), excited by noise at the position
    reference: imported with ``injected_at: reference``, ambid reports the sensitivity 1 - y/r at the controller's
    own sensor, against 1 / (1 + G K) of the loop computed here; u / r (the controller times it) is not taken."""
    import yaml
    from scipy.signal import cont2discrete

    from ambid.frf.sensitivity import iso14839_zone
    from ambid.records.importer import import_record
    from ambid.identification import identify_session

    fs, n = 2000.0, 40000
    m, ks, ki, kp, kd = 5.0, 1.0e5, 50.0, 4000.0, 5.0
    a, b, c, _, _ = cont2discrete((np.array([[0, 1], [ks / m, 0]]), np.array([[0], [ki / m]]), np.eye(1, 2),
                                   np.zeros((1, 1))), 1 / fs)
    rng = np.random.default_rng(7)
    spec = np.zeros(n // 2 + 1, complex)
    band = (np.arange(spec.size) * fs / n >= 2) & (np.arange(spec.size) * fs / n <= 250)
    spec[band] = np.exp(2j * np.pi * rng.random(band.sum()))
    r = np.fft.irfft(spec, n)
    r *= 2e-5 / r.std()
    x, e_prev = np.zeros(2), 0.0
    y, u = np.empty(n), np.empty(n)
    for k in range(n):
        y[k] = (c @ x)[0] + 5e-8 * rng.standard_normal()
        e = r[k] - y[k]
        u[k] = kp * e + kd * (e - e_prev) * fs
        e_prev = e
        x = a @ x + b[:, 0] * u[k]
    np.savez(tmp_path / "rec.npz", y=y, u=u, r=r)
    (tmp_path / "MAP.yaml").write_text(yaml.safe_dump({
        "sample_rate_hz": fs, "outputs": {"y_x": {"column": "y", "unit": "m"}}, "currents": {"u_x": "u"},
        "excitation": {"r_x": {"column": "r", "unit": "m", "injected_at": "reference"}}, "band_hz": [5, 200]}))
    import_record(tmp_path / "rec.npz", tmp_path / "MAP.yaml", tmp_path / "s.mcap")
    sens = identify_session(tmp_path / "s.mcap", tmp_path / "fit", report=False)["sensitivity"]
    # the loop here: G(z) = c (zI - a)^-1 b, K(z) = kp + kd fs (1 - 1/z), S = 1 / (1 + G K)
    f = np.linspace(5, 200, 4000)
    z = np.exp(2j * np.pi * f / fs)
    g = np.array([(c @ np.linalg.solve(zz * np.eye(2) - a, b))[0, 0] for zz in z])
    s_true = np.abs(1 / (1 + g * (kp + kd * fs * (1 - 1 / z))))
    ch = sens["channels"][0]
    assert ch["injected_at"] == "reference" and ch["kind"] == "output" and sens["none"] == []
    assert abs(ch["peak"] / s_true.max() - 1) < 0.05 and abs(ch["peak_hz"] - f[s_true.argmax()]) < 4, (ch, s_true.max())
    assert sens["loop"]["iso_zone"] == iso14839_zone(float(s_true.max()))
