"""One trial of the camera-model choice on a simulated platform, scored against its truth.

What the choice between a pinhole and an affine camera must show (``scripts/
camera_model_choice.py`` runs it over seeds): on a platform of a preset, method (a) with
``camera_model="auto"`` from rendered images of the dot grid at five known heights; each
camera's chosen model, its reprojection RMS against the rendered noise floor (the RMS
distance of the detected dots from their true projections), the pinhole fit's conditioning;
then poses of the end-effector measured in 3D by the chosen cameras, by the true cameras
and by pinhole fits of the same images, each against the truth. Simulator only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validation import FloatArray
from ..errors import DegenerateDataError
from ..geometry import AnyCamera
from ..procedures.rig_stereo import CALIBRATION_STEPS_UM
from ..sim import SimPlatform, platform
from ..sim.platforms import CALIBRATION_TARGET
from ..vision.detect import Detection
from ..vision.known_displacements import calibrate_known_displacements, fit_known_points
from ..vision.measurement import PoseMeasurement, measure_poses
from ..vision.stereo_calibration import StereoCalibration
from ..vision.targets import Target, parse_target
from .demo import target_views

__all__ = ["CameraModelTrial", "camera_model_trial"]


@dataclass
class CameraModelTrial:
    """The figures of one trial (per camera where it says so)."""

    preset: str
    seed: int
    chosen: dict[str, str]
    rms_px: dict[str, float]
    noise_floor_px: dict[str, float]
    pinhole_problem: dict[str, str]
    rms_3d_um: dict[str, float] = field(default_factory=dict)
    """3D RMS error against the truth: ``chosen``, ``true`` cameras, ``pinhole`` fits."""
    mahalanobis_mean_sq: float = float("nan")
    calibration: StereoCalibration | None = None

    @property
    def floor_ratio(self) -> dict[str, float]:
        """Reprojection RMS over the rendered noise floor, per camera."""
        return {n: self.rms_px[n] / self.noise_floor_px[n] for n in self.rms_px}


def _rms_3d(measured: list[PoseMeasurement], truth: FloatArray) -> float:
    p = np.array([m.p_um for m in measured])
    ok = np.all(np.isfinite(p), axis=1)
    return float(np.sqrt(np.mean(np.sum((p[ok] - truth[ok]) ** 2, axis=1))))


def camera_model_trial(
    preset: str, seed: int, *, frames_per_view: int = 8, poses: int = 30, frames: int = 5
) -> CameraModelTrial:
    """Calibrate with ``camera_model="auto"`` and measure ``poses`` poses (see the module).

    Parameters
    ----------
    preset : str
        A simulator preset (``thesis``, ``telecentric``, ``thesis-3cam``).
    seed : int
    frames_per_view : int
        Frames averaged per calibration image.
    poses : int
        End-effector poses measured (0: calibration figures only).
    frames : int
        Frames per pose.
    """
    plat = platform(preset, seed=seed)
    grid = parse_target(CALIBRATION_TARGET)
    steps = np.array([[0.0, 0.0, z] for z in CALIBRATION_STEPS_UM])
    views = target_views(plat, grid, steps, frames_per_view)
    dets, errors = views.detections, views.truth_error_px
    sizes = {n: c.model.image_size_px for n, c in plat.cameras.items()}
    cal = calibrate_known_displacements(dets, views.names, grid, steps, sizes,
                                        camera_model="auto")  # fmt: skip
    floor = {
        n: float(np.sqrt(np.mean(np.sum(np.vstack(e) ** 2, axis=1)))) for n, e in errors.items()
    }
    problems = {}
    for n, c in cal.cameras.items():
        candidates: list[dict[str, object]] = c.model_choice.get("candidates", [])  # type: ignore[assignment]
        pin = [d for d in candidates if d["model"] == "pinhole"]
        problems[n] = (
            str(pin[0].get("ill_conditioned") or pin[0].get("failed") or "") if pin else ""
        )
    trial = CameraModelTrial(
        preset, seed, {n: c.model.kind for n, c in cal.cameras.items()},
        {n: c.rms_px for n, c in cal.cameras.items()}, floor, problems, calibration=cal,
    )  # fmt: skip
    if poses:
        _measure(plat, trial, cal, dets, grid, steps, sizes, poses, frames, seed)
    return trial


def _measure(
    plat: SimPlatform,
    trial: CameraModelTrial,
    cal: StereoCalibration,
    dets: dict[str, list[Detection]],
    grid: Target,
    steps: FloatArray,
    sizes: dict[str, tuple[int, int]],
    poses: int,
    frames: int,
    seed: int,
) -> None:
    """Measure poses with the chosen, the true and pinhole-fitted cameras, against truth."""
    rng = np.random.default_rng(seed + 7919)
    d = rng.uniform([500.0, 500.0, 500.0], [7500.0, 7500.0, 4300.0], (poses, 3))
    grabbed: dict[tuple[int, str], list[np.ndarray]] = {}
    truth = []
    m = plat.manipulator
    for i, di in enumerate(d):
        m.move_to_um(di)
        m.wait_until_stopped(plat.clock)
        plat.clock.sleep(5.0)
        truth.append(plat.truth_position_um())
        for n, cam in plat.cameras.items():
            grabbed[(i, n)] = [cam.grab() for _ in range(frames)]
    t = np.array(truth)
    board = plat.scene.board
    sets: dict[str, dict[str, AnyCamera]] = {
        "chosen": cal.models(),
        "true": plat.camera_models,
    }
    pinholes = {}
    for n, c in dets.items():
        used = [k for k, det in enumerate(c) if det.found]
        p = np.vstack([grid.points_um()[c[k].ids] + steps[k] for k in used])
        q = np.vstack([c[k].q_px for k in used])
        try:
            pinholes[n] = fit_known_points("pinhole", p, q, sizes[n], n)[0]
        except DegenerateDataError:
            break
    if len(pinholes) == len(dets):
        sets["pinhole"] = pinholes
    load = lambda i, n: grabbed[(i, n)]  # noqa: E731
    for key, cams in sets.items():
        measured = measure_poses(list(range(poses)), d, load, cams, board)
        trial.rms_3d_um[key] = _rms_3d(measured, t)
        if key == "chosen":
            e = np.array([r.p_um for r in measured]) - t
            cov = np.array([r.cov_um2 for r in measured])
            ok = np.all(np.isfinite(e), axis=1)
            m2 = np.einsum("ni,nij,nj->n", e[ok], np.linalg.inv(cov[ok]), e[ok])
            trial.mahalanobis_mean_sq = float(m2.mean())
