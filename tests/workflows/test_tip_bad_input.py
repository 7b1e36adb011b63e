"""Bad input with a tool's tip as the target: a tip spec on a board's images, a tool that
leaves the field mid-run, two tools in view. Each is a per-pose reason or one error line,
and nothing is lost: the journal stays whole, the run is measured again as it should be.

The simulated thesis-tip platform carries a needle; what leaves the field or joins it is
set in its scene at chosen poses (in this process)."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from microcal import sim
from microcal.errors import DetectionError
from microcal.formats.cameras_file import write_cameras
from microcal.formats.check_file import read_history
from microcal.sim.platforms import Scene
from microcal.sim.tools import ToolPlacement
from microcal.workflows.station import open_station
from support.cli import invoke_microcal
from support.needle_rig import NEEDLE, write_needle_rig
from support.runs import fails_cleanly, file_hashes, journal_records
from support.station_files import write_truth_calibration

#: Joint commands (a CSV design): the tool leaves the field at the second, a second tool
#: is parked beside it at the third.
DESIGN = ((3000.0, 2000.0, 2500.0), (5000.0, 4000.0, 1500.0), (6000.0, 2500.0, 3000.0),
          (2500.0, 5000.0, 1200.0))  # fmt: skip
GONE, TWO = 1, 2
#: Where the second needle's tip is from the first's, µm: apart in both views (a needle's
#: cone is some 4 mm wide where it enters the field; two cones that overlap are one outline)
SECOND_UM = np.array([0.0, 6000.0, 1000.0])


def test_a_tip_spec_on_a_boards_images_is_one_line_and_loses_nothing(acquired_run, tmp_path):
    run, cameras = shutil.copytree(acquired_run[0], tmp_path / "run"), acquired_run[1]
    before = file_hashes(run)
    out = invoke_microcal("measure", run, "--cameras", cameras, "--target", NEEDLE)
    line = fails_cleanly(out, "no pose measured, all 12 failed", "no tool in view",
                         f"check --cameras and --target ({NEEDLE})")  # fmt: skip
    assert "Traceback" not in line
    assert file_hashes(run) == before  # nothing written, nothing changed
    again = invoke_microcal("measure", run, "--cameras", cameras)  # the run's own board
    assert again.returncode == 0, again.stderr
    assert "measured 12 of 12 poses" in again.stdout


@pytest.fixture
def needle_rig(tmp_path) -> Path:
    return write_needle_rig(tmp_path)


def _scene_with_surprises(monkeypatch) -> None:
    """At DESIGN[GONE] the tool is 40 mm off to the side (out of every field); at DESIGN[TWO]
    a second needle is parked beside it (SECOND_UM)."""
    seen = Scene.__call__

    def call(self, t_s):
        out = seen(self, t_s)
        joints = self.visible().joints_um(t_s)
        tools = [o for o in out if isinstance(o, ToolPlacement)]
        if not tools:
            return out
        tool = tools[-1]
        if np.allclose(joints, DESIGN[GONE], atol=1.0):
            return [dataclasses.replace(tool, tip_um=tool.tip_um + [0.0, 40000.0, 0.0])]
        if np.allclose(joints, DESIGN[TWO], atol=1.0):
            return [*out, dataclasses.replace(tool, tip_um=tool.tip_um + SECOND_UM)]
        return out

    monkeypatch.setattr(Scene, "__call__", call)


@pytest.mark.slow
def test_a_tool_leaving_the_field_and_a_second_tool_fail_their_poses_only(
    needle_rig, tmp_path, monkeypatch
):
    _scene_with_surprises(monkeypatch)
    design = tmp_path / "design.csv"
    design.write_text("dx_um,dy_um,dz_um\n" + "".join(f"{x},{y},{z}\n" for x, y, z in DESIGN))
    run = tmp_path / "run"
    out = invoke_microcal("acquire", "--rig", needle_rig, "--design", design, "--settle",
                          "fixed:0.5", "--frames", 1, "--store", "roi", "--out", run)  # fmt: skip
    assert out.returncode == 0, out.stderr
    records = journal_records(run)
    assert [r["pose"] for r in records] == [1, 2, 3, 4]
    assert all(r["status"] == "ok" for r in records)  # the images are stored: nothing lost
    plat = sim.platform("thesis-tip", seed=0)
    cameras = write_cameras(tmp_path / "cameras.json", {"format": "microcal.cameras/1", "cameras": {
        n: {"image_size_px": list(m.image_size_px), "K": m.K.tolist(), "dist": m.dist.tolist(),
            "R": m.R.tolist(), "t_um": m.t_um.tolist()} for n, m in plat.camera_models.items()}})  # fmt: skip
    before = file_hashes(run)
    measured = invoke_microcal("measure", run, "--cameras", cameras)
    assert measured.returncode == 0, measured.stderr
    text = " ".join(measured.stdout.split())
    assert "measured 2 of 4 poses" in text
    assert f"pose {GONE + 1} failed: top: no tool in view" in text
    # the side camera sees the two apart (in the top one their cones meet before the image's
    # edge: one outline, whose apex is one of the two)
    assert f"pose {TWO + 1} failed: side: 2 tools in view: expected one" in text
    changed = {k for k, v in file_hashes(run).items() if before.get(k) != v}
    assert changed == {"measurements.csv"}  # the journal and the images as they were
    resumed = invoke_microcal("acquire", "--out", run, "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert [r["pose"] for r in journal_records(run)] == [1, 2, 3, 4]


def _scene_where(monkeypatch, change) -> None:
    """The scene's tool, changed by ``change(joints, tool)`` -> the placements seen."""
    seen = Scene.__call__

    def call(self, t_s):
        out = seen(self, t_s)
        tools = [o for o in out if isinstance(o, ToolPlacement)]
        return change(self.visible().joints_um(t_s), tools[-1]) if tools else out

    monkeypatch.setattr(Scene, "__call__", call)


@pytest.fixture
def calibration(tmp_path) -> Path:
    return write_truth_calibration(tmp_path / "calibration.json", preset="thesis-tip")


def test_goto_with_the_tool_out_of_the_field_is_one_line(needle_rig, calibration, monkeypatch):
    away = np.array([0.0, 40000.0, 0.0])
    _scene_where(
        monkeypatch, lambda joints, tool: [dataclasses.replace(tool, tip_um=tool.tip_um + away)]
    )
    out = invoke_microcal(
        "goto", "--rig", needle_rig, "--calibration", calibration, 3000, 2000, 1500
    )
    fails_cleanly(out, "station: the cameras do not find the end-effector's target (is it in view?): "
                       "top: no tool in view", "side: no tool in view")  # fmt: skip


def test_goto_with_two_tools_in_view_refuses_their_mixed_tips(needle_rig, calibration, monkeypatch):
    # at this target the two cones merge in both views: the top camera takes the first tool's
    # tip, the side camera the second's; triangulated, they are 38 px from the side's apex
    _scene_where(monkeypatch, lambda joints, tool: [
        tool, dataclasses.replace(tool, tip_um=tool.tip_um + SECOND_UM)])  # fmt: skip
    with (
        open_station(needle_rig, calibration, frames=1, settle_s=0.5) as station,
        pytest.raises(DetectionError, match=r"in view\?\): the cameras' tips are not one point "
                                            r"\(side's is \d+ px from where the cameras put it\): "
                                            r"two tools in view"),
    ):  # fmt: skip
        station.move_to_um([3000.0, 2000.0, 1500.0])


def test_a_tool_leaving_the_field_during_a_check_is_one_line(
    needle_rig, calibration, tmp_path, monkeypatch
):
    centre = np.array([4000.0, 4000.0, 2400.0])  # check pose 1 (the cube's centre)
    away = np.array([0.0, 40000.0, 0.0])
    _scene_where(monkeypatch, lambda joints, tool: [tool] if np.allclose(joints, centre, atol=1.0)
                 else [dataclasses.replace(tool, tip_um=tool.tip_um + away)])  # fmt: skip
    out = tmp_path / "check.json"
    ran = invoke_microcal("check", "--rig", needle_rig, "--calibration", calibration, "--out", out,
                          "--frames", 1, "--settle-s", 0.5)  # fmt: skip
    fails_cleanly(ran, "check: the cameras did not see the tool's tip at check pose 2",
                  "top: no tool in view", "is it in view and lit?")  # fmt: skip
    assert not out.exists()
    assert read_history(calibration) == []  # nothing recorded of a check not made


def test_evaluate_names_the_measurements_a_tool_out_of_the_field_left_out(
    needle_rig, calibration, tmp_path, monkeypatch
):
    import microcal.procedures.evaluation as evaluation

    cube, conditions = evaluation.iso_cube_poses, evaluation.open_loop_conditions
    monkeypatch.setattr(evaluation, "iso_cube_poses", lambda lo, hi: cube(lo, hi)[:2])  # P1, P2
    monkeypatch.setattr(evaluation, "open_loop_conditions",
                        lambda *a, **k: {"optimal": conditions(*a, **k)["optimal"]})  # fmt: skip
    seen = (np.zeros(3), np.array([4000.0, 4000.0, 2400.0]))  # home, P1 (joints); not P2
    away = np.array([0.0, 40000.0, 0.0])

    def field(joints, tool):
        if any(np.linalg.norm(joints - d) < 50 for d in seen):
            return [tool]
        return [dataclasses.replace(tool, tip_um=tool.tip_um + away)]

    _scene_where(monkeypatch, field)
    out = tmp_path / "results.json"
    ran = invoke_microcal("evaluate", "--rig", needle_rig, "--calibration", calibration,
                          "--test", "pose-accuracy", "--poses", "iso-cube", "--cycles", 1,
                          "--frames", 1, "--settle-s", 0.5, "--out", out)  # fmt: skip
    assert ran.returncode == 0, ran.stderr
    text = " ".join(ran.stdout.split())
    assert "1 measurement(s) not made by the cameras; the figures by vision leave them out" in text
    assert "top: no tool in view" in text
    saved = json.loads(out.read_text())
    assert saved["target"] == NEEDLE
    [unseen] = saved["unseen"]
    assert "top: no tool in view" in unseen["reason"]
    assert np.linalg.norm(np.array(unseen["d_um"]) - [1680.0, 1680.0, 80.0]) < 50  # P2
    assert len(saved["pose_accuracy"]["vision"]["optimal"]["poses"]) == 1  # P1 alone
    assert len(saved["pose_accuracy"]["truth"]["optimal"]["poses"]) == 2
