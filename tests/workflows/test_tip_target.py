"""A tool's tip as the target of ``goto`` (open and closed loop), ``check`` and ``evaluate``,
exactly as a board: a needle on the simulated thesis-tip platform named by a rig file,
measured with few frames (each detection of the tip takes a fraction of a second).

The calibration is the simulator's truth, so what is left is the tip's measurement: a needle
on the thesis's cameras is found within a few µm (3-5 µm 3D RMS, docs/vision.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from microcal.control.visual_servo import ServoConfig
from microcal.formats.check_file import read_history
from microcal.procedures.check import CheckConfig
from microcal.workflows.check import check_calibration
from microcal.workflows.evaluate import EvaluateRequest, evaluate
from microcal.workflows.station import open_station
from support.cli import invoke_microcal
from support.needle_rig import NEEDLE, write_needle_rig
from support.runs import fails_cleanly
from support.station_files import write_truth_calibration

TARGET_UM = (3000.0, 2000.0, 1500.0)
#: What a needle's tip costs on the thesis's cameras in one frame, 3D, µm: 3-5 µm RMS over
#: poses from five frames, up to ~25 µm in one frame at the travel's corners (its detection's
#: own standard deviation along the tool is ~1.5 px, 30 µm)
TIP_UM = 30.0


@pytest.fixture
def rig(tmp_path) -> Path:
    return write_needle_rig(tmp_path)


@pytest.fixture
def calibration(tmp_path) -> Path:
    return write_truth_calibration(tmp_path / "calibration.json", preset="thesis-tip")


@pytest.mark.slow
def test_goto_sends_the_needles_tip_open_and_closed_loop(rig, calibration):
    servo = ServoConfig(tolerance_um=0.5, frames_min=1, frames_max=1, max_iterations=1)
    with open_station(rig, calibration, frames=1, settle_s=0.5, servo=servo) as station:
        assert station.rig.board.spec == NEEDLE
        truth = station.rig.truth
        assert truth is not None
        a = station.move_to_um(TARGET_UM, "open")
        assert a.mode == "open"
        assert np.linalg.norm(truth() - TARGET_UM) < 1.0  # the true model: the tip is there
        assert np.linalg.norm(a.error_um) < TIP_UM  # as the cameras see the needle's tip
        c = station.move_to_um(TARGET_UM, "closed")
        assert c.mode == "closed"
        assert c.status in ("tolerance", "resolution", "iterations")
        assert c.iterations == 1
        # the loop drives the tip as measured onto the target: by truth, off by the
        # measurement's own error, as the open loop's measurement was
        assert np.linalg.norm(c.error_um) < TIP_UM
        assert np.linalg.norm(truth() - TARGET_UM) < TIP_UM


@pytest.mark.slow
def test_check_measures_the_needle_and_records_it(rig, calibration, tmp_path, monkeypatch):
    import microcal.procedures.check as check

    ten = check.check_poses_um
    monkeypatch.setattr(check, "check_poses_um", lambda lo, hi: ten(lo, hi)[:3])  # 3 of 10
    out = tmp_path / "check.json"
    done = check_calibration(rig, calibration, out, config=CheckConfig(frames=1, settle_s=0.5))
    saved = json.loads(out.read_text())
    assert saved["target"] == NEEDLE
    assert saved["n_poses"] == 3
    assert done.result.verdict in ("valid", "offset")  # the needle's bias may read as an offset
    assert np.all(np.abs(done.result.offset_um) < TIP_UM)
    assert read_history(calibration)[-1]["target"] == NEEDLE


@pytest.mark.slow
def test_evaluate_measures_the_needle_and_records_it(rig, calibration, tmp_path, monkeypatch):
    import microcal.procedures.evaluation as evaluation

    cube, conditions = evaluation.iso_cube_poses, evaluation.open_loop_conditions
    monkeypatch.setattr(evaluation, "iso_cube_poses", lambda lo, hi: cube(lo, hi)[:2])  # P1, P2
    monkeypatch.setattr(evaluation, "open_loop_conditions",
                        lambda *a, **k: {"optimal": conditions(*a, **k)["optimal"]})  # fmt: skip
    out = tmp_path / "results.json"
    req = EvaluateRequest(calibration, str(rig), "pose-accuracy", poses="iso-cube", cycles=1,
                          frames=1, settle_s=0.5, out=out)  # fmt: skip
    evaluate(req)
    saved = json.loads(out.read_text())
    assert saved["target"] == NEEDLE
    for source, limit in (("truth", 2.0), ("vision", TIP_UM)):  # truth: the static model's own
        optimal = saved["pose_accuracy"][source]["optimal"]
        assert len(optimal["poses"]) == 2
        assert optimal["max_ap_p_um"] < limit, (source, optimal)


def test_goto_refuses_a_misspelt_tool_in_one_line(rig, calibration):
    rig.write_text(rig.read_text().replace(NEEDLE, "tip:needel:20:5"))
    out = invoke_microcal("goto", "--rig", rig, "--calibration", calibration, *TARGET_UM)
    fails_cleanly(out, f"{rig}: overrides.board: ", "did you mean tip:needle:20:5?")
