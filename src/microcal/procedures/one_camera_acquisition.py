"""The acquisition on a one-camera rig (a camera on a focus drive): move, settle, find the tip
in 3D, store, next; the design fills the user's working volume, the focus follows the tip.

Where the tip will be is not known before the manipulator is calibrated, and a tip is found
only within a few µm of where it is looked for (the depth of field is about a micron; the
region searched is a few µm across). So the poses are taken outwards from where the user
brought the tip into focus at the field's centre:

1. the start pose, measured where the user says the tip is (image and focus);
2. one small step of each joint (:data:`STEP_UM`), looked for where the rig's nominal axes
   put it (a patch manipulator's approach angle is known to a few degrees);
3. the design: ``poses`` points drawn uniformly in the working volume (a box in the
   microscope's frame {M}, :class:`~microcal.vision.microscope_frame.MicroscopeFrame`),
   visited nearest first; each one's joints and the place to look for the tip (its image
   and the focus reading with it in focus) come from a linear map fitted to every pose
   measured so far, so each prediction extrapolates little.

At every pose the manipulator approaches from a random side of each joint (``approach_um``;
the directions are journaled, so the fit can take the approach terms), waits until it
reports stopped, waits ``settle_s`` more, and the tip is measured by
:func:`~microcal.procedures.one_camera_pose.measure_tip_one_camera` (a focus sweep around
the predicted reading, or one frame against the tool's reference stack): the focus moves to
the tip wherever the design takes it. Each pose's :class:`~microcal.journal_record.JournalRecord`
and its tip in {M} go to ``store`` as soon as it is measured (the caller's crash-safe
journal); a pose whose tip is not found is journaled as failed and the run goes on.

A run resumed after a stop hands its stored poses back (``done``): they are taken as
measured, in order, without moving, and the design goes on from there as it would have
(the poses' commands follow from the seed and the tips measured, so the same ones again).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..devices.base import Clock, Manipulator
from ..errors import DetectionError, InputError, LimitError
from ..journal_record import JournalRecord, PoseStatus
from ..json_value import JsonValue
from ..kinematics.extra_inputs import APPROACH_INPUTS, extra_input
from ..vision.focus_depth import Frame, ReferenceStack
from ..vision.microscope_frame import MicroscopeFrame
from .one_camera_pose import measure_tip_one_camera

__all__ = [
    "DEFAULT_VOLUME_HALF_UM",
    "FROM_BELOW",
    "MAP_OUTLIER_UM",
    "RECENTRE_PX",
    "RECENTRE_UM",
    "STEP_UM",
    "OneCameraPose",
    "OneCameraRun",
    "TipFinder",
    "WorkingVolume",
    "acquire_one_camera",
    "linear_map",
]

#: The working volume's half sizes around the field's centre in {M} by default, µm: 200 x 200
#: µm of a 40x objective's 333 µm field, 50 µm of depth (a slice's working depth).
DEFAULT_VOLUME_HALF_UM = (100.0, 100.0, 25.0)
#: The first steps of each joint from the start pose, µm.
STEP_UM = 20.0
#: Design poses approached from below on every joint before the sides are drawn at random.
FROM_BELOW = 8
#: A tip found further than this in focus from where it was looked for is looked for again
#: there, µm (a quarter of the sweep's range).
RECENTRE_UM = 0.8
#: ... or further than this in the image, px.
RECENTRE_PX = 12.0
#: A pose further than this from the linear map of the others is left out of the map, µm.
MAP_OUTLIER_UM = 1.5


@dataclass(frozen=True)
class WorkingVolume:
    """The box the user works in, in {M}: its centre (3,) and half sizes (3,), µm."""

    centre_um: FloatArray
    half_um: FloatArray

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre_um", as_array(self.centre_um, "centre_um", (3,)))
        half = as_array(self.half_um, "half_um", (3,))
        if np.any(half <= 0):
            raise InputError(f"working volume: expected half sizes > 0 µm, got {half.tolist()}")
        object.__setattr__(self, "half_um", half)

    def draw(self, n: int, seed: int) -> FloatArray:
        """``n`` points uniformly in the box, (n, 3) µm."""
        rng = np.random.default_rng(seed)
        out: FloatArray = self.centre_um + rng.uniform(-1.0, 1.0, (n, 3)) * self.half_um
        return out


@dataclass(frozen=True)
class TipFinder:
    """How the tip is measured on this rig (:func:`measure_tip_one_camera`'s inputs).

    Attributes
    ----------
    frame : MicroscopeFrame
        The camera's calibration against its stage: image and focus to {M}.
    axis_px : (2,) float
        The tool's direction in the image, tip to shank.
    end_offset_px : float
        The tip point's distance behind where the tool's image begins, px.
    method : str
        ``"sweep"`` or ``"stack"``.
    stack : ReferenceStack or None
        The tool's reference stack (the stack method).
    frames, step_um : int, float
        The sweep's frames and their spacing.
    looks : int
        How many times a tip found off where it was looked for is looked for again.
    """

    frame: MicroscopeFrame
    axis_px: FloatArray
    end_offset_px: float = 0.0
    method: str = "sweep"
    stack: ReferenceStack | None = None
    frames: int = 13
    step_um: float = 0.5
    looks: int = 3

    def measure(
        self,
        move_focus: Callable[[float], object],
        grab: Callable[[], Frame],
        expected_um: FloatArray,
        clock: Callable[[], float],
    ) -> tuple[FloatArray, FloatArray, int, float]:
        """The tip where ``expected_um`` (3,) in {M} says to look: its position (3,) and
        covariance (3, 3) in {M}, frames grabbed and seconds taken.

        A tip found more than :data:`RECENTRE_UM` in focus (or :data:`RECENTRE_PX` in the
        image) from where it was looked for was found near the sweep's edge, where the
        shank may pass for it: it is looked for again where it was found, up to
        ``looks`` times in all, until two looks agree."""
        frames, seconds = 0, 0.0
        look = np.asarray(expected_um, dtype=np.float64)
        for _ in range(self.looks):
            p, cov, n, secs = self._once(move_focus, grab, look, clock)
            frames, seconds = frames + n, seconds + secs
            q_look, f_look = self.frame.to_image(look)
            q_got, f_got = self.frame.to_image(p)
            if (abs(float(f_got[0] - f_look[0])) <= RECENTRE_UM
                    and float(np.linalg.norm(q_got - q_look)) <= RECENTRE_PX):  # fmt: skip
                return p, cov, frames, seconds
            look = p
        raise DetectionError(
            f"one-camera tip: not found where it was looked for in {self.looks} looks (last "
            f"found {float(f_got[0] - f_look[0]):+.1f} µm in focus from where it was looked for)"
        )

    def _once(
        self,
        move_focus: Callable[[float], object],
        grab: Callable[[], Frame],
        expected_um: FloatArray,
        clock: Callable[[], float],
    ) -> tuple[FloatArray, FloatArray, int, float]:
        q, f = self.frame.to_image(expected_um)
        tip = measure_tip_one_camera(
            move_focus, grab, q, float(f[0]), self.frame.um_per_px, method=self.method,
            axis_px=self.axis_px, stack=self.stack, frames=self.frames, step_um=self.step_um,
            end_offset_px=self.end_offset_px, clock=clock,
        )  # fmt: skip
        est = tip.depth
        c = np.zeros((3, 3))  # (q_x, q_y, f) px, px, µm
        c[:2, :2] = est.cov_px
        c[2, 2] = est.var_um2
        c[:2, 2] = c[2, :2] = est.cov_z_px
        p = self.frame.to_um(est.apex_px, est.z_um)
        return p, self.frame.cov_to_um(c), tip.frames, tip.seconds


@dataclass(frozen=True)
class OneCameraPose:
    """One pose's tip in {M} (NaN when not found) with its covariance, and the cost."""

    pose: int
    p_um: FloatArray
    cov_um2: FloatArray
    frames: int
    seconds: float

    @property
    def found(self) -> bool:
        """The tip was measured."""
        return bool(np.all(np.isfinite(self.p_um)))

    def to_json(self) -> dict[str, JsonValue]:
        """The pose's line of the measurements journal."""
        return {
            "pose": self.pose,
            "p_um": [float(v) for v in self.p_um] if self.found else None,
            "cov_um2": [[float(v) for v in r] for r in self.cov_um2] if self.found else None,
            "frames": self.frames,
            "seconds": self.seconds,
        }


#: Persists one pose as soon as it is measured: its journal record and its tip.
PoseStore = Callable[[JournalRecord, OneCameraPose], None]


@dataclass
class OneCameraRun:
    """What :func:`acquire_one_camera` did: joints commanded (N, 3), the tips, the journal."""

    d_um: FloatArray
    tips: list[OneCameraPose] = field(default_factory=list)
    records: list[JournalRecord] = field(default_factory=list)

    @property
    def ok(self) -> np.ndarray:
        """(N,) bool: the poses whose tip was measured."""
        return np.array([t.found for t in self.tips], dtype=bool)

    @property
    def p_um(self) -> FloatArray:
        """(N, 3) µm in {M} (NaN where not found)."""
        return np.array([t.p_um for t in self.tips])

    @property
    def cov_um2(self) -> FloatArray:
        """(N, 3, 3) µm^2."""
        return np.array([t.cov_um2 for t in self.tips])

    def approach(self) -> dict[str, FloatArray]:
        """Each joint's approach direction per pose, by extra input name, (N,) each."""
        return {
            name: np.array([r.approach[extra_input(name).column] or 0.0 for r in self.records])
            for name in APPROACH_INPUTS
        }


def linear_map(
    d_um: FloatArray, p_um: FloatArray, sides: FloatArray | None = None
) -> Callable[[FloatArray, FloatArray], FloatArray]:
    """The least-squares ``p = L d + H s + o`` over poses (N >= 4), ``s`` each joint's
    approach side (+1 from below; a side's column enters once it varies); with more than 6
    poses, those further than :data:`MAP_OUTLIER_UM` from the first fit are left out and the
    map fitted again. Returns ``predict(d (3,), s (3,)) -> p (3,)``."""
    s_all = np.ones_like(d_um) if sides is None else np.asarray(sides, dtype=np.float64)
    varies = np.ptp(s_all, axis=0) > 0
    X = np.column_stack([d_um, s_all[:, varies], np.ones(len(d_um))])
    coef, *_ = np.linalg.lstsq(X, p_um, rcond=None)
    if len(d_um) > 6:
        keep = np.linalg.norm(X @ coef - p_um, axis=1) <= MAP_OUTLIER_UM
        if keep.sum() >= 5:
            coef, *_ = np.linalg.lstsq(X[keep], p_um[keep], rcond=None)

    def predict(d: FloatArray, s: FloatArray) -> FloatArray:
        x = np.concatenate([d, np.asarray(s, dtype=np.float64)[varies], [1.0]])
        out: FloatArray = x @ coef
        return out

    return predict


def acquire_one_camera(
    manipulator: Manipulator,
    clock: Clock,
    move_focus: Callable[[float], object],
    grab: Callable[[], Frame],
    finder: TipFinder,
    volume: WorkingVolume,
    poses: int,
    *,
    nominal_um_per_um: ArrayLike,
    start_um: ArrayLike = (0.0, 0.0, 0.0),
    start_px: ArrayLike | None = None,
    start_focus_um: float = 0.0,
    settle_s: float = 1.5,
    approach_um: float = 20.0,
    seed: int = 0,
    store: PoseStore | None = None,
    progress: Callable[[int, int], None] | None = None,
    done: Sequence[tuple[JournalRecord, OneCameraPose]] = (),
) -> OneCameraRun:
    """Acquire ``poses`` poses (the start, one step per joint, and the design; see the
    module docstring).

    Parameters
    ----------
    manipulator, clock :
        The device (its joints counted as the caller likes, e.g. from the start pose) and the
        rig's clock.
    move_focus, grab :
        The focus drive (``move_focus(z_um)``, from the side its backlash wants) and the
        camera (``grab()``: a frame or a region frame).
    finder : TipFinder
    volume : WorkingVolume
        Where the design's points lie, {M}.
    poses : int
        Poses in all (5 or more).
    nominal_um_per_um : (3, 3)
        The rig's nominal axes: the tip's move in {M} per µm of each joint (columns).
    start_um, start_px, start_focus_um :
        The start pose's joints, and where the tip is there: its image (the image centre by
        default) and the focus reading with it in focus.
    settle_s, approach_um, seed :
        The wait after the device reports stopped; the length of each pose's approach (0: go
        straight) and the seed of its sides and of the design.
    store : callable, optional
        ``store(record, tip)`` after each pose.
    progress : callable, optional
        ``progress(done, total)`` after each pose.
    done : sequence of (JournalRecord, OneCameraPose)
        The poses a stopped run stored, in order: taken as measured, not moved to again
        (nor stored again).

    Raises
    ------
    InputError
        Too few poses; the start pose's tip not found (where it was said to be); a stored
        pose that is not the one the design asks for there (the run's settings changed).
    """
    if poses < 5:
        raise InputError(f"one-camera acquisition: expected 5 poses or more, got {poses}")
    nominal = as_array(nominal_um_per_um, "nominal_um_per_um", (3, 3))
    start = as_array(start_um, "start_um", (3,))
    frame = finder.frame
    q0 = frame.centre_px if start_px is None else as_array(start_px, "start_px", (2,))
    p_start = frame.to_um(q0, start_focus_um)
    rng = np.random.default_rng([seed, 9283])
    run = OneCameraRun(np.zeros((0, 3)))
    commands: list[FloatArray] = []
    side_list: list[FloatArray] = []
    below = np.ones(3) if approach_um > 0 else np.zeros(3)

    def pose(d: FloatArray, sides: FloatArray, expected_um: FloatArray) -> OneCameraPose:
        k = len(commands) + 1
        if k <= len(done):
            return replay(d, sides, *done[k - 1])
        wall, t0 = time.time(), clock.now_s()
        if approach_um > 0:
            manipulator.move_to_um(d - sides * approach_um)
            manipulator.wait_until_stopped(clock)
        manipulator.move_to_um(d)
        manipulator.wait_until_stopped(clock)
        t1 = clock.now_s()
        clock.sleep(settle_s)
        side_list.append(sides.copy())
        commands.append(d.copy())
        status: PoseStatus = "ok"
        reason: str | None = None
        try:
            p, cov, n, secs = finder.measure(move_focus, grab, expected_um, clock.now_s)
        except (DetectionError, InputError, LimitError) as exc:
            status, reason = "failed", str(exc)
            p, cov, n, secs = np.full(3, np.nan), np.full((3, 3), np.nan), 0, 0.0
        tip = OneCameraPose(k, p, cov, n, secs)
        approach = {extra_input(a).column: (float(v) if v else None)
                    for a, v in zip(APPROACH_INPUTS, sides, strict=True)}  # fmt: skip
        record = JournalRecord(
            k, [float(v) for v in d], approach, status, wall, t0, t1 - t0, settle_s, None,
            reported_um=[float(v) for v in manipulator.position_um()], reason=reason,
        )  # fmt: skip
        run.tips.append(tip)
        run.records.append(record)
        if store is not None:
            store(record, tip)
        if progress is not None:
            progress(k, poses)
        return tip

    def replay(
        d: FloatArray, sides: FloatArray, record: JournalRecord, tip: OneCameraPose
    ) -> OneCameraPose:
        stored_sides = [record.approach.get(extra_input(a).column) or 0.0 for a in APPROACH_INPUTS]
        if not (np.allclose(record.commanded_um, d, rtol=0, atol=1e-6)
                and np.array_equal(stored_sides, sides)):  # fmt: skip
            raise InputError(
                f"one-camera acquisition: stored pose {record.pose} was {record.commanded_um} "
                f"µm, but the design asks for {d.tolist()} µm there: the run's settings "
                f"changed since it was stored; start a new run"
            )
        side_list.append(sides.copy())
        commands.append(np.array(record.commanded_um, dtype=np.float64))
        run.tips.append(tip)
        run.records.append(record)
        return tip

    first = pose(start.copy(), below, p_start)
    if not first.found:
        raise InputError(
            f"one-camera acquisition: no tip at the start pose where it was said to be "
            f"({q0[0]:.0f}, {q0[1]:.0f} px, focus {start_focus_um:.1f} µm): "
            f"{run.records[0].reason}"
        )
    for j in range(3):
        step = np.zeros(3)
        step[j] = STEP_UM
        pose(start + step, below, first.p_um + nominal @ step)
    targets = volume.draw(poses - 4, seed)
    targets = targets[np.argsort(np.linalg.norm(targets - first.p_um, axis=1))]
    for i, target in enumerate(targets):
        ok = run.ok
        # the first poses all come from below (the map learns the sides' effect later)
        sides = below if i < FROM_BELOW or approach_um <= 0 else rng.choice([-1.0, 1.0], 3)
        if ok.sum() >= 4:
            predict = linear_map(np.array(commands)[ok], run.p_um[ok], np.array(side_list)[ok])
            L = np.column_stack([predict(e, sides) - predict(np.zeros(3), sides)
                                 for e in np.eye(3)])  # fmt: skip
            d = np.linalg.solve(L, target - predict(np.zeros(3), sides))
        else:  # the steps were not all found: the nominal axes through the start
            d = start + np.linalg.solve(nominal, target - first.p_um)
            predict = None
        try:
            manipulator.check_limits(d)
        except LimitError:
            continue
        expected = predict(d, sides) if predict is not None else first.p_um + nominal @ (d - start)
        pose(d, sides, expected)
    run.d_um = np.array(commands)
    return run
