"""Pure-Python Micro-Manager devices of a simulated microscope (pymmcore-plus ``unicore``):
an XY stage, a focus stage and a camera that shows the slide of
:class:`microcal.sim.stage_slide.StageSlideScope` where the stages have it.

``load(core, objective="40x", seed=0, size=256)`` registers them as XY, Z and Scope.
"""

from __future__ import annotations

import numpy as np

from microcal.sim.stage_slide import StageSlideScope, random_truth

from .mm_devices import XY, Cam, Z


class SlideCam(Cam):
    """The camera of :mod:`.mm_devices` showing the slide where the stages put it."""

    def __init__(self, scope: StageSlideScope, xy: XY, z: Z) -> None:
        w, h = scope.image_size_px
        super().__init__((h, w))
        self.scope, self.xy, self.z = scope, xy, z

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
