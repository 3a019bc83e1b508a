"""ambid fit: identify the rig from a recorded session, or fit a measured FRF file (never imports rclpy).

A session (.mcap): FRF, order selection, fitted model (state space as .npz
and JSON), modes, physical-model updating and the HTML report, all written
to ``--out`` (:func:`ambid.identification.identify_session`).
An FRF file (.npz, .mat, .csv, UFF 58 .uff/.unv, Touchstone .sNp; :mod:`ambid.frf.frf_file`):
the same fit, the modes with their intervals and a report
(:func:`ambid.identification.frf_file_fit.identify_frf`). The headline figures are printed.
"""

from __future__ import annotations

import argparse
import json
import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ambid.identification.result import FitFigures, Identification, MeasuredFrfFit, OutputFiles, UpdateFigures

HELP = ("identify a recorded session (FRF, fitted model and modes, updated physical parameters, report), or fit a "
        "measured FRF file (.npz, .mat, .csv, UFF 58)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ambid.frf.streaming import ESTIMATORS

    from ambid_cli.commands.inputs import positive_int

    p.add_argument("file", help="session .mcap file, or a measured FRF: .npz/.mat (freq_hz, H (n, ny, nu), optional "
                                "var, outputs, inputs), .csv (freq_hz, re(<out>/<in>), im(<out>/<in>) [, var(..)]), "
                                "UFF 58 (.uff, .unv) or Touchstone (.s1p, .s2p, ...)")
    p.add_argument("--out", required=True, help="output folder (model.npz, model.json, frf.npz, "
                                                "identification.json, report/index.html)")
    p.add_argument("--estimator", default="indirect", choices=ESTIMATORS, help="FRF estimator (default indirect)")
    p.add_argument("--order", type=positive_int, help="model order (default: chosen from the stabilisation diagram)")
    p.add_argument("--max-order", type=positive_int, default=32, help="highest order in the stabilisation diagram")
    p.add_argument("--experiment", help="experiment id (default: the last one recorded)")
    p.add_argument("--rig", help="rig parameter YAML for the nominal model and updating "
                                 "(default: the rig recorded in the session)")
    p.add_argument("--no-update", action="store_true", help="skip the physical-model updating")
    p.add_argument("--no-report", action="store_true", help="skip the HTML report")
    p.add_argument("--recover", action="store_true", help="read a file a killed recorder left")
    p.add_argument("--delay", type=float, default=0.0, metavar="SECONDS",
                   help="FRF files: a known pure delay of the measurement [s] (default 0)")
    p.add_argument("--json", action="store_true", help="print the whole summary as JSON")


def _pct(x) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{100 * x:.3g} %"


def format_summary(s: Identification) -> str:
    """Headline figures of an identification, a few lines of text."""
    from ambid.frf.sensitivity import sensitivity_lines
    from ambid.jsonable import to_jsonable

    ex, fit, sens, noise = s.excitation, s.fit, s.sensitivity, s.noise
    lines = [f"experiment {s.experiment_id}: {ex.kind} ({ex.mimo}), {ex.n_excited_lines} lines in "
             f"{s.band_hz[0]:g}-{s.band_hz[1]:g} Hz, {s.estimator} estimator, "
             f"{len(s.inputs)} inputs x {len(s.outputs)} outputs"]
    ctrl = s.controller
    if ctrl:
        lines.append(f"controller that ran: {ctrl['kind']} ({ctrl['n_states']} states, delay {ctrl['delay_samples']} "
                     "sample(s))")
    err = s.frf_error
    if err:
        lines.append(f"FRF error vs true rig: median {_pct(err.median)}, worst {_pct(err.worst)} at "
                     f"{err.worst_at_hz:g} Hz (fitted model: median {_pct(err.fitted_median)})")
    # as the summary's JSON holds them: a value that is not finite is none
    std = to_jsonable(noise.output_noise_std_m) or []
    ci = to_jsonable(noise.output_noise_std_ci95_m) or [None] * len(std)
    odd, even = to_jsonable(noise.distortion_odd_db), to_jsonable(noise.distortion_even_db)
    units = set(s.output_units or ["m"])
    k, unit = (1e6, "um") if units == {"m"} else (1.0, "/".join(sorted(units)))
    if any(v is not None for v in std):   # a record of one non-periodic excitation has no noise figure
        lines.append(f"output noise std [{unit}] (95 % interval): "
                     + ", ".join("-" if v is None else f"{v * k:.4g}" + ("" if c is None or None in c else
                                                                         f" ({c[0] * k:.4g}..{c[1] * k:.4g})")
                                 for v, c in zip(std, ci))
                     + (f"; detection lines above noise: odd {max(odd):+.1f} dB, even {max(even):+.1f} dB (worst "
                        "output)" if odd and even and None not in odd + even else ""))
    lines.append(f"model order {fit.order} (chi2/dof {fit.chi2_per_dof:.3g}); modes: "
                 + (", ".join(f"{m.freq_hz:.5g} Hz / zeta {m.damping:.3g}" for m in fit.modes) or "none"))
    lines += _computational_lines(fit)
    plant = [r for r in fit.real_poles if r.physical]
    if plant:
        lines.append(f"unstable real pole at {plant[0].pole_hz:.4g} Hz: {plant[0].reason}")
    if s.max_mode_freq_error is not None:
        lines.append(f"modes vs true: worst frequency error {_pct(s.max_mode_freq_error)}, worst damping error "
                     f"{_pct(s.max_mode_damping_error)}")
    lines += _update_lines(s.update)
    lines += sensitivity_lines(sens)
    lines += [f"data quality: {q['text']}" for q in s.quality.findings]
    if sens.updated_peak is not None:
        lines.append(f"updated model with the recorded controller: sensitivity peak {max(sens.updated_peak):.3g}, "
                     f"zone {sens.updated_iso_zone}")
    lines.append(_written(s.files))
    lines += [f"note: {n}" for n in s.notes]
    return "\n".join(lines)


def _update_lines(upd: UpdateFigures | None) -> list[str]:
    """The updated ki and ks, the total lag, what the tolerances set, or why the update failed."""
    if upd is None:
        return []
    if upd.error is not None:
        return [f"model updating failed: {upd.error}"]
    lines = []
    for name in ("ki_n_per_a", "ks_n_per_m"):
        p = (upd.parameters or {}).get(name)
        if p:
            ci = p.ci95 or [math.nan, math.nan]
            true = "" if p.true is None else f", true {p.true:.6g} ({_pct(p.error)})"
            lines.append(f"updated {name}: {p.value:.6g} (95 % CI {ci[0]:.6g} .. {ci[1]:.6g}), nominal "
                         f"{p.nominal:.6g}{true}")
    lag = upd.total_lag
    if lag:
        true = "" if lag.true is None else f", true {lag.true * 1e6:.5g}"
        lines.append(f"total lag (amplifier + sensor + delay): {lag.value * 1e6:.5g} us (95 % CI "
                     f"{lag.ci95[0] * 1e6:.5g} .. {lag.ci95[1] * 1e6:.5g}){true}")
    if upd.prior_dominated:
        lines.append(f"set mostly by their tolerances (the data tell little): {', '.join(upd.prior_dominated)}")
    return lines


def _computational_lines(fit: FitFigures) -> list[str]:
    """One line on the fit's poles that are not modes (kept apart in identification.json), by reason."""
    comp = fit.computational_poles
    if not comp:
        return []
    by: dict[str, int] = {}
    for c in comp:
        key = c.reason.split(" (")[0].split(":")[0].replace("; computational", "")
        by[key] = by.get(key, 0) + 1
    return [f"{len(comp)} computational pole(s) kept apart, not modes (fit.computational_poles): "
            + "; ".join(f"{n} {k}" for k, n in by.items())]


def _written(files: OutputFiles) -> str:
    return (f"written: {files.model_npz}, {files.model_json}" +
            (f", report {files.report}" if files.report is not None else ""))


def format_frf_summary(s: MeasuredFrfFit) -> str:
    """Headline figures of a measured FRF's fit, a few lines of text."""
    fit = s.fit
    unit = f", {s.form} [{s.unit}]" if s.unit else (f", {s.form}" if s.form else "")
    lines = [f"{s.source} ({s.format}{unit}): {len(s.outputs)} outputs x {len(s.inputs)} inputs, "
             f"{s.n_lines} frequencies in {s.band_hz[0]:g}-{s.band_hz[1]:g} Hz, variance "
             + ("given" if s.var_given else "not given"),
             f"model order {fit.order} ("
             + (f"chi2/dof {fit.chi2_per_dof:.3g}" if s.var_given else
                f"relative rms misfit {100 * math.sqrt(max(fit.chi2_per_dof, 0.0)):.2g} %")
             + "); modes (95 % interval):"]
    for m in fit.modes:
        ci_f, ci_z = (None, None) if m.interval is None else (m.interval.freq_hz_ci95, m.interval.damping_ci95)
        lines.append(f"  {m.freq_hz:.6g} Hz" + (f" ({ci_f[0]:.6g}..{ci_f[1]:.6g})" if ci_f else "")
                     + f", zeta {m.damping:.4g}" + (f" ({ci_z[0]:.3g}..{ci_z[1]:.3g})" if ci_z else ""))
    if not fit.modes:
        lines.append("  none in the band")
    lines += _computational_lines(fit)
    lines += [f"data quality: {q['text']}" for q in s.quality.findings]
    lines.append(f"intervals: {s.intervals.modes}")
    lines.append(_written(s.files))
    lines += [f"note: {n}" for n in s.notes]
    return "\n".join(lines)


def _run_frf_file(args: argparse.Namespace) -> int:
    from ambid.frf.frf_file import FrfFileError, read_frf_file
    from ambid.identification.frf_file_fit import identify_frf

    from ambid_cli.commands.inputs import BadInput, output_dir

    try:
        measured = read_frf_file(args.file)   # checked before --out is touched
    except FrfFileError as exc:
        raise BadInput(str(exc)) from None
    output_dir(args.out)
    session_only = [opt for opt, given in (("--experiment", args.experiment), ("--rig", args.rig),
                                           ("--no-update", args.no_update), ("--recover", args.recover),
                                           ("--estimator", args.estimator != "indirect")) if given]
    if session_only:
        raise BadInput(f"{', '.join(session_only)} apply to a session, not to an FRF file; leave them out")
    if not (args.delay >= 0 and args.delay < 1):
        raise BadInput(f"--delay {args.delay} s; give the measurement's pure delay in seconds, >= 0 and < 1")
    shown = []

    def show(summary: MeasuredFrfFit) -> None:   # the figures at once; the report is written after them
        if not args.json:
            print(format_frf_summary(summary) + ("" if args.no_report else "\nwriting the report ..."), flush=True)
            shown.append(True)
            phases.say("writing the report", line=False)

    from ambid_cli.heartbeat import current

    phases = current()   # on a terminal, status lines through the pauses (nothing added to a log)
    phases.say("fitting: stabilisation diagram, order, modes and their intervals", line=False)
    try:
        summary = identify_frf(measured, args.out, order=args.order, max_order=args.max_order, delay_s=args.delay,
                               report=not args.no_report, on_summary=show)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    if args.json:
        print(json.dumps(summary.to_json(), indent=1))
    elif not args.no_report:
        print(f"report written: {summary.files.report}")
    return 0


def run(args: argparse.Namespace) -> int:
    from ambid.frf.frf_file import is_frf_file
    from ambid.recording import IncompleteSessionError

    if is_frf_file(args.file):
        return _run_frf_file(args)
    from ambid.identification.pipeline import identify_session

    from ambid_cli.commands.inputs import BadInput, output_dir, rig_file, session_file

    path = session_file(args.file, args.recover)  # checked before --out is touched: nothing is overwritten
    output_dir(args.out)
    if args.rig:
        rig_file(args.rig)
    from ambid_cli.heartbeat import current

    current().say("identifying the session: FRF, fit, model update, report", line=False)
    try:
        summary = identify_session(path, args.out, estimator=args.estimator, order=args.order,
                                   experiment_id=args.experiment, rig=args.rig, max_order=args.max_order,
                                   update=not args.no_update, report=not args.no_report, recover=args.recover)
    except IncompleteSessionError as exc:
        raise BadInput(f"{exc}; or run 'ambid fit --recover {path} --out {args.out}'") from None
    except ValueError as exc:  # the session cannot give what fit needs: it says what and why
        raise BadInput(str(exc)) from None
    print(json.dumps(summary.to_json(), indent=1) if args.json else format_summary(summary))
    return 0
