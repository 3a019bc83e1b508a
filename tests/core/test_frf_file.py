"""ambid fit FRF_FILE: the test plant's FRF (tests/core/lpm_testbench.py, not ambid's), written by the test itself
as .npz, .mat, .csv, UFF 58 and Touchstone (.s4p, by scikit-rf), fits with modes within 0.5 % (frequency) and 10 % (damping) of the plant's; bad
files get one line naming the problem and the fix, exit code 2, never a traceback."""

from __future__ import annotations

import re

import numpy as np
import pytest
import pyuff
import scipy.io as sio

import lpm_testbench as tb
from ambid.frf.frf_file import FrfFileError, read_frf_file
from ambid.identification.frf_file_fit import identify_frf
from ambid_cli import cli

OUTS = [f"y_{a}" for a in tb.AXES]
INS = [f"u_{a}" for a in tb.AXES]
FIX = re.compile(r"\b(give|leave|make|use)\b")


def _write_csv(path, f, h, var=None):
    cols, data = ["freq_hz"], [f]
    for i, o in enumerate(OUTS):
        for j, u in enumerate(INS):
            cols += [f"re({o}/{u})", f"im({o}/{u})"]
            data += [h[:, i, j].real, h[:, i, j].imag]
            if var is not None:
                cols.append(f"var({o}/{u})")
                data.append(var[:, i, j])
    np.savetxt(path, np.column_stack(data), delimiter=",", header=",".join(cols), comments="", fmt="%.12g")


def _write_uff(path, f, h):
    sets = [pyuff.prepare_58(func_type=4, rsp_node=i + 1, rsp_dir=1, ref_node=j + 1, ref_dir=1, rsp_ent_name=o,
                             ref_ent_name=u, data=h[:, i, j], x=f, id1="ambid test", binary=0,
                             abscissa_spec_data_type=18, ordinate_spec_data_type=8, orddenom_spec_data_type=13,
                             z_axis_spec_data_type=0)
            for i, o in enumerate(OUTS) for j, u in enumerate(INS)]
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The plant's FRF with 1 % noise per entry (and its variance), in every format."""
    d = tmp_path_factory.mktemp("frf")
    f = np.linspace(20.0, 800.0, 400)
    h0 = tb.frf(f, sampled=False)
    sd = 0.01 * np.abs(h0) + 1e-9
    rng = np.random.default_rng(2)
    h = h0 + sd / np.sqrt(2) * (rng.standard_normal(h0.shape) + 1j * rng.standard_normal(h0.shape))
    var = sd ** 2
    np.savez(d / "frf.npz", freq_hz=f, H=h, var=var, outputs=OUTS, inputs=INS)
    sio.savemat(d / "frf.mat", dict(freq_hz=f, H=h, var=var, outputs=np.array(OUTS, dtype=object),
                                    inputs=np.array(INS, dtype=object)))
    _write_csv(d / "frf.csv", f, h, var)
    _write_uff(d / "frf.uff", f, h)
    _write_touchstone(d / "frf.s4p", f, h)
    return d


def _write_touchstone(path, f, h):
    """The square FRF as a 4-port's S parameters, written by scikit-rf (the format's other implementation)."""
    import skrf

    skrf.Network(frequency=skrf.Frequency.from_f(f, unit="Hz"), s=h).write_touchstone(
        str(path.with_suffix("")), form="ri")


@pytest.mark.parametrize("ext", ["npz", "mat", "csv", "uff", "s4p"])
def test_each_format_fits_the_plants_modes(files, ext, tmp_path):
    measured = read_frf_file(files / f"frf.{ext}")
    if ext == "s4p":   # a network's ports: S_ij is the wave leaving port i over the wave entering port j
        assert measured.output_names == ("b1", "b2", "b3", "b4") and measured.input_names == ("a1", "a2", "a3", "a4")
        assert measured.form == "S-parameters" and measured.kind == "touchstone"
    elif ext == "uff":   # UFF names a channel by its node and direction; the entity names are labels only
        assert measured.output_names == tuple(f"{i + 1}+X" for i in range(len(OUTS)))
        assert measured.input_names == tuple(f"{j + 1}+X" for j in range(len(INS)))
        assert measured.form == "receptance" and measured.unit == "m/N"
    else:
        assert measured.output_names == tuple(OUTS) and measured.input_names == tuple(INS)
    assert (measured.var is None) == (ext in ("uff", "s4p"))
    s = identify_frf(measured, tmp_path / "out", max_order=20, report=ext == "csv")
    fitted = [(m["freq_hz"], m["damping"], m) for m in s["fit"]["modes"]]
    for f0, z0 in tb.true_modes((20.0, 800.0)):
        f, z, m = min(fitted, key=lambda x: abs(x[0] - f0))
        assert abs(f / f0 - 1) < 0.005 and abs(z / z0 - 1) < 0.10, (ext, f0, z0, f, z)
        # the intervals are there, and not absurdly narrow: the truth within 5 of their sigmas
        assert m["freq_hz_std"] > 0 and abs(f - f0) < 5 * m["freq_hz_std"] + 1e-9 * f0, (ext, m)
        assert abs(z - z0) < 5 * m["damping_std"], (ext, m)
    assert s["intervals"]["modes"].startswith("95 % intervals" if ext not in ("uff", "s4p") else
                                              "the file gives no variance")
    if ext == "csv":
        assert (tmp_path / "out" / "report" / "index.html").exists()


def test_cli_fits_a_csv(files, tmp_path, capsys):
    assert cli.main(["fit", str(files / "frf.csv"), "--out", str(tmp_path / "o"), "--no-report",
                     "--max-order", "20"]) == 0
    out = capsys.readouterr().out
    assert "variance given" in out and "Hz (" in out


def _bad_files(d, good):
    """name -> (path, what the one line must say)."""
    f = np.linspace(20.0, 800.0, 50)
    h = tb.frf(f, sampled=False)
    out = {}
    out["missing"] = (d / "none.npz", "does not exist")
    (d / "folder.npz").mkdir()
    out["folder"] = (d / "folder.npz", "is a folder")
    for ext in ("npz", "mat", "csv", "uff", "s4p"):
        (d / f"empty.{ext}").write_bytes(b"")
        out[f"empty {ext}"] = (d / f"empty.{ext}", "is empty")
        (d / f"random.{ext}").write_bytes(np.random.default_rng(1).bytes(3000))
        out[f"random {ext}"] = (d / f"random.{ext}", "not|damaged|cannot|holds no")
        data = (good / f"frf.{ext}").read_bytes()
        (d / f"truncated.{ext}").write_bytes(data[:len(data) // 3])
        out[f"truncated {ext}"] = (d / f"truncated.{ext}", "damaged|not|cut short|values for|no FRF")
    # a CSV cut short, both ways on purpose (where a cut at a third of the bytes lands depends on the digits
    # this machine's arithmetic wrote): the last row short but every value a number, and cut inside a number
    rows = (good / "frf.csv").read_text().splitlines()
    short = ",".join(rows[11].split(",")[:5])
    (d / "short_row.csv").write_text("\n".join(rows[:11] + [short]) + "\n")
    out["csv last row short, numeric"] = (d / "short_row.csv", r"row 12 has 5 values for \d+ header columns")
    (d / "cut_number.csv").write_text("\n".join(rows[:11] + [short + ",1.5e"]))
    out["csv cut inside a number"] = (d / "cut_number.csv", r"row 12 is not \d+ comma-separated numbers")
    np.savez(d / "rotor.npz", A=np.eye(2), B=np.ones((2, 1)), C=np.ones((1, 2)), D=np.zeros((1, 1)))
    out["wrong kind"] = (d / "rotor.npz", "has no 'freq_hz'")
    (d / "session.txt").write_text("hello")
    out["wrong suffix"] = (d / "session.txt", "not an FRF file type|is not an MCAP")
    np.savez(d / "shape.npz", freq_hz=f, H=h[:, :, 0])
    out["wrong shape"] = (d / "shape.npz", "H has shape")
    np.savez(d / "varshape.npz", freq_hz=f, H=h, var=np.ones((50, 2)))
    out["var shape"] = (d / "varshape.npz", "var has shape")
    hn = h.copy()
    hn[7, 1, 2] = np.nan
    np.savez(d / "nan.npz", freq_hz=f, H=hn)
    out["nan npz"] = (d / "nan.npz", r"H is \(?nan.* at index")
    _write_csv(d / "nan.csv", f, hn)
    out["nan csv"] = (d / "nan.csv", r"is \(?nan.* at index")
    np.savez(d / "real.npz", freq_hz=f, H=np.abs(h))
    out["magnitude"] = (d / "real.npz", "H is real")
    np.savez(d / "order.npz", freq_hz=f[::-1], H=h)
    out["descending"] = (d / "order.npz", "increasing")
    (d / "hybrid.s2p").write_text("# GHz H RI R 50\n1 0 0 0 0 0 0 0 0\n2 0 0 0 0 0 0 0 0\n")
    out["touchstone hybrid"] = (d / "hybrid.s2p", "hybrid")
    (d / "v2.s1p").write_text("[Version] 2.0\n# GHz S RI R 50\n1 0.5 0\n")
    out["touchstone v2"] = (d / "v2.s1p", "version 2")
    (d / "ports.s3p").write_text((good / "frf.s4p").read_text())
    out["touchstone ports"] = (d / "ports.s3p", "not a whole number of rows")
    np.savez(d / "names.npz", freq_hz=f, H=h, outputs=["a", "b"])
    out["names"] = (d / "names.npz", "'outputs' holds 2 name")
    return out


def test_bad_files_get_one_line_and_exit_2(files, tmp_path, capsys):
    for name, (path, says) in _bad_files(tmp_path, files).items():
        try:
            code = cli.main(["fit", str(path), "--out", str(tmp_path / "o")])
        except SystemExit as exc:
            code = exc.code
        cap = capsys.readouterr()
        lines = [ln for ln in cap.err.splitlines() if ln.strip()]
        assert code == 2 and len(lines) == 1 and "Traceback" not in cap.err + cap.out, (name, cap.err)
        assert lines[0].startswith("ambid fit: ") and re.search(says, lines[0]), (name, lines[0])
        assert FIX.search(lines[0]), (name, lines[0])
        assert not (tmp_path / "o").exists(), name     # refused before anything is written


def test_reader_refuses_partial_var_columns(tmp_path):
    f = np.linspace(20.0, 800.0, 20)
    h = tb.frf(f, sampled=False)
    _write_csv(tmp_path / "v.csv", f, h, np.ones(h.shape))
    text = (tmp_path / "v.csv").read_text().splitlines()
    cols = text[0].split(",")
    keep = [i for i, c in enumerate(cols) if c != "var(y_a_x/u_a_x)"]
    (tmp_path / "w.csv").write_text("\n".join(",".join(ln.split(",")[i] for i in keep) for ln in text))
    with pytest.raises(FrfFileError, match="var columns for some pairs"):
        read_frf_file(tmp_path / "w.csv")
