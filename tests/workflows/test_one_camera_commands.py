"""goto, evaluate and check on a one-camera rig (a rig file ``preset = "patch"``): the tip
measured through the scope calibration by the one-camera probe, open and closed loop, by
ground truth within the issue's bounds; moves along the approach axis; refusals in one
line, nothing written."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.errors import InputError
from microcal.workflows.station import goto_target, open_station

SEED = 1
TARGET_UM = np.array([30.0, -40.0, 10.0])  # inside the working volume (±100, ±100, ±25 µm)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """A short patch demo (its calibration.json and scope.json) and a rig file of the same
    simulated rig, opened afresh by each command."""
    from microcal.workflows.patch_demo import patch_demo

    root = tmp_path_factory.mktemp("one-camera")
    run = patch_demo(root / "demo", seed=SEED, poses=30, quick=True).out
    rig = root / "patch.toml"
    rig.write_text(f'driver = "sim"\npreset = "patch"\nseed = {SEED}\n', encoding="utf-8")
    return {"rig": str(rig), "calibration": str(run / "calibration.json"),
            "scope": str(run / "scope.json"), "root": str(root)}  # fmt: skip


def _station(c: dict[str, str], **options):
    return open_station(c["rig"], c["calibration"], scope=c["scope"], settle_s=1.0, **options)


@pytest.mark.slow
def test_goto_open_and_closed_by_truth(calibrated) -> None:
    with _station(calibrated) as station:
        truth = station.rig.truth
        assert truth is not None  # the simulator's: the tip in the true {M}
        home = truth()
        assert np.linalg.norm(home) < 2.0  # the start pose, at {M}'s origin
        open_ = station.move_to_um(TARGET_UM, "open")
        open_error = np.linalg.norm(truth() - TARGET_UM)
        closed = station.move_to_um(TARGET_UM + [0.0, 20.0, -5.0], "closed", 0.5)
        closed_error = np.linalg.norm(truth() - TARGET_UM - [0.0, 20.0, -5.0])
    assert open_error < 1.0  # µm: the open-loop AP bound
    assert closed_error < 0.5  # µm: its closed-loop bound
    assert np.linalg.norm(open_.error_um) < 0.5  # as measured by the one-camera probe
    assert 5 <= open_.frames <= 40  # a focus sweep's frames, not the stereo default
    assert closed.status == "tolerance"


@pytest.mark.slow
@pytest.mark.parametrize(
    ("mode", "path"), [("open", "joint"), ("open", "line"), ("closed", "joint")]
)
def test_a_move_along_the_approach_axis_by_truth(calibrated, mode, path) -> None:
    with _station(calibrated) as station:
        station.move_to_um(TARGET_UM, "open")  # the joints commanded: the move holds them
        truth = station.rig.truth
        assert truth is not None
        before = truth()
        move, arrival = station.move_along_approach_um(-30.0, mode, 0.5, step_um=10.0, path=path)
        moved = truth() - before
    assert move.elevation_deg == pytest.approx(-30.0, abs=0.5)  # the axis, into the sample
    assert len(move.targets_um) == 3
    np.testing.assert_allclose(move.targets_um[-1], move.start_um - 30.0 * move.axis)
    # by truth: the tip moved the distance along the calibrated axis within the open loop's
    # accuracy (the AP bound, 1.0 µm)
    assert np.linalg.norm(moved - (-30.0) * move.axis) < 1.0
    assert np.linalg.norm(arrival.error_um) < (0.5 if mode == "closed" else 1.0)


@pytest.mark.slow
def test_evaluate_by_the_one_camera_probe_and_by_truth(calibrated, tmp_path) -> None:
    from microcal.workflows.evaluate import EvaluateRequest, evaluate

    out = tmp_path / "results.json"
    request = EvaluateRequest(Path(calibrated["calibration"]), calibrated["rig"],
                              "pose-accuracy", cycles=1, poses="iso-cube", settle_s=1.0,
                              out=out, control="all", scope=Path(calibrated["scope"]))  # fmt: skip
    done = evaluate(request)
    pa = json.loads(out.read_text(encoding="utf-8"))["pose_accuracy"]
    assert set(pa) == {"vision", "truth"}
    assert pa["truth"]["optimal"]["mean_ap_p_um"] < 1.0  # the open-loop bound
    assert pa["truth"]["closed_loop"]["mean_ap_p_um"] < 0.5  # and closed-loop
    assert pa["vision"]["optimal"]["mean_ap_p_um"] < 0.3
    assert pa["truth"]["uncalibrated"]["mean_ap_p_um"] > 10.0  # the tilted approach axis
    desired = np.array([p["desired_um"] for p in pa["truth"]["optimal"]["poses"]])
    assert np.all(np.abs(desired) <= [100.0, 100.0, 25.0])  # the cube inside the volume
    assert done.evaluation.closed_loop is not None


@pytest.mark.slow
def test_check_measures_an_unchanged_then_a_moved_tool(calibrated, tmp_path) -> None:
    from microcal.workflows.check import CheckConfig, check_calibration

    cal = tmp_path / "calibration.json"
    shutil.copy(calibrated["calibration"], cal)
    cfg = CheckConfig(frames=1, settle_s=1.0)
    done = check_calibration(calibrated["rig"], cal, tmp_path / "check.json",
                             config=cfg, scope=calibrated["scope"])  # fmt: skip
    # an unchanged tool: valid, within 0.05 µm (the sweep read the tips 0.07 µm along the
    # pipette and 0.05 µm in depth otherwise than the acquisition, and called it "offset",
    # while the strips' bins were placed at their middles: a tool along a pixel row put
    # every pixel on a bin's edge, half a pixel from where the probe's axis put it)
    assert done.result.verdict == "valid"
    assert np.all(np.abs(done.result.offset_um) < 0.05)
    moved = tmp_path / "moved.json"  # the joints counted from 1 µm further: a moved tool
    data = json.loads(cal.read_text(encoding="utf-8"))
    data["manipulators"]["m1"]["joint_origin_um"][1] += 1.0
    moved.write_text(json.dumps(data), encoding="utf-8")
    again = check_calibration(calibrated["rig"], moved, tmp_path / "check2.json",
                              config=cfg, scope=calibrated["scope"])  # fmt: skip
    assert again.result.verdict == "offset"
    offset = np.asarray(again.result.offset_um) - np.asarray(done.result.offset_um)
    # the model now puts the tip 1 µm off in {M}'s y (the y joint is horizontal, across the
    # pipette); the sweep follows the tool's own centre line, not the one it expected
    assert offset[1] == pytest.approx(-1.0, abs=0.15)
    assert np.all(np.abs(offset[[0, 2]]) < 0.2)


@pytest.mark.slow
def test_goto_along_the_approach_axis_from_the_command_line(calibrated) -> None:
    c = calibrated
    args = ["goto", "--rig", c["rig"], "--calibration", c["calibration"], "--scope", c["scope"],
            "--objective", "40x", "--along-approach-um", "20"]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "along the approach axis" in result.output
    assert "of joint dx" in result.output
    assert "arrived at" in result.output
    assert ") µm in {M}, std" in result.output  # the scope calibration's frame, not {G}
    assert "frames per camera" not in result.output


@pytest.mark.slow
@pytest.mark.parametrize(
    ("options", "says"),
    [
        ({"scope": None}, "--scope: a one-camera rig measures the tip"),
        ({"objective": "10x"}, "objective '10x' is not in"),
        ({"rig": "sim"}, "--scope: the rig has 2 cameras"),
    ],
)
def test_bad_input_is_refused_in_one_line(calibrated, options, says) -> None:
    c = {"rig": calibrated["rig"], "calibration": calibrated["calibration"],
         "scope": calibrated["scope"], "objective": None} | options  # fmt: skip
    with pytest.raises(InputError, match=says) as info:
        open_station(c["rig"], c["calibration"], scope=c["scope"], objective=c["objective"])
    assert "\n" not in str(info.value)


@pytest.mark.slow
def test_evaluate_refuses_the_whole_travel_s_tests_and_writes_nothing(calibrated, tmp_path):
    from microcal.workflows.evaluate import EvaluateRequest, evaluate

    out = tmp_path / "results.json"
    request = EvaluateRequest(Path(calibrated["calibration"]), calibrated["rig"], "all",
                              out=out, scope=Path(calibrated["scope"]))  # fmt: skip
    with pytest.raises(InputError, match="use --poses iso-cube") as info:
        evaluate(request)
    assert "\n" not in str(info.value)
    assert not out.exists()


@pytest.mark.parametrize(
    ("xyz", "along", "says"),
    [((1.0, 2.0, None), None, "got 2 of them"), ((1.0, 2.0, 3.0), 5.0, "not both"),
     ((None, None, None), None, "got 0 of them")],
)  # fmt: skip
def test_goto_takes_x_y_z_or_a_move_along_the_approach_axis(xyz, along, says) -> None:
    with pytest.raises(InputError, match=says):
        goto_target(xyz, along)
    assert goto_target((1.0, 2.0, 3.0), None) == [1.0, 2.0, 3.0]
    assert goto_target((None, None, None), 5.0) is None


@pytest.mark.slow
def test_a_calibration_fitted_from_acquire_serves_goto_and_evaluate(tmp_path) -> None:
    """scope-calibrate, acquire --scope and fit on the rig (smaller frames), then the tip sent
    through the station: fit records where the run counted the joints from and its volume."""
    from microcal.workflows.evaluate import EvaluateRequest, evaluate

    rig = tmp_path / "patch.toml"
    rig.write_text('driver = "sim"\npreset = "patch"\nseed = 4\n[overrides]\n'
                   "size_px = [512, 512]\nsupersample = 1\n", encoding="utf-8")  # fmt: skip
    scope, run, cal = tmp_path / "scope.json", tmp_path / "run", tmp_path / "calibration.json"
    for args in (
        ["scope-calibrate", "--rig", str(rig), "--objective", "40x", "--out", str(scope)],
        ["acquire", "--rig", str(rig), "--scope", str(scope), "--objective", "40x", "--poses",
         "30", "--volume-um", "30,30,10", "--out", str(run)],
        ["fit", str(run), "--out", str(cal)],
    ):  # fmt: skip
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, result.output
    entry = json.loads(cal.read_text(encoding="utf-8"))["manipulators"]["m1"]
    assert entry["joint_origin_um"] == [10000.0, 10000.0, 10000.0]  # where the run began
    assert entry["working_volume_um"] == [[-30.0, -30.0, -10.0], [30.0, 30.0, 10.0]]
    target = np.array([10.0, -10.0, 5.0])
    with open_station(str(rig), cal, scope=scope, settle_s=1.0) as station:
        station.move_to_um(target, "open")
        truth = station.rig.truth
        assert truth is not None
        assert np.linalg.norm(truth() - target) < 1.0  # µm, by truth
    out = tmp_path / "results.json"
    evaluate(EvaluateRequest(cal, str(rig), "pose-accuracy", cycles=1, poses="iso-cube",
                             settle_s=1.0, out=out, scope=scope))  # fmt: skip
    pa = json.loads(out.read_text(encoding="utf-8"))["pose_accuracy"]
    assert pa["truth"]["optimal"]["mean_ap_p_um"] < 1.0
    desired = np.array([p["desired_um"] for p in pa["truth"]["optimal"]["poses"]])
    assert np.all(np.abs(desired) <= [30.0, 30.0, 10.0])  # the cube inside the run's volume
    from microcal.report import write_report

    html = write_report(run).read_text(encoding="utf-8")  # the run's page: one-camera sections
    assert 'id="scope"' in html
    assert "<h3>objective 40x</h3>" in html
    assert "A one-camera acquisition" in html
    assert "30 tips measured" in html


@pytest.mark.slow
def test_the_station_page_refuses_a_one_camera_rig_naming_what_serves_it(calibrated) -> None:
    from microcal.workflows.live import open_live_station

    with pytest.raises(InputError, match="the station page does not serve a rig of one camera"):
        open_live_station(calibrated["rig"], calibrated["calibration"])
    got = CliRunner().invoke(app, ["ui", "--rig", calibrated["rig"], "--calibration",
                                   calibrated["calibration"], "--port", "0"])  # fmt: skip
    assert got.exit_code == 2
    lines = got.stderr.strip().splitlines()
    assert len(lines) == 1
    assert "goto, evaluate and check take --scope scope.json" in lines[0]
    assert "give --scope" not in lines[0]  # an option the page does not have


@pytest.mark.slow
def test_goto_beyond_the_identified_range_says_the_model_extrapolates(calibrated) -> None:
    c = calibrated
    args = ["goto", "--rig", c["rig"], "--calibration", c["calibration"], "--scope", c["scope"]]
    outside = CliRunner().invoke(app, [*args, "--", "150", "0", "0"])  # the volume: ±100 µm
    assert outside.exit_code == 0, outside.output
    assert "note: the joints it arrived at lie outside the range the model was identified on" in (
        outside.stderr
    )
    inside = CliRunner().invoke(app, [*args, "--", *map(str, TARGET_UM)])
    assert inside.exit_code == 0, inside.output
    assert "extrapolates" not in inside.stderr
