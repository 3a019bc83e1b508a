"""Rig parameters: eqs. 2.16-2.17 and 2.24 by hand, YAML validation, the generated doc."""

from pathlib import Path

import numpy as np
import pytest
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import RIG_FIELDS, load_rig, make_rig
from ambid.plant.rig_doc import rig_markdown

REPO = Path(__file__).resolve().parents[2]
MU0 = 4e-7 * np.pi


def test_ki_ks_from_eqs_2_16_2_17_by_hand():
    rig = make_rig()
    nc, aa, s0, ib, alpha = 200.0, 4.5e-4, 0.6e-3, 3.0, np.deg2rad(22.5)
    k = 0.25 * MU0 * nc**2 * aa  # eq. 2.12
    ki = 4 * k * ib * np.cos(alpha) / s0**2  # eq. 2.16 (with the cos(alpha) of eq. 2.15)
    ks = 4 * k * ib**2 * np.cos(alpha) / s0**3  # magnitude of eq. 2.17
    assert rig.magnet.ki == pytest.approx(ki, rel=1e-12)
    assert rig.magnet.ks == pytest.approx(ks, rel=1e-12)
    assert ki == pytest.approx(174.147, rel=1e-5) and ks == pytest.approx(870736, rel=1e-5)
    d = rig.derived()
    assert d["true_ki_n_per_a"] == pytest.approx(1.03 * ki, rel=1e-12)
    assert d["true_ks_n_per_m"] == pytest.approx(0.95 * ks, rel=1e-12)
    # The analytical model carries the nominal values: its DC bearing force per current is ki.
    model = analytical_model(rig)
    assert np.any(np.isclose(np.linalg.eigvals(model.a).real, -2 * np.pi * rig.current_loop_bandwidth_hz))


def test_amplifier_bandwidth_is_eq_2_24_with_the_coil_inductance():
    rig = make_rig({"dc_link_voltage_v": 400.0, "current_limit_a": 2.0})
    inductance = MU0 * 200.0**2 * 4.5e-4 / (2 * 0.6e-3)  # two gaps s0 in series, flux of eq. 2.8
    imax = 3.0 + 2.0  # bias + control current limit
    w_bw = np.log(9.0) * 400.0 / (inductance * imax)  # eq. 2.24
    assert rig.coil_inductance_h == pytest.approx(inductance, rel=1e-12)
    assert rig.current_loop_bandwidth_hz == pytest.approx(w_bw / (2 * np.pi), rel=1e-12)
    # the analytical model's amplifier poles sit at -omega_BW (eq. 2.21)
    poles = np.linalg.eigvals(analytical_model(rig).a)
    assert np.sum(np.isclose(poles, -w_bw, rtol=1e-9)) == 4


@pytest.mark.parametrize("text, words", [
    ("air_gap_m: 5.0\n", ["air_gap_m", "allowed range", "0.01"]),
    ("bias_current_a: -1\n", ["bias_current_a", "allowed range"]),
    ("coil_turnz: 100\n", ["coil_turnz", "unknown"]),
    ("sensor_gain: fast\n", ["sensor_gain", "number"]),
    ("bending_modes: 2.5\n", ["bending_modes", "whole number"]),
    ("sensor_b_z_m: 0.45\n", ["sensor_b_z_m", "outside the shaft"]),
    ("extra_delay_s: 0.001\n", ["extra_delay_s", "one sample"]),
    ("- 1\n- 2\n", ["mapping"]),
    ("tolerances:\n  ki_n_per_a: lots\n", ["ki_n_per_a", "not a tolerance", "x3"]),
    ("tolerances:\n  kii: 5 %\n", ["kii", "unknown", "ki_n_per_a"]),
    ("tolerances:\n  ks_n_per_m: 150 %\n", ["ks_n_per_m", "100 %"]),
    ("tolerances:\n  bending_damping_ratio: x0.5\n", ["bending_damping_ratio", "factor > 1"]),
    ("tolerances:\n  amplifier_bandwidth_hz: 0..1 sample\n", ["amplifier_bandwidth_hz", "only delay_s"]),
    ("tolerances: 5 %\n", ["tolerances", "mapping"]),
])
def test_rig_yaml_with_a_bad_field_names_it(tmp_path, text, words):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError) as err:
        load_rig(path)
    for word in words:
        assert word in str(err.value), (word, str(err.value))


def test_rig_yaml_round_trip_and_examples(tmp_path):
    rig = make_rig({"housing_freq_hz": 150.0, "bending_modes": 2}, name="mine")
    assert make_rig(rig.to_dict()) == rig
    path = tmp_path / "mine.yaml"
    path.write_text("housing_freq_hz: 150\nbending_modes: 2\n")
    loaded = load_rig(path)
    assert loaded.values == rig.values and loaded.name == "mine"
    assert loaded.housing_freq_hz == 150.0 and loaded.dt == pytest.approx(1e-4)
    examples = sorted((REPO / "rigs").glob("*.yaml"))
    assert examples, "rigs/ holds example rig files"
    for example in examples:
        assert set(load_rig(example).values) == set(RIG_FIELDS)


def test_tolerances_are_data_sheet_priors(tmp_path):
    from ambid.plant.tolerances import DEFAULT_TOLERANCES, Z95, parse_tolerance, tolerance_for

    rig = make_rig()
    assert rig.tolerances == {}                    # the defaults hold
    # each form read as a 95 % interval of a normal prior
    assert parse_tolerance("ki_n_per_a", "5 %").centre_and_sd(180.0, rig.dt) == (180.0, pytest.approx(9.0 / Z95),
                                                                               False)
    assert parse_tolerance("bending_damping_ratio", "x3").centre_and_sd(0.005, rig.dt) == \
        (0.005, pytest.approx(np.log(3) / Z95), True)
    assert parse_tolerance("delay_s", 2e-5).centre_and_sd(5e-5, rig.dt) == (5e-5, pytest.approx(2e-5 / Z95), False)
    assert parse_tolerance("delay_s", "0..1 sample").centre_and_sd(0.0, 1e-4) == \
        (pytest.approx(5e-5), pytest.approx(5e-5 / Z95), False)
    assert parse_tolerance("sensor_bandwidth_hz", "fixed").centre_and_sd(5e3, rig.dt)[1] == 0
    for name, tol in DEFAULT_TOLERANCES.items():     # the canonical text reads back to the same tolerance
        assert parse_tolerance(name, tol.to_text()) == tol
    # a rig file overrides some; the others keep their default; a higher bending mode takes the first's
    path = tmp_path / "nominal.yaml"
    path.write_text("sensor_bandwidth_hz: 3000\ntolerances:\n  sensor_bandwidth_hz: 20 %\n"
                    "  bending_damping_ratio: x2\n  delay_s: 0..2e-4\n")
    loaded = load_rig(path)
    assert tolerance_for("sensor_bandwidth_hz", loaded.tolerances).value == pytest.approx(0.2)
    assert tolerance_for("bending_2_damping_ratio", loaded.tolerances).value == 2.0
    assert tolerance_for("ki_n_per_a", loaded.tolerances) == DEFAULT_TOLERANCES["ki_n_per_a"]
    assert tolerance_for("delay_s", loaded.tolerances).high == pytest.approx(2e-4)
    # recorded with the rig (a session's rig facts) and read back the same
    again = make_rig(loaded.to_dict())
    assert again.tolerances == loaded.tolerances and again.values == loaded.values


def test_default_rig_doc_tables_are_up_to_date():
    text = (REPO / "docs" / "default_rig.md").read_text()
    begin, end = "<!-- rig-tables:begin -->", "<!-- rig-tables:end -->"
    assert begin in text and end in text
    tables = text.split(begin, 1)[1].split(end, 1)[0]
    assert tables.strip() == rig_markdown().strip(), "regenerate docs/default_rig.md's tables with rig_markdown()"
    # every parameter is documented with its value
    for key in RIG_FIELDS:
        assert f"`{key}`" in tables
