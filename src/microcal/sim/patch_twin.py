"""The ``patch`` preset served by the digital twin: one camera, a focus drive, an X-Y stage.

``Twin(preset="patch")`` (``microcal twin --preset patch``) holds a
:class:`~microcal.sim.patch.PatchRig` on its scaled clock and serves

- its camera ``scope`` (2048 x 2048, 12 bits in uint16) through the frame server: GRAB
  renders the whole frame (seconds), SNAP exposes one that is rendered only where REGION
  requests read it (:mod:`microcal.devices.twin_protocol`);
- its focus drive ``Focus`` and X-Y stage ``XYStage`` through the frame server's stage
  requests (MOVE, POS, BUSY, STOP), read on the other side by the pure-Python Micro-Manager
  stages of :mod:`microcal.devices.twin_stages`;
- its pipette's manipulator through the MCS2 peer, channels 0-2
  (:mod:`microcal.sim.mcs2_peer`).

The devices behave as the in-process rig's (``sim/patch_devices``): a focus move approaches
from below (the drive's backlash compensation) and is answered once settled; the stage moves
at its speed (BUSY meanwhile); a command to where a device already is moves nothing. A
position outside a device's travel is refused before anything moves.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..devices.smaract_mcs2 import MCS2_PORT
from ..devices.twin_protocol import FRAMES_PORT, StageInfo
from ..errors import InputError, LimitError
from ..vision.lazy_frame import ArrayFrame
from .frame_server import FramePeer, ServedStage
from .patch import PATCH_PRESET, PatchFrame, PatchRig
from .patch_scope import scope_truth
from .stage_slide import StageSlideScope
from .twin_rig import TwinRig, TwinRigCamera, TwinRigDevice, TwinRigMicroscope

__all__ = [
    "CAMERA",
    "FOCUS",
    "SAMPLES",
    "XY_STAGE",
    "PatchFramePeer",
    "PatchTwinCamera",
    "ServedFocus",
    "ServedXYStage",
    "patch_twin_rig",
    "tool_spec",
]

#: The names the twin serves the ``patch`` rig's devices by (Micro-Manager labels).
CAMERA, FOCUS, XY_STAGE = "scope", "Focus", "XYStage"
#: What can lie on the stage: the tissue the pipette works in, or the calibration slide.
SAMPLES = ("tissue", "slide")


def check_sample(sample: str) -> str:
    """``sample`` if it is one of :data:`SAMPLES` (InputError naming them otherwise)."""
    if sample not in SAMPLES:
        raise InputError(f"sample {sample!r}: the patch twin's stage holds {' or '.join(SAMPLES)}")
    return sample


class PatchTwinCamera:
    """The ``patch`` rig's camera as the frame server serves it (:class:`ServedCamera`).

    ``sample`` is what lies on the stage: ``"tissue"`` (the rig's own scene: tissue and the
    pipette) or ``"slide"``: the marked dot slide of :func:`~microcal.sim.patch_scope.
    slide_scope` over the whole sensor, under the camera's truth (pixel size, the focus
    axis's tilt, the NA), moved by the rig's X-Y stage (where it truly is) and focus drive
    (its reading), its reflectance in counts of the camera's bit depth (seconds a frame).
    """

    def __init__(self, rig: PatchRig, sample: str = "tissue") -> None:
        self.rig = rig
        self.sample = check_sample(sample)
        self._slide: StageSlideScope | None = None
        cfg = rig.config
        self.sensor_size_px = (int(cfg.size_px[0]), int(cfg.size_px[1]))
        self.bit_depth = int(cfg.bit_depth)
        self.pixel_size_um = float(cfg.sensor_pixel_um)
        self.dtype: Any = np.uint16
        #: Its frames are read by region (INFO says so): a whole one takes minutes to render.
        self.regions = True

    @property
    def exposure_s(self) -> float:
        """The exposure, s (the rig's)."""
        return float(self.rig.config.exposure_s)

    @exposure_s.setter
    def exposure_s(self, value: float) -> None:
        self.rig.config = dataclasses.replace(self.rig.config, exposure_s=float(value))

    @property
    def slide(self) -> StageSlideScope:
        """The calibration slide (made when first asked for)."""
        if self._slide is None:
            cfg = self.rig.config
            self._slide = StageSlideScope(scope_truth(cfg), image_size_px=cfg.size_px,
                                          seed=self.rig.seed)  # fmt: skip
        return self._slide

    def grab(self) -> NDArray[np.uint16]:
        """One whole frame (a few seconds to render)."""
        if self.sample == "slide":
            return self._grab_slide()
        return self.rig.grab().full()

    def grab_lazy(self) -> PatchFrame | ArrayFrame:
        """One frame, rendered where it is read (the slide's: whole)."""
        if self.sample == "slide":
            return ArrayFrame(self._grab_slide())
        return self.rig.grab()

    def _grab_slide(self) -> NDArray[np.uint16]:
        rig, slide = self.rig, self.slide
        slide.move_stage(rig.stage.joints_um(rig.clock.now_s())[:2])
        slide.move_focus(rig.focus.position_um())
        rig.clock.sleep(rig.config.exposure_s + rig.config.readout_s)
        top = 2**self.bit_depth - 1
        counts = np.clip(np.rint(slide.grab() * np.float32(top)), 0, top)
        out: NDArray[np.uint16] = counts.astype(np.uint16)
        return out


class ServedXYStage:
    """The rig's X-Y stage (its z held): x, y µm; a move to the last command moves nothing."""

    def __init__(self, rig: PatchRig) -> None:
        self.rig = rig
        limits = rig.stage.limits_um[:2]
        self.info = StageInfo(XY_STAGE, "xy", tuple((float(lo), float(hi)) for lo, hi in limits))
        self._command = tuple(float(v) for v in rig.stage.joints_um(rig.clock.now_s())[:2])

    def move(self, values_um: tuple[float, ...]) -> None:
        """Move to (x, y) µm (LimitError outside the travel, nothing moved)."""
        if values_um == self._command:
            return
        self.rig.stage.move_to_um([values_um[0], values_um[1], 0.0])
        self._command = values_um

    def position(self) -> tuple[float, ...]:
        """The readout (sensor noise included), (x, y) µm."""
        x, y = self.rig.stage.position_um()[:2]
        return float(x), float(y)

    def busy(self) -> bool:
        return bool(self.rig.stage.is_moving())

    def stop(self) -> None:
        self.rig.stage.stop()
        self._command = tuple(
            float(v) for v in self.rig.stage.joints_um(self.rig.clock.now_s())[:2]
        )


class ServedFocus:
    """The rig's focus drive: z µm, approached from below; answered once it has settled."""

    def __init__(self, rig: PatchRig) -> None:
        self.rig = rig
        self.info = StageInfo(FOCUS, "focus", (rig.focus.limits_um,))

    def move(self, values_um: tuple[float, ...]) -> None:
        """Move to z µm (LimitError outside the drive's range, nothing moved)."""
        z = float(values_um[0])
        lo, hi = self.rig.focus.limits_um
        if not (math.isfinite(z) and lo <= z <= hi):
            raise LimitError(
                f"focus: {z:g} µm is outside the focus drive's range {lo:g} to {hi:g} µm"
            )
        if z != self.rig.focus.position_um():
            self.rig.move_focus(z)

    def position(self) -> tuple[float, ...]:
        """The drive's readout (its last command), µm."""
        return (float(self.rig.focus.position_um()),)

    def busy(self) -> bool:
        return False  # a move is answered once settled

    def stop(self) -> None:
        pass  # nothing moves between requests


class PatchFramePeer(FramePeer):
    """The frame server over a ``patch`` rig: its camera and its two stages."""

    def __init__(
        self, rig: PatchRig, lock: threading.Lock, *, seed: int, time_scale: float,
        stop: threading.Event | None = None, sample: str = "tissue",
    ) -> None:  # fmt: skip
        self.rig = rig
        self.camera = PatchTwinCamera(rig, sample)
        stages: dict[str, ServedStage] = {XY_STAGE: ServedXYStage(rig), FOCUS: ServedFocus(rig)}
        self.serve({CAMERA: self.camera}, stages, rig.clock, lock, preset=PATCH_PRESET,
                   seed=seed, time_scale=time_scale, stop=stop)  # fmt: skip

    def truth(self) -> dict[str, Any]:
        """The TRUTH answer: the tip's true position ({G}, µm) as ``position_um`` and
        ``devices.m1``, the stage's true x, y (``stage_um``) and the objective's true offset
        from its home (``objective_um``)."""
        rig = self.rig
        t = rig.clock.now_s()
        tip = rig.manipulator.true_position_um().tolist()
        return {
            "t_s": t,
            "position_um": tip,
            "target_stage_um": None,
            "devices": {"m1": tip},
            "stage_um": rig.stage.joints_um(t)[:2].tolist(),
            "objective_um": rig.focus.objective_offset_um().tolist(),
        }


def tool_spec(rig: PatchRig) -> str:
    """The pipette's tip as a rig file's board (``tip:pipette:10:1``)."""
    tool = rig.config.tool
    return f"tip:{tool.kind}:{tool.taper_deg:g}:{tool.tip_um:g}"


def patch_twin_rig(
    rig: PatchRig,
    *,
    host: str = "127.0.0.1",
    mcs2_port: int = MCS2_PORT,
    frames_port: int = FRAMES_PORT,
    time_scale: float = 1.0,
) -> TwinRig:
    """The rig of a twin serving the ``patch`` rig ``rig``: the manipulator ``m1`` on
    channels 0-2, the camera ``scope``, the microscope's ``XYStage`` and ``Focus``, each
    with its simulated travel."""
    m = rig.manipulator
    limits = tuple((float(lo), float(hi)) for lo, hi in m.limits_um)
    xy = rig.stage.limits_um[:2]
    scope_limits = (*((float(lo), float(hi)) for lo, hi in xy), rig.focus.limits_um)
    return TwinRig(
        preset=PATCH_PRESET, seed=rig.seed, host=host, mcs2_port=mcs2_port,
        frames_port=frames_port, time_scale=time_scale, board=tool_spec(rig),
        calibration_target=None, manipulator=TwinRigDevice("m1", 0, limits), target_stage=None,
        further=(), cameras=(TwinRigCamera(CAMERA, float(rig.config.sensor_pixel_um)),),
        microscope=TwinRigMicroscope(XY_STAGE, FOCUS, scope_limits),
    )  # fmt: skip
