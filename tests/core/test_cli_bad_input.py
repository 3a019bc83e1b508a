"""Every CLI command meets bad input with one line naming the problem and the fix, and exit code 2:
a table of commands x inputs (missing file, folder, empty file, random bytes, truncated session, an MCAP of
unrelated topics, wrong option values), run in-process through ``ambid_cli.cli.main``. None of these
starts ROS: a bad input stops a command before its graph does."""

from __future__ import annotations

import os
import re

import numpy as np
import pytest
from ambid.channels import RADIAL
from ambid.excitation import design_multisine
from ambid.plant.rig import make_rig
from ambid_cli import cli
from mcap.writer import Writer
from session_testbench import design_message, plant_message, simulate_closed_loop, write_session

FIX = re.compile(r"\b(give|run|record|check|create|leave out|make|use)\b")
KINDS = ("missing", "folder", "empty", "random", "truncated", "unrelated")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad")
    rig = make_rig()
    design = design_multisine((20.0, 500.0), 20.0, rig.sample_rate_hz, list(RADIAL.inputs), 0.5,
                              n_periods=2, n_realisations=1, seed=3)
    names, x = simulate_closed_loop(rig, design, 2000, post_samples=100, seed=4)
    good = d / "good.mcap"
    write_session(good, [(k, x[k:k + 1000]) for k in range(0, len(x), 1000)], names,
                  [(0, design_message(design, 2000))], rig.dt, plant=plant_message(rig))
    data = good.read_bytes()
    (d / "truncated.mcap").write_bytes(data[:len(data) // 2])
    (d / "empty.mcap").write_bytes(b"")
    (d / "random.mcap").write_bytes(np.random.default_rng(0).bytes(5000))
    (d / "folder.mcap").mkdir()
    with open(d / "unrelated.mcap", "wb") as f:  # a valid MCAP with a ROS 2 string topic, nothing of ambid's
        w = Writer(f)
        w.start(profile="ros2")
        schema = w.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
        channel = w.register_channel("/chatter", "cdr", schema)
        w.add_message(channel, 0, b"\x00\x01\x00\x00\x06\x00\x00\x00hello\x00\x00\x00", 0)
        w.finish()
    paths = {k: str(d / f"{k}.mcap") for k in KINDS}
    return dict(dir=d, good=str(good), **paths)


def _run(argv, capsys):
    try:
        code = cli.main(argv)
    except SystemExit as exc:  # argparse's own refusal of an option value
        code = exc.code
    out = capsys.readouterr()
    assert "Traceback" not in out.err + out.out
    return code, out


def _one_line(err: str, command: str, names: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    line = lines[0]
    assert line.startswith(f"ambid {command}: "), line
    assert names in line, (names, line)
    assert FIX.search(line), f"no fix in: {line}"
    return line


SESSION_COMMANDS = {
    "fit": lambda f, d: ["fit", f, "--out", str(d / "fit_out"), "--no-report", "--no-update"],
    "fit --recover": lambda f, d: ["fit", f, "--out", str(d / "fit_out"), "--no-report", "--no-update", "--recover"],
    "inspect": lambda f, d: ["inspect", f],
    "inspect --recover": lambda f, d: ["inspect", f, "--recover"],
    "export": lambda f, d: ["export", f, "--format", "csv", "--out", str(d / "export_out.csv")],
}
# what each bad session file is refused for (a part of the one line)
SESSION_REFUSAL = {"missing": "no such file", "folder": "is a folder", "empty": "is empty",
                   "random": "is not an MCAP file", "truncated": "no valid MCAP footer|is incomplete",
                   "unrelated": "holds no"}


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("command", list(SESSION_COMMANDS))
def test_session_commands_refuse_bad_files(files, command, kind, capsys):
    argv = SESSION_COMMANDS[command](files[kind], files["dir"])
    code, out = _run(argv, capsys)
    if command == "inspect --recover" and kind == "truncated":  # what recover is for: read what is complete
        assert code == 0 and "RECOVERED" in out.out
        return
    assert code == 2
    line = _one_line(out.err, argv[0], files[kind] if kind != "truncated" or command.startswith("inspect")
                     else "")
    expected = "no complete realisation" if command == "fit --recover" and kind == "truncated" else \
        SESSION_REFUSAL[kind]
    assert re.search(expected, line), line


RIG_COMMANDS = {
    "graph": lambda rig, d: ["graph", "--rig", rig, "--sim-seconds", "0.1"],
    "identify": lambda rig, d: ["identify", "--rig", rig, "--out", str(d / "identify_out")],
    "design": lambda rig, d: ["design", "--rig", rig, "--out", str(d / "design_out"), "--no-figure"],
    "compare": lambda rig, d: ["compare", "--rig", rig, "--out", str(d / "compare_out")],
    "campaign": lambda rig, d: ["campaign", "--speeds-rpm", "0", "--rig", rig, "--out", str(d / "campaign_out")],
    "validate": lambda rig, d: ["validate", "--rig", rig, "--out", str(d / "validate_out")],
    "fit": None,  # filled in the test: it needs the good session
    "target-model": lambda rig, d: ["target-model", "--rig", rig, "--out", str(d / "target-model_out")],
    "commission": lambda rig, d: ["commission", "--rig", rig, "--out", str(d / "commission_out")],
}
RIG_REFUSAL = {"missing": "does not exist", "folder": "is a folder", "empty": "is empty", "random": "is not YAML text",
               "truncated": "is not YAML text", "unrelated": "is not YAML text"}


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("command", list(RIG_COMMANDS))
def test_rig_files_are_refused_before_anything_starts(files, command, kind, capsys):
    d = files["dir"]
    argv = (["fit", files["good"], "--out", str(d / "fit_rig"), "--rig", files[kind]] if command == "fit"
            else RIG_COMMANDS[command](files[kind], d))
    code, out = _run(argv, capsys)
    assert code == 2
    line = _one_line(out.err, command, files[kind])
    assert RIG_REFUSAL[kind] in line
    assert not (d / f"{command}_out").exists() and not (d / "fit_rig").exists()  # nothing was started


OPTION_VALUES = [  # argv, the option the error names
    (["fit", "{good}", "--out", "{dir}/o", "--estimator", "bogus"], "--estimator"),
    (["fit", "{good}", "--out", "{dir}/o", "--order", "-3"], "--order"),
    (["fit", "{good}", "--out", "{dir}/o", "--max-order", "x"], "--max-order"),
    (["identify", "--periods", "0"], "--periods"),
    (["identify", "--seed", "x"], "--seed"),
    (["identify", "--peak-current", "-0.4"], "--peak-current"),
    (["design", "--resolution", "0"], "--resolution"),
    (["design", "--kind", "bogus"], "--kind"),
    (["design", "--harmonics", "0"], "--harmonics"),
    (["campaign", "--out", "{dir}/c1", "--speeds-rpm", "fast"], "--speeds-rpm"),
    (["campaign", "--out", "{dir}/c1", "--speeds-rpm", "0", "--resolution", "-5"], "--resolution"),
    (["graph", "--sim-seconds", "-1"], "--sim-seconds"),
    (["graph", "--controller", "bogus"], "--controller"),
    (["graph", "--hardware", "nonsense"], "--hardware"),
    (["identify", "--hardware", "nonsense"], "--hardware"),
    (["compare", "--preset", "huge"], "--preset"),
    (["bench", "--repeats", "0"], "--repeats"),
    (["validate", "--seeds", "0"], "--seeds"),
    (["validate", "--preset", "huge"], "--preset"),
    (["validate", "--controller", "bogus"], "--controller"),
    (["validate", "--tune", "--tune-samples", "0"], "--tune-samples"),
    (["identify", "--noise-seed", "-1"], "--noise-seed"),
    (["commission", "--tune-checks", "0"], "--tune-checks"),
    (["validate", "--resolution", "-5"], "--resolution"),
]


@pytest.mark.parametrize("argv, option", OPTION_VALUES, ids=[" ".join(a[:1] + a[-2:]) for a, _ in OPTION_VALUES])
def test_wrong_option_values_are_refused_by_name(files, argv, option, capsys):
    argv = [a.format(good=files["good"], dir=files["dir"]) for a in argv]
    code, out = _run(argv, capsys)
    assert code == 2
    errors = [ln for ln in out.err.splitlines() if "error:" in ln]
    assert len(errors) == 1 and option in errors[0], out.err


RANGE_REFUSALS = [  # values argparse cannot judge alone: the command's one line, naming the option
    (["identify", "--band", "500", "10"], "--band 500 10"),
    (["design", "--band", "500", "10", "--out", "{dir}/d2"], "--band 500 10"),
    (["design", "--speed-rpm", "-5", "--out", "{dir}/d3"], "--speed-rpm"),
    (["campaign", "--speeds-rpm", "0", "-3000", "--out", "{dir}/c2"], "--speeds-rpm"),
    (["campaign", "--speeds-rpm", "0", "--out", "{good}"], "--out"),
    (["compare", "--parts", "bogus"], "--parts"),
    (["bench", "--skip", "bogus"], "--skip"),
    (["node", "bogus"], "unknown node 'bogus'"),
    (["fit", "{good}", "--out", "{good}"], "--out"),
    (["design", "--out", "{good}"], "--out"),
    (["identify", "--out", "{good}"], "--out"),
    (["compare", "--out", "{good}"], "--out"),
    (["validate", "--out", "{good}"], "--out"),
    (["bench", "--json", "{dir}/no_such_folder/b.json"], "--json"),
    (["bench", "--json", "{dir}"], "--json"),
    (["target-model", "--out", "{dir}"], "--out"),
    (["identify", "--true-model", "{good}"], "--true-model needs --hardware"),
    (["identify", "--hardware", "127.0.0.1:9", "--true-model", "{good}"], "--true-model"),
    (["identify", "--hardware", "127.0.0.1:9", "--true-model", "{dir}"], "--true-model"),
    (["identify", "--hardware", "127.0.0.1:9", "--true-model", "{dir}/no_model.txt"], "no_model.txt does not exist"),
    (["identify", "--hardware", "127.0.0.1:9", "--true-model", "{dir}/cut_model.txt"], "is cut short"),
    (["identify", "--hardware", "127.0.0.1:9", "--true-model", "{random}"], "is not text"),
    (["target-model", "--out", "{dir}/no_such_folder/m.txt"], "--out"),
    (["identify", "--hardware", "127.0.0.1:9", "--controller", "lqg"], "--controller with --hardware"),
    (["identify", "--hardware", "127.0.0.1:9", "--noise-seed", "3"], "--noise-seed with --hardware"),
    (["graph", "--hardware", "127.0.0.1:9", "--controller", "lqg"], "--controller with --hardware"),
    (["identify", "--hardware", "127.0.0.1:9"], "--hardware needs --key-file"),
    (["graph", "--hardware", "127.0.0.1:9"], "--hardware needs --key-file"),
    (["identify", "--key-file", "{dir}/rig.key"], "--key-file without --hardware"),
    (["graph", "--hardware", "127.0.0.1:9", "--key-file", "{dir}/no.key"], "no.key does not exist"),
    (["identify", "--hardware", "127.0.0.1:9", "--key-file", "{random}"], "may be read by group or others"),
    (["graph", "--hardware", "127.0.0.1:9", "--key-file", "{dir}"], "is a folder"),
    (["identify", "--hardware", "127.0.0.1:9", "--protocol-version", "2", "--key-file", "{random}"],
     "--key-file with --protocol-version 2"),
    (["keygen", "--out", "{good}"], "exists"),
    (["keygen", "--out", "{dir}/no_such_folder/rig.key"], "cannot write the key file"),
]


@pytest.mark.parametrize("argv, names", RANGE_REFUSALS, ids=[" ".join(a[:2]) for a, _ in RANGE_REFUSALS])
def test_impossible_values_get_one_line(files, argv, names, capsys):
    (files["dir"] / "cut_model.txt").write_text("ambid_target_model 1\ndt 0.0001\ncurrent_limit 3\n")
    os.chmod(files["random"], 0o644)  # as a file is written with the usual umask: others may read it
    argv = [a.format(good=files["good"], dir=files["dir"], random=files["random"]) for a in argv]
    code, out = _run(argv, capsys)
    assert code == 2
    line = [ln for ln in out.err.splitlines() if ln.strip()]
    assert len(line) == 1 and line[0].startswith(f"ambid {argv[0]}: ") and names in line[0], out.err


def test_bad_input_loses_nothing_already_written(files, capsys):
    out = files["dir"] / "earlier"
    out.mkdir()
    (out / "summary.json").write_text('{"kept": true}')
    for kind in KINDS:
        code, _ = _run(["fit", files[kind], "--out", str(out)], capsys)
        assert code == 2
    assert [p.name for p in out.iterdir()] == ["summary.json"]
    assert (out / "summary.json").read_text() == '{"kept": true}'
    assert open(files["good"], "rb").read(8) == b"\x89MCAP0\r\n"  # the inputs are only read


def test_a_run_the_amplifier_would_refuse_is_refused_before_any_node_starts(files, capsys):
    # 5 A of excitation + the 1 A working current over the rig's 3 A: the excitation generator would refuse
    # it once the graph runs (exit 1, a session left behind); identify and design refuse it first
    for command in ("identify", "design"):
        out = files["dir"] / f"over_{command}"
        code, printed = _run([command, "--peak-current", "5", "--resolution", "20", "--out", str(out)], capsys)
        assert code == 2 and printed.out == ""
        line = _one_line(printed.err, command, "exceeds the amplifier's 3 A limit on u_a_x, u_b_x, u_a_y, u_b_y")
        assert "give --peak-current 2 or less" in line
        assert not out.exists()


def test_an_excitation_the_amplifiers_voltage_cannot_follow_is_refused_before_any_node_starts(files, capsys):
    # a PRBS of +-1.6 A: within the current limit (1.6 + 1 A working < 3 A), but a step of 3.2 A in one 0.1 ms
    # sample needs L di/dt = 18.8 mH x 3.2 A / 0.1 ms ~ 600 V of the 560 V dc link: the amplifier would saturate
    import re

    from ambid.excitation.spec import DesignSpec

    rig = make_rig()
    design = DesignSpec(kind="prbs", peak_current_a=1.6).build(float(rig.sample_rate_hz), 0.0, rig.layout.inputs)
    x = design.samples(0, design.total_samples)
    need = rig.coil_inductance_h * np.abs(np.diff(x, axis=0)).max() * design.fs_hz   # R = 0 on the default rig
    assert need > rig.values["dc_link_voltage_v"] and rig.amplifier.resistance_ohm == 0
    for command in ("identify", "design"):
        out = files["dir"] / f"volts_{command}"
        code, printed = _run([command, "--kind", "prbs", "--peak-current", "1.6", "--out", str(out)], capsys)
        assert code == 2 and printed.out == ""
        line = _one_line(printed.err, command, f"need {need:.4g} V of the amplifier's 560 V dc link")
        fits = float(re.search(r"give --peak-current ([0-9.]+) or less", line).group(1))
        assert fits == pytest.approx(1.6 * 560 / need, rel=5e-3)   # the voltage is proportional to the steps
        assert not out.exists()
    # the default experiment is far inside: its steps need a fraction of the dc link
    assert _run(["design", "--no-plan", "--no-figure", "--out", str(files["dir"] / "volts_ok")], capsys)[0] == 0


@pytest.mark.parametrize("argv, says", [
    (["identfy"], "ambid: unknown command 'identfy'; did you mean 'identify'?"),
    (["desing", "--out", "x"], "ambid: unknown command 'desing'; did you mean 'design'?"),
    (["bogus"], "ambid: unknown command 'bogus' ('ambid --help' lists the commands)"),
    (["inspect", "{good}", "--bogus"], "ambid inspect: unknown option '--bogus' ('ambid inspect --help' lists"),
    (["identify", "--peak-curent", "0.4"], "ambid identify: unknown option '--peak-curent'; did you mean "
                                           "'--peak-current'?"),
    (["fit", "{good}", "--out", "{dir}/typo", "--no-reprot"], "ambid fit: unknown option '--no-reprot'; did you "
                                                              "mean '--no-report'?"),
    (["design", "--bnad", "10", "500"], "ambid design: unknown option '--bnad'; did you mean '--band'?"),
])
def test_mistyped_commands_and_options_get_did_you_mean(files, argv, says, capsys):
    argv = [a.format(good=files["good"], dir=files["dir"]) for a in argv]
    code, out = _run(argv, capsys)
    lines = [ln for ln in out.err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith(says), out.err
    assert not (files["dir"] / "typo").exists()


# ambid import: the record (each format) and MAP.yaml, as a missing file, a folder, empty, random bytes
RECORD_REFUSAL = {"missing": "no such file", "folder": "is a folder", "empty": "is empty",
                  "random": "is not a CSV text file|is not an .npz file|is not a MATLAB .mat file"}
MAP_REFUSAL = {"missing": "no such file", "folder": "is a folder", "empty": "is empty", "random": "is not YAML text"}


def _bad_file(d, kind, name):
    p = d / "import_bad" / kind / name
    p.parent.mkdir(parents=True, exist_ok=True)
    if kind == "folder":
        p.mkdir(exist_ok=True)
    elif kind == "empty":
        p.write_bytes(b"")
    elif kind == "random":
        p.write_bytes(np.random.default_rng(1).bytes(3000))
    return p


@pytest.mark.parametrize("kind", list(RECORD_REFUSAL))
@pytest.mark.parametrize("ext", ["csv", "mat", "npz"])
def test_import_refuses_bad_record_and_map_files(files, kind, ext, capsys):
    d = files["dir"]
    good_map = d / "import_map.yaml"
    good_map.write_text("sample_rate_hz: 10000\noutputs: {y_a_x: x1}\ncurrents: {u_a_x: i1}\n"
                        "excitation: {r_a_x: e1}\n")
    data = _bad_file(d, kind, f"rec.{ext}")
    out = d / "import_out.mcap"
    code, res = _run(["import", str(data), "--map", str(good_map), "--out", str(out)], capsys)
    assert code == 2 and re.search(RECORD_REFUSAL[kind], _one_line(res.err, "import", str(data)))
    good_csv = d / "import_good.csv"
    good_csv.write_text("x1,i1,e1\n0,0,0\n")
    bad_map = _bad_file(d, kind, "MAP.yaml")
    code, res = _run(["import", str(good_csv), "--map", str(bad_map), "--out", str(out)], capsys)
    assert code == 2 and re.search(MAP_REFUSAL[kind], _one_line(res.err, "import", str(bad_map)))
    assert not out.exists()


def test_import_and_export_options(files, capsys):
    d = files["dir"]
    code, res = _run(["export", files["good"], "--format", "xls", "--out", str(d / "x.xls")], capsys)
    assert code == 2 and "--format" in res.err
    code, res = _run(["import", files["good"], "--map", str(d / "m.yaml"), "--out", files["good"]], capsys)
    assert code == 2 and "--out" in _one_line(res.err, "import", files["good"])
    code, res = _run(["export", files["good"], "--format", "csv", "--out", str(d)], capsys)
    assert code == 2 and "is a folder" in _one_line(res.err, "export", str(d))
    record = d / "import_self.csv"
    record.write_text("x1,i1,e1\n0,0,0\n")
    code, res = _run(["import", str(record), "--map", str(d / "m.yaml"), "--out", str(record), "--overwrite"], capsys)
    assert code == 2 and "is the record being imported" in _one_line(res.err, "import", str(record))
    assert record.read_text() == "x1,i1,e1\n0,0,0\n"


# a rig file's rotor_file: and controller: entries, and --controller FILE, naming a file that cannot be read:
# the command's one line names that file (the rig is loaded before anything starts)
ENTRY_REFUSAL = {"missing": "does not exist", "folder": "is a folder", "empty": "is empty",
                 "random": r"is not an \.npz file|is not a MATLAB \.mat file",
                 "truncated": r"is not an \.npz file|damaged or cut short"}


@pytest.mark.parametrize("kind", list(ENTRY_REFUSAL))
@pytest.mark.parametrize("entry", ["rotor_file", "controller", "--controller"])
@pytest.mark.parametrize("ext", [".npz", ".mat"])
def test_rotor_and_controller_files_that_cannot_be_read(files, entry, kind, ext, capsys):
    d = files["dir"] / "entries" / f"{entry}-{kind}{ext}"
    d.mkdir(parents=True)
    bad = d / f"model{ext}"
    if kind == "folder":
        bad.mkdir()
    elif kind != "missing":
        good = np.random.default_rng(3).standard_normal((40, 40))
        buf = d / f"good{ext}"
        if ext == ".npz":
            np.savez(buf, M=good, K=good)
        else:
            from scipy import io as sio
            sio.savemat(buf, {"M": good, "K": good})
        data = buf.read_bytes()
        bad.write_bytes({"empty": b"", "random": np.random.default_rng(4).bytes(3000),
                         "truncated": data[:len(data) // 2]}[kind])
    out = d / "model.txt"
    if entry == "--controller":
        argv = ["target-model", "--controller", str(bad), "--out", str(out)]
    else:
        rig = d / "rig.yaml"
        rig.write_text(f"{entry}: {bad.name}\n")
        argv = ["target-model", "--rig", str(rig), "--out", str(out)]
    code, res = _run(argv, capsys)
    assert code == 2 and not out.exists()
    if entry == "--controller" and kind in ("missing", "folder"):  # argparse's check of the option value
        errors = [ln for ln in res.err.splitlines() if "error:" in ln]
        assert len(errors) == 1 and "--controller" in errors[0] and str(bad) in errors[0]
        return
    line = _one_line(res.err, "target-model", str(bad))
    assert re.search(ENTRY_REFUSAL[kind], line), line


def test_export_keeps_what_is_there_and_names_what_import_could_not_read(files, capsys):
    d = files["dir"] / "export_checks"
    d.mkdir()
    mine = d / "rig.csv"
    mine.write_text("a rig's own record\n")
    code, res = _run(["export", files["good"], "--format", "csv", "--out", str(mine)], capsys)
    assert code == 2 and "--overwrite" in _one_line(res.err, "export", str(mine))
    assert mine.read_text() == "a rig's own record\n" and sorted(p.name for p in d.iterdir()) == ["rig.csv"]
    code, res = _run(["export", files["good"], "--format", "mat", "--out", str(d / "r.csv")], capsys)
    assert code == 2 and "give --out ending in .mat" in _one_line(res.err, "export", "r.csv")
    code, res = _run(["export", files["good"], "--format", "npz", "--out", str(d / "r.npz"), "--experiment", "x"],
                     capsys)
    assert code == 2 and re.search(r"no experiment 'x' \(it has \S+\)", _one_line(res.err, "export", "'x'"))
    assert sorted(p.name for p in d.iterdir()) == ["rig.csv"]
    code, _ = _run(["export", files["good"], "--format", "csv", "--out", str(mine), "--overwrite"], capsys)
    umask = os.umask(0)
    os.umask(umask)
    assert code == 0 and mine.stat().st_mode & 0o777 == 0o666 & ~umask   # not mkstemp's owner-only 0600
