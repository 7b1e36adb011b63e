"""Pure-Python Micro-Manager devices (pymmcore-plus ``unicore``) for the bridge's tests.

An XY and a Z stage that move at a finite speed (busy meanwhile) and two cameras of the
thesis's sizes; ``load(core)`` registers them as XY, Z, TopCam and SideCam.
"""

from __future__ import annotations

import time

import numpy as np
from pymmcore_plus.experimental.unicore import SimpleCameraDevice, StageDevice, XYStageDevice

SPEED_UM_S = 20000.0


class _Motion:
    def __init__(self, n: int) -> None:
        self.start = np.zeros(n)
        self.target = np.zeros(n)
        self.t0 = 0.0
        self.duration = 0.0

    def go(self, target) -> None:
        self.start = self.now()
        self.target = np.asarray(target, dtype=float)
        self.t0 = time.monotonic()
        self.duration = float(np.max(np.abs(self.target - self.start))) / SPEED_UM_S

    def now(self) -> np.ndarray:
        if self.duration <= 0:
            return self.target.copy()
        f = min(1.0, (time.monotonic() - self.t0) / self.duration)
        return self.start + f * (self.target - self.start)

    def busy(self) -> bool:
        return time.monotonic() - self.t0 < self.duration

    def halt(self) -> None:
        here = self.now()
        self.start = self.target = here
        self.duration = 0.0


class XY(XYStageDevice):
    def __init__(self) -> None:
        super().__init__()
        self.motion = _Motion(2)

    def set_position_um(self, x: float, y: float) -> None:
        self.motion.go([x, y])

    def get_position_um(self) -> tuple[float, float]:
        x, y = self.motion.now()
        return float(x), float(y)

    def busy(self) -> bool:
        return self.motion.busy()

    def set_origin_x(self) -> None: ...

    def set_origin_y(self) -> None: ...

    def home(self) -> None:
        self.motion.go([0.0, 0.0])

    def stop(self) -> None:
        self.motion.halt()


class Z(StageDevice):
    def __init__(self) -> None:
        super().__init__()
        self.motion = _Motion(1)

    def set_position_um(self, val: float) -> None:
        self.motion.go([val])

    def get_position_um(self) -> float:
        return float(self.motion.now()[0])

    def busy(self) -> bool:
        return self.motion.busy()

    def home(self) -> None:
        self.motion.go([0.0])

    def stop(self) -> None:
        self.motion.halt()

    def set_origin(self) -> None: ...


class Cam(SimpleCameraDevice):
    def __init__(self, shape: tuple[int, int]) -> None:
        super().__init__()
        self._shape = shape
        self._exposure_ms = 10.0
        self._rng = np.random.default_rng(7)

    def sensor_shape(self) -> tuple[int, int]:
        return self._shape

    def get_exposure(self) -> float:
        return self._exposure_ms

    def set_exposure(self, exposure: float) -> None:
        self._exposure_ms = exposure

    def dtype(self):
        return np.uint16

    def snap(self, buffer):
        buffer[:] = self._rng.integers(0, 4096, buffer.shape, dtype=np.uint16)
        return {}


def load(core) -> None:
    core.loadPyDevice("XY", XY())
    core.loadPyDevice("Z", Z())
    core.loadPyDevice("TopCam", Cam((120, 160)))
    core.loadPyDevice("SideCam", Cam((103, 123)))
