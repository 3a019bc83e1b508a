"""Every YAML file a user writes reads numbers as people write them: ``2e-05``, ``1e3``, ``.5``, ``-1E-3``
(PyYAML's YAML 1.1 resolver takes the first three for strings), one test per reader: the reader itself,
the rig file (its parameters, its controller mapping and its tolerances), MAP.yaml, a controller file; a file that is not
YAML is still one line naming the file, the line and the fix."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from ambid.control.user_controller import load_controller
from ambid.plant.rig import load_rig
from ambid.records.mapping import load_map
from ambid.records.readers import RecordError
from ambid.yaml_file import load_yaml, read_yaml

FORMS = {"2e-05": 2e-05, "1e3": 1000.0, ".5": 0.5, "-1E-3": -1e-3, "+4e+2": 400.0, "1.0e-7": 1e-7, "-.25": -0.25}


def test_pyyaml_alone_reads_them_as_strings():
    """What the reader is for: YAML 1.1 (PyYAML) leaves these strings."""
    assert isinstance(yaml.safe_load("x: 2e-05")["x"], str) and isinstance(yaml.safe_load("x: 1e3")["x"], str)


@pytest.mark.parametrize("text,value", FORMS.items())
def test_the_reader_reads_every_form_as_a_number(text, value):
    got = load_yaml(f"x: {text}\nlist: [{text}, 7]\n")
    assert isinstance(got["x"], float) and got["x"] == value and got["list"] == [value, 7]


def test_the_reader_leaves_the_rest_as_yaml_has_it():
    got = load_yaml("i: 12\nname: x1\nversion: 1.2.3\nquoted: '2e-05'\nword: e5\nyes_no: true\nnull_: ~\n")
    assert got == {"i": 12, "name": "x1", "version": "1.2.3", "quoted": "2e-05", "word": "e5", "yes_no": True,
                   "null_": None}
    assert isinstance(got["i"], int)


def test_a_file_that_is_not_yaml_is_one_line_with_its_line(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("a: 1\nb: [1, 2\nc: 3\n")
    with pytest.raises(ValueError) as exc:
        read_yaml(p, "rig file", "give parameter: value lines")
    msg = str(exc.value)
    assert "\n" not in msg and str(p) in msg and "line" in msg and msg.endswith("; give parameter: value lines")


def test_rig_file(tmp_path):
    p = tmp_path / "rig.yaml"
    p.write_text("sensor_noise_m: 2e-07\nair_gap_m: .6e-3\nhousing_mass_kg: 2E1\nextra_delay_s: 5e-5\n"
                 "dc_link_voltage_v: 5.6e2\n")
    rig = load_rig(p)
    assert rig.sensor_noise_m == 2e-07 and rig.air_gap_m == 6e-4 and rig.housing_mass_kg == 20.0
    assert rig.extra_delay_s == 5e-5 and rig.dc_link_voltage_v == 560.0
    # a rig file's own controller mapping is read by the same reader
    p.write_text("controller: {kind: pid, kp: 1.2e4, td: 1.5e-3}\n")
    assert load_rig(p).controller == {"kind": "pid", "kp": 12000.0, "td": 0.0015}
    # an error still names the key and the fix in one line
    p.write_text("air_gap_m: 1e3\n")
    with pytest.raises(ValueError) as exc:
        load_rig(p)
    assert "\n" not in str(exc.value) and "air_gap_m" in str(exc.value) and "allowed range" in str(exc.value)


def test_map_yaml(tmp_path):
    p = tmp_path / "MAP.yaml"
    p.write_text("sample_rate_hz: 1e4\ntime_scale: 1E-3\ntime_column: t\n"
                 "outputs: {y_a_x: {column: x1, scale: 2e-05, offset: -1E-6}}\n"
                 "currents: {u_a_x: {column: i1, scale: .5}}\n"
                 "excitation: {r_a_x: {column: exc1, scale: 1e0}}\nband_hz: [1e1, 1e3]\n")
    m = load_map(p)
    assert m.sample_rate_hz == 1e4 and m.time_scale == 1e-3 and m.band_hz == (10.0, 1000.0)
    assert (m.outputs[0].scale, m.outputs[0].offset, m.currents[0].scale, m.excitation[0].scale) == \
        (2e-05, -1e-06, 0.5, 1.0)
    p.write_text("sample_rate_hz: 1e4\noutputs: {y_a_x: {column: x1, scale: two}}\n"
                 "currents: {u_a_x: i1}\nexcitation: {r_a_x: exc1}\n")
    with pytest.raises(RecordError) as exc:
        load_map(p)
    assert "\n" not in str(exc.value) and "outputs.y_a_x.scale" in str(exc.value) and "give a finite" in \
        str(exc.value)


def test_controller_file(tmp_path):
    p = tmp_path / "ctrl.yaml"
    # a discrete PD-like filter per axis in z^-1 powers, one sample of delay, numbers in every form
    p.write_text("num: [0, -1.2e4, 1.1E4]\nden: [1, -.5, 0]\ndt: 1e-4\n")
    model = load_controller(p, 1e-4)
    assert model.dt == 1e-4 and (model.n_inputs, model.n_outputs) == (4, 4)
    z = np.exp(2j * np.pi * 100.0 * 1e-4)
    expect = (-1.2e4 * z**-1 + 1.1e4 * z**-2) / (1 - 0.5 * z**-1)
    assert np.allclose(model.freqresp([100.0])[0], expect * np.eye(4))


def test_tolerances_in_a_rig_file(tmp_path):
    """The rig file's ``tolerances:`` (the priors of model updating): a number is an absolute half-width,
    written as people write it; the forms with a unit stay text; an error names the parameter and the forms."""
    p = tmp_path / "rig.yaml"
    p.write_text("tolerances: {delay_s: 2e-05, ks_n_per_m: 1e4, ki_n_per_a: 5 %, bending_damping_ratio: x3,\n"
                 "             support_freq_hz: .5e1, axial_ks_n_per_m: 1.5E5, sensor_bandwidth_hz: 1e3..2E4}\n")
    tol = load_rig(p).tolerances
    assert (tol["delay_s"].kind, tol["delay_s"].value) == ("absolute", 2e-05)
    assert (tol["ks_n_per_m"].value, tol["support_freq_hz"].value, tol["axial_ks_n_per_m"].value) == \
        (1e4, 5.0, 1.5e5)
    assert (tol["ki_n_per_a"].kind, tol["ki_n_per_a"].value) == ("relative", 0.05)
    assert (tol["bending_damping_ratio"].kind, tol["bending_damping_ratio"].value) == ("factor", 3.0)
    assert (tol["sensor_bandwidth_hz"].low, tol["sensor_bandwidth_hz"].high) == (1e3, 2e4)
    p.write_text("tolerances: {delay_s: -1E-3}\n")
    with pytest.raises(ValueError) as exc:
        load_rig(p)
    assert "\n" not in str(exc.value) and "delay_s" in str(exc.value) and "must be > 0" in str(exc.value)
