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
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..devices.base import Camera, Clock, Manipulator
from ..errors import DeviceError, DeviceTimeoutError, FrameError, MicrocalError
from ..vision.detect import detect
from ..vision.targets import Target
from .measurement import RoiPredictor

__all__ = ["AcquisitionConfig", "RunStoppedError", "acquire"]

Frame = NDArray[np.generic]
Store = Callable[[int, dict[str, list[Frame]], dict[str, Any]], None]


class RunStoppedError(MicrocalError):
    """The run stopped before its end (device error or a stop request); it can be resumed."""


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
    """

    settle: str = "vision"
    fixed_s: float = 30.0
    frames_per_pose: int = 5
    block: int = 6
    threshold_px: float = 0.05
    settle_timeout_s: float = 10.0
    move_timeout_s: float = 60.0
    retries: int = 3


def _retry(what: Callable[[], Any], retries: int) -> Any:
    for attempt in range(retries + 1):
        try:
            return what()
        except (FrameError, DeviceTimeoutError):
            if attempt == retries:
                raise
    raise AssertionError("unreachable")


def _grab(camera: Camera, retries: int) -> Frame:
    frame: Frame = _retry(camera.grab, retries)
    return frame


def _board_vp(
    frame: Frame, target: Target, roi: tuple[int, int, int, int] | None
) -> FloatArray | None:
    det = detect(frame, target, roi=roi) if roi else None
    if det is None or not det.found:
        det = detect(frame, target)
    if not det.found or len(det.ids) != target.pattern_size[0] * target.pattern_size[1]:
        return None
    out: FloatArray = det.q_px.mean(axis=0)
    return out


def _settle_vision(
    cameras: dict[str, Camera],
    target: Target,
    clock: Clock,
    config: AcquisitionConfig,
    roi: tuple[int, int, int, int] | None,
) -> tuple[float, float, dict[str, list[Frame]]]:
    """Grab until the virtual point stops moving; returns (time, last block change px, frames)."""
    first = next(iter(cameras))
    start = clock.now_s()
    vps: list[FloatArray] = []
    frames: list[Frame] = []
    change = float("nan")
    while True:
        frame = _grab(cameras[first], config.retries)
        frames.append(frame)
        vp = _board_vp(frame, target, roi)
        if vp is not None:
            vps.append(vp)
        b = config.block
        if len(vps) >= 2 * b:
            change = float(
                np.linalg.norm(np.mean(vps[-b:], axis=0) - np.mean(vps[-2 * b : -b], axis=0))
            )
            if change < config.threshold_px:
                break
        if clock.now_s() - start > config.settle_timeout_s:
            break
    n = config.frames_per_pose
    got = {first: frames[-n:]}
    for name, cam in cameras.items():
        if name != first:
            got[name] = [_grab(cam, config.retries) for _ in range(n)]
    if len(got[first]) < n:
        got[first] += [_grab(cameras[first], config.retries) for _ in range(n - len(got[first]))]
    return clock.now_s() - start, change, got


def acquire(
    manipulator: Manipulator,
    cameras: dict[str, Camera],
    clock: Clock,
    commands_um: FloatArray,
    poses: Sequence[int],
    target: Target,
    store: Store,
    *,
    config: AcquisitionConfig | None = None,
    temperature: Callable[[], float] | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    progress: Callable[[int, int, dict[str, Any]], None] | None = None,
) -> int:
    """Visit the poses, settle, grab and store each; returns the number of poses stored.

    Parameters
    ----------
    commands_um : (N, 3) float
        Joint commands of every pose of the run, indexed by pose - 1.
    poses : sequence of int
        The poses still to do (1-based), in order.
    store : callable (pose, frames per camera, record)
        Persists one pose; the record is the journal line.

    Raises
    ------
    RunStoppedError
        On a manipulator error or when ``should_stop`` says so; the poses before are stored.
    """
    cfg = config or AcquisitionConfig()
    predictors = {n: RoiPredictor() for n in cameras}
    first = next(iter(cameras))
    done = 0
    for k, pose in enumerate(poses):
        if should_stop():
            manipulator.stop()
            raise RunStoppedError(f"stopped on request before pose {pose}")
        d = np.asarray(commands_um[pose - 1], dtype=np.float64)
        t0 = clock.now_s()
        wall0 = time.time()
        try:
            _retry(functools.partial(manipulator.move_to_um, d), cfg.retries)
            manipulator.wait_until_stopped(clock, timeout_s=cfg.move_timeout_s)
        except DeviceError as exc:
            with contextlib.suppress(DeviceError):
                manipulator.stop()
            raise RunStoppedError(f"pose {pose}: {exc}") from None
        moved_s = clock.now_s() - t0
        record: dict[str, Any] = {"pose": pose, "commanded_um": d.tolist()}
        try:
            if cfg.settle == "fixed":
                clock.sleep(cfg.fixed_s)
                settle_s, change = cfg.fixed_s, float("nan")
                frames = {
                    n: [_grab(cam, cfg.retries) for _ in range(cfg.frames_per_pose)]
                    for n, cam in cameras.items()
                }
            else:
                settle_s, change, frames = _settle_vision(
                    cameras, target, clock, cfg, predictors[first].predict(d)
                )
            reported = _retry(manipulator.position_um, cfg.retries)
            record |= {"status": "ok", "reported_um": np.asarray(reported).tolist()}
        except DeviceError as exc:
            frames = {}
            settle_s, change = clock.now_s() - t0 - moved_s, float("nan")
            record |= {"status": "failed", "reason": str(exc)}
        if (record["status"] == "ok" and np.isfinite(change)) or cfg.settle == "fixed":
            vp = (
                _board_vp(frames[first][-1], target, predictors[first].predict(d))
                if frames
                else None
            )
            if vp is not None:
                # teach the region predictor where the board is (its size from a detection)
                det = detect(frames[first][-1], target)
                if det.found:
                    predictors[first].add(d, det.q_px)
        record |= {
            "time": wall0,
            "sim_time_s": round(t0, 6),
            "move_s": round(moved_s, 6),
            "settle_s": round(settle_s, 6),
            "residual_px": None if not np.isfinite(change) else round(change, 6),
        }
        if temperature is not None:
            record["temperature_c"] = float(temperature())
        store(pose, frames, record)
        done += 1
        if progress:
            progress(k + 1, len(poses), record)
    return done
