"""The tool-centre point from poses of board and tip: the fit, its refusals, and applied to a
board's calibration."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from microcal.errors import DetectionError, InputError
from microcal.kinematics.manipulator_calibration import ManipulatorCalibration
from microcal.kinematics.models import fit_matrix_model
from microcal.procedures.tool_centre import (
    CarriedPose,
    fit_carried,
    measure_carried,
    tip_calibration,
)
from microcal.sim import platform
from microcal.vision.targets import parse_target
from microcal.vision.tip_target import parse_tip

TRUTH = np.array([-2400.0, 30.0, -50.0])


def _poses(rng, n=10, turning=False, board_R=None):
    base = np.eye(3) if board_R is None else board_R
    out = []
    for _ in range(n):
        b = rng.uniform(0, 8000, 3)
        R = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix() @ base if turning else base
        tip = b + R @ TRUTH + rng.normal(0, 0.3, 3)
        seen_R = Rotation.from_rotvec(rng.normal(0, 0.002, 3)).as_matrix() @ R  # its noise
        out.append(CarriedPose("ok", "", b + rng.normal(0, 0.1, 3), np.eye(3) * 0.01, seen_R,
                               tip, np.eye(3) * 0.09))  # fmt: skip
    return out


def test_a_board_that_only_translates_gives_its_offset_and_orientation_with_a_covariance():
    rng = np.random.default_rng(0)
    board_R = Rotation.from_rotvec([0.0, 0.0, 0.02]).as_matrix()
    misses = []
    for _ in range(100):
        tool = fit_carried(_poses(rng, board_R=board_R))
        e = tool.offset_um - TRUTH
        misses.append(float(e @ np.linalg.solve(tool.cov_um2, e)))
        assert tool.board_R is not None
    assert np.linalg.norm(tool.offset_g_um - board_R @ TRUTH) < 0.5  # µm: what is applied
    assert 0.9 <= np.mean(np.array(misses) < 7.81) <= 1.0  # chi-square, 3 dof, 95 %


def test_the_offset_applied_in_g_has_its_own_covariance_without_the_boards_turn():
    rng = np.random.default_rng(2)
    board_R = Rotation.from_rotvec([0.0, 0.01, 0.02]).as_matrix()
    misses, ratios = [], []
    for _ in range(200):
        tool = fit_carried(_poses(rng, board_R=board_R))
        e = tool.offset_g_um - board_R @ TRUTH
        c = tool.offset_g_cov_um2
        misses.append(float(e @ np.linalg.solve(c, e)))
        ratios.append(np.trace(c) / np.trace(tool.cov_um2))
    # 0.3 µm tip and 0.1 µm board noise over 10 poses: 0.1 µm per axis in {G}, where the
    # board's orientation (2 mrad a pose over a 2.4 mm lever) adds some 1.5 µm in its frame
    assert 0.90 <= np.mean(np.array(misses) < 7.81) <= 0.99  # chi-square, 3 dof, 95 %
    assert np.sqrt(np.trace(c) / 3) == pytest.approx(0.10, abs=0.02)
    assert max(ratios) < 0.05


def test_the_tips_own_error_is_added_whole_not_averaged_over_the_poses():
    import dataclasses

    rng = np.random.default_rng(3)
    model = np.diag([0.09, 0.0, 0.01])  # µm²: e.g. 0.3 µm along the jaw
    for n in (5, 40):
        poses = _poses(rng, n=n)
        plain = fit_carried(poses)
        tool = fit_carried([dataclasses.replace(p, tip_model_cov_um2=model) for p in poses])
        np.testing.assert_allclose(tool.offset_um, plain.offset_um)
        np.testing.assert_allclose(tool.offset_g_cov_um2 - plain.offset_g_cov_um2, model,
                                   atol=1e-12)  # fmt: skip
        np.testing.assert_allclose(tool.cov_um2 - plain.cov_um2, model, atol=1e-3)  # R near I


def test_a_turning_board_is_fitted_pose_by_pose():
    rng = np.random.default_rng(1)
    tool = fit_carried(_poses(rng, turning=True))
    assert tool.board_R is None
    e = tool.offset_um - TRUTH  # each pose's measured turn (2 mrad) moves the tip by ~5 µm
    assert np.linalg.norm(e) < 3.0
    assert float(e @ np.linalg.solve(tool.cov_um2, e)) < 11.3  # chi-square, 3 dof, 99 %


def test_failed_poses_are_left_out_and_too_few_is_one_line_with_their_reasons():
    rng = np.random.default_rng(2)
    poses = _poses(rng, n=3)
    poses[1] = CarriedPose("failed", "tip: side: no tool in view")
    assert fit_carried(poses).poses == 2
    poses[2] = CarriedPose("failed", "board: top: board not found")
    with pytest.raises(DetectionError) as info:
        fit_carried(poses)
    message = str(info.value)
    assert "\n" not in message
    assert "got 1 (pose 2: tip: side: no tool in view; pose 3: board: top:" in message
    with pytest.raises(DetectionError, match=r"got 0 \(poses 1, 2: tip: top: no tool in view\)"):
        fit_carried([CarriedPose("failed", "tip: top: no tool in view")] * 2)


def test_applied_the_board_calibration_serves_the_tip():
    rng = np.random.default_rng(4)
    d_fit = rng.uniform(0, 8000, (20, 3))
    model = fit_matrix_model(d_fit, d_fit @ np.diag([0.98, 1.01, 0.99]).T + [50.0, -20.0, 10.0])
    entry = ManipulatorCalibration("m1", model)
    rng = np.random.default_rng(3)
    tool = fit_carried(_poses(rng))
    tip = tip_calibration(entry, tool)
    d = np.array([[1000.0, 2000.0, 3000.0]])
    np.testing.assert_allclose(tip.predict_um(d) - entry.predict_um(d), tool.offset_g_um[None],
                               atol=1e-9)  # fmt: skip
    np.testing.assert_allclose(tip.joints_for(tip.predict_um(d)[0]).ravel(), d[0], atol=1e-6)
    assert "tool_centre" not in tip.extra
    with pytest.raises(InputError, match="the board turns"):
        tip_calibration(entry, fit_carried(_poses(rng, turning=True)))


@pytest.fixture(scope="module")
def board_frames():
    """One pose of the thesis platform (a board, no tool), two cameras, one frame each."""
    plat = platform("thesis", seed=0)
    plat.manipulator.move_to_um([5000.0, 4800.0, 2700.0])
    plat.manipulator.wait_until_stopped(plat.clock)
    return {n: [c.grab()] for n, c in plat.cameras.items()}, plat.camera_models


def test_a_tip_spec_on_images_of_a_board_fails_the_pose_with_its_reason(board_frames):
    frames, models = board_frames
    pose = measure_carried(frames, models, parse_target("chessboard:4x3:400"),
                           parse_tip("tip:jaw"))  # fmt: skip
    assert pose.status == "failed"
    assert pose.reason.startswith("tip: ")
    assert "no tool" in pose.reason or "tool" in pose.reason


def test_specs_the_wrong_way_round_are_one_line():
    with pytest.raises(InputError, match="expected a board's spec and a tip's spec"):
        measure_carried({}, {}, parse_tip("tip:jaw"), parse_target("chessboard:4x3:400"))  # type: ignore[arg-type]


def test_a_board_spec_on_images_of_a_bare_tool_fails_the_pose_with_its_reason():
    plat = platform("thesis-tip", seed=0)
    plat.manipulator.move_to_um([5000.0, 4800.0, 2700.0])
    plat.manipulator.wait_until_stopped(plat.clock)
    # one camera, the part of its frame around the tool: a board's search in vain is slow
    x, y = plat.cameras["top"].model.project(plat.truth_position_um()[None])[0].astype(int)
    frames = {"top": [plat.cameras["top"].grab()[y - 150 : y + 150, x - 150 : x + 250]]}
    pose = measure_carried(frames, plat.camera_models, parse_target("chessboard:4x3:400"),
                           parse_tip("tip:pipette"))  # fmt: skip
    assert pose.status == "failed"
    assert pose.reason.startswith("board: ")
    assert "top: " in pose.reason


def test_the_orientation_is_carried_in_the_calibration_file_and_a_bad_one_refused(tmp_path):
    import json

    from microcal.errors import FormatError
    from microcal.formats.calibration_file import (
        Calibration,
        load_calibration,
        tool_centre_of,
        write_calibration,
    )

    rng = np.random.default_rng(5)
    d = rng.uniform(0, 8000, (20, 3))
    figures = {"n_fit": 20, "n_validate": 0, "mean_um": 0.1, "std_um": 0.1, "max_um": 0.2,
               "rms_um": 0.1}  # fmt: skip
    tool = fit_carried(_poses(rng))
    entry = ManipulatorCalibration("m1", fit_matrix_model(d, d), figures,
                                   {"tool_centre": tool.to_json()})  # fmt: skip
    path = tmp_path / "calibration.json"
    write_calibration(path, Calibration({"m1": entry}))
    back = tool_centre_of(load_calibration(path).manipulator("m1"))
    assert back is not None
    assert back.board_R is not None
    np.testing.assert_allclose(back.offset_g_um, tool.offset_g_um)
    np.testing.assert_allclose(back.offset_g_cov_um2, tool.offset_g_cov_um2)
    raw = json.loads(path.read_text())
    good = json.dumps(raw)
    raw["manipulators"]["m1"]["tool_centre"]["board_R"][0][0] = 2.0
    path.write_text(json.dumps(raw))
    with pytest.raises(FormatError, match=r"tool_centre.board_R: expected a 3 x 3 rotation"):
        load_calibration(path)
    raw = json.loads(good)
    raw["manipulators"]["m1"]["tool_centre"]["cov_g_um2"][2][2] = -0.1
    path.write_text(json.dumps(raw))
    with pytest.raises(FormatError, match=r"tool_centre.cov_g_um2: expected 3 x 3 numbers"):
        load_calibration(path)
    del raw["manipulators"]["m1"]["tool_centre"]["cov_g_um2"]  # an older file: cov_um2 turned
    path.write_text(json.dumps(raw))
    old = tool_centre_of(load_calibration(path).manipulator("m1"))
    assert old is not None
    np.testing.assert_allclose(old.offset_g_cov_um2,
                               tool.board_R @ tool.cov_um2 @ tool.board_R.T)  # fmt: skip


@pytest.mark.slow
def test_the_jaw_beside_the_board_is_measured_on_the_gripper_preset():
    """Two poses of ``thesis-gripper`` with its true cameras: board and jaw are both found at
    each, and the offset comes out as far from the truth as the jaw's tip is found on these
    cameras (the jaw's tip from its taper's vertex and axis in 3D: one frame's point scatters
    by a few µm; it was 10-20 µm along the jaw from its apexes)."""
    plat = platform("thesis-gripper", seed=0)
    m, clock = plat.manipulator, plat.clock
    board, tip = parse_target(plat.config.board), parse_tip(plat.config.tool)
    poses = []
    for d in ([3000.0, 3000.0, 2500.0], [6000.0, 5000.0, 2800.0]):
        m.move_to_um(d)
        m.wait_until_stopped(clock)
        frames = {n: [c.grab()] for n, c in plat.cameras.items()}
        poses.append(measure_carried(frames, plat.camera_models, board, tip))
    assert [p.status for p in poses] == ["ok"] * 2, [p.reason for p in poses]
    tool = fit_carried(poses)
    assert tool.board_R is not None
    assert np.linalg.norm(tool.offset_g_um - plat.config.tool_offset_um) < 15.0  # µm
