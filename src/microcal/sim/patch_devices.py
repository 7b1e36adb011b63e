"""The ``patch`` rig (:class:`~microcal.sim.patch.PatchRig`) as a generic
:class:`~microcal.devices.rig.Rig`: what ``open_rig`` gives for ``preset = "patch"``.

- :class:`PatchCamera`: the rig's one camera as a :class:`~microcal.devices.base.Camera`
  (``grab()`` the whole frame, ``grab_lazy()`` the lazy :class:`~microcal.sim.patch.PatchFrame`
  rendered where it is read).
- :class:`PatchMicroscope`: the X-Y stage and the focus drive as one
  :class:`~microcal.devices.base.Manipulator` of joints x, y (the stage) and z (the focus);
  a move of z approaches from below (the drive's backlash compensation), and the position
  reads back the last command (open-loop steppers, as most microscopes' drives are).
- :func:`patch_as_rig`: the :class:`Rig` of both, with the pipette's manipulator ``m1``, its
  tip as the board, and the ground truth.
- :func:`patch_config`: a rig file's ``[overrides]`` for ``preset = "patch"`` (settings of
  :class:`~microcal.sim.patch.PatchConfig` by name: ``approach_deg = 25``,
  ``size_px = [512, 512]``), each checked.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import FloatArray, as_array, did_you_mean
from ..devices.base import Camera, Manipulator
from ..devices.rig import Rig
from ..errors import InputError
from ..vision.tip_target import TipTarget, parse_tip
from .patch import PatchConfig, PatchFrame, PatchRig

__all__ = ["PatchCamera", "PatchMicroscope", "patch_as_rig", "patch_config", "tool_target"]

#: The settings of :class:`PatchConfig` a rig file may change (numbers and pairs).
OVERRIDABLE = (
    "magnification", "numerical_aperture", "refractive_index", "wavelength_um",
    "sensor_pixel_um", "size_px", "approach_deg", "approach_azimuth_deg", "tissue_contrast",
    "focus_period_um", "light_level", "light_gradient", "full_well_e", "read_noise_e",
    "bit_depth", "exposure_s", "readout_s", "supersample",
)  # fmt: skip


class PatchCamera(Camera):
    """The ``patch`` rig's camera (``scope``): frames of the rig's tissue and pipette."""

    def __init__(self, rig: PatchRig, name: str = "scope") -> None:
        cfg = rig.config
        super().__init__(name, cfg.size_px, cfg.sensor_pixel_um, cfg.bit_depth, cfg.exposure_s)
        self.rig = rig

    def _grab(self) -> NDArray[np.unsignedinteger]:
        full: NDArray[np.unsignedinteger] = self.rig.grab().full()
        return full

    def grab_lazy(self) -> PatchFrame:
        """One frame as :meth:`grab` gives it, rendered only where it is read."""
        self._check_open("grab")
        return self.rig.grab()

    def _close(self) -> None:
        pass  # nothing to release


class PatchMicroscope(Manipulator):
    """The ``patch`` rig's X-Y stage (joints x, y) and focus drive (joint z), µm.

    A command of all three joints moves what it changes: the stage when x, y differ from
    its last command, the focus (from below, waiting until it has settled) when z differs
    from its readout. :meth:`move_stage_um` and :meth:`move_focus_um` move one of them
    alone, even to where it is (it settles again), as a microscope's own controls do.
    """

    def __init__(self, rig: PatchRig, name: str = "microscope") -> None:
        stage = rig.stage.limits_um[:2]
        focus = np.array([rig.focus.limits_um])
        super().__init__(name, ("x", "y", "z"), np.vstack([stage, focus]))
        self.rig = rig
        self._xy: FloatArray = rig.stage.joints_um(rig.clock.now_s())[:2].copy()

    def move_stage_um(self, xy_um: ArrayLike) -> None:
        """Start a move of the stage alone to ``xy_um`` (2,), µm (checked as :meth:`move_to_um`
        checks)."""
        self._check_open("move")
        xy = as_array(xy_um, "xy_um", (2,))
        d = self.check_limits([xy[0], xy[1], self.rig.focus.position_um()])
        self.rig.stage.move_to_um([float(d[0]), float(d[1]), 0.0])
        self._xy = d[:2].copy()

    def move_focus_um(self, z_um: float) -> None:
        """Move the focus alone to ``z_um`` (from below) and let it settle, µm."""
        self._check_open("move")
        d = self.check_limits([self._xy[0], self._xy[1], float(z_um)])
        self.rig.move_focus(float(d[2]))

    def _move(self, d_um: FloatArray) -> None:
        if not np.array_equal(d_um[:2], self._xy):
            self.rig.stage.move_to_um([float(d_um[0]), float(d_um[1]), 0.0])
            self._xy = d_um[:2].copy()
        if float(d_um[2]) != self.rig.focus.position_um():
            self.rig.move_focus(float(d_um[2]))

    def _position_um(self) -> FloatArray:
        out: FloatArray = np.array([*self._xy, self.rig.focus.position_um()])
        return out

    def _is_moving(self) -> bool:
        return self.rig.stage.is_moving()

    def _stop(self) -> None:
        self.rig.stage.stop()
        self._xy = self.rig.stage.joints_um(self.rig.clock.now_s())[:2].copy()

    def _close(self) -> None:
        pass  # nothing to release


def tool_target(rig: PatchRig) -> TipTarget:
    """The pipette's tip as the end-effector's target (``tip:pipette:TAPER:TIP``)."""
    tool = rig.config.tool
    return parse_tip(f"tip:{tool.kind}:{tool.taper_deg:g}:{tool.tip_um:g}")


def patch_as_rig(rig: PatchRig, description: str = "simulated, preset patch") -> Rig:
    """The :class:`Rig` of a ``patch`` rig: ``cameras`` its one camera (``scope``),
    ``microscope`` its stage and focus, ``manipulator`` the pipette's (``m1``), ``board`` the
    pipette's tip, ``truth`` the tip's true position in {G}, µm."""
    m = rig.manipulator

    def truth() -> FloatArray:
        return m.true_position_um()

    def temperature() -> float:
        return m.temperature_at(rig.clock.now_s())

    truths: dict[str, Callable[[], FloatArray]] = {"m1": truth}
    return Rig(
        m, {"scope": PatchCamera(rig)}, rig.clock, tool_target(rig), temperature=temperature,
        truth=truth, description={"platform": description}, manipulators={"m1": m},
        truths=truths, temperatures={"m1": temperature}, microscope=PatchMicroscope(rig),
    )  # fmt: skip


def patch_config(overrides: Mapping[str, object]) -> PatchConfig:
    """The ``patch`` preset's configuration with ``overrides`` (:data:`OVERRIDABLE` names;
    lists become tuples) applied, each checked.

    Raises
    ------
    InputError
        An unknown name (with the nearest one) or a value out of range (one line).
    """
    changes: dict[str, object] = {}
    for key, value in overrides.items():
        if key not in OVERRIDABLE:
            hint = did_you_mean(key, OVERRIDABLE).strip()
            raise InputError(
                f"override {key!r}: preset 'patch' has no such setting (it has "
                f"{', '.join(OVERRIDABLE)})" + (f"; {hint}" if hint else "")
            )
        changes[key] = tuple(value) if isinstance(value, list) else value
    try:
        return dataclasses.replace(PatchConfig(), **changes)  # type: ignore[arg-type]
    except (TypeError, ValueError) as exc:
        raise InputError(f"overrides of preset 'patch': {exc}") from None
