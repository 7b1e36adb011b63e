"""Finding a new tool: move it a little, find what moved, home in on its tip and centre it.

A tool just mounted is somewhere near the field, perhaps outside it. The search:

1. looks for the tip where the tool is (:func:`~microcal.vision.tip.detect_tip`); when it is
   not in the field, the tool is moved along a square spiral in the image plane's joints, a
   field's width a step, until its tip is seen or the search's reach is spent;
2. with the tip in view, jogs each joint of the plane a little back and forth and sees where
   the tip goes: the image's Jacobian (px per µm of each joint);
3. moves the tip to the image's centre through that Jacobian, again until it is within a
   pixel (or a few steps are spent).

A tool that cannot be found is put back where it began. The procedure works on callables
(move, read the position, grab a frame), so it serves a simulated and a real rig alike.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..vision.tip import TipDetection, detect_tip
from ..vision.tip_target import TipTarget

__all__ = ["TipSearch", "find_tip"]


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
        The small moves that measure the image's Jacobian.
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

    nan2 = np.full(2, np.nan)
    det = detect_tip(grab(), target)
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
            det = at(here)
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
    for _ in range(5):
        if not seen.found:
            break
        miss = centre - seen.apex_px
        if float(np.hypot(*miss)) <= tolerance_px:
            break
        here = here.copy()
        here[list(plane)] += np.linalg.solve(J, miss)
        seen = at(here)
    if not seen.found:
        move_to(start)
        return TipSearch(False, start, nan2, J, moves + 1,
                         f"the tip was lost while centring: {seen.reason}")  # fmt: skip
    return TipSearch(True, np.asarray(position(), dtype=np.float64), seen.apex_px, J, moves)
