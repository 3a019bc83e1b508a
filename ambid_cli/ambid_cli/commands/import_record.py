"""ambid import: a real rig's time records become a session (never imports rclpy).

Reads DATA (.csv, .mat v5/v7.3, .npz) in chunks as MAP.yaml maps it
(:mod:`ambid.records.mapping`), checks every row, finds the excitation
design again when MAP.yaml gives none, and writes SESSION.mcap in the
recorder's layout (:func:`ambid.records.importer.import_record`); prints what
it found, the throughput and the peak memory.
"""

from __future__ import annotations

import argparse
import os
import resource

HELP = "convert a rig's time records (CSV, MAT v5/v7.3, NPZ) and their MAP.yaml into a session .mcap"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", nargs="+", help="the record: .csv (header row), .mat (v5 or v7.3; LMS/Simcenter structs "
                                           "too) or .npz; several .mat/.npz files of one recording side by side")
    p.add_argument("--map", required=True, help="MAP.yaml: sample rate or time column, outputs, currents, "
                                                "excitation (+ controller, design)")
    p.add_argument("--out", required=True, help="session .mcap to write")
    p.add_argument("--overwrite", action="store_true", help="replace --out if it exists")


def run(args: argparse.Namespace) -> int:
    from ambid.records import RecordError
    from ambid.records.importer import import_record

    from ambid_cli.commands.inputs import BadInput, output_file

    out = output_file(args.out, "--out")
    for given, what in [(d, "the record") for d in args.data] + [(args.map, "MAP.yaml")]:   # --overwrite: replace
        if out.exists() and os.path.exists(given) and os.path.samefile(out, given):
            raise BadInput(f"--out {out} is {what} being imported; give a new .mcap file name")
    if out.exists() and not args.overwrite:
        raise BadInput(f"--out {out} exists; give a new file name or add --overwrite")
    try:
        res = import_record(args.data if len(args.data) > 1 else args.data[0], args.map, out)
    except RecordError as exc:
        raise BadInput(str(exc)) from None
    except OSError as exc:
        raise BadInput(f"{' '.join(args.data)}: cannot be read ({exc.strerror or exc}); check the file") from None
    d = res.design
    print(f"imported {res.n_rows} rows at {res.fs_hz:g} Hz from {' + '.join(args.data)} "
          f"({res.bytes_read / 1e6:.3g} MB in {res.seconds:.3g} s, {res.bytes_read / 1e6 / res.seconds:.3g} MB/s; "
          f"peak memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB)")
    if d.kind == "recorded":
        print(f"the excitation does not repeat itself: {d.n_per_period} rows from row {res.start_row + 1}, "
              f"{d.excited_lines.size} lines in {d.band_hz[0]:g}-{d.band_hz[1]:g} Hz")
    else:
        print(("design found from the excitation:" if res.reconstructed else "design given:") +
              f" {d.kind}, N = {d.n_per_period}, P = {d.n_periods}, Pt = {d.n_transient_periods}, "
              f"M = {d.n_realisations}, Ne = {d.n_experiments}, {d.excited_lines.size} lines, experiment from row "
              f"{res.start_row + 1}")
    print(res.estimator)
    for note in res.notes:
        print(f"  {note}")
    print(f"written: {res.session} ({os.path.getsize(res.session) / 1e6:.3g} MB); "
          f"next: ambid fit {res.session} --out DIR")
    return 0
