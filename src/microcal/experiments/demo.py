"""The whole procedure on the simulated thesis platform (what ``microcal demo`` runs).

1. Stereo calibration from rendered images: the dot grid at five known heights (method (a),
   the thesis's), frames averaged per view.
2. Acquisition: random joint commands over the travel (the thesis's design), settling
   detected by vision, several frames per pose, stored as regions around the board;
   measurement of every pose in 3D with its covariance.
3. Identification: matrix and polynomial (stepwise) models, fitted on the first poses and
   validated on the rest (the thesis's split), next to the oracle (the simulator's true
   kinematics predicting the same measurements).
4. Evaluation: ISO 9283 pose accuracy and the decoupling test, without compensation and with
   the matrix and optimal compensators (thesis 5.3).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .._parallel import Background
from .._validation import FloatArray
from ..control.conditions import open_loop_conditions
from ..control.feedforward import extra_inputs_reader
from ..errors import FormatError, InputError
from ..journal_record import JournalRecord
from ..kinematics.designs import make_design
from ..kinematics.extra_inputs import APPROACH_INPUTS, extra_input
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..kinematics.models import held_from_limits
from ..metrics.error_summary import summarize_errors
from ..procedures.acquisition import AcquisitionConfig, Store, acquire
from ..procedures.evaluation import RunOptions, iso_cube_poses
from ..procedures.evaluation_figures import Evaluation
from ..procedures.identification import Identification, calibrate_manipulator, default_train
from ..procedures.rig_stereo import CALIBRATION_STEPS_UM
from ..sim import SimPlatform, platform
from ..sim.paint_process import painting_elsewhere
from ..sim.platforms import CALIBRATION_TARGET
from ..sim.render import Placement
from ..thesis.experiment import TABLE_5_2_POSES_UM, WORKSPACE_MAX_UM, WORKSPACE_MIN_UM
from ..vision.detect import Detection, detect
from ..vision.lazy_frame import PastedFrame, pasted_frames
from ..vision.measurement import PoseMeasurement, measure_poses
from ..vision.measurement_stream import MeasurementStream
from ..vision.probe import VisionProbe
from ..vision.stereo_calibration import StereoCalibration, calibrate_known_displacements
from ..vision.targets import Target, parse_target
from .demo_evaluation import DemoTests, run_demo_tests
from .stage_clock import StageClock

__all__ = [
    "DemoResult",
    "calibrate_on_platform",
    "demo_design",
    "demo_design_seed",
    "demo_family",
    "run_demo",
]


def demo_family(preset: str) -> str:
    """The polynomial model's family the demo fits on a preset: the thesis's ``quadratic``,
    and ``auto`` (chosen by held-out error) on ``population``, whose errors lie outside it."""
    return "auto" if preset == "population" else "quadratic"


@dataclass
class DemoResult:
    """Everything the demo measured; ``truth_*`` from the simulator's ground truth."""

    seed: int
    calibration: StereoCalibration
    calibration_truth_px: dict[str, float]  # per camera: RMS reprojection vs the true camera
    d_um: FloatArray
    measurements: list[PoseMeasurement]
    truth_um: FloatArray
    models: dict[str, Identification] = field(default_factory=dict)  # matrix, polynomial
    manipulator: ManipulatorCalibration | None = None  # what calibration.json holds
    oracle: dict[str, float] = field(default_factory=dict)
    evaluation: Evaluation = field(default_factory=Evaluation)  # pose_accuracy, decoupling
    records: list[JournalRecord] = field(default_factory=list)  # the acquisition's journal
    sim_time_s: float = 0.0
    stages_s: dict[str, float] = field(default_factory=dict)  # wall seconds per stage

    @property
    def measured_ok(self) -> np.ndarray:
        """Poses measured successfully (bool per pose)."""
        return np.array([m.status == "ok" for m in self.measurements])

    @property
    def measurement_rms_um(self) -> float:
        """RMS 3D error of the measured positions against ground truth."""
        return float(np.sqrt(np.sum(self.measurement_rms_axis_um**2)))

    @property
    def measurement_rms_axis_um(self) -> FloatArray:
        """(3,) RMS error per axis of {G} (x, y, z) against ground truth, µm."""
        ok = self.measured_ok
        p = np.array([m.p_um for m in self.measurements])[ok]
        out: FloatArray = np.sqrt(np.mean((p - self.truth_um[ok]) ** 2, axis=0))
        return out

    @property
    def mahalanobis_mean_sq(self) -> float:
        """Mean of ``e^T C^-1 e`` over the measured poses (e the error against the truth, C
        the reported covariance): 3 when the covariance matches the scatter."""
        ok = self.measured_ok
        e = np.array([m.p_um for m in self.measurements])[ok] - self.truth_um[ok]
        cov = np.array([m.cov_um2 for m in self.measurements])[ok]
        return float(np.mean(np.einsum("ni,nij,nj->n", e, np.linalg.inv(cov), e)))


def demo_design_seed(seed: int) -> int:
    """The seed of the demo's design (its draws are apart from the platform's)."""
    return seed + 1


def demo_design(
    seed: int, poses: int, workspace_um: tuple[FloatArray, FloatArray] | None = None
) -> FloatArray:
    """The demo's joint commands: the ``random`` design over the thesis's workspace (or
    ``workspace_um``, (low, high) µm).

    ``make_design("random", poses, WORKSPACE_MIN_UM, WORKSPACE_MAX_UM, demo_design_seed(seed))``,
    which is what the demo's run.json records; (poses, 3) µm.
    """
    low, high = workspace_um or (WORKSPACE_MIN_UM, WORKSPACE_MAX_UM)
    return make_design("random", poses, low, high, demo_design_seed(seed))


#: How far inside its soft limits a simulated device's demo workspace is, µm (the thesis's
#: workspace is the thesis preset's limits less this).
WORKSPACE_MARGIN_UM = 500.0


def device_workspace(limits_um: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The demo workspace of a simulated device: its soft limits (3, 2) less the margin (a
    held joint, limits of one value, keeps that value)."""
    margin = np.where(limits_um[:, 1] > limits_um[:, 0], WORKSPACE_MARGIN_UM, 0.0)
    return limits_um[:, 0] + margin, limits_um[:, 1] - margin


@dataclass
class TargetViews:
    """A target's views at known steps on a simulated platform, per camera: the detections,
    the image names, and each found detection's error against the target's true projection
    (averaged over the frames as the image is; simulator truth, for studies)."""

    detections: dict[str, list[Detection]]
    names: dict[str, list[str]]
    truth_error_px: dict[str, list[FloatArray]]


def target_views(
    plat: SimPlatform,
    target: Target,
    steps_um: FloatArray,
    frames_per_view: int = 8,
    progress: Callable[[int, int], None] | None = None,
) -> TargetViews:
    """The target at each known step, ``frames_per_view`` frames averaged per view, detected.

    The target's frame at zero displacement is {G}; the board on the gripper is hidden while
    the target is shown, and shown again afterwards.
    """
    plat.scene.show_board = False
    views = TargetViews({n: [] for n in plat.cameras}, {n: [] for n in plat.cameras},
                        {n: [] for n in plat.cameras})  # fmt: skip
    # each view is detected on a second thread while the next is grabbed (rendered)
    pending: dict[str, list[Future[tuple[Detection, FloatArray | None]]]] = {
        n: [] for n in plat.cameras
    }
    with ThreadPoolExecutor(max_workers=1) as detector:
        for k, step in enumerate(steps_um):
            plat.scene.fixed = Placement(target, np.eye(3), step)
            for n, cam in plat.cameras.items():
                images, truth = [], []
                for _ in range(frames_per_view):
                    images.append(cam.grab().astype(np.float32))
                    assert cam.last_truth is not None
                    truth.append(cam.last_truth.features_px[0])
                pending[n].append(detector.submit(_detect_view, images, truth, target))
                views.names[n].append(f"{n}_{k + 1:02d}")
            if progress:
                progress(k + 1, len(steps_um))
        for n, found in pending.items():
            for view in found:
                det, error = view.result()
                views.detections[n].append(det)
                if error is not None:
                    views.truth_error_px[n].append(error)
    plat.scene.fixed = None
    plat.scene.show_board = True
    return views


def _detect_view(
    images: list[NDArray[np.float32]], truth: list[FloatArray], target: Target
) -> tuple[Detection, FloatArray | None]:
    """A view's frames averaged and detected, and the detection's error against the truth
    averaged over the frames (None when the target is not found)."""
    det = detect(np.mean(images, axis=0), target)
    if not det.found:
        return det, None
    return det, det.q_px - np.mean(truth, axis=0)[det.ids]


def calibrate_on_platform(
    plat: SimPlatform,
    target: Target,
    steps_um: FloatArray,
    frames_per_view: int = 8,
    progress: Callable[[int, int], None] | None = None,
    camera_model: str = "auto",
) -> StereoCalibration:
    """Method (a) on a simulated platform (the views of :func:`target_views`), each camera's
    model as ``camera_model`` says (``auto``: chosen by held-out error)."""
    views = target_views(plat, target, steps_um, frames_per_view, progress)
    sizes = {n: c.model.image_size_px for n, c in plat.cameras.items()}
    return calibrate_known_displacements(
        views.detections, views.names, target, steps_um, sizes, camera_model=camera_model
    )


@contextlib.contextmanager
def _closing(streams: list[MeasurementStream]) -> Iterator[None]:
    """Ends the measuring processes when the block raises (a stopped run, Ctrl-C)."""
    try:
        yield
    except BaseException:
        for stream in streams:
            stream.close()
        raise


@contextlib.contextmanager
def _written(writer: ThreadPoolExecutor | None, writes: list[Future[None]]) -> Iterator[None]:
    """Waits, at the block's end, for every write given to ``writer``; raises the first that
    failed (unless the block raised: its error goes on, the poses written so far stay)."""
    try:
        yield
    finally:
        if writer is not None:
            writer.shutdown(wait=True)
    for write in writes:
        write.result()


def _journaled(records: list[JournalRecord], column: str) -> FloatArray:
    """An extra input's journal column over the records, (N,): NaN where one has none."""
    values = [r.journaled(column) for r in records]
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def run_demo(
    seed: int = 0,
    poses: int = 170,
    frames_per_pose: int = 5,
    frames_per_view: int = 8,
    settle_s: float = 5.0,
    evaluate: bool = True,
    cycles: int = 3,
    decoupling_samples: int = 17,
    progress: Callable[[str, int, int], None] | None = None,
    store: Store | None = None,
    creep_learn_poses: int = 5,
    plat: SimPlatform | None = None,
    camera_model: str = "auto",
    direction_terms: bool = True,
    approach_um: float = 0.0,
    family: str = "quadratic",
    device: str = "m1",
    cameras: StereoCalibration | None = None,
    fixed_settle_s: float | None = None,
    stages: StageClock | None = None,
    workers: int | None = None,
) -> DemoResult:
    """Run the calibration on the simulated thesis platform (see the module docstring).

    With ``evaluate``, step 4 runs the pose-accuracy test (``cycles`` ISO cycles at the Table
    5-2 poses) and the decoupling test without and with both compensators, measured by the
    calibrated cameras and by ground truth. ``settle_s`` is the fixed wait of those tests;
    the acquisition settles by vision. ``store`` receives every acquired pose as the
    acquisition gives it (see :func:`~microcal.procedures.acquisition.acquire`). ``plat`` is
    the platform to run on, if the caller has built it already (``platform(preset, seed)``;
    the thesis's by default). ``camera_model`` is the stereo calibration's (method (a)).
    With ``direction_terms`` the polynomial model may take the joints' approach directions
    (terms sx, sy, sz; the compensator then approaches every target from below);
    ``approach_um`` > 0 approaches each acquired pose from a random side (see
    :class:`~microcal.procedures.acquisition.AcquisitionConfig`). The evaluation adds ISO
    9283's multi-directional test by ground truth (``vap_um`` per condition). ``family`` is
    the polynomial model's (:data:`~microcal.kinematics.families.FAMILIES` or ``auto``);
    with any but the thesis's ``quadratic``, a room temperature that varies during the run
    joins the model as an extra input. ``device`` is the platform's device to calibrate
    (``m2`` or ``p1`` on ``thesis-platform``), over its own workspace; a device whose
    workspace is not the thesis's is evaluated at ISO 9283's cube poses, without the
    thesis's decoupling path. ``cameras``: a stereo calibration of this platform made
    before (the devices of one platform share it, and so the frame {G}).
    ``fixed_settle_s``: settle each acquired pose by this fixed wait instead of by vision.
    ``stages``: adds the wall time of each stage (stereo calibration, acquisition,
    measurement, identification, evaluation) to it; the result's ``stages_s`` holds them.
    ``workers``: processes for the measurement and the evaluation (None: one per core; 1:
    everything here, in turn). The evaluation's units then run in forked processes that
    replay the same moves (:mod:`~microcal.experiments.demo_evaluation`): the figures by
    ground truth are the same, those by vision the same in distribution (other noise).
    """
    clock = stages if stages is not None else StageClock()

    def tick(stage: str, done: int, total: int) -> None:
        if progress:
            progress(stage, done, total)

    plat = plat or platform("thesis", seed=seed)
    grid = parse_target(CALIBRATION_TARGET)
    steps = np.array([[0.0, 0.0, z] for z in CALIBRATION_STEPS_UM])
    calibration: Background[StereoCalibration] | None = None
    with clock.stage("stereo calibration"):
        if cameras is None:
            # the views are rendered here; the calibration from them runs on the other core
            # while the poses are acquired (it reads nothing the acquisition changes)
            views = target_views(
                plat,
                grid,
                steps,
                frames_per_view,
                lambda done, total: tick("stereo calibration", done, total),
            )
            sizes = {n: c.model.image_size_px for n, c in plat.cameras.items()}
            calibration = Background(
                lambda: calibrate_known_displacements(
                    views.detections, views.names, grid, steps, sizes, camera_model=camera_model
                )
            )
    if device not in plat.manipulators:
        raise InputError(f"device: expected one of {list(plat.manipulators)}, got {device!r}")
    m = plat.manipulators[device]
    plat.scene.show(device, plat.clock.now_s())
    workspace = device_workspace(m.limits_um)
    thesis_sized = bool(
        np.allclose(workspace[0], WORKSPACE_MIN_UM) and np.allclose(workspace[1], WORKSPACE_MAX_UM)
    )
    pts = np.random.default_rng(seed).uniform([0, 0, 0], [9000, 9000, 5000], (500, 3))
    d = demo_design(seed, poses, workspace)
    board = plat.scene.board
    sensors = {"temperature": lambda: m.temperature_at(plat.clock.now_s())}
    kept: dict[int, tuple[dict[str, list[NDArray[np.generic]]], JournalRecord]] = {}
    truth = np.full((poses, 3), np.nan)

    def load(pose: int, name: str) -> list[NDArray[np.generic]] | list[PastedFrame]:
        frames, record = kept[pose]
        if record.status != "ok":
            raise FormatError(f"acquisition failed: {record.reason or ''}")
        if name not in frames:
            raise FormatError("no image")
        roi = record.roi_px.get(name)
        if roi is None:
            return frames[name]
        return pasted_frames(frames[name], roi[:2], roi[2:])  # made where they are read

    # the poses are measured while the next are acquired, in a forked process per camera, from
    # when the cameras' calibration is there (with one worker: after the acquisition, here)
    measuring: list[MeasurementStream] = []
    calibrated: list[StereoCalibration] = [] if cameras is None else [cameras]

    def measure_from_now() -> None:
        if workers == 1 or measuring:
            return
        if not calibrated and calibration is not None and calibration.done():
            calibrated.append(calibration.result())
        if calibrated:
            stream = MeasurementStream(
                list(range(1, poses + 1)), d, load, calibrated[0].models(), board,
                progress=lambda done, total: tick("measurement", done, total),
            )  # fmt: skip
            measuring.append(stream)
            for pose in sorted(kept):
                stream.add(pose)

    # the run directory's files are written on a thread of their own (compressing and syncing
    # leave the interpreter to the acquisition), in order; a failed write is raised at the
    # next pose, and every pose is written before the acquisition's stage ends
    writer = ThreadPoolExecutor(max_workers=1) if store is not None and workers != 1 else None
    writes: list[Future[None]] = []

    def keep(
        pose: int, frames: dict[str, list[NDArray[np.generic]]], record: JournalRecord
    ) -> None:
        kept[pose] = (frames, record)
        truth[pose - 1] = m.true_position_um()
        if store is not None and writer is None:
            store(pose, frames, record)
        elif store is not None and writer is not None:
            while writes and writes[0].done():
                writes.pop(0).result()
            writes.append(writer.submit(store, pose, frames, record))
        if measuring:
            measuring[0].add(pose)
        else:
            measure_from_now()

    # the frames painted on the other core while this one plans, settles and stores
    painting = (
        painting_elsewhere(plat.cameras.values()) if workers != 1 else contextlib.nullcontext()
    )
    with clock.stage("acquisition"), _closing(measuring), _written(writer, writes), painting:
        acquire(
            m,
            plat.cameras,
            plat.clock,
            d,
            list(range(1, poses + 1)),
            board,
            keep,
            config=AcquisitionConfig(
                frames_per_pose=frames_per_pose,
                store_roi=True,
                creep_learn_poses=creep_learn_poses,
                approach_um=approach_um,
                approach_seed=demo_design_seed(seed),
                settle="vision" if fixed_settle_s is None else "fixed",
                fixed_s=fixed_settle_s or 0.0,
                search_process=workers != 1,
            ),
            sensors=sensors,
            progress=lambda done, total, _record: tick(
                "acquisition (vision settle)" if fixed_settle_s is None else "acquisition",
                done,
                total,
            ),
        )
    with clock.stage("stereo calibration"):  # what is left of it once the poses are in
        if not calibrated:
            got = calibration.result() if calibration is not None else cameras
            assert got is not None  # one of the two is there
            calibrated.append(got)
        cal = calibrated[0]
    truth_px = {
        n: float(
            np.sqrt(
                np.mean(
                    np.sum((c.model.project(pts) - plat.cameras[n].model.project(pts)) ** 2, axis=1)
                )
            )
        )
        for n, c in cal.cameras.items()
    }

    with clock.stage("measurement"), _closing(measuring):
        measure_from_now()  # (when the calibration came after the last pose)
        if measuring:
            measurements = measuring[0].results()
        else:
            measurements = measure_poses(
                list(range(1, poses + 1)),
                d,
                load,
                cal.models(),
                board,
                progress=lambda done, total: tick("measurement", done, total),
                workers=workers,
            )
    result = DemoResult(
        seed,
        cal,
        truth_px,
        d,
        measurements,
        truth,
        records=[kept[k][1] for k in sorted(kept)],
        sim_time_s=plat.clock.now_s(),
    )
    ok = result.measured_ok
    p = np.array([m.p_um for m in measurements])[ok]
    d_ok = d[ok]
    n_fit = default_train(len(d_ok))
    approach = {name: _journaled(result.records, extra_input(name).column)[ok]
                for name in APPROACH_INPUTS}  # fmt: skip
    extra = dict(approach) if direction_terms else {}
    temps = _journaled(result.records, extra_input("temperature").column)[ok]
    if family != "quadratic" and np.all(np.isfinite(temps)) and np.ptp(temps) > 0:
        extra["temperature"] = temps
    with clock.stage("identification"):
        result.manipulator, result.models = calibrate_manipulator(
            device,
            d_ok,
            p,
            "polynomial",
            train=n_fit,
            extra_inputs=extra or None,
            family=family,
            seed=seed,
            held_um=held_from_limits(m.limits_um),
        )
    oracle = summarize_errors(np.linalg.norm(p[n_fit:] - result.truth_um[ok][n_fit:], axis=1))
    result.oracle = {"mean": oracle.mean, "std": oracle.std, "max": oracle.max}
    if evaluate:
        with clock.stage("evaluation"):
            conditions = open_loop_conditions(
                m,
                result.manipulator,
                extra=extra_inputs_reader(result.manipulator.model, sensors),
                clock=plat.clock,
            )
            probe = VisionProbe(plat.cameras, cal.models(), board, frames=frames_per_pose)
            for d_k, measured in zip(d, measurements, strict=True):  # where the board was
                if measured.status == "ok":
                    probe.learn_regions(d_k, measured.corners_px)
            options = RunOptions(settle_s=settle_s, truth=m.true_position_um, progress=progress)
            tests = DemoTests(
                m,
                plat.clock,
                conditions,
                TABLE_5_2_POSES_UM if thesis_sized else iso_cube_poses(*workspace),
                cycles,
                decoupling_samples if thesis_sized else None,
                options,
            )
            # the tests' units in forked processes, each replaying the moves (see demo_evaluation)
            pa, decoupling = run_demo_tests(tests, probe, plat.cameras, workers)
            result.evaluation.pose_accuracy = pa
            if decoupling is not None:
                result.evaluation.decoupling = decoupling
            result.sim_time_s = plat.clock.now_s()
    result.stages_s = dict(clock.stages_s)
    return result
