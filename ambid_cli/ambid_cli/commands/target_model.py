"""ambid target-model: write the model file the C reference target runs (docs/target_c.md)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ambid.control.kinds import describe_kinds

from ambid_cli.commands.inputs import BadInput, checked_controller, controller, output_file, rig_file

HELP = "write the plant and controller model file of the C reference target (ambp_udp_target --model)"

# where `ambid setup` builds the C target (launch_scripts/setup/setup.sh, ambid_build_target_c)
TARGET_C_DIR = Path(__file__).resolve().parents[3] / "ros_ws" / "install" / "target_c"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="model file to write (text)")
    p.add_argument("--rig", default="", help="rig parameter YAML file (default: the built-in rig)")
    p.add_argument("--controller", type=controller, default="",
                   help=f"position controller: {describe_kinds()}, or a controller file (.npz, .mat, .yaml) "
                        "(default: the rig file's controller, else pid)")


def run(args: argparse.Namespace) -> int:
    from ambid.hardware.target_model import rig_target_model, write_target_model

    out = output_file(args.out, "--out")
    rig = rig_file(args.rig)
    checked_controller(args.controller, rig)  # an unknown or unstable controller stops here
    try:
        model = rig_target_model(rig, args.controller)
        write_target_model(out, model)
    except (ValueError, OSError) as exc:
        raise BadInput(str(exc)) from None
    print(f"ambid target-model: {out}: {model.plant.n_states}-state plant (true rig, ZOH at {model.dt:g} s), "
          f"{model.controller.n_states}-state controller, axes {' '.join(model.layout.axes)}, sensor noise "
          f"{', '.join(f'{v:.3g}' for v in dict.fromkeys(model.noise_std_m.tolist()))} m")
    binary = TARGET_C_DIR / "ambp_udp_target"
    if binary.is_file() and os.access(binary, os.X_OK):
        print(f"run it: {binary} --model {out} --bind 127.0.0.1:50001 --bridge 127.0.0.1:50002")
    return 0
