"""The probe of an evaluation on a one-camera rig: the tip in {M} from its image and focus.

:class:`OneCameraTipProbe` is what :func:`~microcal.procedures.evaluation.run_pose_accuracy`
and the closed loop (:class:`~microcal.control.closed_loop.ClosedLoop`) measure with on a
microscope: it looks for the tip where the calibration puts it for the joints commanded
(``expect``), measures it by :meth:`~microcal.procedures.one_camera_acquisition.TipFinder.
measure` (the focus follows it there) and gives its position in the microscope's frame {M}
with its covariance. A tip not found is NaN, as the cameras' probe gives it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..devices.base import Clock
from ..errors import DetectionError, InputError, LimitError
from ..vision.focus_depth import Frame
from .one_camera_acquisition import TipFinder

__all__ = ["OneCameraTipProbe"]


@dataclass
class OneCameraTipProbe:
    """Measures the tip in {M} at the current pose (module docstring).

    Attributes
    ----------
    finder : TipFinder
    move_focus, grab : callable
        The rig's focus drive and camera.
    clock : Clock
    expect : callable
        ``expect(d_um (3,)) -> (3,)``: where the calibration puts the tip for the joints
        commanded, {M} µm.
    """

    finder: TipFinder
    move_focus: Callable[[float], object]
    grab: Callable[[], Frame]
    clock: Clock
    expect: Callable[[FloatArray], FloatArray]
    frames_used: int = 0

    def measure_with_covariance(
        self, d_um: FloatArray, frames: int = 1
    ) -> tuple[FloatArray, FloatArray]:
        """Position (3,) µm in {M} and its covariance (3, 3) µm^2; NaN when not found.
        ``frames`` is the closed loop's frame count, which the sweep sets itself."""
        try:
            p, cov, n, _ = self.finder.measure(self.move_focus, self.grab,
                                               self.expect(np.asarray(d_um, float)),
                                               self.clock.now_s)  # fmt: skip
        except (DetectionError, InputError, LimitError):
            return np.full(3, np.nan), np.full((3, 3), np.nan)
        self.frames_used += n
        return p, cov

    def measure(self, d_um: FloatArray) -> FloatArray:
        """Position (3,) µm in {M}; NaN when not found."""
        return self.measure_with_covariance(d_um)[0]
