"""ambid export: a session's time records out as CSV, MAT (v5 or v7.3) or NPZ, with their MAP.yaml.

:func:`ambid.records.exporter.export_session`; ``ambid import FILE --map
FILE's MAP.yaml`` brings them back as a session with the same FRF.
"""

from __future__ import annotations

import argparse

HELP = "write a session's time records (y, u, ic, r, t) as csv|mat|mat73|npz and a MAP.yaml to import them"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ambid.records import WRITE_FORMATS

    p.add_argument("file", help="session .mcap file")
    p.add_argument("--format", required=True, choices=WRITE_FORMATS,
                   help="csv, mat (MAT v5), mat73 (MAT v7.3, HDF5) or npz")
    p.add_argument("--out", required=True, help="record file to write; <stem>.MAP.yaml is written beside it")
    p.add_argument("--experiment", help="experiment id (default: the last one recorded)")
    p.add_argument("--overwrite", action="store_true", help="replace --out (and its MAP.yaml) if they exist")


def run(args: argparse.Namespace) -> int:
    from ambid.records import RecordError
    from ambid.records.exporter import export_paths, export_session

    from ambid_cli.commands.inputs import BadInput, output_file, session_file

    path = session_file(args.file)
    output_file(args.out, "--out")
    if not args.overwrite:   # a rig's own record of the same name is not replaced unasked
        there = [str(p) for p in export_paths(args.out) if p.exists()]
        if there:
            raise BadInput(f"--out: {there[0]} exists; give a new file name or add --overwrite")
    try:
        res = export_session(path, args.out, args.format, args.experiment)
    except (RecordError, ValueError) as exc:
        raise BadInput(str(exc)) from None
    print(f"exported {res.n_rows} rows x {len(res.columns)} columns ({', '.join(res.columns)}) to {res.record}")
    print(f"map: {res.map_yaml}" + (f"; controller: {res.controller}" if res.controller else ""))
    print(f"back in: ambid import {res.record} --map {res.map_yaml} --out SESSION.mcap")
    return 0
