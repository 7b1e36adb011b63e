"""Calibration and end-effector targets: their geometry in their own plane.

Target specs are strings:

- ``chessboard:COLSxROWS:PITCH_UM``: COLS x ROWS *inner* corners, squares of PITCH µm
  (OpenCV's pattern size); the thesis's end-effector board is ``chessboard:4x3:400``.
- ``dotgrid:COLSxROWS:PITCH_UM[:DIAMETER_UM]``: a symmetric grid of dots (the thesis's
  chrome-on-glass target: pitch 125 µm, dots 62.5 µm, the default diameter pitch / 2).
- ``charuco:COLSxROWS:PITCH_UM[:MARKER_UM][:idFIRST]``: a ChArUco board of COLS x ROWS
  *squares* (OpenCV's convention), ArUco markers of the 4x4 dictionary (default size 0.7
  pitch) numbered from FIRST (default 0). Boards whose markers' numbers do not overlap are
  told apart in one image: give each device of a station its own (``charuco:5x4:400:id0``,
  ``charuco:5x4:400:id10``).
- ``dotgrid:COLSxROWS:PITCH_UM[:DIAMETER_UM]:markers=C,R/C,R/C,R``: a dot grid of which
  any part may be in view (a calibration slide that overfills the field), numbered from its
  hollow ("donut") marker dots at the given (column, row) positions of the grid, counted
  from 0 at the first dot, rows down the slide as printed. Three or more markers, placed so
  that no turn of the slide maps them onto themselves (an L with arms of different lengths:
  ``dotgrid:16x14:3500:1750:markers=4,8/9,8/4,5``). Dots found beyond the COLS x ROWS grid
  are left out; give the grid of the whole slide, or of the part that may be seen.
- ``chessboard:COLSxROWS:PITCH_UM:markers=C,R/C,R/C,R``: a chessboard of which any part may
  be in view, numbered from three circles printed inside squares (dark circles in light
  squares, light in dark; OpenCV's calibration pattern generator's "radon checkerboard"). The
  markers are given by their squares' (column, row) among the board's (COLS + 1) x (ROWS + 1)
  squares, counted from 0 at the top-left (border) square; square (C, R) lies between inner
  corners (C - 1, R - 1) and (C, R). They must be an L of neighbouring inner squares (a square
  and one neighbour along each axis: ``chessboard:30x24:250:markers=15,12/15,13/16,13``), the
  layout OpenCV's sector-based finder numbers a board from.
- ``tip[:KIND][:TAPER_DEG][:TIP_UM]``: not a board but a tool's tip (a pipette, a needle, a
  gripper jaw; :mod:`microcal.vision.tip_target`); :func:`parse_spec` reads every kind,
  :func:`parse_target` the boards alone.

The target frame: x along the columns, y along the rows, z = 0 on the target; the first
feature (inner corner or dot) is at the origin. On a chessboard the square between the first
four inner corners (corners 0, 1, COLS and COLS + 1) is the dark one: that fixes the origin
of an odd x even board whichever way it is seen (boards symmetric under a turn, see
:mod:`microcal.vision.board_symmetry`, are numbered as far as the picture can tell).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._validation import FloatArray
from ..errors import InputError
from .tip_target import TipTarget, is_tip_spec, parse_tip

__all__ = ["Target", "parse_spec", "parse_target"]

TargetKind = Literal["chessboard", "dotgrid", "charuco"]
_SPEC = re.compile(
    r"^(chessboard|dotgrid|charuco):(\d+)x(\d+):([0-9.]+)(?::([0-9.]+))?(?::id(\d+))?"
    r"(?::markers=([^:]*))?$",
    re.IGNORECASE,
)
#: Markers of the ArUco dictionary ChArUco boards use (4x4, 250 markers).
MARKERS = 250


@dataclass(frozen=True)
class Target:
    """A planar target.

    Attributes
    ----------
    kind : {"chessboard", "dotgrid", "charuco"}
    cols, rows : int
        Inner corners (chessboard), dots (dotgrid) or squares (charuco).
    pitch_um : float
        Square size or dot spacing, µm.
    feature_um : float
        Dot diameter (dotgrid) or marker size (charuco); 0 for a chessboard.
    first_marker : int
        The number of a ChArUco board's first marker (0 for the others).
    markers : tuple of (column, row)
        Grid positions of a dot grid's hollow marker dots (empty: the whole grid is in view
        and numbered from its top-left dot).
    """

    kind: TargetKind
    cols: int
    rows: int
    pitch_um: float
    feature_um: float = 0.0
    first_marker: int = 0
    markers: tuple[tuple[int, int], ...] = ()

    @property
    def spec(self) -> str:
        """The spec string this target parses from."""
        base = f"{self.kind}:{self.cols}x{self.rows}:{self.pitch_um:g}"
        base += f":{self.feature_um:g}" if self.kind != "chessboard" else ""
        base += f":id{self.first_marker}" if self.first_marker else ""
        return base + (f":markers={marker_text(self.markers)}" if self.markers else "")

    @property
    def partial(self) -> bool:
        """Whether any part of the target may be in view (numbered from its markers)."""
        return bool(self.markers)

    def marker_ids(self) -> np.ndarray:
        """The numbers of a ChArUco board's markers, (cols * rows // 2,) int (empty for the
        other kinds)."""
        n = self.cols * self.rows // 2 if self.kind == "charuco" else 0
        return np.arange(self.first_marker, self.first_marker + n, dtype=np.int32)

    def told_apart_from(self, other: Target) -> bool:
        """Whether a detection of this target can never be of ``other`` when both are in one
        image: two ChArUco boards whose markers' numbers do not overlap."""
        if self.kind != "charuco" or other.kind != "charuco":
            return False
        return not set(self.marker_ids().tolist()) & set(other.marker_ids().tolist())

    @property
    def pattern_size(self) -> tuple[int, int]:
        """(cols, rows) of the detected features: inner corners or dots."""
        if self.kind == "charuco":
            return (self.cols - 1, self.rows - 1)
        return (self.cols, self.rows)

    def points_um(self) -> FloatArray:
        """Feature positions in the target frame, row by row (x fastest), (N, 3) µm.

        Inner corners for chessboards and ChArUco boards, dot centres for dot grids; in the
        order OpenCV's detectors return them for an unrotated view.
        """
        c, r = self.pattern_size
        gx, gy = np.meshgrid(np.arange(c) * self.pitch_um, np.arange(r) * self.pitch_um)
        return np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])

    def extent_um(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the printed pattern in the target frame."""
        p = self.pitch_um
        c, r = self.pattern_size
        if self.kind == "dotgrid":
            m = self.feature_um
            return (-m, (c - 1) * p + m, -m, (r - 1) * p + m)
        return (-p, c * p, -p, r * p)

    @property
    def centre_um(self) -> FloatArray:
        """Mean of the feature positions (the virtual point of Eq 4.13 for a chessboard)."""
        out: FloatArray = self.points_um().mean(axis=0)
        return out


def marker_text(markers: tuple[tuple[int, int], ...]) -> str:
    """The ``markers=`` value of a spec: ``C,R/C,R/...``."""
    return "/".join(f"{c},{r}" for c, r in markers)


#: The four turns of the grid in its plane (integer rotations of (column, row)).
_TURNS = (((1, 0), (0, 1)), ((0, -1), (1, 0)), ((-1, 0), (0, -1)), ((0, 1), (-1, 0)))


def marker_turn_symmetry(markers: tuple[tuple[int, int], ...]) -> int:
    """The smallest turn (degrees, 90, 180 or 270) that maps the markers onto themselves,
    0 when none does (the markers then fix the numbering)."""
    pts = np.array(markers, dtype=int)
    for k, turn in enumerate(_TURNS[1:], start=1):
        moved = pts @ np.array(turn).T
        moved = moved - moved.min(axis=0) + pts.min(axis=0)
        if {tuple(p) for p in moved.tolist()} == {tuple(p) for p in pts.tolist()}:
            return 90 * k
    return 0


def _parse_markers(spec: str, text: str, cols: int, rows: int) -> tuple[tuple[int, int], ...]:
    example = "markers=2,5/7,5/2,2"
    items = [t.strip() for t in text.split("/")]
    out: list[tuple[int, int]] = []
    for item in items:
        m = re.fullmatch(r"(\d+),(\d+)", item)
        if not m:
            raise InputError(
                f"target {spec!r}: expected markers=C,R/C,R/... (column, row of each hollow "
                f"dot, from 0), e.g. {example}; got {item!r}"
            )
        c, r = int(m.group(1)), int(m.group(2))
        if c >= cols or r >= rows:
            raise InputError(
                f"target {spec!r}: marker {c},{r} is outside the {cols}x{rows} grid (columns "
                f"0-{cols - 1}, rows 0-{rows - 1})"
            )
        out.append((c, r))
    if len(set(out)) != len(out):
        raise InputError(f"target {spec!r}: a marker position is given twice")
    if len(out) < 3:
        raise InputError(
            f"target {spec!r}: expected 3 or more marker dots (two look the same turned by "
            f"180 degrees), e.g. {example}"
        )
    turn = marker_turn_symmetry(tuple(out))
    if turn:
        raise InputError(
            f"target {spec!r}: the markers look the same turned by {turn} degrees, so they "
            f"cannot number the grid; place them as an L with arms of different lengths, "
            f"e.g. {example}"
        )
    return tuple(out)


def _parse_square_markers(
    spec: str, text: str, cols: int, rows: int
) -> tuple[tuple[int, int], ...]:
    """A chessboard's three marker circles: (column, row) of their squares, an L of
    neighbouring squares (the layout OpenCV's sector-based finder numbers a board from)."""
    example = "markers=4,3/4,4/5,4"
    out: list[tuple[int, int]] = []
    for item in (t.strip() for t in text.split("/")):
        m = re.fullmatch(r"(\d+),(\d+)", item)
        if not m:
            raise InputError(
                f"target {spec!r}: expected markers=C,R/C,R/C,R (column, row of each square "
                f"with a circle, from 0), e.g. {example}; got {item!r}"
            )
        c, r = int(m.group(1)), int(m.group(2))
        if not (1 <= c <= cols - 1 and 1 <= r <= rows - 1):
            raise InputError(
                f"target {spec!r}: marker square {c},{r} is outside the board's inner squares "
                f"(columns 1-{cols - 1}, rows 1-{rows - 1} of its {cols + 1}x{rows + 1} squares)"
            )
        out.append((c, r))
    if len(set(out)) != len(out):
        raise InputError(f"target {spec!r}: a marker square is given twice")
    if len(out) != 3:
        raise InputError(
            f"target {spec!r}: a chessboard takes exactly 3 marker circles (OpenCV's layout), "
            f"got {len(out)}, e.g. {example}"
        )
    if _l_corner(tuple(out)) is None:
        raise InputError(
            f"target {spec!r}: OpenCV numbers a chessboard from 3 circles in an L of "
            f"neighbouring squares (a square and one neighbour along each axis), e.g. {example}"
        )
    return tuple(out)


def _l_corner(markers: tuple[tuple[int, int], ...]) -> tuple[int, int] | None:
    """The square of an L of three neighbouring squares that touches both others (None
    when the three are not such an L)."""
    for c, r in markers:
        others = [(a - c, b - r) for a, b in markers if (a, b) != (c, r)]
        if len(others) == 2 and sorted(abs(a) + 2 * abs(b) for a, b in others) == [1, 2]:
            return (c, r)
    return None


#: More features than this is a typing slip, not a target (a 1000 x 1000 dot grid).
MAX_FEATURES = 1_000_000


def parse_target(spec: str) -> Target:
    """Parse a target spec string (see the module docstring).

    Raises
    ------
    InputError
        A one-line message with the expected form.
    """
    m = _SPEC.match(spec.strip())
    if not m and is_tip_spec(spec):
        raise InputError(
            f"target {spec!r}: a tool's tip, not a board; this needs a board such as "
            f"chessboard:4x3:400"
        )
    if not m:
        raise InputError(
            f"target {spec!r}: expected KIND:COLSxROWS:PITCH_UM with KIND chessboard, dotgrid "
            f"or charuco, e.g. chessboard:4x3:400 (charuco:5x4:400:id10: markers from 10; "
            f"dotgrid:16x14:3500:1750:markers=4,8/9,8/4,5: a slide numbered from hollow dots)"
        )
    kind = m.group(1).lower()
    cols, rows = int(m.group(2)), int(m.group(3))
    try:
        pitch = float(m.group(4))
        feature = float(m.group(5)) if m.group(5) else 0.0
    except ValueError:
        raise InputError(f"target {spec!r}: the pitch and feature size must be numbers") from None
    if pitch <= 0:
        raise InputError(f"target {spec!r}: expected a pitch > 0 µm, got {pitch:g}")
    minimum = 2 if kind == "dotgrid" else 3  # OpenCV's chessboard finders need 3 x 3
    if cols < minimum or rows < minimum:
        raise InputError(
            f"target {spec!r}: expected at least {minimum}x{minimum}, got {cols}x{rows}"
        )
    if cols * rows > MAX_FEATURES:
        raise InputError(
            f"target {spec!r}: {cols}x{rows} features is more than a target has (at most "
            f"{MAX_FEATURES}); give its columns and rows of inner corners or dots"
        )
    if kind == "chessboard" and feature:
        raise InputError(f"target {spec!r}: a chessboard takes no feature size")
    if kind == "dotgrid":
        feature = feature or pitch / 2
        if not 0 < feature < pitch:
            raise InputError(
                f"target {spec!r}: expected a dot diameter below the pitch {pitch:g} µm"
            )
    first = int(m.group(6)) if m.group(6) else 0
    if m.group(6) and kind != "charuco":
        raise InputError(f"target {spec!r}: only a charuco board numbers its markers (:idN)")
    if kind == "charuco":
        feature = feature or 0.7 * pitch
        if not 0 < feature < pitch:
            raise InputError(
                f"target {spec!r}: expected a marker size below the pitch {pitch:g} µm"
            )
        if first + cols * rows // 2 > MARKERS:
            raise InputError(
                f"target {spec!r}: its {cols * rows // 2} markers from {first} pass the "
                f"dictionary's {MARKERS}; give a first marker of at most "
                f"{MARKERS - cols * rows // 2}"
            )
    markers: tuple[tuple[int, int], ...] = ()
    if m.group(7) is not None:
        if kind == "charuco":
            raise InputError(
                f"target {spec!r}: a charuco board is numbered by its own codes; markers=... "
                f"is for a dot grid's hollow dots or a chessboard's circles"
            )
        if kind == "chessboard":
            markers = _parse_square_markers(spec, m.group(7), cols, rows)
        else:
            markers = _parse_markers(spec, m.group(7), cols, rows)
    return Target(kind, cols, rows, pitch, feature, first, markers)  # type: ignore[arg-type]


def parse_spec(spec: str) -> Target | TipTarget:
    """Parse any target spec: a board (:func:`parse_target`) or a tool's tip
    (:func:`~microcal.vision.tip_target.parse_tip`).

    Raises
    ------
    InputError
        A one-line message with the expected form.
    """
    return parse_tip(spec) if is_tip_spec(spec) else parse_target(spec)
