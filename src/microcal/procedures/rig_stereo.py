"""Camera calibration on a rig: move the calibration target by known steps, grab, calibrate.

Method (a) of the stereo calibration (thesis 5.1) needs views of a target at known
displacements. On a rig with a target stage (``Rig.target_stage``) this procedure makes them:
every step is checked against the stage's soft limits before anything moves; the stage goes to
its starting position plus each step, the device reports "stopped", the image is let settle
(the target's detected centre in the first camera, compared block by block, as acquisition
does with the board; or a fixed wait), every camera grabs ``frames_per_view`` frames, and the
frames are handed to ``store`` (so that they can be kept as files and the calibration repeated
from them). The stage returns to where it started, and the views are calibrated exactly as
the image-file command does (:func:`~microcal.procedures.stereo.calibrate_views`).

The step at zero displacement defines {G}: the target's frame there.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import get_args

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray, as_array
from ..devices.base import Camera, Clock, Manipulator
from ..errors import InputError, MicrocalError
from ..vision.detect import detect
from ..vision.stereo_calibration import StereoCalibration
from ..vision.targets import Target
from .acquisition import Settle, grab_retrying
from .stereo import calibrate_views

__all__ = [
    "CALIBRATION_STEPS_UM",
    "RigViewsConfig",
    "calibrate_on_rig",
    "default_steps_um",
    "view_name",
]

#: The known displacements of the calibration target along z, µm (thesis section 3.3.2).
CALIBRATION_STEPS_UM = (0.0, 1000.0, 2000.0, 3000.0, 4000.0)

Frame = NDArray[np.generic]
#: ``store(view, camera, frames)``: keep the frames of one view of one camera.
ViewStore = Callable[[int, str, list[Frame]], None]


def default_steps_um() -> FloatArray:
    """The demo's steps: the target lifted 0, 1, 2, 3 and 4 mm along z, (5, 3) µm."""
    return np.array([[0.0, 0.0, z] for z in CALIBRATION_STEPS_UM])


@dataclass(frozen=True)
class RigViewsConfig:
    """How the views are made.

    Attributes
    ----------
    frames_per_view : int
        Frames grabbed per camera and view (averaged before detection).
    settle : {"vision", "fixed"}
        Vision: grab blocks of ``block`` frames from the first camera until the target's
        detected centre moves less than ``threshold_px`` from one block to the next (or
        ``settle_timeout_s`` passed). Fixed: wait ``fixed_s``.
    block, threshold_px, settle_timeout_s, fixed_s :
        As above (frames, px, s, s).
    move_timeout_s : float
        The stage must report "stopped" within this.
    retries : int
        Grabs tried this many times more after a dropped frame or a timeout.
    camera_model : str
        ``"pinhole"``, ``"affine"`` or ``"auto"`` (chosen by held-out error).
    """

    frames_per_view: int = 8
    settle: Settle = "vision"
    block: int = 3
    threshold_px: float = 0.05
    settle_timeout_s: float = 10.0
    fixed_s: float = 2.0
    move_timeout_s: float = 60.0
    retries: int = 3
    camera_model: str = "auto"

    def __post_init__(self) -> None:
        if self.settle not in get_args(Settle):
            raise InputError(f"settle: expected 'vision' or 'fixed', got {self.settle!r}")
        if not 1 <= self.frames_per_view <= 100:
            raise InputError(
                f"frames_per_view: expected 1 to 100 frames, got {self.frames_per_view}"
            )


def _centre_px(frame: Frame, target: Target) -> FloatArray | None:
    det = detect(frame, target)
    return det.q_px.mean(axis=0) if det.found else None


def _settle(camera: Camera, target: Target, clock: Clock, cfg: RigViewsConfig) -> None:
    """Wait until the target's image is still (see :class:`RigViewsConfig`)."""
    if cfg.settle == "fixed":
        clock.sleep(cfg.fixed_s)
        return
    start = clock.now_s()
    centres: list[FloatArray] = []
    while clock.now_s() - start <= cfg.settle_timeout_s:
        c = _centre_px(grab_retrying(camera, cfg.retries), target)
        if c is not None:
            centres.append(c)
        b = cfg.block
        if len(centres) >= 2 * b:
            change = np.linalg.norm(np.mean(centres[-b:], 0) - np.mean(centres[-2 * b : -b], 0))
            if change < cfg.threshold_px:
                return


def calibrate_on_rig(
    stage: Manipulator,
    cameras: Mapping[str, Camera],
    clock: Clock,
    target: Target,
    steps_um: FloatArray,
    *,
    config: RigViewsConfig | None = None,
    store: ViewStore | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> StereoCalibration:
    """Move ``stage`` by each known step, grab every camera, calibrate (method (a)).

    Parameters
    ----------
    stage : Manipulator
        Carries ``target``; its x, y, z joints move the target along {G}'s axes.
    cameras : dict of str to Camera
    clock : Clock
    target : Target
    steps_um : (V, 3) float
        Known displacements from the stage's starting position, µm; V >= 2 and not all in
        one plane for a pinhole camera (see
        :func:`~microcal.vision.stereo_calibration.calibrate_known_displacements`).
    config : RigViewsConfig, optional
    store : callable (view, camera, frames), optional
        Called with the frames of each view and camera as they are grabbed.
    progress : callable (done, total), optional

    Raises
    ------
    LimitError
        A step outside the stage's soft limits (nothing has moved).
    InputError, DeviceError
        As the stage, the cameras and the calibration raise them.
    """
    cfg = config or RigViewsConfig()
    steps = as_array(steps_um, "steps_um", (None, 3))
    if stage.n_axes != 3:
        raise InputError(f"target stage: expected x, y and z joints, got {stage.axes}")
    origin = stage.position_um()
    for step in steps:  # every view checked before the first move
        stage.check_limits(origin + step)
    frames: dict[str, list[list[Frame]]] = {name: [] for name in cameras}
    first = next(iter(cameras))
    try:
        for view, step in enumerate(steps):
            stage.move_to_um(origin + step)
            stage.wait_until_stopped(clock, timeout_s=cfg.move_timeout_s)
            _settle(cameras[first], target, clock, cfg)
            for name, cam in cameras.items():
                got = [grab_retrying(cam, cfg.retries) for _ in range(cfg.frames_per_view)]
                frames[name].append(got)
                if store is not None:
                    store(view, name, got)
            if progress is not None:
                progress(view + 1, len(steps))
    except BaseException:
        with contextlib.suppress(MicrocalError):  # the error that stopped the views is the news
            _return(stage, origin, clock, cfg)
        raise
    _return(stage, origin, clock, cfg)
    names = {name: [view_name(name, v) for v in range(len(steps))] for name in cameras}
    return calibrate_views(
        names,
        lambda cam, i: frames[cam][i],
        target,
        displacements_um=steps,
        camera_model=cfg.camera_model,
    )


def _return(stage: Manipulator, origin: FloatArray, clock: Clock, cfg: RigViewsConfig) -> None:
    stage.move_to_um(origin)
    stage.wait_until_stopped(clock, timeout_s=cfg.move_timeout_s)


def view_name(camera: str, view: int) -> str:
    """The file name of a view's frames: ``top_01.tiff`` for view 0 of ``top``."""
    return f"{camera}_{view + 1:02d}.tiff"
