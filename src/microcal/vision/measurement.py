"""3D measurement of the end-effector from two or more cameras (thesis 4.2, Eq 4.13, Eq 3.18).

For each pose: find the board in every camera's frames (in a region predicted from the
commanded joints once a few poses are known, else in the whole image), take the virtual
point of each frame from the undistorted corners, average over the pose's frames, and
triangulate the cameras' virtual points optimally into {G}, with the covariance of the
result. A camera that lost its frames or did not find the board leaves the others to
measure (the pose's reason names it, its covariance counts the cameras that saw it); a pose
seen by fewer than two cameras is marked failed with each camera's reason.

A target numbered from markers (``dotgrid:...:markers=...``, ``chessboard:...:markers=...``)
may be seen in part, a different part in each camera and at each pose: each frame's virtual
point is then the picture of the target's centre through the homography of the features seen
(:func:`~microcal.vision.virtual_point.virtual_point`), so every camera triangulates the same
target point, and its covariance grows where the centre is extrapolated.

The pixel covariance of a virtual point comes from the corners' residuals (independent
corner noise); when poses have several frames, the frame-to-frame scatter pooled over the
run replaces it, which also counts what moves all corners together (vibration).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .._parallel import fork_map
from .._validation import FloatArray
from ..errors import DetectionError
from ..geometry import AnyCamera, CameraModelProtocol, triangulate_views
from .lazy_frame import RegionFrame, detect_in, pixels_of
from .roi import RoiPredictor, box_around
from .targets import Target
from .tip_measurement import tip_of_frames
from .tip_target import TipTarget
from .view_agreement import refuse_disagreeing
from .virtual_point import virtual_point

__all__ = [
    "PoseMeasurement",
    "Seen",
    "camera_track",
    "camera_view",
    "measure_one",
    "measure_poses",
    "measure_seen",
    "measurements_of_tracks",
]

Frames = Sequence[NDArray[np.generic]]
#: Frames of one camera, as arrays or as region frames (read where they are searched).
AnyFrames = Sequence[NDArray[np.generic] | RegionFrame]


@dataclass
class PoseMeasurement:
    """The measured end-effector of one pose."""

    pose: int
    status: str  # "ok" or "failed"
    reason: str = ""
    p_um: FloatArray = field(default_factory=lambda: np.full(3, np.nan))
    cov_um2: FloatArray = field(default_factory=lambda: np.full((3, 3), np.nan))
    vp_px: dict[str, FloatArray] = field(default_factory=dict)  # per camera, per frame (k, 2)
    vp_cov_px2: dict[str, FloatArray] = field(default_factory=dict)
    corners_px: dict[str, FloatArray] = field(default_factory=dict)  # per camera, frame 0

    @property
    def std_um(self) -> FloatArray:
        """Standard deviation per axis, µm."""
        out: FloatArray = np.sqrt(np.diagonal(self.cov_um2))
        return out


def _vp_of_frames(
    frames: AnyFrames,
    target: Target | TipTarget,
    model: AnyCamera,
    roi: tuple[int, int, int, int] | None,
) -> tuple[FloatArray, FloatArray, FloatArray] | str:
    """Virtual points (k, 2), their mean residual covariance (2, 2), and corners of frame 0
    (a tool's tip: its apexes, their covariance and the first apex)."""
    if isinstance(target, TipTarget):
        return tip_of_frames([pixels_of(f) for f in frames], target, model, roi)
    vps, covs, corners0, last = [], [], None, None
    for image in frames:
        if corners0 is not None:  # the board stays put during a pose: search around frame 0
            roi = box_around(corners0)
        # and is followed from the frame before (vision.detect: searched where it moved)
        det = detect_in(image, target, roi, last) if roi is not None else None
        if det is None or not det.found:
            det = detect_in(image, target)
        if not det.found:
            return det.reason
        try:
            vp = virtual_point(det, target, model)
        except DetectionError as exc:
            return str(exc)
        vps.append(vp.q_px)
        covs.append(vp.cov_px2)
        last = det.q_px
        if corners0 is None:
            corners0 = det.q_px
    assert corners0 is not None
    return np.array(vps), np.mean(covs, axis=0), corners0


def _frames_of(
    load_frames: Callable[[int, str], AnyFrames], pose: int, name: str, size: tuple[int, int]
) -> AnyFrames | str:
    """The frames of one camera at one pose, or why there are none usable."""
    from ..errors import FormatError

    try:
        frames = load_frames(pose, name)
    except FormatError as exc:
        return str(exc)
    if not frames:
        return "no image"
    w, h = size
    if frames[0].shape[:2] != (h, w):
        got_h, got_w = frames[0].shape[:2]
        return f"image is {got_w}x{got_h} px, the camera's calibration {w}x{h}"
    return frames


def _check_cameras(cameras: Mapping[str, object]) -> list[str]:
    names = list(cameras)
    if len(names) < 2:
        raise DetectionError(
            f"measurement: expected 2 or more calibrated cameras, got {len(names)} ({names})"
        )
    return names


def measure_poses(
    poses: Sequence[int],
    commands_um: FloatArray,
    load_frames: Callable[[int, str], AnyFrames],
    cameras: Mapping[str, AnyCamera],
    target: Target | TipTarget,
    *,
    progress: Callable[[int, int], None] | None = None,
    workers: int | None = 1,
) -> list[PoseMeasurement]:
    """Measure every pose of a run.

    A pose is measured by every camera that found the board in its frames; with two or more
    of them it is triangulated from those (its covariance counting only them, and its
    ``reason`` naming the cameras left out), with fewer it fails naming each camera's reason.

    Parameters
    ----------
    poses : sequence of int
        Pose numbers.
    commands_um : (N, k) float
        The joint commands of those poses (for predicting where the board is).
    load_frames : callable (pose, camera) -> list of images
        The frames of one pose from one camera (arrays, or region frames of
        :mod:`~microcal.vision.lazy_frame`); raise ``FormatError`` for a broken file.
    cameras : dict name -> camera model
        Two or more cameras in {G}, of any kind.
    target : Target or TipTarget
        The end-effector board, or the tool whose tip is measured (its apex in each camera
        triangulated as the board's virtual point is).
    progress : callable (done, total), optional
        Counts a camera's frames of a pose at a time (total: poses x cameras).
    workers : int or None
        Cameras measured at once (None: one per core), each in its own forked process (on
        Linux; elsewhere in turn). Each camera's poses are measured in order either way, so
        the results are the same.
    """
    names = _check_cameras(cameras)
    total = len(poses) * len(names)
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress:
            progress(done, total)

    def one_camera(name: str, tick: Callable[[], None]) -> list[Seen]:
        return camera_track(poses, commands_um, load_frames, cameras[name], name, target, tick)

    tracks = dict(zip(names, fork_map(one_camera, names, workers, tick), strict=True))
    return measurements_of_tracks(poses, tracks, cameras, target)


def measurements_of_tracks(
    poses: Sequence[int],
    tracks: Mapping[str, Sequence[Seen]],
    cameras: Mapping[str, AnyCamera],
    target: Target | TipTarget,
) -> list[PoseMeasurement]:
    """The poses measured from every camera's track (:func:`camera_track`, one per camera of
    ``cameras``, in its order) of ``target``: judged and triangulated as :func:`measure_poses`
    does (a tool's tip that the views do not agree on fails its pose)."""
    names = _check_cameras(cameras)
    results: list[PoseMeasurement] = []
    for k, pose in enumerate(poses):
        m = PoseMeasurement(pose, "ok")
        lost: list[str] = []
        for name in names:
            got = tracks[name][k]
            if isinstance(got, str):
                lost.append(f"{name}: {got}")
                continue
            m.vp_px[name], m.vp_cov_px2[name], m.corners_px[name] = got
        _judge(m, lost)
        results.append(m)
    _triangulate(results, cameras, names)
    if isinstance(target, TipTarget):  # one tip each camera, maybe each another tool's
        refuse_disagreeing(results, cameras)
    return results


#: What one camera made of one pose: virtual points (k, 2), their covariance (2, 2) and the
#: corners of frame 0, or why it has none.
Seen = tuple[FloatArray, FloatArray, FloatArray] | str


def camera_track(
    poses: Sequence[int],
    commands_um: FloatArray,
    load_frames: Callable[[int, str], AnyFrames],
    camera: AnyCamera,
    name: str,
    target: Target | TipTarget,
    tick: Callable[[], None],
) -> list[Seen]:
    """One camera's view of every pose, in order (where it finds the board is predicted
    from the poses before)."""
    predictor = RoiPredictor()
    out: list[Seen] = []
    for k, pose in enumerate(poses):
        got: AnyFrames | Seen = _frames_of(load_frames, pose, name, camera.image_size_px)
        if not isinstance(got, str):
            # a target numbered from markers shows a different part at each pose: the mean
            # of the features seen does not follow the joints, so the whole image is searched
            roi = None if getattr(target, "partial", False) else predictor.predict(commands_um[k])
            got = _vp_of_frames(got, target, camera, roi)
        if not isinstance(got, str):
            predictor.add(commands_um[k], got[2])
        out.append(got)
        tick()
    return out


def _judge(m: PoseMeasurement, lost: list[str]) -> None:
    """Failed with every camera's reason when fewer than two saw the board; else ok, and the
    cameras left out named."""
    if len(m.vp_px) < 2:
        m.status, m.reason = "failed", "; ".join(lost)
        m.vp_px.clear()
        m.vp_cov_px2.clear()
        m.corners_px.clear()
    elif lost:
        m.reason = "measured without " + "; ".join(lost)


def _calibration_cov(camera: object) -> FloatArray:
    """(2, 2) covariance of a camera's projections from its calibration (0 when unknown):
    common to every frame, so it is added after the frames are averaged."""
    sigma = float(getattr(camera, "projection_sigma_px", 0.0))
    return np.eye(2) * sigma**2


def _pooled_frame_covariance(results: list[PoseMeasurement], name: str) -> FloatArray | None:
    """Frame-to-frame covariance of one camera's virtual point, pooled over the poses."""
    scatter = np.zeros((2, 2))
    dof = 0
    for m in results:
        vps = m.vp_px.get(name)
        if m.status == "ok" and vps is not None and len(vps) > 1:
            dev = vps - vps.mean(axis=0)
            scatter += dev.T @ dev
            dof += len(vps) - 1
    return scatter / dof if dof >= 10 else None


def _triangulate(
    results: list[PoseMeasurement], cameras: Mapping[str, CameraModelProtocol], names: list[str]
) -> None:
    """Optimal positions in {G} and their covariances for the poses measured, each from the
    cameras that saw it.

    The cameras are used through the camera-model protocol only (any kind of camera model).
    """
    ok = [m for m in results if m.status == "ok"]
    if not ok:
        return
    pooled = {n: _pooled_frame_covariance(results, n) for n in names}
    q, cov = [], []
    for n in names:
        q_n = np.full((len(ok), 2), np.nan)
        cov_n = np.broadcast_to(np.eye(2), (len(ok), 2, 2)).copy()
        for i, m in enumerate(ok):
            if n not in m.vp_px:
                continue
            q_n[i] = m.vp_px[n].mean(axis=0)
            frame_cov = pooled[n]
            base = frame_cov if frame_cov is not None else m.vp_cov_px2[n]
            cov_n[i] = base / len(m.vp_px[n]) + _calibration_cov(cameras[n])
        q.append(q_n)
        cov.append(cov_n)
    p, c, _ = triangulate_views([cameras[n] for n in names], q, cov)
    for m, pi, ci in zip(ok, p, c, strict=True):
        m.p_um, m.cov_um2 = pi, ci


def measure_one(
    frames: Mapping[str, AnyFrames],
    cameras: Mapping[str, AnyCamera],
    target: Target | TipTarget,
    rois: dict[str, tuple[int, int, int, int] | None] | None = None,
    frame_cov_px2: dict[str, FloatArray] | None = None,
) -> PoseMeasurement:
    """Measure one pose from its frames (per camera), triangulated on the spot from every
    camera that found the board (two at least).

    ``frame_cov_px2`` gives the per-frame pixel covariance of each camera's virtual point
    when it is known (from a run's pooled scatter); otherwise the corners' residuals are used.
    """
    names = _check_cameras(cameras)
    seen = {
        name: camera_view(frames.get(name) or [], target, cameras[name], (rois or {}).get(name))
        for name in names
    }
    m = measure_seen(seen, cameras, frame_cov_px2)
    if isinstance(target, TipTarget):
        refuse_disagreeing([m], cameras)
    return m


def camera_view(
    frames: AnyFrames,
    target: Target | TipTarget,
    model: AnyCamera,
    roi: tuple[int, int, int, int] | None = None,
) -> Seen:
    """What one camera makes of one pose's frames: virtual points (k, 2), their covariance
    (2, 2) and the corners of frame 0, or why it has none (``"no image"`` without frames).

    The board is searched in ``roi`` first (the whole frame when it is not found there),
    then around frame 0's corners in the other frames.
    """
    if not frames:
        return "no image"
    return _vp_of_frames(frames, target, model, roi)


def measure_seen(
    seen: Mapping[str, Seen],
    cameras: Mapping[str, AnyCamera],
    frame_cov_px2: dict[str, FloatArray] | None = None,
) -> PoseMeasurement:
    """One pose triangulated from what each camera made of it (:func:`camera_view`), as
    :func:`measure_one` does."""
    names = _check_cameras(cameras)
    m = PoseMeasurement(0, "ok")
    lost = []
    for name in names:
        got = seen.get(name, "no image")
        if isinstance(got, str):
            lost.append(f"{name}: {got}")
            continue
        m.vp_px[name], m.vp_cov_px2[name], m.corners_px[name] = got
    _judge(m, lost)
    if m.status != "ok":
        return m
    used = [n for n in names if n in m.vp_px]
    q = [m.vp_px[n].mean(axis=0)[None, :] for n in used]
    cov = [
        (frame_cov_px2[n] if frame_cov_px2 and n in frame_cov_px2 else m.vp_cov_px2[n])
        / len(m.vp_px[n])
        + _calibration_cov(cameras[n])
        for n in used
    ]
    p, c, _ = triangulate_views([cameras[n] for n in used], q, cov)
    m.p_um, m.cov_um2 = p[0], c[0]
    return m
