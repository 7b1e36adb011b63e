"""A calibrated station: one manipulator and its cameras, driven in {G} and measured.

Each device of a rig with several (two manipulators and a positioner) is a station of its
own on the same rig (``Station(rig.select("m2"), ...)``); ``move_relative_um`` brings one's
tip to another's end-effector, or to an offset from it.

:class:`Station` is what a user opens to use a calibration (``microcal.open_station`` reads
the files and opens the rig): ``move_to_um(p)`` sends the tip to a position in {G}, open
loop (the identified model's joints, approached from below when the model has direction
terms) or closed (then visual servoing to a tolerance, :mod:`~microcal.control.visual_servo`),
and says where the tip arrived and how sure that is; ``where_um()`` measures the tip now.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, check_number
from ..control.closed_loop import ClosedLoop
from ..control.feedforward import FeedForward, extra_inputs_reader
from ..control.visual_servo import ServoConfig, ServoStep
from ..devices.rig import Rig
from ..errors import DetectionError, InputError
from ..geometry import AnyCamera
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..vision.probe import VisionProbe
from ..vision.targets import Target
from .approach_axis import ApproachMove, plan_approach

__all__ = ["Arrival", "Station", "check_frames"]


@dataclass(frozen=True)
class Arrival:
    """Where a move left the tip, as measured.

    Attributes
    ----------
    target_um, d_um, measured_um : (3,) float
        The target in {G}, the joints commanded, the measured position.
    cov_um2 : (3, 3) float
        The measurement's covariance.
    mode : {"open", "closed"}
    status : str
        ``open`` for the open loop; how the closed loop ended (``tolerance``,
        ``resolution``, ``iterations``).
    iterations, frames : int
        Corrections made, frames grabbed per camera.
    tolerance_um, confidence : float, optional
        What the closed loop aimed at (None for the open loop).
    max_iterations : int, optional
        The closed loop's cap on corrections.
    """

    target_um: FloatArray
    d_um: FloatArray
    measured_um: FloatArray
    cov_um2: FloatArray
    mode: str
    status: str
    iterations: int
    frames: int
    tolerance_um: float | None = None
    confidence: float | None = None
    max_iterations: int | None = None

    @property
    def error_um(self) -> FloatArray:
        """(3,) measured minus target."""
        out: FloatArray = self.measured_um - self.target_um
        return out

    @property
    def std_um(self) -> FloatArray:
        """(3,) standard deviation of the measurement per axis."""
        out: FloatArray = np.sqrt(np.diagonal(self.cov_um2))
        return out

    def as_dict(self) -> dict[str, object]:
        """Plain dict for printing and JSON."""
        return {"target_um": self.target_um.tolist(), "d_um": self.d_um.tolist(),
                "measured_um": self.measured_um.tolist(), "std_um": self.std_um.tolist(),
                "error_um": self.error_um.tolist(), "mode": self.mode, "status": self.status,
                "iterations": self.iterations, "frames": self.frames}  # fmt: skip


def check_frames(frames: object, where: str) -> None:
    """Refuse a number of frames per camera that is not a whole number >= 1 (InputError
    naming ``where``)."""
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise InputError(f"{where}: frames: expected a whole number >= 1, got {frames!r}")


class Station:
    """A calibrated manipulator with its cameras (see the module docstring).

    Parameters
    ----------
    rig : Rig
        The opened rig; the station closes it.
    calibration : ManipulatorCalibration
    cameras : mapping of name -> camera model
        The calibrated cameras (every camera of the rig needs one).
    frames : int
        Frames per camera of a measurement (``where_um``, the open loop's arrival).
    settle_s : float
        Wait after a move before measuring.
    servo : ServoConfig, optional
        The closed loop's settings.
    on_correction : callable (ServoStep) -> None, optional
        Called with each measurement of the closed loop as it is made (progress).
    probe : object, optional
        What measures the tip: ``measure_with_covariance(d_um, frames)`` (the cameras'
        :class:`VisionProbe` by default; one camera needs another, see
        ``microcal.workflows.one_camera``).

    Raises
    ------
    InputError
        A camera of the rig without a calibration, or the model needs a sensor the rig lacks.
    """

    def __init__(
        self,
        rig: Rig,
        calibration: ManipulatorCalibration,
        cameras: Mapping[str, AnyCamera],
        *,
        frames: int = 10,
        settle_s: float = 1.0,
        servo: ServoConfig | None = None,
        on_correction: Callable[[ServoStep], None] | None = None,
        probe: Any = None,
    ) -> None:
        missing = sorted(set(rig.cameras) - set(cameras))
        if missing and probe is None:
            raise InputError(f"station: no camera calibration for the rig's camera(s) {missing}")
        calibration.check_device(rig.manipulator.identity)
        check_number("settle_s", settle_s, low=0)
        if frames < 1:
            raise InputError(f"frames: expected 1 or more, got {frames}")
        self.rig = rig
        rig.look_at()
        self.calibration = calibration
        self.frames = int(frames)
        self.settle_s = float(settle_s)
        model = calibration.model
        extra = extra_inputs_reader(model, rig.sensors)
        self.probe = probe or VisionProbe(
            rig.cameras, {n: cameras[n] for n in rig.cameras}, rig.board, self.frames
        )
        method: Literal["optimal", "matrix"] = "optimal" if model.kind == "polynomial" else "matrix"
        self._open = FeedForward(rig.manipulator, model, method, extra, rig.clock)
        measure = self.probe.measure_with_covariance
        self._closed = ClosedLoop(rig.manipulator, model, measure, rig.clock, extra, servo,
                                  self.settle_s, on_correction)  # fmt: skip
        self._d = rig.manipulator.position_um()

    def where_um(self, frames: int | None = None) -> tuple[FloatArray, FloatArray]:
        """The tip now in {G}: position (3,) µm and covariance (3, 3) µm².

        Raises
        ------
        DetectionError
            The cameras do not find the end-effector's target.
        """
        if frames is not None:
            check_frames(frames, "where_um")
        self.rig.look_at()
        p, cov = self.probe.measure_with_covariance(self._d, frames or self.frames)
        if not np.all(np.isfinite(p)):
            why = getattr(self.probe, "last_reason", "")
            raise DetectionError(
                "station: the cameras do not find the end-effector's target (is it in view?)"
                + (f": {why}" if why else "")
            )
        return p, cov

    def move_to_um(
        self,
        p_um: ArrayLike,
        mode: Literal["open", "closed"] = "open",
        tolerance_um: float | None = None,
    ) -> Arrival:
        """Send the tip to ``p_um`` in {G}; where it arrived, as measured.

        Parameters
        ----------
        p_um : (3,) float
        mode : {"open", "closed"}
        tolerance_um : float, optional
            The closed loop's tolerance (its configured one by default).

        Raises
        ------
        LimitError
            The joints would leave the soft limits (nothing moves).
        DetectionError
            The cameras lost the tip (the tip stays where the last move left it).
        """
        target = as_array(p_um, "p_um", (3,))
        if mode not in ("open", "closed"):
            raise InputError(f"mode: expected 'open' or 'closed', got {mode!r}")
        if mode == "open":
            d = self._open.move_to_position_um(target)
            self._d = d
            self.rig.manipulator.wait_until_stopped(self.rig.clock)
            self.rig.clock.sleep(self.settle_s)
            p, cov, frames = self._measured()
            return Arrival(target, d, p, cov, "open", "open", 0, frames)
        if tolerance_um is not None:
            self._closed.config = dataclasses.replace(
                self._closed.config, tolerance_um=tolerance_um
            )
        d = self._closed.move_to_position_um(target)
        self._d = d
        r = self._closed.results[-1]
        c = self._closed.config
        return Arrival(target, d, r.measured_um, r.cov_um2, "closed", r.status, r.iterations,
                       r.frames, c.tolerance_um, c.confidence, c.max_iterations)  # fmt: skip

    def move_along_approach_um(
        self,
        distance_um: float,
        mode: Literal["open", "closed"] = "open",
        tolerance_um: float | None = None,
        step_um: float | None = None,
        path: Literal["joint", "line"] = "joint",
    ) -> tuple[ApproachMove, Arrival]:
        """Move the tip ``distance_um`` along the tool's approach axis (the calibration's
        direction of the approach joint ``dx``, the manipulator's x;
        :mod:`~microcal.procedures.approach_axis`), through targets ``step_um`` apart (None:
        one), from where the model puts the tip for the joints commanded last.

        ``path="joint"``: the approach joint alone travels (no joint goes back and forth);
        ``"line"``: the compensator's joints for each target. ``mode="closed"`` then servoes
        to the last target (the closed loop's moves arrive from below, as every closed loop's
        do). Every joint is checked against the soft limits before anything moves.

        Returns
        -------
        move : ApproachMove
            The plan (start, axis, targets, the joint's travel).
        arrival : Arrival
            Where the last target left the tip, as measured.

        Raises
        ------
        LimitError
            A target outside the soft limits (nothing moves).
        DetectionError
            The tip is not found (the tip stays where the last move left it).
        """
        if mode not in ("open", "closed") or path not in ("joint", "line"):
            raise InputError(f"mode, path: expected open|closed and joint|line, got {mode!r}, "
                             f"{path!r}")  # fmt: skip
        extra = None if self._open.extra is None else self._open.extra()
        move = plan_approach(self.calibration.model, self._d, distance_um, extra=extra,
                             step_um=step_um)  # fmt: skip
        m = self.rig.manipulator
        for d, target in zip(move.joints_um, move.targets_um, strict=True):
            if path == "joint":
                m.check_limits(d)
            else:
                self.check_reach(target)
        last = move.targets_um[-1]
        for d, target in zip(move.joints_um, move.targets_um, strict=True):
            self._d = d if path == "joint" else self._open.move_to_position_um(target)
            if path == "joint":
                m.move_to_um(d)
            m.wait_until_stopped(self.rig.clock)
            self.rig.clock.sleep(self.settle_s)
        if mode == "closed":
            return move, self.move_to_um(last, "closed", tolerance_um)
        p, cov, frames = self._measured()
        return move, Arrival(last, self._d, p, cov, "open", "open", 0, frames)

    def _measured(self) -> tuple[FloatArray, FloatArray, int]:
        """:meth:`where_um` and the frames it took: per camera, or a one-camera probe's
        (its focus sweep's, which it counts in ``frames_used``)."""
        before = getattr(self.probe, "frames_used", None)
        p, cov = self.where_um()
        after = getattr(self.probe, "frames_used", None)
        used = after - before if isinstance(after, int) and isinstance(before, int) else None
        return p, cov, self.frames if used is None else used

    def check_reach(self, p_um: ArrayLike) -> None:
        """Raise :class:`LimitError` if the model's joints for ``p_um`` (3,) in {G} leave the
        soft limits (nothing moves)."""
        self.rig.manipulator.check_limits(self._open.joints_for(as_array(p_um, "p_um", (3,))))

    def check_told_apart(self, other: Station) -> None:
        """Refuse to work with another device's target in view unless the cameras can tell
        the two targets apart: ChArUco boards with their own markers, or a rig that shows
        one target at a time (the simulator).

        Raises
        ------
        InputError
            Naming both devices, their targets and the fix.
        """
        a, b = self.rig.board, other.rig.board
        apart = isinstance(a, Target) and isinstance(b, Target) and a.told_apart_from(b)
        if self.rig.show is None and not apart:
            raise InputError(
                f"{self.rig.selected} and {other.rig.selected} carry targets the cameras cannot "
                f"tell apart in one image ({a.spec} and {b.spec}); give each device a ChArUco "
                f"board with markers of its own in the rig file ([manipulators.NAME] board = "
                f'"charuco:5x4:400:id10")'
            )

    def move_relative_um(
        self,
        other: Station,
        offset_um: ArrayLike = (0.0, 0.0, 0.0),
        mode: Literal["open", "closed"] = "open",
        tolerance_um: float | None = None,
    ) -> Arrival:
        """Send this tip to ``offset_um`` from the other device's end-effector, as measured
        now: two tools to one point (offset 0) or to a given offset from each other, or a tool
        to a point on the sample the positioner carries (the point's offset from the
        positioner's end-effector, plus any stand-off).

        Parameters
        ----------
        other : Station
            Another device of the same rig (its calibration in the same {G}).
        offset_um : (3,) float
            In {G}.

        Raises
        ------
        InputError
            ``other`` is this station, or its target cannot be told from this one's
            (:meth:`check_told_apart`).
        DetectionError, LimitError
            As :meth:`where_um` and :meth:`move_to_um`.
        """
        if other is self:
            raise InputError("move_relative_um: other is this station; give another device's")
        self.check_told_apart(other)
        offset = as_array(offset_um, "offset_um", (3,))
        p_other, _ = other.where_um()
        return self.move_to_um(p_other + offset, mode, tolerance_um)

    def close(self) -> None:
        """Close the rig (again: nothing)."""
        self.rig.close()

    def __enter__(self) -> Station:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.rig.__exit__(exc_type, exc, tb)
