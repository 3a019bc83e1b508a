"""Every record ambid import cannot use is refused with one line naming the column, the row and the fix,
exit code 2, and nothing written: NaN/Inf, columns of different lengths, a name not in the file, a time column
at odds with sample_rate_hz or with gaps, damaged files and bad MAP.yaml entries. An excitation that is not
periodic, shorter than two periods or stops mid-period is no longer refused: it imports for the local
polynomial method, and the import says so."""

from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.io as sio
import yaml
from ambid_cli import cli

FS, N = 1000.0, 100
FIX = re.compile(r"\b(give|run|record|check|create|leave out|make|use|cut|add)\b")


def _signals(seed=0):
    """An orthogonal 4-input multisine (N = 100, lines 1-10, Pt = 1, P = 1) and a made-up response."""
    rng = np.random.default_rng(seed)
    t = np.arange(N)
    w = np.exp(-2j * np.pi * np.outer(np.arange(4), np.arange(4)) / 4)
    ph = np.exp(1j * rng.uniform(0, 2 * np.pi, (4, 10)))
    segs = [np.tile((0.1 * ph[:, :, None] * w[:, e][:, None, None] *
                     np.exp(2j * np.pi * np.arange(1, 11)[None, :, None] * t / N)).real.sum(axis=1).T, (2, 1))
            for e in range(4)]
    r = np.vstack([np.zeros((50, 4)), *segs, np.zeros((50, 4))])
    y = 1e-5 * np.roll(r, 3, axis=0) + 1e-8 * rng.standard_normal(r.shape)
    return r, y, r + 0.01 * y / 1e-5


def _columns(r, y, u):
    return {"time": np.arange(len(r)) / FS, **{f"x{i + 1}": y[:, i] for i in range(4)},
            **{f"i{i + 1}": u[:, i] for i in range(4)}, **{f"exc{i + 1}": r[:, i] for i in range(4)}}


AX = ("a_x", "b_x", "a_y", "b_y")
MAP = {"sample_rate_hz": FS, "time_column": "time",
       "outputs": {f"y_{a}": {"column": f"x{i + 1}"} for i, a in enumerate(AX)},
       "currents": {f"u_{a}": {"column": f"i{i + 1}"} for i, a in enumerate(AX)},
       "excitation": {f"r_{a}": {"column": f"exc{i + 1}"} for i, a in enumerate(AX)}}


def _csv(path, cols, cut_last=False, text=None):
    names = list(cols)
    x = np.column_stack(list(cols.values()))
    lines = [",".join(names)] + [",".join(repr(float(v)) for v in row) for row in x]
    if cut_last:
        lines[-1] = ",".join(lines[-1].split(",")[:3])
    path.write_text(text if text is not None else "\n".join(lines) + "\n")
    return path


def _run(tmp_path, data, rmap, capsys):
    (tmp_path / "MAP.yaml").write_text(yaml.safe_dump(rmap) if isinstance(rmap, dict) else rmap)
    out = tmp_path / "out" / "s.mcap"
    out.parent.mkdir(exist_ok=True)
    code = cli.main(["import", str(data), "--map", str(tmp_path / "MAP.yaml"), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("ambid import: ") and FIX.search(lines[0]), err
    assert list(out.parent.iterdir()) == []   # nothing half-written
    return lines[0]


def test_the_good_record_imports(tmp_path, capsys):
    """The base the cases below spoil one thing of."""
    r, y, u = _signals()
    _csv(tmp_path / "d.csv", _columns(r, y, u))
    (tmp_path / "MAP.yaml").write_text(yaml.safe_dump(MAP))
    assert cli.main(["import", str(tmp_path / "d.csv"), "--map", str(tmp_path / "MAP.yaml"), "--out",
                     str(tmp_path / "s.mcap")]) == 0
    assert "Ne = 4 experiment(s) x M = 1" in capsys.readouterr().out


def _case(name):
    r, y, u = _signals()
    cols, rmap, kw = _columns(r, y, u), dict(MAP), {}
    if name == "not periodic":
        cols.update({f"exc{i + 1}": np.random.default_rng(i).standard_normal(len(r)) for i in range(4)})
    elif name == "shorter than a period":
        for i in range(4):
            cols[f"exc{i + 1}"] = np.where(np.arange(len(r)) < 110, r[:, i], 0.0)
    elif name == "stops mid-period":
        for i in range(4):
            cols[f"exc{i + 1}"] = np.where(np.arange(len(r)) < 50 + 7 * N + 40, r[:, i], 0.0)
    elif name == "nan":
        cols["i2"] = cols["i2"].copy()
        cols["i2"][300] = np.nan
    elif name == "inf":
        cols["x3"] = cols["x3"].copy()
        cols["x3"][42] = -np.inf
    elif name == "different lengths":
        kw["cut_last"] = True
    elif name == "name not in file":
        rmap = {**MAP, "outputs": {**MAP["outputs"], "y_b_y": {"column": "x9"}}}
    elif name == "rate vs time column":
        rmap = {**MAP, "sample_rate_hz": 1200.0}
    elif name == "time gap":
        cols["time"] = cols["time"].copy()
        cols["time"][500:] += 1 / FS
        rmap = {k: v for k, v in MAP.items() if k != "sample_rate_hz"}
    elif name == "output without unit":
        rmap = {**MAP, "outputs": {"disp_a": {"column": "x1"}}}  # any name is an output, with its unit
    elif name == "unit not SI":
        rmap = {**MAP, "outputs": {**MAP["outputs"], "y_a_x": {"column": "x1", "unit": "mm"}}}
    elif name == "unknown unit":
        rmap = {**MAP, "outputs": {**MAP["outputs"], "acc1": {"column": "x1", "unit": "furlong"}}}
    elif name == "current in volts":
        rmap = {**MAP, "excitation": {**MAP["excitation"], "r_a_x": {"column": "exc1", "unit": "V"}}}
    elif name == "injection point":
        rmap = {**MAP, "excitation": {**MAP["excitation"], "r_a_x": {"column": "exc1", "injected_at": "sensor"}}}
    elif name == "excitation axes":
        rmap = {**MAP, "excitation": {"r_a_x": {"column": "exc1"}}}
    return cols, rmap, kw


# an excitation that is no periodic design is no longer refused (issue 28): the local polynomial method takes it
NOT_A_DESIGN = {  # case -> why the import says it took the local polynomial method
    "not periodic": r"does not repeat itself within \d+ rows: it is not periodic",
    "shorter than a period": r"from row 51 does not repeat itself .*shorter than two periods",
    "stops mid-period": r"stops at row 791, 40 rows into a period of 100",
}
CASES = {  # case -> what the one line must say
    "nan": r"column 'i2' is nan at row 301",
    "inf": r"column 'x3' is -inf at row 43",
    "different lengths": r"line 901 \(row 900\) has 3 fields but the header names 13 columns",
    "name not in file": r"no channel 'x9' \(named in MAP.yaml",
    "rate vs time column": r"time column 'time' at row \d+ is .* but sample_rate_hz 1200 .*the column says 1000 Hz",
    "time gap": r"time column 'time' is not evenly spaced: row 501",
    "output without unit": r"outputs.disp_a has no unit \(and the file states none for 'x1'\); give unit:",
    "unit not SI": r"outputs.y_a_x: unit 'mm' is not SI; give unit: m and scale: 0.001",
    "unknown unit": r"outputs.acc1: unit 'furlong' after scaling must be m, m/s, m/s\^2, V",
    "current in volts": r"excitation.r_a_x: unit 'V' after scaling must be A.*or injected_at: reference \| output",
    "injection point": r"excitation.r_a_x.injected_at is 'sensor'; give current",
    "excitation axes": r"must name the same axes as currents",
}


@pytest.mark.parametrize("name", list(NOT_A_DESIGN))
def test_excitations_that_are_no_design_import_through_the_local_polynomial_method(tmp_path, name, capsys):
    cols, rmap, kw = _case(name)
    (tmp_path / "MAP.yaml").write_text(yaml.safe_dump(rmap))
    code = cli.main(["import", str(_csv(tmp_path / "d.csv", cols, **kw)), "--map", str(tmp_path / "MAP.yaml"),
                     "--out", str(tmp_path / "s.mcap")])
    out = capsys.readouterr().out
    line = [ln for ln in out.splitlines() if ln.startswith("estimator: ")]
    assert code == 0 and len(line) == 1 and "local polynomial method" in line[0], out
    assert re.search(NOT_A_DESIGN[name], line[0]), line[0]


@pytest.mark.parametrize("name", list(CASES))
def test_bad_records_are_refused_by_column_and_row(tmp_path, name, capsys):
    cols, rmap, kw = _case(name)
    line = _run(tmp_path, _csv(tmp_path / "d.csv", cols, **kw), rmap, capsys)
    assert re.search(CASES[name], line), line


def test_npz_vectors_of_different_lengths(tmp_path, capsys):
    cols, _, _ = _case("nan")
    cols["i2"] = np.zeros(10)
    np.savez(tmp_path / "d.npz", **cols)
    line = _run(tmp_path, tmp_path / "d.npz", MAP, capsys)
    assert re.search(r"channel '\w+' has 10 rows but '\w+' has 900", line), line


def test_damaged_mat_files(tmp_path, capsys):
    r, y, u = _signals()
    sio.savemat(tmp_path / "d.mat", _columns(r, y, u), do_compression=True)
    data = (tmp_path / "d.mat").read_bytes()
    (tmp_path / "cut.mat").write_bytes(data[:len(data) * 2 // 3])
    assert re.search(r"cut off|truncated", _run(tmp_path, tmp_path / "cut.mat", MAP, capsys))
    (tmp_path / "txt.mat").write_text("x1,x2\n1,2\n")
    assert "is not a MATLAB .mat file" in _run(tmp_path, tmp_path / "txt.mat", MAP, capsys)


@pytest.mark.parametrize("text, expect", [
    ("", "is empty"), ("[1, 2]", "is not a mapping"), ("outputs: {", "is not YAML"),
    ("sample_rate_hz: 1000\nfoo: 1\n", "unknown key 'foo'"),
    ("outputs: {y_a_x: x1}\ncurrents: {u_a_x: i1}\nexcitation: {r_a_x: exc1}\n",
     "neither sample_rate_hz nor time_column"),
    ("sample_rate_hz: -5\n", "sample_rate_hz is -5"),
])
def test_bad_map_files(tmp_path, text, expect, capsys):
    r, y, u = _signals()
    assert expect in _run(tmp_path, _csv(tmp_path / "d.csv", _columns(r, y, u)), text, capsys)


def _csv_text(name):
    r, y, u = _signals()
    cols = _columns(r, y, u)
    lines = [",".join(cols)] + [",".join(repr(float(v)) for v in row) for row in np.column_stack(list(cols.values()))]
    if name == "not utf-8":
        lines[300] = lines[300].replace(",", ",\xe9", 1)   # written as latin-1 below
    elif name == "no header":
        lines = lines[1:]
    elif name == "pipes":
        lines = [ln.replace(",", "|") for ln in lines]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("name, expect", [
    ("not utf-8", r"line 301 \(row 300\), column 'x1': '\ufffd.*' is not a number"),
    ("no header", r"line 1 holds numbers, not channel names; give the file a header row"),
    ("pipes", r"line 1 is one column .* separated by commas, semicolons or tabs"),
])
def test_csv_text_problems_are_named(tmp_path, name, expect, capsys):
    data = tmp_path / "d.csv"
    data.write_bytes(_csv_text(name).encode("latin-1" if name == "not utf-8" else "utf-8"))
    assert re.search(expect, _run(tmp_path, data, MAP, capsys))


def test_a_folder_is_named_as_a_folder(tmp_path, capsys):
    (tmp_path / "records").mkdir()
    assert "is a folder; give the record file in it" in _run(tmp_path, tmp_path / "records", MAP, capsys)


@pytest.mark.parametrize("change, expect", [
    ({"band_hz": [1000, 10]}, r"band_hz is \[1000.0, 10.0\]; give \[f_lo, f_hi\] in Hz with 0 <= f_lo < f_hi"),
    ({"outputs": {**MAP["outputs"], "y_a_x": {"column": "x1", "scale": 0}}}, r"outputs.y_a_x.scale is 0"),
    ({"experiment_id": {"a": 1}}, r"experiment_id is \{'a': 1\}; give a name"),
])
def test_map_values_that_would_fail_later_are_named(tmp_path, change, expect, capsys):
    r, y, u = _signals()
    assert re.search(expect, _run(tmp_path, _csv(tmp_path / "d.csv", _columns(r, y, u)), {**MAP, **change}, capsys))


def test_a_damaged_npz_is_refused_by_its_crc(tmp_path, capsys):
    """One flipped bit in a sample leaves a plausible number: only the zip member's CRC can tell."""
    r, y, u = _signals()
    cols = _columns(r, y, u)
    np.savez(tmp_path / "d.npz", data=np.column_stack(list(cols.values())), names=np.array(list(cols)))
    b = bytearray((tmp_path / "d.npz").read_bytes())
    at = b.index(b"\x93NUMPY", b.index(b"data.npy")) + 128 + 8 * 13 * 400 + 8 * 5   # row 400, column i1
    b[at] ^= 0x01   # the lowest mantissa bit
    (tmp_path / "d.npz").write_bytes(bytes(b))
    assert re.search(r"ends or breaks at row \d+ \(Bad CRC-32", _run(tmp_path, tmp_path / "d.npz", MAP, capsys))


def test_a_complex_mat_channel_is_refused(tmp_path, capsys):
    r, y, u = _signals()
    cols = _columns(r, y, u)
    cols["i2"] = cols["i2"] + 1e-3j
    sio.savemat(tmp_path / "d.mat", cols)
    assert re.search(r"'i2' \(named in MAP.yaml .*\) is complex; .* give the real signal",
                     _run(tmp_path, tmp_path / "d.mat", MAP, capsys))


@pytest.mark.parametrize("style", ["tabs, decimal comma", "quoted"])
def test_tab_separated_and_quoted_csv_import_as_the_plain_one(tmp_path, style, capsys):
    from ambid.recording.blocks import iter_sample_blocks

    r, y, u = _signals()
    plain = _csv(tmp_path / "plain.csv", _columns(r, y, u)).read_text()
    text = (plain.replace(",", "\t").replace(".", ",") if style.startswith("tabs") else
            "".join('"' + ln.replace(",", '","') + '"\n' for ln in plain.splitlines()))
    (tmp_path / "other.csv").write_text(text)
    (tmp_path / "MAP.yaml").write_text(yaml.safe_dump(MAP))
    got = []
    for name in ("plain", "other"):
        assert cli.main(["import", str(tmp_path / f"{name}.csv"), "--map", str(tmp_path / "MAP.yaml"), "--out",
                         str(tmp_path / f"{name}.mcap")]) == 0
        got.append(np.vstack([b.data for _, b in iter_sample_blocks(str(tmp_path / f"{name}.mcap"),
                                                                       "/amb/measurement")]))
    capsys.readouterr()
    assert got[0].shape == (900, 12) and np.array_equal(got[0], got[1])


def test_a_map_controller_at_another_sample_rate_is_named(tmp_path, capsys):
    r, y, u = _signals()
    np.savez(tmp_path / "k.npz", A=np.zeros((1, 1)), B=np.zeros((1, 4)), C=np.zeros((4, 1)), D=np.zeros((4, 4)),
             dt=1e-4)   # made for a 10 kHz rig; the record is at 1 kHz
    line = _run(tmp_path, _csv(tmp_path / "d.csv", _columns(r, y, u)), {**MAP, "controller": "k.npz"}, capsys)
    assert "sample period 0.0001 s differs from the record's 0.001 s" in line, line


def _lms(path, names, values, unit_terms, dt=1e-3, **extra):
    """A MAT file of one LMS Test.Lab-style struct (as scipy writes a struct: the shape of the export, not one)."""
    terms = [{"num": float(e), "den": 1.0, "quantity": q} for q, e in unit_terms]
    sio.savemat(path, {"Signal": {
        "x_values": {"start_value": 0.0, "increment": dt, "number_of_values": float(len(values))},
        "y_values": {"values": values, "quantity": {"label": "x", "quantity_terms": np.array(terms, dtype=object),
                                                    "unit_transformation": {"factor": 1.0}}},
        "function_record": {"name": "x", "primary_channel": {"label": np.array(names, dtype=object)}}, **extra}})
    return path


@pytest.mark.parametrize("case, expect", [
    ("lengths", r"has 800 rows but .* has 900; give files of the same recording"),
    ("csv among several", r"a CSV record is read as one file"),
    ("complex struct", r"'Signal'.y_values.values is complex \(a spectrum or FRF, not a time signal\)"),
    ("unit against the file", r"column 'acc' is in m/s\^2 \(the file says so\) but MAP.yaml .* makes acc1 V"),
    ("rate against the file", r"the file's time base says 1000 Hz but MAP.yaml .* gives sample_rate_hz 2000"),
])
def test_several_files_and_lms_structs_refused_in_one_line(tmp_path, case, expect, capsys):
    """Records from an acquisition system's export: each refusal one line, exit 2, nothing written."""
    r, y, u = _signals()
    acc = [("LENGTH", 1), ("TIME", -2)]
    a = _lms(tmp_path / "a.mat", ["acc"], y[:, :1] * (1j if case == "complex struct" else 1), acc)
    cur_exc = np.column_stack([u[:, 0], r[:, 0]])[:800 if case == "lengths" else None]
    b = _lms(tmp_path / "b.mat", ["cur", "exc"], cur_exc, [("CURRENT", 1)])
    files = [a, _csv(tmp_path / "d.csv", _columns(r, y, u))] if case == "csv among several" else [a, b]
    rmap = {"outputs": {"acc1": {"column": "acc", "unit": "V" if case == "unit against the file" else "m/s^2"}},
            "currents": {"u_x": "cur"}, "excitation": {"r_x": "exc"}}
    if case == "rate against the file":
        rmap["sample_rate_hz"] = 2000
    (tmp_path / "MAP.yaml").write_text(yaml.safe_dump(rmap))
    out = tmp_path / "out" / "s.mcap"
    out.parent.mkdir()
    code = cli.main(["import", *map(str, files), "--map", str(tmp_path / "MAP.yaml"), "--out", str(out)])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and "Traceback" not in err and len(lines) == 1, err
    assert re.search(expect, lines[0]) and FIX.search(lines[0]), lines[0]
    assert list(out.parent.iterdir()) == []
