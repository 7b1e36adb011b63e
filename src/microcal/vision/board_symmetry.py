"""The symmetries of a planar target: turns of the board that its picture cannot tell apart.

A chessboard of COLS x ROWS inner corners has (COLS + 1) x (ROWS + 1) squares. Turned by
180 degrees in its plane about its centre, the grid of corners maps onto itself; the colours
of the squares do too when COLS + ROWS is even (both counts even or both odd). A square board
(COLS == ROWS) also maps onto itself turned by 90 degrees, with its colours when COLS is
even. A detector that sees such a board cannot know which end its numbering starts from:
two cameras (or two views of method (a)) may then number the same corners from opposite
ends. Odd x even chessboards, ChArUco boards and dot grids with marker dots have no such
ambiguity; other dot grids always have it (180 degrees, and 90 for square grids).

:func:`ambiguous_turns` lists the turns a target's picture cannot tell apart (the identity
first); :func:`turn_ids` the corner numbering each turn gives; :func:`turn_transform` the
rigid motion of the target's frame that the renumbering implies, so a board pose estimated
with one numbering converts to another without solving again.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from .targets import Target

__all__ = ["ambiguous_turns", "colour_decides", "turn_ids", "turn_transform"]


def _square(target: Target) -> bool:
    cols, rows = target.pattern_size
    return cols == rows


def colour_decides(target: Target, turn_deg: int) -> bool:
    """True if the squares' colours tell the board from itself turned by ``turn_deg``.

    Only chessboards have colours to tell by; for any other target it is False (ChArUco
    boards have no ambiguous turn at all: see :func:`ambiguous_turns`).
    """
    if target.kind != "chessboard" or turn_deg % 360 == 0:
        return False
    cols, rows = target.pattern_size
    if turn_deg % 180 == 0:
        return (cols + rows) % 2 == 1
    return cols % 2 == 1


def ambiguous_turns(target: Target, *, with_colour: bool = True) -> list[int]:
    """Turns (degrees, counter-clockwise in the target's frame) that map the pattern onto
    itself: ``[0]`` for an unambiguous target, else ``[0, 180]`` or ``[0, 90, 180, 270]``.

    Parameters
    ----------
    target : Target
    with_colour : bool
        Leave out the turns that the squares' colours tell apart (a detector that reads the
        colours, as :mod:`microcal.vision.detect` does, never confuses those).
    """
    if target.kind == "charuco" or target.markers:  # markers number a dot grid whole
        return [0]
    turns = [0, 90, 180, 270] if _square(target) else [0, 180]
    return [t for t in turns if t == 0 or not (with_colour and colour_decides(target, t))]


def turn_ids(target: Target, turn_deg: int) -> NDArray[np.intp]:
    """Feature numbering of the target turned by ``turn_deg`` about its centre.

    Returns
    -------
    ids : (N,) int
        Turning the target by ``turn_deg`` puts feature ``k`` where feature ``ids[k]`` was
        (see :func:`turn_transform`): relabelling a detection's feature ``k`` as ``ids[k]``
        expresses it in the numbering of the turned target.
    """
    cols, rows = target.pattern_size
    j, i = np.divmod(np.arange(cols * rows), cols)
    turn = turn_deg % 360
    if turn == 0:
        ni, nj = i, j
    elif turn == 180:
        ni, nj = cols - 1 - i, rows - 1 - j
    elif turn in (90, 270) and cols == rows:
        ni, nj = (cols - 1 - j, i) if turn == 90 else (j, cols - 1 - i)
    else:
        raise ValueError(
            f"turn_deg: expected 0 or 180 (90, 270 for a square target), got {turn_deg}"
        )
    return (nj * cols + ni).astype(np.intp)


def turn_transform(target: Target, turn_deg: int) -> tuple[FloatArray, FloatArray]:
    """The rigid motion ``(R, t)`` of the target frame with ``R p + t`` = the position of the
    feature ``turn_ids(target, turn_deg)[k]`` for feature ``k``'s position ``p``.

    Returns
    -------
    R : (3, 3) float
        A rotation about the target's z axis.
    t : (3,) float, µm
    """
    points = target.points_um()
    a = np.deg2rad(turn_deg % 360)
    c, s = np.cos(a), np.sin(a)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    ids = turn_ids(target, turn_deg)
    t: FloatArray = np.mean(points[ids] - points @ R.T, axis=0)
    return np.rint(R), t
