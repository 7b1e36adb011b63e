"""One microcal at a time in a run directory: the lock names its holder and ends with it."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from support.cli import invoke_microcal
from support.runs import fails_cleanly, file_hashes


@pytest.fixture
def run(acquired_run, tmp_path) -> Path:
    """This test's own copy of the session's 12-pose run."""
    return shutil.copytree(acquired_run[0], tmp_path / "run")


@pytest.fixture
def cameras(acquired_run) -> Path:
    return acquired_run[1]


def test_a_run_in_use_is_refused_with_the_pid_of_its_holder(run, cameras):
    from microcal.formats.run_lock import run_lock

    before = file_hashes(run)
    with run_lock(run, "test"):
        out = invoke_microcal("acquire", "--out", run, "--resume")
        fails_cleanly(out, f"in use by microcal (PID {os.getpid()})")
        out = invoke_microcal("measure", run, "--cameras", cameras)
        fails_cleanly(out, f"in use by microcal (PID {os.getpid()})")
    assert file_hashes(run) == before
    # the lock ends with its holder: the next command runs
    out = invoke_microcal("measure", run, "--cameras", cameras)
    assert out.returncode == 0, out.stderr
    assert not (run / ".microcal.lock").exists()


def test_a_lock_left_by_a_killed_process_does_not_block(run, cameras):
    (run / ".microcal.lock").write_text("999999\n")  # a holder that died without unlocking
    out = invoke_microcal("measure", run, "--cameras", cameras)
    assert out.returncode == 0, out.stderr
