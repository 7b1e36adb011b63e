"""The ``patch`` rig seen as a user sees it: its slide, its nominal axes, and its truth in {M}.

- :func:`slide_scope`: a marked dot slide on the rig's X-Y stage under its camera, for the
  camera's calibration against the stage (:func:`~microcal.procedures.scope_calibration.
  calibrate_scope`): the slide's frames are rendered by
  :class:`~microcal.sim.stage_slide.StageSlideScope` with the ``patch`` camera's truth
  (pixel size, the image's orientation to the stage, the focus axis's tilt, the NA) on a
  central region of the sensor (``roi_px``), while the rig's own stage and focus drive move
  and its clock counts the moves and every exposure.
- :func:`nominal_axes` and :func:`image_axis`: what the rig's user knows of the manipulator
  (its approach angle and direction) as the acquisition takes it.
- :func:`true_frame` and :func:`truth_in_frame`: the microscope's frame {M} with the rig's
  true parameters, and where the tip truly is in it (ground truth for figures).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..devices.microscope_drive import MicroscopeDrive
from ..vision.microscope_frame import MicroscopeFrame
from ..vision.targets import Target
from .patch import PatchConfig, PatchRig
from .stage_slide import ScopeTruth, StageSlideScope

__all__ = [
    "SlideOnStage",
    "end_offset_px",
    "image_axis",
    "nominal_axes",
    "scope_truth",
    "slide_scope",
    "true_frame",
    "truth_in_frame",
]


def scope_truth(config: PatchConfig) -> ScopeTruth:
    """The ``patch`` camera as the slide simulator's truth: no rotation, skew or distortion
    (the camera is square to the stage), the focus drive's tilt."""
    return ScopeTruth(
        um_per_px=config.um_per_px, focus_tilt_deg=config.focus.tilt_deg,
        focus_azimuth_deg=config.focus.tilt_azimuth_deg,
        numerical_aperture=config.numerical_aperture,
    )  # fmt: skip


@dataclass
class SlideOnStage:
    """The slide's callables on the rig: ``move_stage``, ``move_focus``, ``grab``, and its
    ``target``; the stage and focus moved through ``drive`` (the rig's devices) where given,
    else through the rig's own drives."""

    rig: PatchRig
    scope: StageSlideScope
    drive: MicroscopeDrive | None = None

    @property
    def target(self) -> Target:
        """The slide."""
        return self.scope.target

    def move_stage(self, xy_um: FloatArray) -> None:
        """Move the rig's stage (time on its clock) and the slide with it."""
        if self.drive is not None:
            self.drive.move_stage(xy_um)
        else:
            self.rig.stage.move_to_um([float(xy_um[0]), float(xy_um[1]), 0.0])
            self.rig.stage.wait_until_stopped(self.rig.clock)
        self.scope.move_stage(np.asarray(xy_um, dtype=np.float64))

    def move_focus(self, z_um: float) -> None:
        """Move the rig's focus (from below) and the slide's view with it."""
        if self.drive is not None:
            self.drive.move_focus(z_um)
        else:
            self.rig.move_focus(z_um)
        self.scope.move_focus(z_um)

    def grab(self) -> NDArray[np.float32]:
        """One frame of the slide (the exposure and readout on the rig's clock)."""
        cfg = self.rig.config
        self.rig.clock.sleep(cfg.exposure_s + cfg.readout_s)
        return self.scope.grab()


def slide_scope(
    rig: PatchRig, roi_px: int = 512, seed: int = 0, drive: MicroscopeDrive | None = None
) -> SlideOnStage:
    """A slide on ``rig``'s stage seen through a ``roi_px`` square region of its camera; the
    stage and focus moved through ``drive`` (made from the rig's devices) where given."""
    scope = StageSlideScope(scope_truth(rig.config), image_size_px=(roi_px, roi_px), seed=seed)
    return SlideOnStage(rig, scope, drive)


def nominal_axes(config: PatchConfig) -> FloatArray:
    """The tip's move in {M} per µm of each joint as the rig is built (x along the approach
    axis into the sample, y across it, z vertical), without its small errors, (3, 3)."""
    forward = -config.tool_axis
    across = np.cross([0.0, 0.0, 1.0], forward)
    across /= np.linalg.norm(across)
    out: FloatArray = np.column_stack([forward, across, [0.0, 0.0, 1.0]])
    return out


def image_axis(config: PatchConfig) -> FloatArray:
    """The tool's direction in the image, tip to shank, (2,) (the camera looks down, its
    image y against the stage's y)."""
    t = config.tool_axis
    d = np.array([t[0], -t[1]])
    out: FloatArray = d / np.linalg.norm(d)
    return out


def end_offset_px(config: PatchConfig) -> float:
    """The tip point's distance behind where the tool's image begins, px."""
    rise = math.sin(math.radians(config.approach_deg))
    return config.tool.end_radius_um * rise / config.um_per_px


def true_frame(config: PatchConfig) -> MicroscopeFrame:
    """{M} with the rig's true parameters (what a perfect scope calibration gives)."""
    truth = scope_truth(config)
    w, h = config.size_px
    return MicroscopeFrame(truth.pixels_per_stage(), truth.drift_px_per_um(),
                           np.array([(w - 1) / 2, (h - 1) / 2]))  # fmt: skip


def truth_in_frame(rig: PatchRig, frame: MicroscopeFrame) -> Callable[[], FloatArray]:
    """Where the tip truly is in ``frame`` now, (3,) µm: its image with the focus where it
    is in focus by the drive's true scale and tilt (no backlash, no scatter), through
    ``frame``'s map. The rig is not touched."""
    e = rig.config.focus

    def now() -> FloatArray:
        tip = rig.manipulator.true_position_um()
        reading = float(tip[2] / ((1.0 + e.scale) * e.axis[2]))
        centre = reading * (1.0 + e.scale) * e.axis
        cam = rig.camera()
        q = (tip[:2] - centre[:2]) @ cam.R[:2, :2].T / rig.config.um_per_px
        q = q + (np.asarray(rig.config.size_px, float) - 1.0) / 2.0
        return frame.to_um(q, reading)

    return now
