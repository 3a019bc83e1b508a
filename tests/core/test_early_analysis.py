"""identify's analysis started early (ambid.identification.early) gives the numbers of the recording's analysis.

A simulated session of the default rig (two realisations, the plant described as simulated) is analysed
twice: by identify_session on the file, and by the worker process fed as identify feeds it -- reference
models from what was planned while the session runs, then the inputs as the graph's messages carry them.
Both must agree exactly; inputs that do not match the recording are caught and analysed again from it.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from ambid.channels import RADIAL
from ambid.excitation import design_multisine
from ambid.plant.rig import make_rig
from ambid.identification.early import EarlyAnalysis
from ambid.identification import (identify_session, inputs_from_messages, read_session_inputs,
                                          reference_key, reference_models)
from session_testbench import design_message, plant_message, simulate_closed_loop, write_session

RIG = make_rig()
PRE = 3000
OPTIONS = dict(max_order=16)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    design = design_multisine((20.0, 600.0), 20.0, RIG.sample_rate_hz, list(RADIAL.inputs), 0.4,
                              n_periods=2, n_realisations=2, n_transient_periods=1, seed=5)
    names, x = simulate_closed_loop(RIG, design, PRE, post_samples=200, seed=6)
    root = tmp_path_factory.mktemp("early")
    path = root / "session.mcap"
    plant, dmsg = plant_message(RIG), design_message(design, PRE)
    write_session(path, [(k, x[k:k + 1000]) for k in range(0, len(x), 1000)], names, [(0, dmsg)], RIG.dt,
                  plant=plant)
    reference = identify_session(path, root / "reference", **OPTIONS)
    return dict(root=root, path=path, design=design, plant=plant, design_msg=dmsg, reference=reference)


def _same(a: dict, b: dict) -> None:
    skip = {"wall_s", "files", "session"}
    assert {k: v for k, v in a.items() if k not in skip} == {k: v for k, v in b.items() if k not in skip}


def test_the_messages_give_the_recordings_inputs(session):
    rec = read_session_inputs(session["path"])
    msgs = inputs_from_messages(session["path"], "/amb/excitation/design", SimpleNamespace(**session["design_msg"]),
                                SimpleNamespace(**session["plant"]), None, rec.frf, False)
    assert msgs.digest() == rec.digest()
    other = dataclasses.replace(rec, frf=dataclasses.replace(rec.frf, frf=rec.frf.frf * (1 + 1e-12)))
    assert other.digest() != rec.digest()


def test_reference_models_are_used_only_for_their_own_inputs(session):
    rec = read_session_inputs(session["path"])
    f = rec.frf.freq_hz
    chans = (rec.frf.output_names, rec.frf.input_names)
    refs = reference_models(dataclasses.replace(rec, frf=None), f, *chans)
    assert refs.key == reference_key(rec, f, *chans) and refs.true_g is not None and refs.true_poles is not None
    assert reference_key(dataclasses.replace(rec, nonlinear_magnets=True), f, *chans) != refs.key
    assert reference_key(rec, f, chans[0][:2], chans[1]) != refs.key
    # handed over ready-made, or left to identify_session: the same numbers
    _same(identify_session(session["path"], session["root"] / "given", inputs=rec, references=refs, report=False,
                           **OPTIONS), session["reference"])


def _early(out, inputs, planned=None, freq_hz=None, report=True):
    """The worker fed as identify feeds it: (first summary, how, final summary, notes)."""
    early = EarlyAnalysis(out, report=report, **OPTIONS)
    try:
        if planned is not None:
            early.prepare(planned, freq_hz, RADIAL.outputs, RADIAL.inputs)
        early.analyse(inputs)
        early.recording_closed()
        return (*early.summary(), *early.result())
    finally:
        early.close()


def test_the_early_analysis_gives_the_recordings_numbers(session):
    rec = read_session_inputs(session["path"])
    first, how, final, notes = _early(session["root"] / "early", rec, dataclasses.replace(rec, frf=None),
                                      session["design"].freq_hz)
    assert how["references_used"] and notes == []
    _same(first, session["reference"])
    _same(final, session["reference"])
    assert (session["root"] / "early" / "report" / "index.html").is_file()


def test_inputs_unlike_the_recording_are_analysed_again_from_it(session):
    rec = read_session_inputs(session["path"])
    wrong = dataclasses.replace(rec, frf=dataclasses.replace(rec.frf, frf=rec.frf.frf * 1.01))
    first, _, final, notes = _early(session["root"] / "wrong", wrong, report=False)   # the numbers only
    assert first["frf_error"] != session["reference"]["frf_error"]   # what was shown first came from them
    assert notes and "analysed again from the recording" in notes[0]
    _same(final, session["reference"])
    np.testing.assert_array_equal(np.load(session["root"] / "wrong" / "frf.npz")["frf"], rec.frf.frf)


def test_the_report_in_the_background_follows_the_result_and_is_the_same_page(session):
    """identify's way: the worker returns once the numbers are written; the report's figures follow from a
    detached process (what it was handed crosses as a pickle), the page the one written in line."""
    from ambid.background import read_status, wait

    rec = read_session_inputs(session["path"])
    out = session["root"] / "background"
    early = EarlyAnalysis(out, report="background", **OPTIONS)
    try:
        early.analyse(rec)
        early.recording_closed()
        first, _ = early.summary()
        final, notes = early.result()
    finally:
        early.close()
    assert notes == []
    _same(final, session["reference"])
    assert final["files"]["report"] == str(out / "report" / "index.html")
    assert read_status(out / "report" / "status.json")["state"] in ("writing", "done")
    done = wait(out / "report" / "status.json")
    assert done["state"] == "done" and done["seconds"] > 0
    page, ref = ((d / "report" / "index.html").read_text() for d in (out, session["root"] / "reference"))
    figures = sorted(p.name for p in (out / "report").glob("*.png"))
    assert figures == sorted(p.name for p in (session["root"] / "reference" / "report").glob("*.png")) and figures
    # the same page but for where it was written and the wall times in it
    assert len(page.splitlines()) == len(ref.splitlines())
    assert not list((out / "report").glob("status.json.job"))   # the hand-over is gone once read
