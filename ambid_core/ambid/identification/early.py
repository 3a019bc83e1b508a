"""identify's analysis in a process of its own, started with the session: the results seconds after its end.

:class:`EarlyAnalysis` starts a worker process when the session starts
(``spawn``: a fresh interpreter, nothing shared with the graph's). Then:

1. :meth:`~EarlyAnalysis.prepare`, as soon as the rig, the controller and the
   experiment are decided (before the graph starts): the worker computes what
   the analysis compares with and the measurement does not change
   (:func:`ambid.identification.references.reference_models`: the simulated rig's
   true models, the noise through its loop, the magnets' slopes at this
   excitation, the controller between the lines) on a thread of its own while
   the measurement runs on the other core. They are used only if their key
   matches the inputs the session then recorded;
2. :meth:`~EarlyAnalysis.analyse`, the moment the FRF consumer has the final
   estimate (the last period measured): the worker fits and updates
   (:func:`ambid.identification.identify_session` on those inputs,
   the reference models waited for only after the update) while the caller
   closes the graph and the recording; :meth:`summary`
   returns the summary before the report is written;
3. :meth:`~EarlyAnalysis.recording_closed`: the worker reads the closed
   recording once (its inputs' digest must equal the early ones: else it
   analyses the recording again and says so in the notes), writes the report,
   and :meth:`result` returns the final summary.

The numbers are those of ``identify_session`` on the recording: the same
functions on the same inputs (checked), only computed sooner.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
import traceback
from typing import Any

from ambid.identification.inputs import SessionInputs, read_session_inputs
from ambid.identification.pipeline import identify_session
from ambid.identification.references import reference_key, reference_models
from ambid.identification.result import Identification

__all__ = ["EarlyAnalysis", "EarlyAnalysisFailed"]


class EarlyAnalysisFailed(RuntimeError):
    """The worker failed or vanished; the caller analyses the recording itself."""


class EarlyAnalysis:
    """The analysis of one identify session in a worker process.

    Parameters
    ----------
    out_dir
        the identification's output folder (``identify_session``'s ``out_dir``).
    nice
        added to the worker's niceness: > 0 where the session has a real-time partner (a hardware
        target whose bridge must never fall silent), so that the analysis never takes its CPU.
    **options
        further arguments of ``identify_session`` (estimator, true_model, ...).
    """

    def __init__(self, out_dir: str | os.PathLike, nice: int = 0, **options: Any) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_worker, args=(child, os.fspath(out_dir), options, nice),
                                 name="ambid-analysis", daemon=True)
        self._proc.start()
        child.close()
        self.analysing = False
        self.times: dict[str, float] = {}    # perf_counter of each step, for the timing figures

    def prepare(self, inputs: SessionInputs, freq_hz, output_names, input_names) -> None:
        """The session's inputs without the FRF (``inputs.frf`` None), its lines and the FRF's channels
        (:func:`ambid.identification.references.reference_models`)."""
        self._send(("prepare", inputs, freq_hz, tuple(output_names), tuple(input_names)))
        self.times["prepare"] = time.perf_counter()

    def analyse(self, inputs: SessionInputs) -> None:
        """The inputs with the final FRF: the analysis starts."""
        self._send(("analyse", inputs))
        self.analysing = True
        self.times["analyse"] = time.perf_counter()

    def recording_closed(self) -> None:
        """The session file is complete: the worker may check its inputs against it and write the report."""
        self._send(("closed",))

    def summary(self, timeout_s: float = 600.0) -> tuple[Identification, dict]:
        """The result before the report (:func:`identify_session`'s), and how it was made
        (``references_s``: their computing time, ``references_used``: the session was the planned one)."""
        out = self._expect("summary", timeout_s)
        self.times["summary"] = time.perf_counter()
        return out

    def result(self, timeout_s: float = 600.0) -> tuple[Identification, list[str]]:
        """The final result (report written) and what the worker noted (an inputs mismatch)."""
        out = self._expect("done", timeout_s)
        self.times["done"] = time.perf_counter()
        return out

    def close(self) -> None:
        """End the worker (at once if it is still busy)."""
        try:
            self._conn.close()
        finally:
            if self._proc.is_alive():
                self._proc.terminate()
            self._proc.join(5)

    def _send(self, msg: tuple) -> None:
        try:
            self._conn.send(msg)
        except (OSError, EOFError, ValueError) as exc:
            raise EarlyAnalysisFailed(f"the analysis process is gone ({exc})") from None

    def _expect(self, what: str, timeout_s: float) -> Any:
        end = time.monotonic() + timeout_s
        while True:
            left = end - time.monotonic()
            try:
                ready = left > 0 and self._conn.poll(min(left, 0.5))
            except (OSError, EOFError) as exc:
                raise EarlyAnalysisFailed(f"the analysis process is gone ({exc})") from None
            if not ready:
                if not self._proc.is_alive():
                    raise EarlyAnalysisFailed(f"the analysis process ended (exit code {self._proc.exitcode})")
                if left <= 0:
                    raise EarlyAnalysisFailed(f"no {what} from the analysis process within {timeout_s:g} s")
                continue
            try:
                kind, *payload = self._conn.recv()
            except (OSError, EOFError) as exc:
                raise EarlyAnalysisFailed(f"the analysis process is gone ({exc})") from None
            if kind == "error":
                raise EarlyAnalysisFailed(payload[0])
            if kind == what:
                return payload[0] if len(payload) == 1 else tuple(payload)


def _worker(conn, out_dir: str, options: dict, nice: int = 0) -> None:
    """The worker process: references while the session runs, then the analysis, then the report."""
    if nice > 0:
        os.nice(nice)
    refs: dict[str, Any] = {}
    prep: threading.Thread | None = None

    def prepare(inputs: SessionInputs, freq_hz, output_names, input_names) -> None:
        t0 = time.perf_counter()
        try:
            refs["models"] = reference_models(inputs, freq_hz, output_names, input_names)
        except Exception:  # noqa: BLE001 - the analysis computes them itself then
            refs["error"] = traceback.format_exc()
        refs["seconds"] = time.perf_counter() - t0

    try:
        while True:
            kind, *args = conn.recv()
            if kind == "prepare":
                prep = threading.Thread(target=prepare, args=args, name="ambid-references", daemon=True)
                prep.start()
            elif kind == "analyse":
                _analyse(conn, out_dir, options, args[0], prep, refs)
                return
    except (EOFError, OSError, KeyboardInterrupt):
        return


def _analyse(conn, out_dir: str, options: dict, inputs: SessionInputs, prep: threading.Thread | None,
             refs: dict) -> None:
    notes: list[str] = []

    class _Mismatch(Exception):
        pass

    started, cpu0 = time.perf_counter(), time.process_time()

    def on_summary(summary: Identification) -> None:
        models = refs.get("models")
        used = models is not None and models.key == reference_key(inputs, inputs.frf.freq_hz,
                                                                    inputs.frf.output_names, inputs.frf.input_names)
        conn.send(("summary", summary, {"references_s": refs.get("seconds"), "references_used": used,
                                        "waited_for_references_s": waited,
                                        "analysis_s": time.perf_counter() - started,
                                        "analysis_cpu_s": time.process_time() - cpu0}))
        while conn.recv()[0] != "closed":
            pass
        recorded = read_session_inputs(inputs.path, options.get("estimator", "indirect"),
                                       inputs.experiment["experiment_id"], options.get("recover", False))
        if recorded.digest() != inputs.digest():
            raise _Mismatch

    waited = 0.0

    def references():   # asked for once the fit and the update are done: they may still be in the making
        nonlocal waited
        t0 = time.perf_counter()
        if prep is not None:
            prep.join()
        waited = time.perf_counter() - t0
        return refs.get("models")

    try:
        try:
            summary = identify_session(inputs.path, out_dir, inputs=inputs, references=references,
                                       on_summary=on_summary, **options)
        except _Mismatch:
            notes.append("the session's inputs seen while it ran differ from its recording's: analysed again from "
                         "the recording")
            summary = identify_session(inputs.path, out_dir, **options)
        conn.send(("done", summary, notes))
    except Exception as exc:  # noqa: BLE001 - said to the caller, which analyses the recording itself
        conn.send(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
