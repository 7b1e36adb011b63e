"""``microcal tool-centre`` and ``microcal find-tip``: refusals in one line, in-process; a fit
keeps the device's tool-centre point."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.formats.calibration_file import Calibration, load_calibration, tool_centre_of
from microcal.kinematics.manipulator_calibration import ManipulatorCalibration
from microcal.kinematics.models import fit_matrix_model
from microcal.vision.tool_centre import fit_tool_centre
from microcal.workflows.calibration_update import add_manipulator

runner = CliRunner()


def _one_line(result, says: str) -> None:
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1, result.output
    assert lines[0].startswith("microcal: error: ")
    assert says in lines[0]


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--tip", "chessboard:4x3:400"], "--tip chessboard:4x3:400: is a board"),
        (["--tip", "tip:spoon"], "--tip tip:spoon"),
        (["--tip", "tip:jaw", "--out", "{cal}"], "write the calibration with the tool to a new"),
    ],
)
def test_tool_centre_refusals_are_one_line(tmp_path, args, says):
    cal = tmp_path / "calibration.json"
    args = [a.replace("{cal}", str(cal)) for a in args]
    if "--out" not in args:
        args += ["--out", str(tmp_path / "with-tool.json")]
    result = runner.invoke(app, ["tool-centre", "--calibration", str(cal), *args])
    _one_line(result, says)


def test_find_tip_with_a_board_spec_is_one_line():
    _one_line(runner.invoke(app, ["find-tip", "--tip", "chessboard:4x3:400"]), "is a board")


def test_find_tip_where_there_is_no_tool_refuses_and_puts_the_manipulator_back():
    from microcal.workflows.find_tip import find_tool_tip

    done = find_tool_tip("sim", reach_um=0.0)  # the thesis platform: a board, no tool
    assert not done.search.found
    assert "no tool's tip within 0 µm" in done.search.reason
    np.testing.assert_allclose(done.search.joints_um, 0.0, atol=0.5)
    result = runner.invoke(app, ["find-tip", "--reach-um", "0"])
    _one_line(result, "find-tip: no tip found: no tool's tip within 0 µm")


def test_find_tip_on_a_one_camera_focus_rig_is_one_line_naming_acquire(tmp_path):
    rig = tmp_path / "patch.toml"
    rig.write_text('driver = "sim"\npreset = "patch"\nseed = 0\n[overrides]\n'
                   "size_px = [256, 256]\nsupersample = 1\n")  # fmt: skip
    result = runner.invoke(app, ["find-tip", "--rig", str(rig), "--tip", "tip:pipette"])
    _one_line(result, "put the tip in focus at the field's centre and run microcal acquire")


def test_a_new_fit_keeps_the_devices_tool_centre(tmp_path):
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 8000, (20, 3))
    figures = {"n_fit": 20, "n_validate": 0, "mean_um": 0.1, "std_um": 0.1, "max_um": 0.2,
               "rms_um": 0.1}  # fmt: skip
    entry = ManipulatorCalibration("m1", fit_matrix_model(d, d + [1.0, 2.0, 3.0]), figures)
    board = rng.uniform(0, 8000, (6, 3))
    tool = fit_tool_centre(board, board + [-2400.0, 0.0, 0.0])
    out = tmp_path / "calibration.json"
    with_tool = ManipulatorCalibration("m1", entry.model, figures,
                                       {"tool_centre": tool.to_json()})  # fmt: skip
    add_manipulator(out, with_tool, None, {}, "matrix")
    add_manipulator(out, entry, None, {}, "matrix")  # fitted again, without a tool
    kept = tool_centre_of(load_calibration(out).manipulator("m1"))
    assert kept is not None
    np.testing.assert_allclose(kept.offset_um, tool.offset_um)
    assert isinstance(load_calibration(out), Calibration)
