"""ambid design: the preview command and build_design (the user's terms -> ExcitationDesign)."""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from ambid.background import wait
from ambid.channels import RADIAL
from ambid.excitation import ExcitationDesign, check_headroom
from ambid_cli.commands import design as cmd

ROOT = Path(__file__).resolve().parents[2]


def parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    cmd.add_arguments(p)
    return p.parse_args(argv)


def test_preview_runs_without_rclpy_and_writes_what_it_reports(tmp_path):
    argv = ["design", "--band", "20", "800", "--resolution", "10", "--periods", "3", "--out", str(tmp_path), "--json"]
    code = ("import json, sys\nfrom ambid_cli.cli import main\n"
            f"rc = main({argv!r})\nprint(json.dumps({{'rc': rc, 'rclpy': 'rclpy' in sys.modules}}))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         cwd=tmp_path, env=dict(os.environ, PYTHONPATH=os.pathsep.join(str(ROOT / d) for d in ("ambid_core", "ambid_nodes", "ambid_cli"))))
    assert run.returncode == 0, run.stderr
    summary, status = (json.loads(line) for line in run.stdout.strip().splitlines()[-2:])
    assert status == {"rc": 0, "rclpy": False}

    # design.json is the design build_design makes from the same terms, at the default rig's 10 kHz
    design = ExcitationDesign.from_dict(json.loads((tmp_path / "design.json").read_text()))
    assert design == cmd.build_design("multisine", (20.0, 800.0), 10.0, 10_000.0, input_names=RADIAL.inputs,
                                      peak_current_a=0.4, n_periods=3)
    # orthogonal multisine, 4 inputs, identify's M = 3 and Pt = 3: Ne M (Pt + P) N / fs = 4 x 3 x (3 + 3) x 1000 / 10 kHz
    assert summary["measurement_time_s"] == pytest.approx(4 * 3 * 6 * 1000 / 10_000.0)
    assert summary["n_lines"] == design.excited_lines.size and summary["peak_a"] == pytest.approx([0.4] * 4)
    # 3 A limit - 1 A working current - 0.4 A peak
    assert summary["headroom"]["ok"] and summary["headroom"]["margin_a"] == pytest.approx([1.6] * 4)
    plan = {row["method"]: row["measurement_time_s"] for row in summary["plan"]}
    assert plan["orthogonal multisine"] == pytest.approx(summary["measurement_time_s"])
    assert plan["stepped sine"] > 8 * plan["orthogonal multisine"]  # 63 s against 7.2 s for M = 3 realisations
    # the figure, drawn by a detached process once the command has answered: said "writing" at once, then done
    assert summary["figure_status"] == str(tmp_path / "design.status.json")
    assert wait(summary["figure_status"])["state"] == "done"
    assert (tmp_path / "design.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_headroom_refusal_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys):
    out_dir = tmp_path / "refused"
    args = parse(["--peak-current", "2.5", "--resolution", "20", "--no-plan", "--out", str(out_dir)])
    assert cmd.run(args) == 2
    out = capsys.readouterr()
    assert out.out == "" and not out_dir.exists()
    # 2.5 A + the 1 A working current > the rig's 3 A on every input
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ambid design: headroom: REFUSED")
    assert "give --peak-current 2 or less" in lines[0] and "u_a_x, u_b_x, u_a_y, u_b_y" in lines[0]
    # at the edge it fits: 2 A + 1 A working current is the 3 A limit
    args = parse(["--peak-current", "2", "--resolution", "20", "--no-plan", "--no-figure", "--out", str(out_dir)])
    assert cmd.run(args) == 0
    assert "headroom: fits the 3 A amplifier limit" in capsys.readouterr().out


def test_bad_terms_give_a_clear_error(tmp_path, capsys):
    assert cmd.run(parse(["--band", "10", "6000", "--out", str(tmp_path)])) == 2
    assert "Nyquist" in capsys.readouterr().err
    with pytest.raises(ValueError, match="phases 'schroeder' does not apply to a noise design"):
        cmd.build_design("noise", (10.0, 1000.0), 5.0, 10_000.0, phases="schroeder")
    with pytest.raises(ValueError, match="mimo of a multisine design must be one of"):
        cmd.build_design("multisine", (10.0, 1000.0), 5.0, 10_000.0, mimo="simultaneous")


def test_kind_defaults_and_prbs_clock():
    swept = cmd.build_design("swept_sine", (10.0, 1000.0), 5.0, 10_000.0, spacing="log")
    assert swept.options == {"law": "log", "mimo": "one_at_a_time"}
    assert cmd.build_design("dibs", (10.0, 1000.0), 5.0, 10_000.0).options["grid"] == "odd"
    # divider: largest d with 1000 Hz <= 10 kHz / (3 d) -> 3; order: smallest with 3 (2^o - 1) >= 10 kHz / 5 Hz
    order, divider = cmd.prbs_clock((10.0, 1000.0), 5.0, 10_000.0)
    assert divider == math.floor(10_000 / 3000)
    assert 3 * (2**order - 1) >= 2000 > 3 * (2 ** (order - 1) - 1)
    prbs = cmd.build_design("prbs", (10.0, 1000.0), 5.0, 10_000.0)
    assert prbs.n_per_period == divider * (2**order - 1) and prbs.fs_hz / prbs.n_per_period <= 5.0
    assert np.all(prbs.peak_a == pytest.approx(0.4))  # identify's peak, the default


def test_every_command_defaults_to_the_one_experiment():
    """design, identify and campaign with no experiment options, and the session validate and the generator
    node run, are DesignSpec(): the one home of the experiment's defaults."""
    import yaml
    from ambid.excitation.spec import DesignSpec
    from ambid.quantity import quantities
    from ambid_cli.commands import campaign, identify
    from ambid_cli.commands.inputs import experiment_spec

    spec = DesignSpec()
    for module, argv in ((cmd, []), (identify, []), (campaign, ["--speeds-rpm", "0", "--out", "c"])):
        p = argparse.ArgumentParser()
        module.add_arguments(p)
        args = p.parse_args(argv)
        terms = {"input_names": tuple(s for s in args.inputs.split(",") if s)} if module is cmd else {}
        assert experiment_spec(args, **terms) == spec, module.__name__
    # the generator's parameter file (tests/nodes/test_config_files.py: file == the node's declared defaults)
    gen = yaml.safe_load((ROOT / "ambid_nodes" / "config" / "excitation_generator.yaml").read_text())
    p = gen["/**"]["ros__parameters"]
    terms = {name: p[name] for name, _, _ in quantities(DesignSpec)}
    terms.update(band_hz=tuple(p["band_hz"]), input_names=() if p["input_names"] == ["auto"] else tuple(p["input_names"]))
    assert DesignSpec(**terms) == spec
    # identify's experiment: orthogonal random-odd crest-optimised multisine, 0.4 A, M = 3, 3 + 4 periods
    assert (spec.peak_current_a, spec.n_realisations, spec.n_transient_periods, spec.n_periods) == (0.4, 3, 3, 4)


def test_the_text_preview_shows_the_plan_of_the_same_lines(tmp_path, capsys):
    args = parse(["--resolution", "20", "--realisations", "1", "--phases", "random", "--no-figure",
                  "--out", str(tmp_path)])
    assert cmd.run(args) == 0
    out = capsys.readouterr().out
    assert "measurement time of the full 4 x 4 FRF matrix on the same lines:" in out and "stepped sine" in out
