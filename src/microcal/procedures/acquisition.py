"""The acquisition run (thesis 4.2): move, wait until settled, grab every camera, store, next.

Settling: the device's own "moving" flag first; then either a fixed wait (``fixed``, the
thesis waited 30 s) or a vision check (``vision``): frames of the first camera are grabbed
continuously and the board's virtual point averaged over blocks of frames; the pose is
settled when two successive blocks differ by less than the threshold (px), or at the
timeout. The last frames of the check are the pose's frames, so settling costs no extra
grabs.

Faults: a dropped frame or a camera timeout is retried (a bounded number of times); a pose
that still fails is recorded as failed and the run goes on. A manipulator error stops the
run (motion stopped, everything stored so far consistent) with :class:`RunStoppedError`.
"""

from __future__ import annotations

import contextlib
import functools
import math
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Literal, get_args

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..devices.base import Camera, Clock, Manipulator
from ..errors import DeviceError, DeviceTimeoutError, FrameError, InputError, MicrocalError
from ..journal_record import CreepFigures, JournalRecord, PoseStatus
from ..kinematics.extra_inputs import APPROACH_INPUTS, extra_input
from ..vision.lazy_frame import RegionFrame, grab_frame, pixels_of
from ..vision.roi import RoiPredictor, box_around
from ..vision.target_points import find_target
from ..vision.targets import Target
from ..vision.tip_measurement import TIP_BOX_HALF_PX
from ..vision.tip_target import TipTarget
from .settle_search import ForkedSearcher, PoseSearch

__all__ = ["AcquisitionConfig", "RunStoppedError", "acquire", "grab_retrying"]

Frame = NDArray[np.generic]
#: How a pose settles: the vision check, or a fixed wait.
Settle = Literal["vision", "fixed"]
#: Persists one pose: (pose, frames per camera, its journal record).
Store = Callable[[int, dict[str, list[Frame]], JournalRecord], None]


class RunStoppedError(MicrocalError):
    """The run stopped before its end (device error or a stop request); it can be resumed.

    ``interrupted``: the user asked for the stop (Ctrl-C, SIGTERM), not a device fault (the
    command line exits 130 then, as after any Ctrl-C, and 2 after a fault).
    """

    def __init__(self, message: str, *, interrupted: bool = False) -> None:
        super().__init__(message)
        self.interrupted = interrupted


@dataclass(frozen=True)
class AcquisitionConfig:
    """How a run settles, grabs and retries.

    Attributes
    ----------
    settle : {"vision", "fixed"}
    fixed_s : float
        The wait of the ``fixed`` mode, s (the thesis: 30).
    frames_per_pose : int
        Frames stored per camera and pose (pages of one TIFF).
    block : int
        Frames per block of the vision check.
    threshold_px : float
        Settled when two successive block means of the virtual point differ by less.
    settle_timeout_s : float
        The vision check gives up waiting after this long (the pose is still grabbed).
    move_timeout_s : float
        The device must report "stopped" within this.
    retries : int
        Grabs and queries tried this many times more after a transient fault.
    creep_learn_poses : int
        Poses whose settling is watched in full to learn the creep (vision settling).
    max_failed_in_a_row : int
        The run stops (resumable) when this many poses in a row fail: a device has most
        likely stopped answering, and going on would only record failures.
    store_roi : bool
        Store only the region around the board (``roi_margin_squares`` squares around it);
        the offset goes to the record. A camera whose board is not found keeps full frames.
    approach_um : float
        0 (default): each pose is reached straight from the one before. Above 0: each joint
        first goes this far past the pose on a random side (seeded by ``approach_seed`` and
        the pose number, so a resumed run repeats it), then to the pose: the approach
        directions vary independently of the positions, as a model of reversal error
        (direction terms) needs. Either way each pose's record holds the direction each joint
        last moved in (``approach_x`` ... , +1 / -1).
    approach_seed : int
    approach_directions : tuple of (3,) tuples
        Approach directions chosen for the poses instead of drawn (a design that chooses
        them, :mod:`~microcal.procedures.adaptive`): pose ``k`` (from 1) arrives moving in
        directions ``approach_directions[k - 1]`` (+1: each joint moving up, so starting
        below the pose); poses beyond them, or given NaN, draw theirs as above.
    search_process : bool
        Vision settling of a board: search the frames in a forked process while the next
        frames are grabbed (:mod:`~microcal.procedures.settle_search`; the same corners, so
        the same decisions). For a run in a process of its own (the demo); off by default.
    """

    settle: Settle = "vision"
    fixed_s: float = 30.0
    frames_per_pose: int = 5
    block: int = 6
    threshold_px: float = 0.05
    settle_timeout_s: float = 10.0
    move_timeout_s: float = 60.0
    retries: int = 3
    max_failed_in_a_row: int = 3
    creep_learn_poses: int = 5
    store_roi: bool = False
    roi_margin_squares: float = 3.0
    approach_um: float = 0.0
    approach_seed: int = 0
    approach_directions: tuple[tuple[float, float, float], ...] = ()
    search_process: bool = False

    def __post_init__(self) -> None:
        if not (np.isfinite(self.approach_um) and self.approach_um >= 0):
            raise InputError(f"approach_um: expected a distance >= 0 µm, got {self.approach_um!r}")
        if self.settle not in get_args(Settle):
            raise InputError(f"settle: expected 'vision' or 'fixed', got {self.settle!r}")
        if not _is_wait_s(self.fixed_s):
            raise InputError(
                f"fixed_s: expected a finite number of seconds >= 0, got {self.fixed_s!r}"
            )


def _is_wait_s(value: object) -> bool:
    """A finite real number >= 0 (not a bool, not text)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        return False
    return math.isfinite(value) and float(value) >= 0


def _moved(step_um: FloatArray, signs: FloatArray) -> FloatArray:
    """The direction each joint last moved in after ``step_um``: +1, -1, or as before when
    it did not move (steps below 1 nm count as none)."""
    return np.where(step_um > 1e-3, 1.0, np.where(step_um < -1e-3, -1.0, signs))


def approach_start_um(
    d_um: FloatArray,
    pose: int,
    config: AcquisitionConfig,
    limits_um: FloatArray,
    direction: FloatArray | None = None,
) -> FloatArray:
    """Where a pose is approached from with ``config.approach_um`` > 0, (3,) µm.

    Each joint sits ``approach_um`` past the pose on a side drawn from ``(approach_seed,
    pose)``, or opposite the ``direction`` (3,) chosen for the pose (given, or in
    ``config.approach_directions``); a side that would leave the soft limits ``limits_um``
    (3, 2) is the other one. A held joint (limits of one value) stays where it is.
    """
    chosen = config.approach_directions
    if direction is None and 0 < pose <= len(chosen):
        direction = np.asarray(chosen[pose - 1], dtype=np.float64)
    if direction is not None and np.all(np.isfinite(direction)):
        side = np.where(np.asarray(direction) < 0, 1.0, -1.0)
    else:
        rng = np.random.default_rng([config.approach_seed, pose])
        side = rng.choice([-1.0, 1.0], 3)
    start = d_um + side * config.approach_um
    outside = (start < limits_um[:, 0]) | (start > limits_um[:, 1])
    out: FloatArray = np.where(outside, d_um - side * config.approach_um, start)
    held = limits_um[:, 0] == limits_um[:, 1]
    return np.asarray(np.where(held, d_um, out), dtype=np.float64)


def _retry(what: Callable[[], Any], retries: int) -> Any:
    for attempt in range(retries + 1):
        try:
            return what()
        except (FrameError, DeviceTimeoutError):
            if attempt == retries:
                raise
    raise AssertionError("unreachable")


def grab_retrying(camera: Camera, retries: int) -> Frame:
    """One frame, grabbed again up to ``retries`` times after a dropped frame or a timeout."""
    frame: Frame = _retry(camera.grab, retries)
    return frame


def _grab_region_frame(camera: Camera, retries: int) -> RegionFrame:
    """One frame as a region frame (read where it is looked at), grabbed again after a
    dropped frame or a timeout as :func:`grab_retrying` does."""
    frame: RegionFrame = _retry(functools.partial(grab_frame, camera), retries)
    return frame


def _board_corners(
    frame: RegionFrame,
    target: Target | TipTarget,
    roi: tuple[int, int, int, int] | None,
    previous_px: FloatArray | None = None,
) -> FloatArray | None:
    """The board's corners (a tool's apex); with a region, only there (a hidden board has not
    jumped away); ``previous_px``: its corners in the frame before, followed from there."""
    found = find_target(frame, target, roi, previous_px=previous_px)
    if found is None or not found.complete:
        return None
    return found.points_px


class CreepEstimator:
    """Learns how the end-effector creeps after a move, from the first poses' images.

    After each of the first ``learn_poses`` moves the virtual point is watched for
    ``window_s``; its track is fitted with ``a + b exp(-t / tau)`` (t from the moment the
    device reports "stopped"), ``tau`` pooled over the poses and ``|b|`` proportional to the
    size of the move. Afterwards the wait for a move is the time the fitted creep needs to
    fall below ``target_um``.
    """

    def __init__(self, learn_poses: int = 5, window_s: float = 4.0, target_um: float = 0.2) -> None:
        self.learn_poses = learn_poses
        self.window_s = window_s
        self.target_um = target_um
        self._tracks: list[tuple[FloatArray, FloatArray, float]] = []  # (t, vp (k, 2), |step|)
        self._px_per_um: list[float] = []
        self.tau_s: float | None = None
        self.amplitude_px_per_um: float | None = None

    @property
    def learning(self) -> bool:
        return self.tau_s is None

    @property
    def frame_interval_s(self) -> float:
        """Time between successive frames, from the learning tracks (0 before any)."""
        gaps = [np.diff(t) for t, _, _ in self._tracks if len(t) > 1]
        return float(np.median(np.concatenate(gaps))) if gaps else 0.0

    def add_scale(self, step_um: float, moved_px: float) -> None:
        """Image motion per µm of move (from successive poses), to turn µm into px."""
        if step_um > 500:
            self._px_per_um.append(moved_px / step_um)

    def add_track(self, t_s: FloatArray, vp_px: FloatArray, step_um: float) -> None:
        if len(t_s) >= 10:
            self._tracks.append((t_s, vp_px, step_um))
        if len(self._tracks) >= self.learn_poses:
            self._fit()

    def _fit(self) -> None:
        best = (np.inf, 1.0, 0.0)
        for tau in np.geomspace(0.05, 5.0, 60):
            rss, amps = 0.0, []
            for t, vp, step in self._tracks:
                A = np.column_stack([np.ones_like(t), np.exp(-t / tau)])
                coef, *_ = np.linalg.lstsq(A, vp, rcond=None)
                rss += float(np.sum((A @ coef - vp) ** 2))
                amps.append(float(np.linalg.norm(coef[1])) / max(step, 1.0))
            if rss < best[0]:
                best = (rss, float(tau), float(np.median(amps)))
        self.tau_s, self.amplitude_px_per_um = best[1], best[2]

    def wait_s(self, step_um: float) -> float:
        """Time after "stopped" until the fitted creep of this move is below the target."""
        if self.tau_s is None or self.amplitude_px_per_um is None:
            raise DeviceError(
                f"wait_s: the creep is not learned yet ({len(self._tracks)} of "
                f"{self.learn_poses} poses watched); ask only once learning is False"
            )
        scale = float(np.median(self._px_per_um)) if self._px_per_um else 0.05
        start_px = self.amplitude_px_per_um * step_um
        target_px = self.target_um * scale
        if start_px <= target_px:
            return 0.0
        return float(self.tau_s * np.log(start_px / target_px))


class _FrameSearch:
    """The board's corners in a pose's frames, one after the other: each frame is searched
    in the region around the corners found last, from those corners (the board barely moves
    while it settles). ``state`` is where the chain stands: the region and the corners."""

    def __init__(
        self,
        target: Target | TipTarget,
        state: tuple[tuple[int, int, int, int] | None, FloatArray | None] = (None, None),
    ) -> None:
        self.target = target
        self.roi, self.previous_px = state
        # a tool's box holds enough of its shank
        self.margin_px = 30.0 if isinstance(target, Target) else float(TIP_BOX_HALF_PX)

    @property
    def state(self) -> tuple[tuple[int, int, int, int] | None, FloatArray | None]:
        return self.roi, self.previous_px

    def corners(self, frame: RegionFrame) -> FloatArray | None:
        found = _board_corners(frame, self.target, self.roi, self.previous_px)
        if found is not None:
            self.roi = box_around(found, self.margin_px)
            self.previous_px = found
        return found


def _settle_vision(
    cameras: Mapping[str, Camera],
    target: Target | TipTarget,
    clock: Clock,
    config: AcquisitionConfig,
    roi: tuple[int, int, int, int] | None,
    creep: CreepEstimator,
    step_um: float,
    searcher: ForkedSearcher | None = None,
) -> tuple[float, float, dict[str, list[RegionFrame]], FloatArray | None]:
    """Wait until the board has settled; returns (time, last block change px, frames, the
    corners found last in the first camera's frames).

    ``searcher``: the searches run in that forked process where the pose's region is
    predicted (the same corners, :mod:`~microcal.procedures.settle_search`)."""
    first = next(iter(cameras))
    start = clock.now_s()
    if not creep.learning:
        # wait out the learned creep, less the time the block check itself will take
        check_s = 2 * config.block * creep.frame_interval_s
        clock.sleep(max(0.0, creep.wait_s(step_um) - check_s))
    times: list[float] = []
    vps: list[FloatArray] = []
    last: list[FloatArray] = []
    frames: list[RegionFrame] = []
    change = float("nan")
    b = config.block
    # Each frame is searched on a second thread while the next is grabbed (rendered): the
    # grabs do not depend on what is found until the block check may end the wait, and the
    # frames are searched in order, each in the region the one before found the board in.
    # What the loop decides, and when, is what searching each frame at once decides.
    search = _FrameSearch(target, (roi, None))
    pending: list[tuple[Callable[[], FloatArray | None], float]] = []
    remote: PoseSearch | None = None

    def collect() -> None:
        for found, t_s in pending:
            corners = found()
            if corners is not None:
                vps.append(corners.mean(axis=0))
                times.append(t_s)
                last[:] = [corners]
        pending.clear()

    with ThreadPoolExecutor(max_workers=1) as threaded:
        while True:
            frame = _grab_region_frame(cameras[first], config.retries)
            frames.append(frame)
            elapsed = clock.now_s() - start
            if remote is None and roi is not None and searcher is not None and searcher.forked:
                remote = searcher.pose(roi, frame.shape)
            if remote is not None:
                pending.append((functools.partial(remote.corners, remote.submit(frame)), elapsed))
            else:
                pending.append((threaded.submit(search.corners, frame).result, elapsed))
            if creep.learning:
                if elapsed >= creep.window_s:
                    collect()
                    creep.add_track(np.array(times), np.array(vps).reshape(-1, 2), step_um)
                    break
            elif len(vps) + len(pending) >= 2 * b:  # the block check may decide now
                collect()
                if len(vps) >= 2 * b:
                    change = float(
                        np.linalg.norm(
                            np.mean(vps[-b:], axis=0) - np.mean(vps[-2 * b : -b], axis=0)
                        )
                    )
                    if change < config.threshold_px:
                        break
            if elapsed > config.settle_timeout_s:
                collect()
                break
    n = config.frames_per_pose
    got = {first: frames[-n:]}
    for name, cam in cameras.items():
        if name != first:
            got[name] = [_grab_region_frame(cam, config.retries) for _ in range(n)]
    if len(got[first]) < n:
        got[first] += [
            _grab_region_frame(cameras[first], config.retries) for _ in range(n - len(got[first]))
        ]
    return clock.now_s() - start, change, got, (last[0] if last else None)


def acquire(
    manipulator: Manipulator,
    cameras: Mapping[str, Camera],
    clock: Clock,
    commands_um: FloatArray,
    poses: Sequence[int],
    target: Target | TipTarget,
    store: Store,
    *,
    config: AcquisitionConfig | None = None,
    sensors: Mapping[str, Callable[[], float]] | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    progress: Callable[[int, int, JournalRecord], None] | None = None,
    between: Callable[[int], tuple[FloatArray, FloatArray] | None] | None = None,
) -> int:
    """Visit the poses, settle, grab and store each; returns the number of poses stored.

    Parameters
    ----------
    commands_um : (N, 3) float
        Joint commands of every pose of the run, indexed by pose - 1.
    poses : sequence of int
        The poses still to do (1-based), in order.
    store : callable (pose, frames per camera, record)
        Persists one pose; the record (a :class:`~microcal.journal_record.JournalRecord`) is
        its journal line.
    sensors : mapping of name -> callable () -> float, optional
        The rig's sensors of extra inputs (:mod:`microcal.kinematics.extra_inputs`, e.g.
        ``{"temperature": read}``); each pose's journal line records each under its column.
    between : callable (poses stored) -> ((3,) float, (3,) float) or None, optional
        Called after each stored pose, e.g. a periodic check of an earlier calibration; when
        it moved the manipulator it returns its last move's start and end joints (so that
        each joint's approach direction stays known), None when it did not. A device error
        in it stops the run as one in a move does.

    Raises
    ------
    RunStoppedError
        On a manipulator error or when ``should_stop`` says so; the poses before are stored.
    """
    cfg = config or AcquisitionConfig()
    predictors = {n: RoiPredictor() for n in cameras}
    first = next(iter(cameras))
    creep = CreepEstimator(learn_poses=cfg.creep_learn_poses)
    last: tuple[FloatArray, FloatArray] | None = None  # (joints, virtual point px) of the last pose
    previous_d = np.asarray(manipulator.position_um(), dtype=np.float64)
    signs = np.full(3, np.nan)  # unknown until each joint has moved
    done = 0
    failed_in_a_row = 0
    searcher = None  # ended when the run returns (or, on an error, when it is collected)
    if cfg.search_process and cfg.settle == "vision" and isinstance(target, Target):
        searcher = ForkedSearcher(functools.partial(_FrameSearch, target))
    for k, pose in enumerate(poses):
        if should_stop():
            manipulator.stop()
            raise RunStoppedError(f"stopped on request before pose {pose}")
        d = np.asarray(commands_um[pose - 1], dtype=np.float64)
        t0 = clock.now_s()
        wall0 = time.time()
        try:
            if cfg.approach_um > 0:
                start = approach_start_um(d, pose, cfg, manipulator.limits_um)
                _retry(functools.partial(manipulator.move_to_um, start), cfg.retries)
                manipulator.wait_until_stopped(clock, timeout_s=cfg.move_timeout_s)
                signs = _moved(start - previous_d, signs)
                previous_d = start
            _retry(functools.partial(manipulator.move_to_um, d), cfg.retries)
            manipulator.wait_until_stopped(clock, timeout_s=cfg.move_timeout_s)
        except DeviceError as exc:
            with contextlib.suppress(DeviceError):
                manipulator.stop()
            raise RunStoppedError(f"pose {pose}: {exc}") from None
        moved_s = clock.now_s() - t0
        signs = _moved(d - previous_d, signs)
        approach = {extra_input(name).column: float(sign) if np.isfinite(sign) else None
                    for name, sign in zip(APPROACH_INPUTS, signs, strict=True)}  # fmt: skip
        status: PoseStatus = "ok"
        reported_um: list[float] | None = None
        reason: str | None = None
        settled_px: FloatArray | None = None  # the first camera's corners, settling
        try:
            if cfg.settle == "fixed":
                clock.sleep(cfg.fixed_s)
                settle_s, change = cfg.fixed_s, float("nan")
                frames = {
                    n: [_grab_region_frame(cam, cfg.retries) for _ in range(cfg.frames_per_pose)]
                    for n, cam in cameras.items()
                }
            else:
                step = float(np.abs(d - previous_d).max())
                settle_s, change, frames, settled_px = _settle_vision(
                    cameras, target, clock, cfg, predictors[first].predict(d), creep, step,
                    searcher,
                )  # fmt: skip
            reported_um = np.asarray(_retry(manipulator.position_um, cfg.retries)).tolist()
        except DeviceError as exc:
            frames = {}
            settle_s, change = clock.now_s() - t0 - moved_s, float("nan")
            status, reason = "failed", str(exc)
        rois: dict[str, tuple[int, int, int, int]] = {}
        stored: dict[str, list[Frame]] = {}
        for name, cam_frames in frames.items():
            seen = find_target(cam_frames[-1], target, predictors[name].predict(d),
                               margin_squares=cfg.roi_margin_squares,
                               previous_px=settled_px if name == first else None)  # fmt: skip
            if seen is None:
                stored[name] = [pixels_of(f) for f in cam_frames]
                continue
            predictors[name].add(d, seen.points_px)  # where the board is, for the next pose
            if name == first:
                vp = seen.points_px.mean(axis=0)
                if last is not None:
                    creep.add_scale(
                        float(np.linalg.norm(d - last[0])), float(np.linalg.norm(vp - last[1]))
                    )
                last = (d, vp)
            if cfg.store_roi:
                h, w = cam_frames[0].shape[:2]
                x0, y0, x1, y1 = seen.region_px
                stored[name] = [f.region(x0, y0, x1, y1) for f in cam_frames]
                rois[name] = (x0, y0, w, h)
            else:
                stored[name] = [pixels_of(f) for f in cam_frames]
        # the model's extra inputs, by registry
        readings = {
            extra_input(name).column: float(read()) for name, read in (sensors or {}).items()
        }
        creep_model = None
        if creep.tau_s is not None:
            creep_model = CreepFigures(round(creep.tau_s, 4), creep.amplitude_px_per_um)
        record = JournalRecord(
            pose=pose,
            commanded_um=d.tolist(),
            approach=approach,
            status=status,
            wall_time_s=wall0,
            sim_time_s=round(t0, 6),
            move_s=round(moved_s, 6),
            settle_s=round(settle_s, 6),
            residual_px=None if not np.isfinite(change) else round(change, 6),
            reported_um=reported_um,
            reason=reason,
            roi_px=rois,
            readings=readings,
            creep_model=creep_model,
        )
        store(pose, stored, record)
        previous_d = d
        done += 1
        try:
            last_leg = None if between is None else between(done)
        except DeviceError as exc:
            with contextlib.suppress(DeviceError):
                manipulator.stop()
            raise RunStoppedError(f"after pose {pose}: {exc}") from None
        if last_leg is not None:
            signs = _moved(last_leg[1] - last_leg[0], _moved(last_leg[1] - previous_d, signs))
            previous_d = np.asarray(last_leg[1], dtype=np.float64)
        failed_in_a_row = failed_in_a_row + 1 if record.failed else 0
        if progress:
            progress(k + 1, len(poses), record)
        if failed_in_a_row >= cfg.max_failed_in_a_row:
            with contextlib.suppress(DeviceError):
                manipulator.stop()
            raise RunStoppedError(
                f"{failed_in_a_row} poses in a row failed, the last ({pose}): "
                f"{record.reason or ''}; check the devices"
            )
    if searcher is not None:
        searcher.close()
    return done
