"""Modes, state-space realisation and export of fitted models (ambid.fit.modes, ambid.fit.export)."""

import json

import numpy as np
import pytest
from ambid.fit import (RationalModel, load_model_json, load_model_npz, load_statespace_json, load_statespace_npz,
                       modal_summary, save_model_json, save_model_npz, to_statespace)

F_HZ = np.linspace(1.0, 400.0, 300)


def pair(freq_hz, zeta):
    wn = 2 * np.pi * freq_hz
    return complex(-zeta * wn, wn * np.sqrt(1 - zeta**2))


def make_model(delay_s=0.0):
    """3 outputs x 2 inputs: a rank-1 mode, a rank-2 mode, an unstable and a stable real pole."""
    rng = np.random.default_rng(4)
    u1 = np.array([1.0, 0.5j, -0.3])
    v1 = np.array([2.0, 1.0 - 1.0j])
    r1 = 300.0 * np.outer(u1, v1)
    r2 = 80.0 * (rng.standard_normal((3, 2)) + 1j * rng.standard_normal((3, 2)))
    r3 = 50.0 * np.outer([1.0, -1.0, 0.2], [1.0, 0.5])
    r4 = 400.0 * rng.standard_normal((3, 2))
    p1, p2 = pair(50.0, 0.02), pair(120.0, 0.05)
    poles = np.array([p1, np.conj(p1), p2, np.conj(p2), 30.0, -500.0])
    res = np.stack([r1, r1.conj(), r2, r2.conj(), r3, r4])
    return RationalModel(poles, res, 1e-3 * rng.standard_normal((3, 2)), delay_s=delay_s,
                         input_names=("i_a", "i_b"), output_names=("x_a", "x_b", "x_c"),
                         input_units=("A", "A"), output_units=("m", "m", "m")), u1, v1


def direct_frf(model, f):
    s = 2j * np.pi * f
    g = np.zeros((f.size,) + model.feedthrough.shape, dtype=complex) + model.feedthrough
    for p, r in zip(model.poles, model.residues):
        g += r[None] / (s[:, None, None] - p)
    return g * np.exp(-s * model.delay_s)[:, None, None]


def test_freqresp_is_the_partial_fraction_sum():
    model, _, _ = make_model(delay_s=1e-3)
    np.testing.assert_allclose(model.freqresp(F_HZ), direct_frf(model, F_HZ), rtol=1e-13)
    # d(s) has the poles as roots
    np.testing.assert_allclose(np.polyval(model.denominator(), model.poles) / np.abs(model.poles) ** 6, 0,
                               atol=1e-9)


def test_modal_summary_frequencies_damping_shapes():
    model, u1, v1 = make_model()
    summary = modal_summary(model)
    assert [m.freq_hz for m in summary.modes] == pytest.approx([50.0, 120.0], rel=1e-12)
    assert [m.damping for m in summary.modes] == pytest.approx([0.02, 0.05], rel=1e-10)
    first = summary.modes[0]
    assert first.damped_freq_hz == pytest.approx(50.0 * np.sqrt(1 - 0.02**2), rel=1e-12)
    # rank-1 residue: the shapes are u1 and v1 up to scale and phase, and reproduce R
    assert abs(np.vdot(first.output_shape, u1)) / np.linalg.norm(u1) == pytest.approx(1.0, rel=1e-12)
    sv = first.residue_singular_values
    assert sv[1] < 1e-12 * sv[0]
    np.testing.assert_allclose(sv[0] * np.outer(first.output_shape, first.input_shape), model.residues[0],
                               atol=1e-12 * sv[0])
    assert first.output_shape[np.argmax(np.abs(first.output_shape))].imag == 0
    # the rank-2 mode is flagged by its second singular value
    assert summary.modes[1].residue_singular_values[1] > 0.1 * summary.modes[1].residue_singular_values[0]
    reals = summary.real_poles
    assert [r.pole_rad_s for r in reals] == [-500.0, 30.0]
    assert [r.unstable for r in reals] == [False, True]
    assert reals[1].corner_freq_hz == pytest.approx(30.0 / (2 * np.pi))
    json.dumps(summary.to_dict())  # JSON-safe


def test_statespace_realisation_has_the_model_frf_and_poles():
    model, _, _ = make_model()
    ss = to_statespace(model)
    # Gilbert: rank(R_k) states per pole: 2*1 + 2*2 + 1 + 2
    assert ss.n_states == 9
    np.testing.assert_allclose(ss.freqresp(F_HZ), model.freqresp(F_HZ), rtol=1e-12, atol=1e-15)
    expected = np.concatenate([np.repeat(model.poles[:2], 1), np.repeat(model.poles[2:4], 2), [30.0],
                               [-500.0, -500.0]])
    np.testing.assert_allclose(np.sort_complex(ss.poles()), np.sort_complex(expected), rtol=1e-12)
    assert ss.unstable_poles().size == 1 and ss.dt == 0
    assert ss.input_names == ("i_a", "i_b") and ss.output_units == ("m", "m", "m")
    # a loose rank tolerance drops the weak directions: fewer states, FRF only approximate
    small = to_statespace(model, rank_tol=0.5)
    assert small.n_states < ss.n_states
    with pytest.raises(ValueError, match="rank_tol"):
        to_statespace(model, rank_tol=2.0)


def test_npz_and_json_round_trip_give_identical_frf(tmp_path):
    model, _, _ = make_model(delay_s=2e-4)
    g = model.freqresp(F_HZ)
    save_model_npz(tmp_path / "m.npz", model)
    save_model_json(tmp_path / "m.json", model)
    for loaded in (load_model_npz(tmp_path / "m.npz"), load_model_json(tmp_path / "m.json")):
        assert np.array_equal(loaded.freqresp(F_HZ), g)
        assert loaded.delay_s == model.delay_s
        assert loaded.output_names == model.output_names and loaded.input_units == model.input_units
    ss = to_statespace(model)
    for loaded_ss in (load_statespace_npz(tmp_path / "m.npz"), load_statespace_json(tmp_path / "m.json")):
        assert np.array_equal(loaded_ss.freqresp(F_HZ), ss.freqresp(F_HZ))
    doc = json.loads((tmp_path / "m.json").read_text())
    assert [m["freq_hz"] for m in doc["modes"]["modes"]] == pytest.approx([50.0, 120.0])


def test_loading_a_foreign_file_fails_clearly(tmp_path):
    (tmp_path / "x.json").write_text(json.dumps({"format": "something/else"}))
    with pytest.raises(ValueError, match="format"):
        load_model_json(tmp_path / "x.json")
    np.savez(tmp_path / "x.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="meta"):
        load_model_npz(tmp_path / "x.npz")


def test_rational_model_validation():
    with pytest.raises(ValueError, match="conjugation"):
        RationalModel(np.array([1 + 1j, -2.0]), np.ones((2, 1, 1)), np.zeros((1, 1)))
    with pytest.raises(ValueError, match="residues"):
        RationalModel(np.array([-1.0]), np.ones((2, 1, 1)), np.zeros((1, 1)))
    with pytest.raises(ValueError, match="delay_s"):
        RationalModel(np.array([-1.0]), np.ones((1, 1, 1)), np.zeros((1, 1)), delay_s=-1.0)
    with pytest.raises(ValueError, match="input_names"):
        RationalModel(np.array([-1.0]), np.ones((1, 1, 1)), np.zeros((1, 1)), input_names=("a", "b"))
