"""The whole calibration on the simulated one-camera ``patch`` rig (``microcal demo --preset
patch``).

1. **Slide**: the camera against its X-Y stage (:func:`~microcal.procedures.scope_calibration.
   calibrate_scope`: a marked dot slide moved through a 3 x 3 grid, focus steps; 21 frames)
   gives the microscope's frame {M} (:class:`~microcal.vision.microscope_frame.MicroscopeFrame`).
2. **Acquisition and measurement**: from where the tip is in focus at the field's centre,
   poses outwards through the working volume (a box in {M}), the focus following the tip, the
   tip in 3D at each pose by a focus sweep (:func:`~microcal.procedures.one_camera_acquisition.
   acquire_one_camera`); the manipulator's joints counted from that start
   (:class:`~microcal.devices.shifted_joints.ShiftedJoints`), so the evaluation's home is in
   view.
3. **Identification**: the matrix and polynomial models with the approach-direction terms,
   fitted on the first poses and validated on the rest (the thesis's split).
4. **Evaluation**: ISO 9283 pose accuracy at the cube P1-P5 inside the working volume, by the
   one-camera probe (:class:`~microcal.procedures.one_camera_probe.OneCameraTipProbe`) and by
   ground truth, uncalibrated, matrix, optimal and closed loop; and the open loop by truth at
   random points filling the working volume.

The rig's simulated time is counted per stage (``rig_s``), apart from the wall time
(``stages_s``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .._validation import FloatArray
from ..control.conditions import closed_loop_condition, open_loop_conditions
from ..control.feedforward import extra_inputs_reader
from ..control.visual_servo import ServoConfig
from ..devices.microscope_drive import MicroscopeDrive
from ..devices.rig import Rig
from ..devices.shifted_joints import ShiftedJoints
from ..errors import InputError
from ..journal_record import JournalRecord
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..metrics.error_summary import summarize_errors
from ..procedures.evaluation import iso_cube_poses, run_pose_accuracy
from ..procedures.evaluation_figures import BySource, Evaluation, PoseAccuracyFigures
from ..procedures.identification import Identification, calibrate_manipulator, default_train
from ..procedures.one_camera_acquisition import (
    DEFAULT_VOLUME_HALF_UM,
    OneCameraPose,
    OneCameraRun,
    TipFinder,
    WorkingVolume,
    acquire_one_camera,
)
from ..procedures.one_camera_pose import measure_tip_one_camera
from ..procedures.one_camera_probe import OneCameraTipProbe
from ..procedures.scope_calibration import ScopeRun, calibrate_scope, depth_for, scope_plan
from ..sim.patch import PatchRig, patch_rig
from ..sim.patch_devices import patch_as_rig
from ..sim.patch_scope import (
    end_offset_px,
    image_axis,
    nominal_axes,
    slide_scope,
    true_frame,
    truth_in_frame,
)
from ..vision.focus_depth import ANCHOR_SIGMA_PX, axis_cov_px, grab_stack
from ..vision.microscope_frame import MicroscopeFrame
from .stage_clock import StageClock

__all__ = [
    "MIN_POSES",
    "PATCH_VOLUME_HALF_UM",
    "PatchDemoResult",
    "identify_run",
    "run_patch_demo",
]

#: The working volume's half sizes around the field's centre in {M}, µm: the one-camera
#: acquisition's default (200 x 200 µm of the 333 µm field, 50 µm of depth).
PATCH_VOLUME_HALF_UM = DEFAULT_VOLUME_HALF_UM
#: The fewest poses the demo takes: with fewer than about 20 poses to fit (two thirds of
#: them), the quadratic model's stepwise selection may leave an axis without its terms.
MIN_POSES = 30
#: The slide's frames: a central region of the sensor, px.
SLIDE_ROI_PX = 512


@dataclass
class PatchDemoResult:
    """Everything the ``patch`` demo measured; ``truth_*`` from the simulator."""

    seed: int
    scope: ScopeRun
    scope_errors: dict[str, float]  # the frame's errors against the rig's truth
    run: OneCameraRun
    truth_um: FloatArray  # (N, 3) the tips' true positions in {M}
    models: dict[str, Identification] = field(default_factory=dict)
    manipulator: ManipulatorCalibration | None = None
    oracle: dict[str, float] = field(default_factory=dict)
    evaluation: Evaluation = field(default_factory=Evaluation)
    volume_accuracy: BySource[PoseAccuracyFigures] | None = None  # open loop, by truth
    rig_s: dict[str, float] = field(default_factory=dict)  # simulated seconds per stage
    stages_s: dict[str, float] = field(default_factory=dict)  # wall seconds per stage
    sim_time_s: float = 0.0
    joint_origin_um: FloatArray = field(default_factory=lambda: np.zeros(3))  # joints' zero
    method: str = "sweep"  # how the tips' depth was measured

    @property
    def records(self) -> list[JournalRecord]:
        """The acquisition's journal."""
        return self.run.records

    @property
    def measurement_rms_axis_um(self) -> FloatArray:
        """(3,) RMS error per axis of {M} against ground truth, µm."""
        ok = self.run.ok
        out: FloatArray = np.sqrt(np.mean((self.run.p_um[ok] - self.truth_um[ok]) ** 2, axis=0))
        return out

    @property
    def measurement_rms_um(self) -> float:
        """RMS 3D error of the measured tips against ground truth, µm."""
        return float(np.sqrt(np.sum(self.measurement_rms_axis_um**2)))

    @property
    def mahalanobis_mean_sq(self) -> float:
        """Mean of ``e^T C^-1 e`` over the measured tips: 3 when the covariances match."""
        ok = self.run.ok
        e = self.run.p_um[ok] - self.truth_um[ok]
        c = self.run.cov_um2[ok]
        return float(np.mean(np.einsum("ni,nij,nj->n", e, np.linalg.inv(c), e)))

    @property
    def calibration_rig_s(self) -> float:
        """Simulated seconds of the calibration: slide, acquisition and measurement, fit."""
        return float(sum(v for k, v in self.rig_s.items() if k != "evaluation"))


def _scope_errors(frame: MicroscopeFrame, truth: MicroscopeFrame) -> dict[str, float]:
    """Scale (per cent, worst axis), rotation (degrees) and drift (px/µm) errors."""
    a, b = np.linalg.inv(frame.px_per_um), np.linalg.inv(truth.px_per_um)
    scale = np.linalg.norm(a, axis=0) / np.linalg.norm(b, axis=0) - 1.0
    rot = np.degrees(np.arctan2(a[1, 0], a[0, 0]) - np.arctan2(b[1, 0], b[0, 0]))
    drift = float(np.linalg.norm(frame.drift_px_per_um - truth.drift_px_per_um))
    return {"scale_error_pct": float(100 * np.max(np.abs(scale))),
            "rotation_error_deg": float(abs(rot)), "drift_error_px_per_um": drift}  # fmt: skip


def _stack_finder(drive: MicroscopeDrive, sweep: TipFinder) -> TipFinder:
    """The finder by the tool's reference stack (0.5 µm planes over ±4 µm), grabbed where a
    fine sweep (15 frames 0.4 µm apart) finds the tip at the start."""
    frame = sweep.frame
    tip = measure_tip_one_camera(
        drive.move_focus, drive.grab, frame.centre_px, 0.0, frame.um_per_px,
        axis_px=sweep.axis_px, frames=15, step_um=0.4, end_offset_px=sweep.end_offset_px,
        clock=drive.clock.now_s,
    )  # fmt: skip
    est = tip.depth
    anchor_cov = axis_cov_px(sweep.axis_px, *ANCHOR_SIGMA_PX)  # a sweep at the start pose
    stack = grab_stack(drive.grab_at_focus, est.z_um, est.apex_px, step_um=0.5,
                       tip_focus_var_um2=est.var_um2, tip_cov_px=anchor_cov,
                       axis_px=sweep.axis_px)  # fmt: skip
    return dataclasses.replace(sweep, method="stack", stack=stack)


def identify_run(
    run: OneCameraRun, seed: int = 0
) -> tuple[ManipulatorCalibration, dict[str, Identification]]:
    """The demo's identification of a one-camera run: the quadratic polynomial model (and the
    matrix model) on the measured poses, the first two thirds fitted, with each joint's
    approach direction where every joint came from each side at 3 poses or more."""
    ok = run.ok
    d, p = run.d_um[ok], run.p_um[ok]
    extra: dict[str, FloatArray] | None = {k: v[ok] for k, v in run.approach().items()}
    if extra and min(min(np.sum(v > 0), np.sum(v < 0)) for v in extra.values()) < 3:
        extra = None  # too few poses from each side for the approach terms (a short run)
    return calibrate_manipulator(
        "m1", d, p, "polynomial", train=default_train(len(d)), extra_inputs=extra,
        family="quadratic", seed=seed,
    )  # fmt: skip


def run_patch_demo(
    seed: int = 0,
    poses: int = 80,
    *,
    cycles: int = 3,
    volume_poses: int = 20,
    settle_s: float = 1.0,
    closed_loop: bool = True,
    method: str = "sweep",
    slide_roi_px: int = SLIDE_ROI_PX,
    progress: Callable[[str, int, int], None] | None = None,
    store: Callable[[JournalRecord, OneCameraPose], None] | None = None,
    stages: StageClock | None = None,
    patch: PatchRig | None = None,
    rig: Rig | None = None,
) -> PatchDemoResult:
    """Run the calibration on the ``patch`` rig of ``seed`` (module docstring).

    ``poses`` are acquired (the start, three steps, the design); ``cycles`` ISO cycles at
    the cube's poses; ``volume_poses`` random points of the working volume are visited once
    per condition by truth (0: not); ``settle_s`` the wait after the manipulator reports
    stopped; ``store(record, tip)`` receives each pose as it is measured; ``method``: the
    tip's depth by a focus sweep at every pose, or by one frame against the tool's reference
    stack grabbed at the start (``stack``); ``slide_roi_px``: the square region of the sensor
    the slide is seen in.

    ``patch`` is the simulated rig (``patch_rig(seed)`` by default), whose ground truth and
    slide the demo uses, and ``rig`` the devices it drives (``patch_as_rig(patch)`` by
    default): the same rig served another way, say by the digital twin and opened from its
    rig file through the hardware drivers (``scripts/patch_twin_figures.py``), its clock the
    twin's.
    """
    if poses < MIN_POSES:
        raise InputError(
            f"poses: the patch demo needs {MIN_POSES} or more (its models are fitted on the "
            f"first two thirds of them), got {poses}"
        )
    wall = stages if stages is not None else StageClock()
    patch = patch_rig(seed) if patch is None else patch
    cfg = patch.config
    rig = patch_as_rig(patch, f"simulated, preset patch, seed {seed}") if rig is None else rig
    assert rig.microscope is not None  # the patch rig has one
    drive = MicroscopeDrive(rig.microscope, rig.cameras["scope"], rig.clock)
    rig_clock = StageClock(rig.clock.now_s)

    def tick(stage: str, done: int, total: int) -> None:
        if progress is not None:
            progress(stage, done, total)

    with wall.stage("slide"), rig_clock.stage("slide"):
        slide = slide_scope(patch, slide_roi_px, seed, drive)
        field = slide_roi_px * cfg.um_per_px
        plan = scope_plan(field, depth_for(cfg.numerical_aperture))
        scope = calibrate_scope(slide.move_stage, slide.move_focus, slide.grab, slide.target,
                                plan, progress=lambda k, n: tick("slide", k, n))  # fmt: skip
    frame = MicroscopeFrame.from_scope(scope.calibration, cfg.size_px)
    truth_frame = true_frame(cfg)
    truth = truth_in_frame(patch, truth_frame)
    device = ShiftedJoints(rig.manipulator, rig.manipulator.position_um().round(0))
    finder = TipFinder(frame, image_axis(cfg), end_offset_px(cfg))
    if method == "stack":  # the tool's reference stack, grabbed once at the start
        with (
            wall.stage("acquisition and measurement"),
            rig_clock.stage("acquisition and measurement"),
        ):
            finder = _stack_finder(drive, finder)
    elif method != "sweep":
        raise InputError(f"method: expected sweep or stack, got {method!r}")
    volume = WorkingVolume(np.zeros(3), np.array(PATCH_VOLUME_HALF_UM))
    truths: list[FloatArray] = []

    def keep(record: JournalRecord, tip: OneCameraPose) -> None:
        truths.append(truth())
        if store is not None:
            store(record, tip)

    with wall.stage("acquisition and measurement"), rig_clock.stage("acquisition and measurement"):
        run = acquire_one_camera(
            device, rig.clock, drive.move_focus, drive.grab, finder, volume, poses,
            nominal_um_per_um=nominal_axes(cfg), settle_s=settle_s, seed=seed, store=keep,
            progress=lambda k, n: tick("acquisition and measurement", k, n),
        )  # fmt: skip
    result = PatchDemoResult(seed, scope, _scope_errors(frame, truth_frame), run,
                             np.array(truths))  # fmt: skip
    result.joint_origin_um = device.origin_um.copy()
    result.method = method
    ok = run.ok
    p = run.p_um[ok]
    n_fit = default_train(int(ok.sum()))
    with wall.stage("identification"), rig_clock.stage("identification"):
        result.manipulator, result.models = identify_run(run, seed)
    oracle = summarize_errors(np.linalg.norm(p[n_fit:] - result.truth_um[ok][n_fit:], axis=1))
    result.oracle = {"mean": oracle.mean, "std": oracle.std, "max": oracle.max}
    cal = result.manipulator
    n_extra = len(cal.model.extra_inputs)

    def expect(d_um: FloatArray) -> FloatArray:  # approached from below: sides +1
        out: FloatArray = cal.model.predict_um(np.concatenate([d_um, np.ones(n_extra)]))[0]
        return out

    with wall.stage("evaluation"), rig_clock.stage("evaluation"):
        read_extra = extra_inputs_reader(cal.model, {})
        conditions = dict(open_loop_conditions(device, cal, extra=read_extra, clock=rig.clock))
        probe = OneCameraTipProbe(finder, drive.move_focus, drive.grab, rig.clock, expect)
        loop = None
        if closed_loop:
            loop = closed_loop_condition(device, cal, probe.measure_with_covariance, rig.clock,
                                         read_extra, ServoConfig(tolerance_um=0.5),
                                         settle_s=settle_s, truth=truth)  # fmt: skip
            conditions["closed_loop"] = loop
        cube = iso_cube_poses(-volume.half_um, volume.half_um)
        result.evaluation.pose_accuracy = run_pose_accuracy(
            device, rig.clock, probe, conditions, poses_um=cube, cycles=cycles,
            settle_s=settle_s, truth=truth, progress=progress,
        )  # fmt: skip
        if loop is not None:
            result.evaluation.closed_loop = loop.summary()
        if volume_poses > 0:
            points = volume.draw(volume_poses, seed + 7)
            open_loop = {k: v for k, v in conditions.items() if k != "closed_loop"}
            result.volume_accuracy = run_pose_accuracy(
                device, rig.clock, None, open_loop, poses_um=points, cycles=1,
                settle_s=settle_s, truth=truth, progress=progress,
            )  # fmt: skip
    result.rig_s = dict(rig_clock.stages_s)
    result.stages_s = dict(wall.stages_s)
    result.sim_time_s = rig.clock.now_s()
    return result
