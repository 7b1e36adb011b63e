"""A two-axis X-Y positioner among three-joint devices: its z joint is held. A device of two
axes joins as three joints, designs and evaluation poses span the moving axes, models leave
the held joint out, compensators and the visual servo solve for the moving joints, and files
keep the held joint."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.control.visual_servo import joint_step, reachable_error
from microcal.devices.base import Manipulator
from microcal.devices.held_axes import HeldAxes, with_three_joints
from microcal.devices.rig_spec import MCS2Spec
from microcal.errors import DegenerateDataError, FormatError, InputError, LimitError
from microcal.kinematics.designs import check_design, make_design
from microcal.kinematics.models import KinematicModel, held_from_limits
from microcal.procedures.acquisition import AcquisitionConfig, approach_start_um
from microcal.procedures.evaluation import approach_detours_um, iso_cube_poses
from microcal.procedures.identification import calibrate_manipulator
from microcal.sim.station_devices import positioner_kinematics

LIMITS_XY = np.array([[0.0, 6000.0], [0.0, 6000.0], [0.0, 0.0]])


class _XYStage(Manipulator):
    """Two axes, as a controller with an X and a Y channel reports them."""

    def __init__(self) -> None:
        super().__init__("p1", ("x", "y"), [[0.0, 6000.0], [0.0, 6000.0]])
        self.at = np.zeros(2)

    @property
    def identity(self) -> str:
        return "controller S1 channels 9,10"

    def _move(self, d_um):
        self.at = d_um.copy()

    def _position_um(self):
        return self.at.copy()

    def _is_moving(self):
        return False

    def _stop(self):
        pass

    def _close(self):
        pass


def test_a_two_axis_device_joins_as_three_joints_with_z_held():
    stage = with_three_joints(_XYStage())
    assert isinstance(stage, HeldAxes)
    assert stage.axes == ("x", "y", "z")
    np.testing.assert_array_equal(stage.limits_um, LIMITS_XY)
    assert stage.identity == "controller S1 channels 9,10"
    stage.move_to_um([1000.0, 2000.0, 0.0])
    np.testing.assert_array_equal(stage.position_um(), [1000.0, 2000.0, 0.0])
    with pytest.raises(LimitError, match=r"axis z = 5\.000 µm .*\[0, 0\]"):
        stage.move_to_um([1000.0, 2000.0, 5.0])
    stage.close()
    assert stage.closed
    assert stage.device.closed


def test_axes_other_than_x_y_z_in_order_are_refused():
    class _YX(_XYStage):
        def __init__(self) -> None:
            Manipulator.__init__(self, "s", ("y", "x"), [[0.0, 1.0], [0.0, 1.0]])

    with pytest.raises(InputError, match=r"expected axes among x, y, z in that order, got \['y'"):
        HeldAxes(_YX())
    with pytest.raises(InputError, match="channels: expected axes among x, y, z in that order"):
        MCS2Spec("127.0.0.1", {"z": 0, "x": 1}, {"z": (0, 1), "x": (0, 1)})
    spec = MCS2Spec("127.0.0.1", {"x": 9, "y": 10}, {"x": (0, 6000), "y": (0, 6000)})
    assert spec.axes == ("x", "y")
    with pytest.raises(InputError, match="low == high for an axis the device holds still"):
        Manipulator.__init__(_XYStage(), "s", ("x", "y"), [[1.0, 1.0], [2.0, 2.0]])


def test_designs_span_the_moving_axes_and_keep_the_held_one():
    for kind in ("random", "sobol", "lhs", "grid", "chebyshev"):
        d = make_design(kind, 50, LIMITS_XY[:, 0], LIMITS_XY[:, 1], seed=3)
        assert np.all(d[:, 2] == 0.0), kind
        assert np.ptp(d[:, :2], axis=0).min() > 0.5 * 6000, kind
        check_design(d, LIMITS_XY)
    # a three-axis device whose design leaves z still is refused as before
    three = np.array([[0.0, 6000.0], [0.0, 6000.0], [0.0, 2000.0]])
    with pytest.raises(DegenerateDataError, match="moves axis z over 0 %"):
        check_design(d, three)
    with pytest.raises(InputError, match="low < high on every axis"):
        make_design("random", 10, [1.0, 1.0, 1.0], [1.0, 1.0, 1.0])
    # an acquisition's random approach leaves the held joint where it is
    start = approach_start_um(np.array([3000.0, 3000.0, 0.0]), 7,
                              AcquisitionConfig(approach_um=20.0, approach_seed=1), LIMITS_XY)  # fmt: skip
    assert start[2] == 0.0
    assert np.all(np.abs(start[:2] - 3000.0) == 20.0)


def _xy_data(n: int, noise_um: float, seed: int) -> tuple[np.ndarray, np.ndarray, KinematicModel]:
    truth = positioner_kinematics().static
    rng = np.random.default_rng(seed)
    d = make_design("random", n, LIMITS_XY[:, 0], LIMITS_XY[:, 1], seed=seed)
    return d, truth.predict_um(d) + rng.normal(0.0, noise_um, (n, 3)), truth


def test_a_positioners_model_leaves_the_held_joint_out_and_solves_for_the_others():
    d, p, truth = _xy_data(170, 0.01, seed=1)
    held = held_from_limits(LIMITS_XY)
    assert held == {"dz": 0.0}
    # not said to be held, a joint that never moved is refused, as for any manipulator
    with pytest.raises(DegenerateDataError, match="'dz' has the same value in every sample"):
        calibrate_manipulator("p1", d, p)
    with pytest.raises(DegenerateDataError, match="'dz' has the same value in every sample"):
        calibrate_manipulator("p1", d, p, family="smooth")
    # said to be held at a value its commands do not have: not this device's poses
    with pytest.raises(DegenerateDataError, match=r"joint dz is held at 5 µm, but its commands"):
        calibrate_manipulator("p1", d, p, held_um={"dz": 5.0})
    cal, fits = calibrate_manipulator("p1", d, p, family="quadratic", seed=0, held_um=held)
    model = cal.model
    assert model.held_um == {"dz": 0.0}
    assert model.moving_joints == ("dx", "dy")
    assert not any("dz" in t.inputs for t in model.terms)
    assert fits["matrix"].model.held_um == {"dz": 0.0}
    # data of a quadratic map with 10 nm of noise: the model is the map within a few nm
    grid = make_design("grid", 25, [500, 500, 0], [5500, 5500, 0])
    np.testing.assert_allclose(model.predict_um(grid), truth.predict_um(grid), atol=0.01)
    # a target on the surface the model reaches is met exactly; z stays held
    targets = model.predict_um(grid)
    result = cal.compensator.solve(targets)
    assert result.converged.all()
    assert result.residual_um.max() < 1e-6
    np.testing.assert_allclose(result.d_um, grid, atol=1e-6)
    # off the surface by 5 µm along its normal: the nearest point, 5 µm left
    J = model.jacobian(grid)
    normal = np.cross(J[:, :, 0], J[:, :, 1])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    off = cal.compensator.solve(targets + 5.0 * normal)
    assert off.converged.all()
    np.testing.assert_allclose(off.residual_um, 5.0, atol=0.01)
    np.testing.assert_allclose(off.d_um, grid, atol=1e-3)
    assert np.all(off.d_um[:, 2] == 0.0)
    # the matrix compensator too
    linear = cal.compensator.linear(targets)
    assert np.all(linear[:, 2] == 0.0)
    # the model file keeps the held joint
    again = KinematicModel.from_dict(model.to_dict())
    assert again.held_um == {"dz": 0.0}
    np.testing.assert_array_equal(again.predict_um(grid), model.predict_um(grid))
    # a manipulator's model (every joint moves) is written as before, without the key
    d3 = make_design("random", 60, [0, 0, 0], [6000, 6000, 2000], seed=2)
    three, _ = calibrate_manipulator("m1", d3, truth.predict_um(d3 * [1, 1, 0]) + d3 * [0, 0, 1],
                                     "matrix")  # fmt: skip
    assert three.model.held_um == {}
    assert "held_joints_um" not in three.model.to_dict()


def test_a_model_cannot_use_a_held_joint_and_some_joint_must_move():
    truth = positioner_kinematics().static
    with pytest.raises(FormatError, match=r"held_um: expected joints among .* got 'dq'"):
        KinematicModel.from_dict(truth.to_dict() | {"held_joints_um": {"dq": 0.0}})
    with pytest.raises(FormatError, match=r"term dx uses the held joint"):
        KinematicModel.from_dict(truth.to_dict() | {"held_joints_um": {"dx": 0.0}})
    with pytest.raises(FormatError, match=r"held_joints_um: expected \{joint: µm\}, got \[1, 2\]"):
        KinematicModel.from_dict(truth.to_dict() | {"held_joints_um": [1, 2]})
    with pytest.raises(InputError, match="every joint is held"):
        calibrate_manipulator("p1", np.ones((10, 3)), np.ones((10, 3)),
                              held_um={"dx": 1.0, "dy": 1.0, "dz": 1.0})  # fmt: skip


def test_the_servo_corrects_along_the_surface_only():
    J = np.array([[1.0, 0.01, 0.0], [-0.01, 1.0, 0.0], [0.002, 0.001, 0.0]])  # z held
    e = np.array([0.4, -0.3, 2.0])
    step = joint_step(J, e)
    assert step[2] == 0.0
    reach = reachable_error(J, e)
    # what is left after the step is normal to the surface: no joint can remove it
    left = e - reach
    np.testing.assert_allclose(J[:, :2].T @ left, 0.0, atol=1e-12)
    np.testing.assert_allclose(J @ step, reach, atol=1e-12)
    full = np.eye(3) + 0.01
    np.testing.assert_array_equal(reachable_error(full, e), e)


def test_evaluation_poses_lie_in_the_plane_of_the_moving_axes():
    low, high = np.array([500.0, 500.0, 0.0]), np.array([5500.0, 5500.0, 0.0])
    poses = iso_cube_poses(low, high)
    assert np.all(poses[:, 2] == 0.0)
    np.testing.assert_allclose(poses[0], [3000.0, 3000.0, 0.0])
    np.testing.assert_allclose(poses[1], [1000.0, 1000.0, 0.0])  # 10 % of the diagonal in
    detours = approach_detours_um(poses[0], low, high)
    assert np.all(detours[:, 2] == 0.0)
    assert np.all(np.abs(detours[:, :2] - 3000.0) == 300.0)


def test_check_poses_of_a_positioner_lie_in_its_plane_and_take_no_approach_on_z():
    from microcal.kinematics.manipulator_calibration import ManipulatorCalibration
    from microcal.procedures.check import check_poses_um, planned_check

    poses = check_poses_um(np.array([0.0, 0.0, 0.0]), np.array([6000.0, 4000.0, 0.0]))
    assert poses.shape == (10, 3)
    assert np.all(poses[:, 2] == 0.0)
    assert len(np.unique(poses, axis=0)) == 5  # the centre and the square's four corners
    np.testing.assert_allclose(np.ptp(poses[:, :2], axis=0), [0.8 * 4000, 0.8 * 4000])
    d, p, _ = _xy_data(170, 0.01, seed=4)
    s = np.where(np.random.default_rng(1).random((170, 2)) < 0.5, 1.0, -1.0)
    cal, _ = calibrate_manipulator("p1", d, p + 0.2 * s[:, [0, 1, 1]], held_um={"dz": 0.0},
                                   extra_inputs={"approach_x": s[:, 0], "approach_y": s[:, 1],
                                                 "approach_z": np.ones(170)})  # fmt: skip
    assert "sz" not in cal.model.inputs  # the held joint's direction is left out
    stage = with_three_joints(_XYStage())
    d_all, approach = planned_check(ManipulatorCalibration("p1", cal.model, extra=cal.extra), stage)
    assert approach.tolist() == [20.0, 20.0, 0.0]
    assert np.all(d_all[:, 2] == 0.0)


def test_solve_says_how_far_a_target_is_off_a_positioners_surface():
    from microcal.procedures.compensation import solve_position
    from microcal.report.text_tables import solution_lines

    d, p, _ = _xy_data(170, 0.01, seed=5)
    cal, _ = calibrate_manipulator("p1", d, p, "matrix", held_um={"dz": 0.0})
    on = cal.predict_um([3000.0, 2000.0, 0.0])[0]
    sol = solve_position(cal, on + [0.0, 0.0, 4.0], {})
    assert sol.d_um[2] == 0.0
    lines = solution_lines(sol, cal)
    assert any("'p1' holds dz still" in line and "4.000 µm off it" in line for line in lines)
    assert not any("holds dz" in line for line in solution_lines(solve_position(cal, on, {}), cal))


XY_RIG = """
driver = "hardware"
[manipulator]
kind = "smaract-mcs2"
address = "127.0.0.1"
channels = { x = 0, y = 1, z = 2 }
limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }
[manipulators.p1]
kind = "micromanager"
xy_stage = "XY"
limits_um = LIMITS
[micromanager]
python_devices = "support.mm_devices:load"
[cameras.top]
kind = "aravis"
address = "10.0.0.11"
[cameras.side]
kind = "aravis"
address = "10.0.0.12"
"""


def test_a_micromanager_xy_stage_is_a_positioner_of_a_rig_file(tmp_path):
    from microcal.formats.rig_file import load_rig, rig_from_record

    path = tmp_path / "rig.toml"
    path.write_text(XY_RIG.replace("LIMITS", "{ x = [0, 6000], y = [0, 6000] }"), encoding="utf-8")
    spec = load_rig(str(path))
    assert spec.manipulators["p1"].axes == ("x", "y")
    assert spec.manipulators["p1"].focus is None
    record = spec.to_dict()
    assert rig_from_record(record, "run.json") == spec  # a resume reads its own record
    assert record == spec.to_dict()  # and leaves it as it was
    path.write_text(XY_RIG.replace("LIMITS", "{ x = [0, 6000], y = [0, 6000], z = [0, 1] }"),
                    encoding="utf-8")  # fmt: skip
    with pytest.raises(Exception, match="limits give z but no focus stage is named"):
        load_rig(str(path))


def test_a_micromanager_xy_stage_moves_as_three_joints(mm_core):
    from microcal.devices.micromanager import MMManipulator

    stage = with_three_joints(MMManipulator(mm_core, xy_stage="XY", focus=None,
                                            limits_um=[[0, 6000], [0, 6000]]))  # fmt: skip
    assert stage.identity == "Micro-Manager XY"
    from microcal.devices.base import RealClock

    stage.move_to_um([1200.0, 800.0, 0.0])
    stage.wait_until_stopped(RealClock(), timeout_s=10.0)
    np.testing.assert_allclose(stage.position_um(), [1200.0, 800.0, 0.0], atol=1e-6)
    with pytest.raises(LimitError, match="axis z"):
        stage.move_to_um([1200.0, 800.0, 10.0])


def test_a_positioners_evaluation_aims_at_its_surface():
    from microcal.control.feedforward import FeedForward
    from microcal.procedures.evaluation import aimed_poses_um
    from microcal.sim import platform

    plat = platform("thesis-platform", seed=0)
    device = plat.manipulators["p1"]
    ff = FeedForward(device, device.truth.static)
    poses = iso_cube_poses(np.array([500.0, 500.0, 0.0]), np.array([5500.0, 5500.0, 0.0]))
    aims = aimed_poses_um(ff, poses)
    home = ff.home_um()
    # each aim is on the model's surface, and the nearest point of it to the pose
    reached = device.truth.static.predict_um(np.array([ff.joints_for(home + a) for a in aims]))
    np.testing.assert_allclose(reached - home, aims, atol=1e-6)
    assert np.abs(aims[:, 2]).max() > 1.0  # the stage's tilt and bow lift the poses
    np.testing.assert_allclose(aims[:, :2], poses[:, :2], atol=0.1)
    # a manipulator's poses are its poses, and so is the uncompensated condition's
    m1 = plat.manipulators["m1"]
    assert aimed_poses_um(FeedForward(m1, m1.truth.static), poses) is not None
    np.testing.assert_array_equal(aimed_poses_um(FeedForward(m1, m1.truth.static), poses), poses)
    np.testing.assert_array_equal(aimed_poses_um(None, poses), poses)
    # an approach from below leaves the held joint where it is
    assert device.below_um([100.0, 200.0, 0.0], 20.0).tolist() == [80.0, 180.0, 0.0]


def test_bad_held_joint_values_are_refused_in_one_line():
    truth = positioner_kinematics().static
    for bad in ({"dz": True}, {"dz": "0"}):
        with pytest.raises(FormatError, match="held_joints_um: expected"):
            KinematicModel.from_dict(truth.to_dict() | {"held_joints_um": bad})
    d, p, _ = _xy_data(40, 0.01, seed=6)
    with pytest.raises(InputError, match="held joints: expected a value in µm for dz"):
        calibrate_manipulator("p1", d, p, "matrix", held_um={"dz": "zero"})
    with pytest.raises(InputError, match="held joints: expected names among"):
        calibrate_manipulator("p1", d, p, "matrix", held_um={"dq": 0.0})
