"""ambid bench: loop throughput, identify real-time factor, offline rates and memory, side by side.

Sections (each can be skipped):

* loop: plant + controller lock-step, composed and as processes, each beside a
  bare rclpy ping-pong of the same message size, QoS, executor and layout,
  interleaved (:mod:`ambid_cli.bench.loop`);
* identify: a full default ``identify`` session composed, recorder and
  consumer included (:mod:`ambid_cli.bench.identify`);
* analysis: a whole ``identify``: wall seconds from the last period to the
  headline and to the report, beside the analysis of the same recording after
  the session as it used to run (:mod:`ambid_cli.bench.live`);
* live: the live view's cost on the loop, an identify session with the live
  view and a connected Foxglove client against one without
  (:mod:`ambid_cli.bench.live`);
* offline: FRF of a session beside bare reads of the same MCAP file
  (:mod:`ambid_cli.bench.offline`);
* fit: the common-denominator fit of a 4x4 FRF of 2,000 lines;
* settling: measurement time at equal FRF error with and without settling
  periods (the transient removed by one rational model of all the segments'
  transients), on the core loop (:mod:`ambid_cli.bench.settling`);
* memory: peak memory of sessions of one kind, one six times longer
  (:mod:`ambid_cli.bench.memory`);
* commands: ``ambid design``, ``ambid fit FRF_FILE`` and ``ambid identify`` as typed at a terminal: wall
  time to the answer and to the end, the longest silence, identify's time beyond its session
  (:mod:`ambid_cli.bench.commands`);
* link: what the authenticated link (protocol version 3) costs the C reference
  target and the Python bridge beside version 2: CPU per datagram sealed and
  checked, and the C target
  at 10 kHz under the hardware bridge, its overruns and late samples
  (:mod:`ambid_cli.bench.link`).

The machine may be shared: the ratios (ours over bare, measured back to
back) are the robust figures; the load average is recorded with them.
Exit code 0 when every target is met, 1 when one is missed, 2 when a section failed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path

from ambid_cli.commands.inputs import output_dir, output_file, positive_float, positive_int
from ambid_cli.results_page import measured_on, write_section

from ambid.jsonable import to_jsonable

HELP = "measure loop throughput, identify real-time factor, offline rates and memory against the targets"
SECTIONS = ("commands", "loop", "identify", "analysis", "live", "offline", "fit", "settling", "memory", "link")
FACTOR = 6  # the long session of the memory figure is this many times longer

# the sizes of a --quick run (the smoke test): every section, seconds each
QUICK = {
    "loop_seconds": 0.2, "repeats": 1, "fit_lines": 200, "fit_order": 12,
    "identify": {"band_hz": (50.0, 1000.0), "resolution_hz": 50.0, "n_periods": 1, "n_realisations": 1,
                 "n_transient_periods": 1},
    "analysis": {"band_hz": (50.0, 1000.0), "resolution_hz": 50.0, "n_periods": 2, "n_realisations": 2,
                 "n_transient_periods": 1},
    "live": {"band_hz": (50.0, 1000.0), "resolution_hz": 50.0, "n_periods": 1, "n_realisations": 1,
             "n_transient_periods": 1},
    "live_repeats": 1,
    "offline_design": {"band_hz": (50.0, 1000.0), "resolution_hz": 50.0, "n_periods": 1, "n_realisations": 1,
                       "n_transient_periods": 1},
    "live_memory": {"band_hz": (50.0, 1000.0), "resolution_hz": 50.0, "n_periods": 1, "n_realisations": 1,
                    "n_transient_periods": 1},
    "settling": {"band_hz": (50.0, 1000.0), "resolution_hz": 50.0, "n_realisations": 1},
    "link_seconds": 0.3, "link_repeats": 2000,
    "commands_identify": ["--band", "50", "1000", "--resolution", "50", "--periods", "1", "--realisations", "1",
                          "--transient-periods", "1"],
}
# the default sizes: the identify session and the offline file are the default identify experiment
FULL = {
    # five rounds: this machine's speed drifts by up to 2x within seconds, the median of five pairs holds
    "loop_seconds": 2.0, "repeats": 5, "fit_lines": 2000, "fit_order": 24,
    "identify": {},
    "analysis": {},
    "live": {},
    "live_repeats": 5,   # five pairs of default identify sessions with and without the live view (the load drifts)
    "offline_design": {},
    "offline_memory_design": {"n_realisations": 1},
    "live_memory": {"resolution_hz": 10.0, "n_periods": 2, "n_realisations": 1, "n_transient_periods": 1},
    "settling": {},
    "link_seconds": 5.0, "link_repeats": 20000,  # 5 s at 10 kHz: 50,000 samples on absolute deadlines per version
    "commands_identify": [],   # the default experiment, as a user's first identify runs it
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", metavar="FILE", help="write every figure and its details to FILE")
    p.add_argument("--results", metavar="FILE",
                   help="write the figures as the bench section of a results page, e.g. docs/results.md")
    p.add_argument("--loop-seconds", type=positive_float, help="simulated time per loop run [s], >= 0.05 (default 2)")
    p.add_argument("--repeats", type=positive_int, help="interleaved rounds of the loop and offline timings (default 5)")
    p.add_argument("--fit-lines", type=positive_int, help="lines of the 4x4 FRF to fit (default 2000)")
    p.add_argument("--skip", default="", help=f"comma-separated sections to leave out: {','.join(SECTIONS)}")
    p.add_argument("--quick", action="store_true", help="tiny sizes everywhere (a smoke test, not a measurement)")
    p.add_argument("--work-dir", help="where session files go (default: a temporary directory, removed)")


def _figure(name: str, value, unit: str, target: str | None = None, ok: bool | None = None) -> dict:
    return {"name": name, "value": value, "unit": unit, "target": target, "pass": ok}


def _at_least(name: str, value: float | None, unit: str, low: float, label: str) -> dict:
    return _figure(name, value, unit, f">= {label}", None if value is None else bool(value >= low))


def _at_most(name: str, value: float | None, unit: str, high: float, label: str) -> dict:
    return _figure(name, value, unit, f"<= {label}", None if value is None else bool(value <= high))


def _commands_section(sizes: dict, work: Path, figures: list) -> dict:
    from ambid_cli.bench.commands import command_figures

    res = command_figures(work / "commands", sizes["commands_identify"])
    d, f, i = res["design"], res["fit"], res["identify"]
    figures += [
        _figure("ambid design (default experiment): wall time to the prompt", d["wall_s"], "s", "< 1 s",
                bool(d["wall_s"] < 1.0)),
        _figure("ambid design: design.png there (drawn in the background), from the start", d["figure_s"], "s"),
        _at_most(f"ambid fit {Path(f['file']).name}: wall time to its figures", f["to_figures_s"], "s", 2.0, "2 s"),
        _figure("ambid fit of that file: wall time, report written", f["wall_s"], "s"),
        _figure("ambid identify: the session (lift-off and experiment on the graph)", i["session_s"], "s"),
        _at_most("ambid identify: wall time beyond the session, to the headline", i["beyond_session_to_headline_s"],
                 "s", 8.0, "8 s"),
        _at_most("ambid identify: wall time beyond the session, to its exit (the report follows)",
                 i["beyond_session_s"], "s", 8.0, "8 s"),
        _figure("ambid identify: the report, written after the headline by a process of its own: its time",
                i["report_own_s"], "s"),
        _at_most("ambid identify on a terminal: longest silence", i["longest_silence_s"], "s", 3.0, "3 s"),
    ]
    return res


def _loop_section(sizes: dict, figures: list) -> dict:
    from ambid_cli.bench.loop import loop_figures

    import numpy as np
    from ambid.control.lqg import lqg_controller
    from ambid.plant.rig import make_rig

    # a user's controller file on the compiled path: the LQG's dense matrices as an .npz
    user = lqg_controller(make_rig())
    with tempfile.TemporaryDirectory(prefix="ambid_bench_ctrl_") as tmp:
        path = str(Path(tmp) / "user_controller.npz")
        np.savez(path, A=user.a, B=user.b, C=user.c, D=user.d, dt=user.dt)
        res = loop_figures(sizes["loop_seconds"], sizes["repeats"], user_controller=path)
    c, p = res["composed"], res["processes"]
    figures += [
        _at_least("loop composed: simulated samples/s", c["ours_samples_per_s"], "1/s", 20_000, "20000 (2x real time)"),
        _figure("bare ping-pong composed: round trips/s", c["bare_samples_per_s"], "1/s"),
        _at_least("loop composed / bare ping-pong composed", c["ratio"], "", 0.70, "0.70"),
        _figure(f"loop composed, user controller file ({user.n_states} states): samples/s", c["user_samples_per_s"],
                "1/s"),
        _at_least("loop composed, user controller file / bare ping-pong", c["user_ratio"], "", 0.70, "0.70"),
        _figure("loop composed: CPU per sample", c["ours_cpu_us_per_sample"], "us"),
        _figure("bare ping-pong composed: CPU per round trip", c["bare_cpu_us_per_sample"], "us"),
        _figure("loop composed / bare ping-pong composed, by CPU time", c["cpu_ratio"], ""),
        _figure("loop processes: simulated samples/s", p["ours_samples_per_s"], "1/s"),
        _figure("bare ping-pong processes: round trips/s", p["bare_samples_per_s"], "1/s"),
        _at_least("loop processes / bare ping-pong processes", p["ratio"], "", 0.80, "0.80"),
    ]
    return res


def _identify_section(sizes: dict, work: Path, figures: list) -> dict:
    from ambid_cli.bench.identify import identify_figures

    res = identify_figures(work / "identify", sizes["identify"])
    if not res["available"]:
        figures.append(_figure("identify session real-time factor (composed)", None, "x", ">= 1.0", None))
        return res
    figures += [
        _at_least("identify session real-time factor (composed)", res["real_time_factor"], "x", 1.0, "1.0"),
        _figure("identify session, loop only: real-time factor", res["loop_real_time_factor"], "x"),
    ]
    return res


def _analysis_section(sizes: dict, work: Path, figures: list) -> dict:
    from ambid_cli.bench.live import analysis_figures

    res = analysis_figures(work, sizes["analysis"])
    figures += [
        _at_most("analysis after the last period: headline", res.get("headline_after_last_period_s"), "s", 2.0,
                 "2 s"),
        _figure("analysis after the last period: report written", res.get("report_after_last_period_s"), "s"),
        _figure("the same recording analysed after the session (the old path)", res["before_s"], "s"),
        _figure("identify session beside its analysis process: samples/s", res["session_samples_per_s"], "1/s"),
    ]
    return res


def _live_section(sizes: dict, work: Path, figures: list) -> dict:
    from ambid_cli.bench.live import live_figures

    res = live_figures(work, sizes["live"], sizes["live_repeats"])
    figures += [
        _at_least("identify loop with the live view and a client / without", res["ratio"], "", 0.95, "0.95"),
        _figure("identify session with the live view and a client / without", res["session_ratio"], ""),
        _figure("live view and client CPU / identify session CPU", res["live_and_client_cpu_share"], ""),
        _figure("live view: messages the client received per session", res["client_messages"], ""),
    ]
    return res


def _offline_section(sizes: dict, work: Path, figures: list) -> dict:
    from ambid_cli.bench.offline import make_design, offline_figures, write_simulated_session

    path = work / "offline.mcap"
    t0 = time.perf_counter()
    info = write_simulated_session(path, make_design(**sizes["offline_design"]))
    info["write_s"] = time.perf_counter() - t0
    res = {"session": info, **offline_figures(path, info["samples"], sizes["repeats"])}
    figures += [
        _figure("offline FRF of a session: MB/s", res["frf"]["mb_per_s"], "MB/s"),
        _figure("offline FRF of a session: samples/s", res["frf"]["samples_per_s"], "1/s"),
        _figure("bare MCAP read (mcap iter_messages): MB/s", res["mcap_bare"]["mb_per_s"], "MB/s"),
        _figure("bare MCAP read (mcap iter_messages): samples/s", res["mcap_bare"]["samples_per_s"], "1/s"),
        _figure("session reader (ambid iter_messages): MB/s", res["session_iter"]["mb_per_s"], "MB/s"),
        _at_least("offline FRF / bare MCAP read", res["ratio_frf_to_bare"], "", 0.50, "0.50"),
    ]
    path.unlink()
    return res


def _fit_section(sizes: dict, figures: list) -> dict:
    from ambid_cli.bench.offline import fit_figures

    res = fit_figures(sizes["fit_lines"], sizes["fit_order"])
    figures.append(_at_most(f"4x4 fit of {res['n_lines']} lines, order {res['order']}: wall time",
                            res["time_s"], "s", 10.0, "10 s"))
    figures.append(_figure("4x4 fit: CPU time", res["cpu_time_s"], "s"))
    return res


def _settling_section(sizes: dict, figures: list) -> dict:
    from ambid_cli.bench.settling import settling_figures

    res = settling_figures(sizes["settling"])
    b, a = res["before"], res["after"]
    # the claim is the time at equal error (each run's whole ladder of realisations fitted: 10.7-12.9 s of the
    # default's 16.8 s over seeds 1-6); the error ratio at equal realisations is one draw of two runs' noise
    # (seeds 1-6: 1.17, 1.02, 1.06, 1.07, 1.01, 1.22; mean 1.09, sd 0.085): its bound, mean + 3 sd, catches a
    # transient model that fails, not the noise of one seed (1.15 failed seed 1 and seed 6 by chance)
    figures += [
        _figure(f"time at the default's FRF error ({100 * b['median_error']:.2f} %), {b['transient_periods']} settling "
                "periods (before)", b["time_s"], "s"),
        _at_most("time at that error, no settling periods, transient removed, by error = c / sqrt(time) fitted to "
                 "each run's realisations (after)", res["time_at_equal_error_by_law_s"], "s", b["time_s"],
                 "the default's time"),
        _at_most(f"FRF error, no settling periods ({a['time_at_default_realisations_s']:.3g} s) / default "
                 f"({b['time_s']:.3g} s), one seed", res["ratio_at_default_realisations"], "", 1.35, "1.35"),
    ]
    return res


def _memory_section(sizes: dict, work: Path, figures: list) -> dict:
    from ambid_cli.bench.memory import memory_figures

    res = memory_figures(work, {**sizes["offline_design"], **sizes.get("offline_memory_design", {})},
                         sizes["live_memory"], FACTOR)
    off, live = res["offline"], res["live"]
    figures += [
        _figure("offline FRF, short session: peak RSS", off["short"]["peak_mb"], "MB"),
        _at_most(f"offline FRF peak RSS, {FACTOR}x / 1x session", off["peak_ratio"], "", 1.10, "1.10"),
    ]
    if live["available"]:
        figures += [
            _figure("identify session composed, short: peak RSS", live["short"]["peak_mb"], "MB"),
            _at_most(f"identify session peak RSS, {FACTOR}x / 1x experiment", live["peak_ratio"], "", 1.10,
                     "1.10"),
        ]
    else:
        figures.append(_figure(f"identify session peak RSS, {FACTOR}x / 1x experiment", None, "", "<= 1.10"))
    return res


def _link_section(sizes: dict, work: Path, figures: list) -> dict:
    from ambid_cli.bench.link import datagram_costs, python_datagram_costs, real_time_run

    cost = datagram_costs(4, sizes["link_repeats"])
    py_cost = python_datagram_costs(4, max(5, sizes["link_repeats"] // 4))  # a fraction of a second
    runs = {v: real_time_run(work / "link", v, sizes["link_seconds"]) for v in (2, 3)}
    v2, v3 = cost["v2"], cost["v3"]
    figures += [
        _figure("C target: MEASUREMENT datagram encoded, version 2 (before)", v2["encode_measurement_ns"] / 1e3, "us"),
        _figure("C target: MEASUREMENT datagram encoded and sealed, version 3 (after)",
                v3["encode_measurement_ns"] / 1e3, "us"),
        _figure("C target: EXCITATION datagram decoded, version 2 (before)", v2["decode_excitation_ns"] / 1e3, "us"),
        _figure("C target: EXCITATION datagram decoded and its tag checked, version 3 (after)",
                v3["decode_excitation_ns"] / 1e3, "us"),
    ]
    for v, when in (("v2", "version 2 (before)"), ("v3", "version 3 (after)")):
        figures += [
            _figure(f"Python bridge/target: MEASUREMENT datagram packed, {when}", py_cost[v]["encode_measurement_ns"]
                    / 1e3, "us"),
            _figure(f"Python bridge/target: EXCITATION datagram opened, {when}", py_cost[v]["decode_excitation_ns"]
                    / 1e3, "us"),
        ]
    for v, run in runs.items():
        t = run["target"]
        when = ("before" if v < 3 else "after") + (f", SCHED_FIFO {run['priority']}" if run["priority"] else "")
        figures += [
            _at_least(f"C target at 10 kHz under the bridge, version {v} ({when}): samples/s", t["samples_per_wall_s"],
                      "1/s", 9_900, "9900"),
            _at_most(f"C target at 10 kHz, version {v} ({when}): overruns", t["overruns"], "count", 0, "0"),
            _figure(f"C target at 10 kHz, version {v} ({when}): samples started a period late", t["late_samples"],
                    "count"),
            _figure(f"C target at 10 kHz, version {v} ({when}): worst lateness", t["max_late_us"], "us"),
        ]
    return {"cost": cost, "python_cost": py_cost, "runs": runs}


def _format(value, unit: str) -> str:
    if value is None:
        return "n/a"
    if unit == "count":
        return f"{value:,.0f}"
    if unit in ("1/s",):
        return f"{value:,.0f} /s"
    if unit == "":
        return f"{value:.2f}"
    return f"{value:.3g} {unit}"


def print_table(figures: list, out=None) -> None:
    """The figures as a table: name, value, target, pass/FAIL."""
    out = sys.stdout if out is None else out
    w = max(len(f["name"]) for f in figures)
    out.write(f"{'figure':<{w}}  {'value':>14}  {'target':<22}  result\n")
    out.write("-" * (w + 48) + "\n")
    for f in figures:
        result = {True: "pass", False: "FAIL", None: "" if f["target"] is None else "n/a"}[f["pass"]]
        out.write(f"{f['name']:<{w}}  {_format(f['value'], f['unit']):>14}  {f['target'] or '':<22}  {result}\n")


def results_markdown(figures: list) -> str:
    """The figures as a markdown table: figure, value, target, result."""
    rows = ["| figure | value | target | result |", "| --- | --- | --- | --- |"]
    for f in figures:
        result = {True: "pass", False: "FAIL", None: "" if f["target"] is None else "n/a"}[f["pass"]]
        rows.append(f"| {f['name']} | {_format(f['value'], f['unit'])} | {f['target'] or ''} | {result} |")
    return "\n".join(rows)


def run(args: argparse.Namespace) -> int:
    if args.json:
        output_file(args.json, "--json")
    if args.results:
        output_file(args.results, "--results")
    if args.work_dir:
        output_dir(args.work_dir, "--work-dir")
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    unknown = skip - set(SECTIONS)
    if unknown:
        print(f"ambid bench: unknown section(s) {sorted(unknown)} in --skip; sections are {', '.join(SECTIONS)}",
              file=sys.stderr)
        return 2
    sizes = dict(QUICK if args.quick else FULL)
    for key, value, low in (("loop_seconds", args.loop_seconds, 0.05), ("repeats", args.repeats, 1),
                            ("fit_lines", args.fit_lines, 50)):
        if value is not None:
            if value < low:
                print(f"ambid bench: --{key.replace('_', '-')} must be at least {low}, got {value}", file=sys.stderr)
                return 2
            sizes[key] = value
    work = Path(args.work_dir) if args.work_dir else Path(tempfile.mkdtemp(prefix="ambid_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    report: dict = {
        "machine": {"cpu_count": os.cpu_count(), "python": platform.python_version(),
                    "rmw": os.environ.get("RMW_IMPLEMENTATION", ""),
                    "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS", ""),
                    "load_average_start": list(os.getloadavg())},
        "config": {"quick": args.quick, "skip": sorted(skip), **{k: v for k, v in sizes.items()}},
        "figures": [], "sections": {}, "errors": {},
    }
    figures = report["figures"]
    sections = {
        "commands": lambda: _commands_section(sizes, work, figures),
        "loop": lambda: _loop_section(sizes, figures),
        "identify": lambda: _identify_section(sizes, work, figures),
        "analysis": lambda: _analysis_section(sizes, work, figures),
        "live": lambda: _live_section(sizes, work, figures),
        "offline": lambda: _offline_section(sizes, work, figures),
        "fit": lambda: _fit_section(sizes, figures),
        "settling": lambda: _settling_section(sizes, figures),
        "memory": lambda: _memory_section(sizes, work, figures),
        "link": lambda: _link_section(sizes, work, figures),
    }
    t_start = time.perf_counter()
    try:
        for name in SECTIONS:
            if name in skip:
                continue
            print(f"ambid bench: {name} ...", file=sys.stderr, flush=True)
            t0 = time.perf_counter()
            load0 = os.getloadavg()[0]
            try:
                report["sections"][name] = sections[name]()
            except KeyboardInterrupt:
                raise
            except Exception as exc:  # noqa: BLE001 - one failed section must not lose the others
                report["errors"][name] = f"{type(exc).__name__}: {exc}"
                traceback.print_exc()
                print(f"ambid bench: the {name} section failed: {exc}", file=sys.stderr)
                continue
            report["sections"][name]["wall_s"] = time.perf_counter() - t0
            report["sections"][name]["load_average_1min"] = [load0, os.getloadavg()[0]]
    except KeyboardInterrupt:
        print("ambid bench: interrupted", file=sys.stderr)
        return 130
    finally:
        if not args.work_dir:
            shutil.rmtree(work, ignore_errors=True)
    report["machine"]["load_average_end"] = list(os.getloadavg())
    report["wall_s"] = time.perf_counter() - t_start
    if figures:
        print_table(figures)
    la = report["machine"]
    print(f"load average (1, 5, 15 min): start {', '.join(f'{x:.2f}' for x in la['load_average_start'])}; "
          f"end {', '.join(f'{x:.2f}' for x in la['load_average_end'])} on {la['cpu_count']} CPUs; "
          f"bench took {report['wall_s']:.0f} s")
    for name, err in report["errors"].items():
        print(f"section {name} FAILED: {err}")
    if args.json:
        Path(args.json).write_text(json.dumps(to_jsonable(report), indent=2))
        print(f"figures written to {args.json}")
    if args.results and figures:
        errors = "".join(f"\n\nSection {name} failed: {err}" for name, err in report["errors"].items())
        write_section(args.results, "bench", "Performance (`ambid bench`)",
                      f"{measured_on()} Sections: {', '.join(n for n in SECTIONS if n not in skip)}"
                      f"{' (--quick sizes: a smoke test, not a measurement)' if args.quick else ''}.\n\n"
                      + results_markdown(figures) + errors)
        print(f"results written to {args.results}")
    if report["errors"]:
        return 2
    return 1 if any(f["pass"] is False or (f["target"] and f["pass"] is None) for f in figures) else 0
