"""Runs from the station page on the page's own rig: an acquisition cancelled and resumed (from
the page and from the command line), a check that joins the calibration's history, the cameras'
calibration, and runs that fail or are refused in words while the station goes on."""

from __future__ import annotations

import json
import re
import time

import numpy as np
import pytest

from microcal.errors import DeviceError, InputError
from microcal.formats.check_file import read_history
from microcal.formats.run_directory import RunDirectory
from microcal.workflows.live import open_live_station
from microcal.workflows.live_runs import StationRuns
from support.cli import invoke_microcal
from support.station_files import write_truth_calibration


@pytest.fixture
def station(tmp_path):
    calibration = write_truth_calibration(tmp_path / "calibration.json")
    live = open_live_station("sim", str(calibration), seed=0, frames=2)
    yield live, StationRuns(live)
    live.close()


def _until(runs: StationRuns, test, timeout_s: float = 240.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        state = runs.state()
        if state is not None and test(state):
            return state
        time.sleep(0.05)
    raise AssertionError(f"run state not reached: {runs.state()}")


@pytest.mark.slow
def test_a_cancelled_acquisition_resumes_from_the_page_and_from_the_command_line(station):
    live, runs = station
    runs.start("acquire", {"name": "a", "poses": 12, "frames": 1})
    with pytest.raises(InputError, match=r"^busy: acquiring"):
        runs.start("check")  # one thing at a time
    with pytest.raises(InputError, match=r"^busy: acquiring"):
        live.go([3000.0, 2000.0, 1500.0])
    _until(runs, lambda s: s["done"] >= 2)
    assert runs.cancel()
    assert live.wait(120.0)
    state = runs.state()
    out = runs.root / "a"
    stored = len(RunDirectory(out).journal())
    assert state["status"] == "cancelled"
    assert 2 <= stored < 12
    assert state["done"] == stored
    assert state["resume"] == f"microcal acquire --out {out} --resume"
    assert f"{stored} of 12 poses stored" in state["message"]
    # resumed from the page, cancelled again after one more pose
    runs.start("acquire", {"name": "a", "resume": True})
    _until(runs, lambda s: s["done"] >= stored + 1)
    runs.cancel()
    assert live.wait(120.0)
    again = len(RunDirectory(out).journal())
    assert stored < again < 12
    assert runs.state()["status"] == "cancelled"
    # and finished by the command line, as a run Ctrl-C stopped
    ran = invoke_microcal("acquire", "--out", out, "--resume")
    assert ran.returncode == 0, ran.stderr
    assert f"resuming {out}: {12 - again} of 12 poses to do" in ran.stdout
    assert len(RunDirectory(out).journal()) == 12


@pytest.mark.slow
def test_a_check_joins_the_history_and_the_health_and_the_cameras_calibrate(station):
    live, runs = station
    assert live.health["checks"] == []
    runs.start("check", {"name": "first", "frames": 2})  # the command's default: 20
    assert live.wait(240.0)
    state = runs.state()
    assert state["status"] == "done", state
    assert (state["done"], state["total"]) == (10, 10)
    assert (runs.root / "checks" / "first.json").is_file()
    assert json.loads((runs.root / "checks" / "first.json").read_text())["frames"] == 2
    assert len(read_history(live.calibration_path)) == 1
    verdict = read_history(live.calibration_path)[0]["verdict"]
    assert [c["verdict"] for c in live.health["checks"]] == [verdict]
    runs.start("cameras", {"name": "cams", "frames": 2})  # the command's default: 8
    assert live.wait(240.0)
    state = runs.state()
    assert state["status"] == "done", state
    assert (runs.root / "cams" / "cameras.json").is_file()
    assert "2 camera(s), RMS" in state["message"]
    # the station measures its tip again after the target stage moved
    p, _ = live.station.where_um()
    assert np.all(np.isfinite(p))


def test_a_failing_run_is_said_in_words_and_the_station_goes_on(station, monkeypatch):
    live, runs = station
    stage = live.station.rig.target_stage

    def broken(d_um):
        raise DeviceError("target stage: no answer (is it connected?)")

    monkeypatch.setattr(stage, "_move", broken)
    runs.start("cameras", {})
    assert live.wait(60.0)
    state = runs.state()
    assert state["status"] == "failed"
    assert "target stage: no answer" in state["message"]
    # refused before anything starts, in one line each
    for kind, options, message in (
        ("fly", {}, "run: expected one of cameras, acquire, check"),
        ("acquire", {"name": "../up"}, "name: expected a plain word"),
        ("acquire", {"poses": 3}, "poses: expected 12 to"),
        ("acquire", {"name": "nothing", "resume": True}, "no run to resume"),
        ("check", {"speed": 2}, "run: unknown option(s) speed"),
        ("check", {"frames": 0}, "frames: expected a whole number from 1 to 1000 per pose"),
        ("check", {"frames": True}, "frames: expected a whole number from 1 to 1000"),
        ("acquire", {"frames": 101}, "frames: expected a whole number from 1 to 100 per"),
        ("cameras", {"frames": 200}, "frames: expected a whole number from 1 to 100 per view"),
    ):
        with pytest.raises(InputError, match=re.escape(message)):
            runs.start(kind, options)
    assert runs.state()["status"] == "failed"  # the last run's state stays
    live.measure()
    assert live.wait(60.0)
    assert live.state()["error"] == ""
