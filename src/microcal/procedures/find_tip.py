"""Finding a new tool: move it a little, find what moved, home in on its tip and centre it.

A tool just mounted is somewhere near the field, perhaps outside it. The search:

1. looks where the tool is: jogs the plane's joints a little forward and back and
   takes what changed between the frames (:func:`moved_box`) as the tool; its tip
   (:func:`~microcal.vision.tip.detect_tip`) counts only where something moved, so a
   tool-like edge that stands still (a board, debris) is never taken for it. When nothing
   moved in the field, the tool is moved along a square spiral in the image plane's joints, a
   field's width a step, and looked for again, until its tip is seen or the search's reach
   is spent;
2. with the tip in view, jogs each joint of the plane a little back and forth and sees where
   the tip goes: the image's Jacobian (px per µm of each joint);
3. moves the tip to the image's centre through that Jacobian, again until it is within a
   pixel (or :data:`CENTRING_STEPS` are spent), the Jacobian refined by each step (Broyden).

A tool that cannot be found is put back where it began. The procedure works on callables
(move, read the position, grab a frame), so it serves a simulated and a real rig alike.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..vision.tip import TipDetection, detect_tip
from ..vision.tip_target import TipTarget

__all__ = ["BROYDEN_MIN_PX", "CENTRING_STEPS", "MOVED_LEVELS", "TipSearch", "find_tip", "moved_box"]

#: The centring's steps at most (each refines the image's Jacobian by what it moved).
CENTRING_STEPS = 8

#: A centring step refines the Jacobian when it was meant to move the tip this far, px.
BROYDEN_MIN_PX = 10.0

#: A pixel moved when its change between two frames exceeds this many times the frames'
#: typical change (the median absolute difference, noise).
MOVED_LEVELS = 6.0


@dataclass(frozen=True)
class TipSearch:
    """What the search found.

    Attributes
    ----------
    found : bool
    joints_um : (k,) float
        Where the manipulator is now (the tip centred, or where it began).
    apex_px : (2,) float
        The tip in the image at the end (NaN when not found).
    jacobian_px_per_um : (2, 2) float
        The image's motion per µm of the two joints of the plane (NaN when not found).
    moves : int
        Moves made.
    reason : str
        Why it was not found ("" when found).
    """

    found: bool
    joints_um: FloatArray
    apex_px: FloatArray
    jacobian_px_per_um: FloatArray
    moves: int
    reason: str = ""


def _spiral(n: int) -> list[tuple[int, int]]:
    """The first ``n`` cells of a square spiral around (0, 0), (0, 0) excluded."""
    out: list[tuple[int, int]] = []
    x = y = 0
    dx, dy = 1, 0
    run = 1
    while len(out) < n:
        for _ in range(2):
            for _ in range(run):
                x, y = x + dx, y + dy
                out.append((x, y))
                if len(out) == n:
                    return out
            dx, dy = -dy, dx
        run += 1
    return out


def moved_box(
    before: NDArray[np.generic], after: NDArray[np.generic], *, min_px: int = 12
) -> tuple[int, int, int, int] | None:
    """The box (x0, y0, x1, y1), end exclusive, around what changed between two frames (a
    tool jogged between them), or None when nothing did.

    A pixel changed when the frames' difference, averaged over 3 x 3, exceeds
    :data:`MOVED_LEVELS` times its robust standard deviation (1.4826 times its median
    absolute deviation: the noise); the box holds the changed pixels once there are
    ``min_px`` of them.
    """
    a = np.asarray(before, dtype=np.float32)
    b = np.asarray(after, dtype=np.float32)
    diff = cv2.blur(b - a, (3, 3))
    centre = float(np.median(diff))
    sigma = 1.4826 * float(np.median(np.abs(diff - centre)))
    level = max(sigma, 1e-3 * max(float(np.ptp(a)), 1.0))
    rows, cols = np.nonzero(np.abs(diff - centre) > MOVED_LEVELS * level)
    if len(rows) < min_px:
        return None
    return int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1


def find_tip(
    move_to: Callable[[FloatArray], None],
    position: Callable[[], FloatArray],
    grab: Callable[[], NDArray[np.generic]],
    target: TipTarget,
    *,
    image_size_px: tuple[int, int],
    field_um: float,
    plane: tuple[int, int] = (0, 1),
    reach_um: float = 400.0,
    jog_um: float = 10.0,
    tolerance_px: float = 1.0,
) -> TipSearch:
    """Find the tool's tip and centre it (see the module docstring).

    Parameters
    ----------
    move_to, position, grab : callables
        Move the manipulator to joints (µm) and wait; read its joints; grab a frame.
    target : TipTarget
    image_size_px : (int, int)
        The frame's width and height.
    field_um : float
        The field's width in the object, µm (a step of the spiral).
    plane : (int, int)
        The joints that move the tool across the image.
    reach_um : float
        How far from where it began the search goes.
    jog_um : float
        The small moves that show what moved and measure the image's Jacobian (a few pixels
        at least).
    tolerance_px : float
        How near the centre the tip is put.
    """
    start = np.asarray(position(), dtype=np.float64).copy()
    moves = 0

    def at(joints: FloatArray) -> TipDetection:
        nonlocal moves
        move_to(joints)
        moves += 1
        return detect_tip(grab(), target)

    def look(joints: FloatArray, first: bool = False) -> TipDetection:
        """The tip at ``joints`` where something moved when the tool was jogged there."""
        nonlocal moves
        if not first:
            move_to(joints)
            moves += 1
        before = grab()
        jogged = joints.copy()
        jogged[list(plane)] += jog_um  # across the image whatever the tool's direction
        move_to(jogged)
        after = grab()
        move_to(joints)
        moves += 2
        box = moved_box(before, after)
        if box is None:
            return TipDetection.none("nothing moved in the field")
        det = detect_tip(before, target)  # the tool is back where this frame saw it
        if not det.found:
            return det
        x, y = det.apex_px
        pad = 8.0
        if not (box[0] - pad <= x <= box[2] + pad and box[1] - pad <= y <= box[3] + pad):
            return TipDetection.none("the tip seen does not move with the manipulator")
        return det

    nan2 = np.full(2, np.nan)
    det = look(start, first=True)
    here = start.copy()
    if not det.found:
        step = 0.8 * field_um
        cells = int((2 * reach_um / step + 1) ** 2)
        for i, j in _spiral(cells):
            if max(abs(i), abs(j)) * step > reach_um:
                continue
            here = start.copy()
            here[plane[0]] += i * step
            here[plane[1]] += j * step
            det = look(here)
            if det.found:
                break
    if not det.found:
        move_to(start)
        return TipSearch(False, start, nan2, np.full((2, 2), np.nan), moves + 1,
                         f"no tool's tip within {reach_um:g} µm: {det.reason}")  # fmt: skip
    # The image's Jacobian from a jog of each joint of the plane.
    J = np.zeros((2, 2))
    for col, joint in enumerate(plane):
        jogged = here.copy()
        jogged[joint] += jog_um
        seen = at(jogged)
        if not seen.found:
            jogged[joint] -= 2 * jog_um
            seen = at(jogged)
            if not seen.found:
                move_to(start)
                return TipSearch(False, start, nan2, np.full((2, 2), np.nan), moves + 1,
                                 f"the tip was lost while jogging: {seen.reason}")  # fmt: skip
        J[:, col] = (seen.apex_px - det.apex_px) / (jogged[joint] - here[joint])
    if abs(np.linalg.det(J)) < 1e-9:
        move_to(start)
        return TipSearch(False, start, nan2, J, moves + 1,
                         "the tip does not move across the image with these joints")  # fmt: skip
    centre = (np.asarray(image_size_px, dtype=np.float64) - 1.0) / 2.0
    seen = at(here)
    for _ in range(CENTRING_STEPS):
        if not seen.found:
            break
        miss = centre - seen.apex_px
        if float(np.hypot(*miss)) <= tolerance_px:
            break
        step_um = np.linalg.solve(J, miss)
        here = here.copy()
        here[list(plane)] += step_um
        before = seen.apex_px
        seen = at(here)
        if seen.found and float(np.hypot(*(J @ step_um))) > BROYDEN_MIN_PX:
            # Broyden's update: the Jacobian learns from each long step what the jogs missed
            # (a short one would teach it the apex's noise)
            moved = seen.apex_px - before
            J = J + np.outer(moved - J @ step_um, step_um) / float(step_um @ step_um)
    if not seen.found:
        move_to(start)
        return TipSearch(False, start, nan2, J, moves + 1,
                         f"the tip was lost while centring: {seen.reason}")  # fmt: skip
    return TipSearch(True, np.asarray(position(), dtype=np.float64), seen.apex_px, J, moves)
