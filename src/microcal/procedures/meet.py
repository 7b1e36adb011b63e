"""The meet test: two calibrated tools sent to the same points of {G}, and how close they get.

For each target the first device is sent to it, then the second (to the target plus an
optional ``offset_um``), both open loop or both closed; then both end-effectors are measured
again by the cameras, and on the simulator by ground truth. The figure is the distance of
the second from the first plus the offset, ``|p2 - p1 - offset|``: by vision it is what
the cameras can tell, by truth what the tools really did. Open loop each tip carries its
own calibration's error, so the distance is about sqrt(2) times one device's absolute
accuracy; closed loop both tips are servoed onto the same camera measurement, whose errors
at one place are shared by both and cancel in the distance.

:func:`meet_targets_um` picks the targets: ISO 9283's cube poses P1-P5 in the part of {G}
that both devices reach.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, as_rows
from ..errors import DetectionError, InputError
from ..json_value import JsonValue
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..metrics.error_summary import ErrorSummary, summarize_errors
from .evaluation import iso_cube_poses
from .station import Station, check_frames

__all__ = ["MeetResult", "meet_targets_um", "meet_test"]


@dataclass(frozen=True)
class MeetResult:
    """What a meet test measured.

    Attributes
    ----------
    targets_um : (N, 3) float
        Where the first tip was sent, {G}.
    offset_um : (3,) float
    mode : {"open", "closed"}
    vision_um : (N,) float
        ``|p2 - p1 - offset|`` measured by the cameras (NaN where a tip was not found).
    truth_um : (N,) float or None
        The same by ground truth (simulator only).
    """

    targets_um: FloatArray
    offset_um: FloatArray
    mode: str
    vision_um: FloatArray
    truth_um: FloatArray | None

    def gap_summary(self, source: str) -> ErrorSummary | None:
        """The gap's figures by ``source`` (``vision`` or ``truth``) over the targets where it
        was measured; None where it was at none (or the source is not there)."""
        values = {"vision": self.vision_um, "truth": self.truth_um}.get(source)
        if values is None:
            return None
        ok = values[np.isfinite(values)]
        return summarize_errors(ok) if ok.size else None

    def as_dict(self) -> dict[str, JsonValue]:
        """Plain dict for results.json: the summaries and each target's distances."""
        out: dict[str, JsonValue] = {"mode": self.mode, "offset_um": self.offset_um.tolist(),
                                     "targets_um": self.targets_um.tolist()}  # fmt: skip
        for source, values in (("vision", self.vision_um), ("truth", self.truth_um)):
            if values is None:
                continue
            s = self.gap_summary(source)
            out[source] = {
                "mean_um": None if s is None else s.mean,
                "max_um": None if s is None else s.max,
                "distances_um": [None if not np.isfinite(v) else float(v) for v in values],
            }
        return out


def meet_targets_um(
    first: ManipulatorCalibration,
    second: ManipulatorCalibration,
    first_workspace_um: tuple[ArrayLike, ArrayLike],
    second_workspace_um: tuple[ArrayLike, ArrayLike],
) -> FloatArray:
    """ISO 9283's P1-P5 in the box of {G} both devices reach, (5, 3) µm.

    Each device's reach is the box of its model's positions at the eight corners of its
    joint workspace ((low, high) µm, for models with the joints as their only inputs; the
    others at their inputs' zero); the cube is the two boxes' overlap.

    Raises
    ------
    InputError
        The devices' reaches do not overlap.
    """
    boxes = []
    for cal, (low, high) in ((first, first_workspace_um), (second, second_workspace_um)):
        lo, hi = as_array(low, "low_um", (3,)), as_array(high, "high_um", (3,))
        corners = np.array([[(lo, hi)[b >> k & 1][k] for k in range(3)] for b in range(8)])
        u = np.hstack([corners, np.zeros((8, len(cal.model.extra_inputs)))])
        p = cal.model.predict_um(u)
        boxes.append((p.min(axis=0), p.max(axis=0)))
    low_g = np.maximum(boxes[0][0], boxes[1][0])
    high_g = np.minimum(boxes[0][1], boxes[1][1])
    if np.any(high_g <= low_g):
        raise InputError(
            f"meet: {first.name} and {second.name} reach no common part of {{G}} "
            f"(their boxes {np.round(boxes[0], 0).tolist()} and {np.round(boxes[1], 0).tolist()})"
        )
    return iso_cube_poses(low_g, high_g)


def meet_test(
    first: Station,
    second: Station,
    targets_um: ArrayLike,
    *,
    offset_um: ArrayLike = (0.0, 0.0, 0.0),
    mode: Literal["open", "closed"] = "open",
    progress: Callable[[int, int], None] | None = None,
    frames: int = 20,
) -> MeetResult:
    """Send both tips to each target (the second to target + offset) and measure the gap.

    Parameters
    ----------
    first, second : Station
        Two devices of one rig, calibrated in the same {G}.
    targets_um : (N, 3) float
    offset_um : (3,) float
    mode : {"open", "closed"}
    progress : callable (done, total), optional
    frames : int
        Frames per camera of each tip's measurement of the gap (the stations' own frames
        move them); the noise falls as 1 / sqrt(frames), so 20 halve that of 5.

    Raises
    ------
    InputError
        The same station twice, or two targets the cameras cannot tell apart.
    LimitError
        A target outside a device's soft limits (checked for all before anything moves).
    """
    if first is second:
        raise InputError("meet: first and second are the same station; give two devices")
    check_frames(frames, "meet")
    first.check_told_apart(second)
    targets = as_rows(targets_um, "targets_um", 3)
    offset = as_array(offset_um, "offset_um", (3,))
    truths = (first.rig.truth, second.rig.truth)
    with_truth = truths[0] is not None and truths[1] is not None
    vision = np.full(len(targets), np.nan)
    truth = np.full(len(targets), np.nan) if with_truth else None
    for target in targets:  # every target in reach of both before anything moves
        first.check_reach(target)
        second.check_reach(target + offset)
    for i, target in enumerate(targets):
        first.move_to_um(target, mode)
        second.move_to_um(target + offset, mode)
        try:
            p1, _ = first.where_um(frames)
            p2, _ = second.where_um(frames)
            vision[i] = float(np.linalg.norm(p2 - p1 - offset))
        except DetectionError:  # a tip out of view: that target's distance is unknown
            pass
        if truth is not None and truths[0] is not None and truths[1] is not None:
            truth[i] = float(np.linalg.norm(truths[1]() - truths[0]() - offset))
        if progress:
            progress(i + 1, len(targets))
    return MeetResult(targets, offset, mode, vision, truth)
