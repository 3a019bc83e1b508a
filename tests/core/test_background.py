"""ambid.background: a function run in a detached process, its state in a status file (design.png, identify's
report). The process is real: a new session, its own interpreter; the status says writing, then done or failed."""

from __future__ import annotations

import os
import shutil

import pytest
from ambid.background import BackgroundFailed, read_status, start, wait


def test_the_job_runs_detached_and_says_done(tmp_path):
    src = tmp_path / "src.bin"
    src.write_bytes(os.urandom(1000))
    status = start(tmp_path / "job" / "status.json", shutil.copyfile, src, tmp_path / "job" / "copy.bin")
    first = read_status(status)
    assert first["state"] in ("writing", "done")   # never missing, never the old state
    done = wait(status, timeout_s=60)
    assert done["state"] == "done" and done["pid"] != os.getpid() and done["seconds"] >= 0
    assert (tmp_path / "job" / "copy.bin").read_bytes() == src.read_bytes()
    # its own session: not the caller's process group (Ctrl-C at the prompt does not reach it)
    assert os.getsid(0) != done["pid"]
    assert sorted(p.name for p in (tmp_path / "job").iterdir()) == ["copy.bin", "status.json"]


def test_a_failing_job_says_why(tmp_path):
    status = start(tmp_path / "status.json", shutil.copyfile, tmp_path / "missing", tmp_path / "copy")
    with pytest.raises(BackgroundFailed, match="FileNotFoundError"):
        wait(status, timeout_s=60)
    assert read_status(status)["state"] == "failed"
    assert "FileNotFoundError" in (tmp_path / "status.json.log").read_text()   # the traceback kept for whoever looks


def test_a_job_that_dies_without_a_word_is_told_apart_from_one_still_writing(tmp_path):
    status = start(tmp_path / "status.json", os.abort)   # SIGABRT: no status written after the start's
    with pytest.raises(BackgroundFailed, match="ended without a word"):
        wait(status, timeout_s=60)
    assert read_status(status)["state"] == "writing"


def test_nothing_started_is_not_waited_for(tmp_path):
    with pytest.raises(BackgroundFailed, match="nothing was started"):
        wait(tmp_path / "status.json", timeout_s=1)
