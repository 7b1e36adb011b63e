"""Pure-Python Micro-Manager devices of a simulated microscope (pymmcore-plus ``unicore``):
an XY stage, a focus stage and a camera that shows the slide of
:class:`microcal.sim.stage_slide.StageSlideScope` where the stages have it.

``load(core, objective="40x", seed=0, size=256)`` registers them as XY, Z and Scope.
"""

from __future__ import annotations

import numpy as np
from pymmcore_plus.experimental.unicore import SimpleCameraDevice

from microcal.sim.stage_slide import StageSlideScope, random_truth

from .mm_devices import XY, Z


class SlideCam(SimpleCameraDevice):
    def __init__(self, scope: StageSlideScope, xy: XY, z: Z) -> None:
        super().__init__()
        self.scope, self.xy, self.z = scope, xy, z
        self._exposure_ms = 10.0

    def sensor_shape(self) -> tuple[int, int]:
        w, h = self.scope.image_size_px
        return (h, w)

    def get_exposure(self) -> float:
        return self._exposure_ms

    def set_exposure(self, exposure: float) -> None:
        self._exposure_ms = exposure

    def dtype(self):
        return np.uint16

    def snap(self, buffer):
        self.scope.move_stage(np.array(self.xy.get_position_um()))
        self.scope.move_focus(self.z.get_position_um())
        buffer[:] = np.clip(self.scope.grab() * 4000.0, 0, 65535).astype(np.uint16)
        return {}


def load(core, objective: str = "40x", seed: int = 0, size: int = 256) -> None:
    xy, z = XY(), Z()
    scope = StageSlideScope(random_truth(seed, objective), image_size_px=(size, size), seed=seed)
    core.loadPyDevice("XY", xy)
    core.loadPyDevice("Z", z)
    core.loadPyDevice("Scope", SlideCam(scope, xy, z))
