"""The quick check of a calibration: its two tests hold their false-alarm rate, see an offset and
a misfit, the offset update moves the base and nothing else, and the check on the simulator
(fast path) tells a re-mounted device from a rescaled one."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.errors import DetectionError, InputError, LimitError
from microcal.kinematics.manipulator_calibration import ManipulatorCalibration
from microcal.kinematics.models import fit_matrix_model, fit_polynomial_model
from microcal.procedures.check import (
    CheckConfig,
    check_poses_um,
    compare,
    offset_updated,
    run_check,
)
from microcal.sim import platform
from microcal.sim.synthetic_run import ProjectedProbe

BOX = np.array([[0.0, 8000.0], [0.0, 8000.0], [0.0, 4800.0]])
SIGMA_UM = 0.5


def _matrix_model(seed: int = 0):
    rng = np.random.default_rng(seed)
    d = rng.uniform(0, 4800, (60, 3))
    p = d @ np.array([[1.01, 0.002, 0], [0, 0.99, 0.003], [0.001, 0, 1.0]]).T + [100, 200, 300]
    return fit_matrix_model(d, p + rng.normal(0, 0.01, p.shape))


def _measured(model, d, rng, shift=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)):
    p = model.predict_um(d * np.asarray(scale)) + shift + rng.normal(0, SIGMA_UM, d.shape)
    return p, np.tile(np.eye(3) * SIGMA_UM**2, (len(d), 1, 1))


def test_check_poses_are_the_iso_cube_centre_and_eight_inner_corners():
    poses = check_poses_um(*BOX.T)
    assert poses.shape == (10, 3)
    np.testing.assert_allclose(poses[0], [4000, 4000, 2400])
    np.testing.assert_allclose(poses[-1], poses[0])
    # 10 % of the cube's diagonal in from its eight corners (cube of side 4800)
    inner = np.abs(poses[1:9] - poses[0])
    np.testing.assert_allclose(inner, 0.8 * 2400.0)
    assert len({tuple(np.sign(p - poses[0])) for p in poses[1:9]}) == 8


def test_the_tests_hold_their_false_alarm_rate_and_see_offsets_and_misfits():
    model = _matrix_model()
    d = check_poses_um(*BOX.T)
    rng = np.random.default_rng(1)
    trials = 400
    verdicts = {"none": [], "offset": [], "scale": []}
    for _ in range(trials):
        for change, kw in (("none", {}), ("offset", {"shift": np.array([0.6, 0.0, 0.0])}),
                           ("scale", {"scale": np.array([1.002, 1.0, 1.0])})):  # fmt: skip
            p, cov = _measured(model, d, rng, **kw)
            verdicts[change].append(compare(model, np.zeros(3), d, p, cov).verdict)
    none = np.array(verdicts["none"])
    # each test at 5 %: the offset test alone decides "offset" on unchanged data, the fit
    # test "refit"; binomial 400 trials: 5 % ± 3.3 % (3 sigma)
    assert abs(np.mean(none == "offset") - 0.05 * 0.95) < 0.033
    assert abs(np.mean(none == "refit") - 0.05) < 0.033
    # 0.6 µm along x against sigma_mean = 0.5 / sqrt(10) = 0.16 µm: noncentrality 14.4
    assert np.mean(np.array(verdicts["offset"]) == "offset") > 0.8
    # 0.2 % of x over the cube's ±1920 µm: ±3.8 µm at the corners
    assert np.mean(np.array(verdicts["scale"]) == "refit") > 0.99


def test_the_offset_is_estimated_within_its_standard_deviation():
    model = _matrix_model()
    d = check_poses_um(*BOX.T)
    rng = np.random.default_rng(2)
    shift = np.array([1.0, -2.0, 0.5])
    z = []
    for _ in range(200):
        p, cov = _measured(model, d, rng, shift=shift)
        r = compare(model, np.zeros(3), d, p, cov)
        z.append((r.offset_um - shift) / r.offset_std_um)
    assert np.std(z, axis=0) == pytest.approx(np.ones(3), abs=0.15)
    # the matrix model's own prediction uncertainty adds a hair: common to the ten poses, it
    # does not average down
    np.testing.assert_allclose(r.offset_std_um, SIGMA_UM / np.sqrt(10), rtol=5e-4)


def test_a_reference_check_cancels_the_models_misfit():
    model = _matrix_model()
    d = check_poses_um(*BOX.T)
    rng = np.random.default_rng(3)
    misfit = rng.normal(0, 2.0, d.shape)  # the model's error at each check pose, µm
    p0, cov = _measured(model, d, rng)
    p1, _ = _measured(model, d, rng, shift=np.array([0.0, 0.0, 1.0]))
    alone = compare(model, np.zeros(3), d, p1 + misfit, cov)
    assert alone.verdict == "refit"  # without its misfit in the model's record, a misfit
    ref = compare(model, np.zeros(3), d, p0 + misfit, cov)
    against = compare(model, np.zeros(3), d, p1 + misfit, cov,
                      reference=(ref.residual_um, ref.covariance_um2))  # fmt: skip
    assert against.verdict == "offset"
    assert against.offset_um[2] == pytest.approx(1.0, abs=4 * against.offset_std_um[2])


def test_the_offset_update_moves_every_prediction_by_the_offset_and_changes_nothing_else():
    rng = np.random.default_rng(4)
    d = rng.uniform(0, 4000, (40, 3))
    model = fit_polynomial_model(d, d * 1.01 + 0.0001 * d**2 + 50.0, select="all")
    moved = offset_updated(model, np.array([1.5, -2.0, 0.25]))
    np.testing.assert_allclose(moved.predict_um(d) - model.predict_um(d), [[1.5, -2.0, 0.25]] * 40)
    np.testing.assert_allclose(moved.jacobian(d), model.jacobian(d))
    np.testing.assert_array_equal(moved.covariance, model.covariance)
    with pytest.raises(InputError, match="offset_um"):
        offset_updated(model, [1.0, 2.0])


@pytest.fixture(scope="module")
def calibration():
    """A polynomial model of the thesis preset's manipulator (with the approach directions'
    terms, so the check approaches every pose from below) fitted on ground truth."""
    plat = platform("thesis", seed=0)
    rng = np.random.default_rng(5)
    d = rng.uniform(BOX[:, 0], BOX[:, 1], (120, 3))
    signs = rng.choice([-1.0, 1.0], d.shape)
    p = plat.manipulator.truth.position_um(d, signs)
    model = fit_polynomial_model(np.hstack([d, signs]), p, select="all",
                                 extra={"sx": 1, "sy": 1, "sz": 1})  # fmt: skip
    return ManipulatorCalibration("m1", model, {"rms_axis_um": {"x": 0.2, "y": 0.2, "z": 0.2}})


@pytest.mark.parametrize(("change", "expected"), [
    ("none", "valid"), ("offset", "offset"), ("scale", "refit"),
])  # fmt: skip
def test_the_check_on_the_simulator_tells_the_changes_apart(calibration, change, expected):
    plat = platform("thesis", seed=11)
    probe = ProjectedProbe.on_platform(plat, np.random.default_rng(11))
    if change == "offset":
        plat.manipulator.mount_offset_um = np.array([0.0, 0.8, -0.6])
    if change == "scale":
        plat.manipulator.joint_scale[1] = 1.002
    result = run_check(plat.manipulator, plat.clock, probe.measure_with_covariance, calibration,
                       config=CheckConfig(frames=20))  # fmt: skip
    assert result.verdict == expected, result.as_dict()
    if change == "offset":
        np.testing.assert_allclose(result.offset_um, [0.0, 0.8, -0.6],
                                   atol=float(4 * result.offset_std_um.max()))  # fmt: skip
    # ten poses, 20 frames each, 5 s settling: under two minutes of simulated time
    assert result.extra["duration_s"] < 120.0


def test_the_check_refuses_poses_beyond_the_limits_and_a_board_out_of_view(calibration):
    plat = platform("thesis", seed=12)
    probe = ProjectedProbe.on_platform(plat, np.random.default_rng(12))
    before = plat.manipulator.joints_um(plat.clock.now_s())
    with pytest.raises(LimitError):
        run_check(plat.manipulator, plat.clock, probe.measure_with_covariance, calibration,
                  poses_um=np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 9000.0]]))  # fmt: skip
    np.testing.assert_array_equal(plat.manipulator.joints_um(plat.clock.now_s()), before)

    def blind(d_um, frames):
        return np.full(3, np.nan), np.full((3, 3), np.nan)

    with pytest.raises(DetectionError, match="check pose 1"):
        run_check(plat.manipulator, plat.clock, blind, calibration)


@pytest.mark.slow
def test_a_run_records_its_device_and_a_calibration_refuses_another(tmp_path):
    from typer.testing import CliRunner

    from microcal.cli import app
    from microcal.formats.run_directory import RunDirectory

    runner = CliRunner()
    got = runner.invoke(app, ["acquire", "--rig", "sim", "--poses", "12", "--settle", "fixed:1",
                              "--frames", "1", "--out", str(tmp_path / "run")])  # fmt: skip
    assert got.exit_code == 0, got.output
    manifest = RunDirectory(tmp_path / "run").manifest
    assert manifest is not None
    assert manifest.device == "simulated m1"
    from microcal.formats.calibration_file import load_calibration
    from microcal.workflows.calibration_update import add_manipulator

    validation = {"n_fit": 10, "n_validate": 2, "mean_um": 0.5, "std_um": 0.2, "max_um": 1.0,
                  "rms_um": 0.55}  # fmt: skip
    entry = ManipulatorCalibration("m1", _matrix_model(), validation)
    (tmp_path / "run" / "measurements.csv").write_text("pose\n")  # only hashed here
    add_manipulator(tmp_path / "cal.json", entry, None,
                    {"measurements": tmp_path / "run" / "measurements.csv"}, "matrix",
                    manifest)  # fmt: skip
    assert load_calibration(tmp_path / "cal.json").manipulator().device == "simulated m1"
    m = ManipulatorCalibration(
        "m1", _matrix_model(), extra={"device": "SmarAct MCS2 A1 channels 0,1,2"}
    )
    m.check_device("SmarAct MCS2 A1 channels 0,1,2")
    m.check_device("")  # a backend that cannot tell
    with pytest.raises(InputError, match=r"calibrated on SmarAct MCS2 A1 .* manipulator is B2"):
        m.check_device("B2")
    ManipulatorCalibration("m1", _matrix_model()).check_device("B2")  # an older calibration


@pytest.mark.slow
def test_the_offset_tests_covariance_holds_the_models_error_common_to_the_poses():
    """Monte Carlo: each trial fits a matrix model afresh on 30 noisy poses (3 µm) and checks
    it at the ten poses of an unchanged rig (0.2 µm): the model's coefficient errors move all
    ten predictions together, so the mean residual scatters as its propagated covariance
    says, not ten times less, and the offset test keeps its 5 %."""
    rng = np.random.default_rng(31)
    R = np.array([[1.01, 0.002, 0.0], [0.0, 0.99, 0.003], [0.001, 0.0, 1.0]])
    d = check_poses_um(*BOX.T)
    cov = np.tile(np.eye(3) * 0.2**2, (len(d), 1, 1))
    z, alarms = [], []
    for _ in range(300):
        d_cal = rng.uniform(BOX[:, 0], BOX[:, 1], (30, 3))
        model = fit_matrix_model(d_cal, d_cal @ R.T + 100.0 + rng.normal(0, 3.0, d_cal.shape))
        p = d @ R.T + 100.0 + rng.normal(0, 0.2, d.shape)
        r = compare(model, np.zeros(3), d, p, cov)
        z.append(r.offset_um / r.offset_std_um)
        alarms.append(r.offset_p_value < 0.05)
    # 300 trials: the z-scores' standard deviation within 0.12 of 1 (0.04 standard error; each
    # fit's noise estimate from 26 degrees of freedom widens it to 1.04), the false alarms
    # 5 % ± 3.8 % (3 sigma); before, the model's error counted as independent from pose to
    # pose, the z-scores scattered three times as wide
    np.testing.assert_allclose(np.std(z, axis=0), 1.0, atol=0.12)
    assert abs(np.mean(alarms) - 0.05) < 0.038


def test_a_small_calibrations_own_bias_is_no_offset():
    """A calibration from 40 poses (26 fitted, 14 validated; measured to 0.35 / 0.3 / 0.9 µm)
    whose x lacks the approach-direction term, as stepwise selection leaves it out on few
    poses: the check approaches every pose from below, so the x hysteresis (0.5 µm) is a bias
    common to the ten poses. Its validation error holds it; the offset test now counts it
    (20 seeds: 9 said "offset" before)."""
    from microcal.procedures.identification import calibrate_manipulator
    from microcal.sim.thesis_kinematics import thesis_kinematics

    truth = thesis_kinematics()
    d = check_poses_um(*BOX.T)
    sigma_cal, sigma_check = np.array([0.35, 0.3, 0.9]), np.array([0.15, 0.15, 0.4])
    cov = np.tile(np.diag(sigma_check**2), (len(d), 1, 1))
    verdicts = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        d_cal = rng.uniform(BOX[:, 0], BOX[:, 1], (40, 3))
        signs = rng.choice([-1.0, 1.0], d_cal.shape)
        p_cal = truth.position_um(d_cal, signs) + rng.normal(0, sigma_cal, d_cal.shape)
        cal, _ = calibrate_manipulator("m1", d_cal, p_cal, "polynomial", train=26,
                                       extra_inputs={"approach_y": signs[:, 1],
                                                     "approach_z": signs[:, 2]})  # fmt: skip
        misfit = np.array([cal.validation["rms_axis_um"][a] for a in "xyz"])
        p = truth.position_um(d, np.ones_like(d)) + rng.normal(0, sigma_check, d.shape)
        verdicts.append(compare(cal.model, misfit, d, p, cov).verdict)
    assert verdicts.count("valid") >= 19, verdicts
