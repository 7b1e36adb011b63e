"""``microcal find-tip``: find a new tool on a rig and centre its tip in a camera.

Opens the rig, runs :func:`~microcal.procedures.find_tip.find_tip` with the rig's
manipulator and one camera (the first unless named), and sees where the tip is in the other
cameras. It moves no focus drive, so the tip is centred but not focused (a rig of one camera
on a focus drive is refused: its acquisition finds the tip by focus). A tool
that is not found, or a search stopped by a soft limit, leaves the manipulator where it
began.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from .._validation import FloatArray
from ..errors import InputError, LimitError
from ..formats.rig_file import load_rig
from ..procedures.find_tip import TipSearch, find_tip
from ..vision.targets import parse_spec
from ..vision.tip import detect_tip
from ..vision.tip_target import TipTarget
from .one_camera_station import is_one_camera
from .options import rig_with_seed
from .rigs import open_rig

__all__ = ["FoundTip", "find_tool_tip"]


@dataclass(frozen=True)
class FoundTip:
    """What ``microcal find-tip`` found.

    Attributes
    ----------
    search : TipSearch
    camera : str
        The camera the tip was centred in.
    seen_px : dict of str -> (2,) float
        The tip's apex in every camera that sees it at the end.
    """

    search: TipSearch
    camera: str
    seen_px: dict[str, FloatArray] = field(default_factory=dict)


def find_tool_tip(
    rig: str | os.PathLike[str] = "sim",
    *,
    manipulator: str | None = None,
    seed: int | None = None,
    camera: str | None = None,
    tip: str = "tip",
    field_um: float = 1000.0,
    reach_um: float = 2000.0,
    jog_um: float = 50.0,
) -> FoundTip:
    """Find the tool's tip on the rig and centre it in ``camera`` (see the module).

    Raises
    ------
    InputError
        ``tip`` not a tip spec, a camera the rig does not have, a rig of one camera on a
        focus drive (its tip is found by focus: ``acquire --scope``).
    """
    target = parse_spec(tip)
    if not isinstance(target, TipTarget):
        raise InputError(f"--tip {tip}: is a board; expected a tool's tip (tip, tip:needle)")
    spec = rig_with_seed(load_rig(str(rig)), seed)
    with open_rig(spec, manipulator) as opened:
        if is_one_camera(opened):
            raise InputError(
                "find-tip looks for a tool that moves in a stereo rig's views; on a rig of one "
                "camera on a focus drive, put the tip in focus at the field's centre and run "
                "microcal acquire --scope scope.json (it finds the tip by a focus sweep)"
            )
        names = list(opened.cameras)
        name = camera or names[0]
        if name not in opened.cameras:
            raise InputError(f"--camera {name}: the rig's cameras are {', '.join(names)}")
        cam, man, clock = opened.cameras[name], opened.manipulator, opened.clock
        start = np.asarray(man.position_um(), dtype=np.float64).copy()

        def move_to(d: FloatArray) -> None:
            man.check_limits(d)
            man.move_to_um(d)
            man.wait_until_stopped(clock)

        try:
            search = find_tip(move_to, lambda: np.asarray(man.position_um(), dtype=np.float64),
                              cam.grab, target, image_size_px=_size(cam.grab()),
                              field_um=field_um, reach_um=reach_um, jog_um=jog_um)  # fmt: skip
        except LimitError as exc:
            man.move_to_um(start)
            man.wait_until_stopped(clock)
            nan = np.full(2, np.nan)
            search = TipSearch(False, start, nan, np.full((2, 2), np.nan), 0,
                               f"the search reached a soft limit ({exc})")  # fmt: skip
        seen: dict[str, FloatArray] = {}
        if search.found:
            for n, other in opened.cameras.items():
                det = detect_tip(other.grab(), target)
                if det.found:
                    seen[n] = det.apex_px
    return FoundTip(search, name, seen)


def _size(frame: np.ndarray) -> tuple[int, int]:
    h, w = frame.shape[:2]
    return int(w), int(h)
