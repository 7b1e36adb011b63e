"""Synthetic camera-calibration image sets with known truth (library code).

A printed chessboard (or ChArUco board) photographed by an ordinary wide-angle camera, in
many poses, the way one collects images to calibrate a camera: the board is held at random
distances and tilts, its image spread over the whole picture (or kept near the centre), now
and then turned by 180 degrees in its plane. The images are rendered with the simulator's
renderer (:func:`microcal.sim.render.render_placement`: lens distortion, box-filtered
anti-aliasing), blurred, given Gaussian noise and quantised to 8 bits; the true cameras, board
poses and corner positions come with them.

- :func:`render_calibration_views`: one camera, :class:`CalibrationViews`;
- :func:`render_stereo_calibration_views`: a rig of two or more cameras seeing the same board
  poses, :class:`StereoCalibrationViews`;
- :func:`wide_angle_camera`, :func:`wide_angle_stereo_pair`: a strongly distorted 640 x 480
  camera (like a Point Grey Bumblebee2) and a stereo pair of two of them.

Units are µm and pixels throughout, pixel centres at integer coordinates (OpenCV's
convention). See ``docs/simulator.md``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..errors import InputError
from ..geometry.camera_model import CameraModel
from ..vision.targets import Target
from .render import Placement, Reflectance, render_placement
from .slide_render import render_slide

__all__ = [
    "CalibrationViews",
    "StereoCalibrationViews",
    "render_calibration_views",
    "render_stereo_calibration_views",
    "wide_angle_camera",
    "wide_angle_stereo_pair",
]

Spread = Literal["wide", "centre"]
UInt8Image = NDArray[np.uint8]

#: Subsamples per pixel side of the renderer.
_SUPERSAMPLE = 4
#: Grey level of reflectance 1 (white paper at 0.85 reads 217, the black squares 20).
_FULL_SCALE = 255.0
#: Clearance between the board's edge and the image's edge, as a fraction of the shorter side.
_EDGE_FRACTION = 0.03
#: Square sizes drawn (log-uniformly), as fractions of the size at which the board (pattern
#: and white margin) would just fill the image face-on, by where the board is aimed: a board
#: wholly in view near a corner of the picture has to be smaller. On a 640 x 480 camera the
#: centre's range is 27-54 px for a 7 x 5 board, 24-48 px for a 9 x 6 board.
_SQUARE_FRACTION = {"corner": (0.22, 0.36), "edge": (0.33, 0.66), "centre": (0.45, 0.9)}
#: Rotation of the board about its normal (besides a 180 degree turn), degrees at most.
_ROLL_DEG = 10.0
#: Points per side of the board's outline checked against the image's edges.
_OUTLINE_POINTS = 16


@dataclass(frozen=True, eq=False)
class CalibrationViews:
    """Calibration images of one camera with their truth.

    Attributes
    ----------
    images : list of (H, W) uint8
        One image per view, grey levels 0-255.
    corners_px : list of (N, 2) float
        True pixel position of every target point (``target.points_um()``, in that order: the
        target's own numbering, also in views turned by 180 degrees), as the camera projects
        it, lens distortion included.
    board_R : (V, 3, 3) float
        Board pose per view in the world frame {G}: ``p_G = board_R[v] @ p_target +
        board_t_um[v]`` (a :class:`~microcal.sim.render.Placement`). The camera's own pose is
        in ``camera``; for :func:`wide_angle_camera` {G} is the camera frame.
        :meth:`board_in_camera` gives the pose in the camera frame.
    board_t_um : (V, 3) float
        Board translation per view in {G}, µm.
    camera : CameraModel
        The true camera.
    target : Target
        The board.
    rotated_180 : list of bool
        Views in which the board is turned by 180 degrees in its plane about its centre
        (relative to the pose it was drawn in); the pose above includes the turn.
    blur_px : float
        Standard deviation of the Gaussian blur applied, px.
    noise : float
        Standard deviation of the Gaussian noise added, grey levels of 255.
    """

    images: list[UInt8Image]
    corners_px: list[FloatArray]
    board_R: FloatArray  # noqa: N815 (R, as in the thesis and Placement)
    board_t_um: FloatArray
    camera: CameraModel
    target: Target
    rotated_180: list[bool]
    blur_px: float
    noise: float

    @property
    def n_views(self) -> int:
        """Number of views V."""
        return len(self.images)

    @property
    def cameras(self) -> dict[str, CameraModel]:
        """The true camera by its name, ``{camera.name: camera}``."""
        return {self.camera.name: self.camera}

    def placement(self, view: int) -> Placement:
        """The board of view ``view`` as a :class:`~microcal.sim.render.Placement` in {G}."""
        return Placement(self.target, self.board_R[view], self.board_t_um[view])

    def board_in_camera(self, view: int) -> tuple[FloatArray, FloatArray]:
        """Board pose of view ``view`` in the camera frame.

        Returns
        -------
        R : (3, 3) float
        t_um : (3,) float
            ``p_camera = R @ p_target + t_um``, µm (OpenCV's rvec and tvec of the view).
        """
        return _in_camera(self.camera, self.board_R[view], self.board_t_um[view])


@dataclass(frozen=True, eq=False)
class StereoCalibrationViews:
    """Calibration images of a rig of cameras that see the same board poses.

    Attributes
    ----------
    images : dict of str to list of (H, W) uint8
        Per camera name, one image per view.
    corners_px : dict of str to list of (N, 2) float
        Per camera name, the true pixel positions of the target points in each view (the
        target's own numbering, lens distortion included).
    board_R : (V, 3, 3) float
        Board pose per view in the world frame {G} the cameras are given in:
        ``p_G = board_R[v] @ p_target + board_t_um[v]``.
    board_t_um : (V, 3) float
        Board translation per view in {G}, µm.
    cameras : dict of str to CameraModel
        The true cameras, in {G}.
    target : Target
    rotated_180 : list of bool
        Views in which the board is turned by 180 degrees in its plane (see
        :class:`CalibrationViews`).
    blur_px : float
        Gaussian blur, px.
    noise : float
        Gaussian noise, grey levels of 255.
    """

    images: dict[str, list[UInt8Image]]
    corners_px: dict[str, list[FloatArray]]
    board_R: FloatArray  # noqa: N815 (R, as in the thesis and Placement)
    board_t_um: FloatArray
    cameras: dict[str, CameraModel]
    target: Target
    rotated_180: list[bool]
    blur_px: float
    noise: float

    @property
    def n_views(self) -> int:
        """Number of views V (the same for every camera)."""
        return int(self.board_R.shape[0])

    def placement(self, view: int) -> Placement:
        """The board of view ``view`` as a :class:`~microcal.sim.render.Placement` in {G}."""
        return Placement(self.target, self.board_R[view], self.board_t_um[view])

    def for_camera(self, name: str) -> CalibrationViews:
        """The views of one camera, as a single-camera set.

        Raises
        ------
        InputError
            If the rig has no camera of that name.
        """
        if name not in self.cameras:
            raise InputError(f"camera: expected one of {sorted(self.cameras)}, got {name!r}")
        return CalibrationViews(
            images=self.images[name],
            corners_px=self.corners_px[name],
            board_R=self.board_R,
            board_t_um=self.board_t_um,
            camera=self.cameras[name],
            target=self.target,
            rotated_180=self.rotated_180,
            blur_px=self.blur_px,
            noise=self.noise,
        )


# --- cameras --------------------------------------------------------------------------------


def wide_angle_camera(
    name: str = "left",
    *,
    fx: float = 525.0,
    fy: float = 527.0,
    cx: float = 320.0,
    cy: float = 245.0,
    dist: Sequence[float] = (-0.37, 0.24, 5e-4, -5e-4, -0.13),
    image_size_px: tuple[int, int] = (640, 480),
    R: FloatArray | None = None,
    t_um: FloatArray | None = None,
) -> CameraModel:
    """An ordinary wide-angle camera with strong barrel distortion (like a Bumblebee2).

    A field of view of about 71 x 54 degrees (63 x 49 for the pinhole alone): the distortion
    moves the middles of the side edges by 50 px and points near the image corners by some
    100 px.
    The polynomial model folds over just inside the image corners (beyond a normalised radius
    of about 0.745): the outermost few pixels of each corner see no point of the scene.

    Parameters
    ----------
    name : str
    fx, fy, cx, cy : float
        Focal lengths and principal point, px.
    dist : (5,) float
        k1, k2, p1, p2, k3 (OpenCV's order).
    image_size_px : (int, int)
        Width and height.
    R : (3, 3) float, optional
        Rotation from {G} to the camera frame; the identity by default.
    t_um : (3,) float, optional
        ``p_camera = R p_G + t_um``, µm; zero by default (the camera frame is {G}).

    Returns
    -------
    CameraModel
    """
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return CameraModel(
        K,
        np.asarray(dist, dtype=np.float64),
        np.eye(3) if R is None else np.asarray(R, dtype=np.float64),
        np.zeros(3) if t_um is None else np.asarray(t_um, dtype=np.float64),
        image_size_px,
        name,
    )


def wide_angle_stereo_pair(
    baseline_um: float = 120_000.0,
    *,
    right_rotation_deg: Sequence[float] = (0.3, -0.5, 0.2),
) -> dict[str, CameraModel]:
    """A stereo pair of two wide-angle cameras, side by side and (nearly) parallel.

    The left camera is :func:`wide_angle_camera` at the origin looking along +z (its frame is
    {G}); the right one sits ``baseline_um`` to its +x, looking along +z too but for a small
    misalignment, with slightly different intrinsics and distortion (a second unit of the same
    lens). Both see a board 0.4-1 m in front of them.

    Parameters
    ----------
    baseline_um : float
        Distance between the projection centres, µm (> 0).
    right_rotation_deg : (3,) float
        Rotation vector of the right camera relative to the left one, degrees (about its x,
        y and z axes).

    Returns
    -------
    dict of str to CameraModel
        ``{"left": ..., "right": ...}``, both in {G}.

    Raises
    ------
    InputError
        If the baseline is not a positive number.
    """
    b = float(baseline_um)
    if not (np.isfinite(b) and b > 0):
        raise InputError(f"baseline_um: expected a positive distance in µm, got {baseline_um!r}")
    rot = np.asarray(right_rotation_deg, dtype=np.float64)
    if rot.shape != (3,) or not np.all(np.isfinite(rot)):
        raise InputError(
            f"right_rotation_deg: expected 3 finite angles, got {right_rotation_deg!r}"
        )
    left = wide_angle_camera("left")
    R_right = _rotation_from_vector(np.deg2rad(rot))
    centre = np.array([b, 0.0, 0.0])
    right = wide_angle_camera(
        "right",
        fx=522.0,
        fy=524.5,
        cx=316.0,
        cy=248.0,
        dist=(-0.36, 0.22, -3e-4, 4e-4, -0.11),
        R=R_right,
        t_um=-R_right @ centre,
    )
    return {"left": left, "right": right}


# --- rendering ------------------------------------------------------------------------------


def render_calibration_views(
    camera: CameraModel,
    target: Target,
    n_views: int,
    *,
    seed: int,
    blur_sigma_px: float = 0.7,
    noise_sigma: float = 2.0,
    flip_fraction: float = 0.0,
    spread: Spread = "wide",
    tilt_deg: float = 40.0,
) -> CalibrationViews:
    """Render a calibration image set of one camera: a board in ``n_views`` random poses.

    Poses are drawn with ``np.random.default_rng(seed)``, then the images' noise with the same
    generator, so the poses do not depend on the blur or the noise. In every view the whole
    board (pattern and its white margin of one square) is in view with a clearance of 3 % of
    the image's shorter side, faces the camera, and stays inside the radius where the lens
    model folds over. Its squares' size is drawn log-uniformly as a fraction of ``fill``, the
    size at which the board would just fill the image face-on: 0.45-0.9 of it when aimed at
    the image centre, 0.33-0.66 at an edge, 0.22-0.36 at a corner (a board wholly in view near
    a corner must be small); the distance is ``f * pitch / square_px``. For a 7 x 5 board on a
    640 x 480 camera ``fill`` is 60 px: squares of 27-54 px in the centre, 13-22 px in the
    corners (fewer where the barrel distortion compresses the image). The board is tilted by
    up to ``tilt_deg`` about a random axis in its plane (relative to facing the camera
    squarely) and rotated by up to 10 degrees about its normal.

    The image: reflectance 0.85 (white), 0.08 (black squares), 0.35 (background), rendered
    with 4 x 4 box-filtered subsamples per pixel over the board's bounding box, times 255;
    then the blur, the noise, rounding and clipping to 0-255.

    Parameters
    ----------
    camera : CameraModel
        The true camera (any pose in {G}).
    target : Target
        A chessboard or ChArUco board.
    n_views : int
        Number of views V (>= 1).
    seed : int
        Seed of the random generator: the same seed gives the same images, bit for bit.
    blur_sigma_px : float
        Standard deviation of the Gaussian blur (``cv2.GaussianBlur``), px (>= 0; 0: none).
    noise_sigma : float
        Standard deviation of the Gaussian noise added before 8-bit quantisation, grey levels
        of 255 (>= 0).
    flip_fraction : float
        Fraction of the views, in [0, 1], in which the board is turned by 180 degrees in its
        plane about its centre: ``round(flip_fraction * V)`` views, at least one if the
        fraction is > 0, chosen at random. A chessboard whose inner corner counts add up to an
        even number looks the same turned; its corner numbering then starts at the other end.
    spread : {"wide", "centre"}
        "wide": the board's centre is aimed at the cells of a 3 x 3 grid over the image (its
        outer tenth in a corner or edge cell), rounds of nine views each covering every cell
        with the four corners first (so any 4 or more views reach all four corners), the
        order then shuffled. A board that does not fit where it is aimed slides towards the
        image centre until it does (in a corner, it is made smaller first). "centre": aimed
        within the middle sixth of the image in each direction (the middle third's centre),
        tilted by at most ``tilt_deg / 4``.
    tilt_deg : float
        Largest tilt, degrees, in [0, 70].

    Returns
    -------
    CalibrationViews
        Images, true corners, board poses in {G}, flips, and the camera and target.

    Raises
    ------
    InputError
        On an invalid argument, or if no pose in view is found (hardly: at its smallest the
        board spans 22 % of the image).
    """
    _check_camera(camera, "camera")
    _check_options(target, n_views, seed, blur_sigma_px, noise_sigma, flip_fraction, spread,
                   tilt_deg)  # fmt: skip
    rng = np.random.default_rng(seed)
    board_R, board_t, flipped = _draw_poses(
        [camera], target, n_views, rng, flip_fraction, spread, tilt_deg
    )
    images: list[UInt8Image] = []
    corners: list[FloatArray] = []
    for v in range(n_views):
        placement = Placement(target, board_R[v], board_t[v])
        images.append(_render_view(camera, placement, blur_sigma_px, noise_sigma, rng))
        corners.append(camera.project(placement.points_world_um()))
    return CalibrationViews(
        images=images,
        corners_px=corners,
        board_R=board_R,
        board_t_um=board_t,
        camera=camera,
        target=target,
        rotated_180=flipped,
        blur_px=float(blur_sigma_px),
        noise=float(noise_sigma),
    )


def render_stereo_calibration_views(
    cameras: Mapping[str, CameraModel],
    target: Target,
    n_views: int,
    *,
    seed: int,
    blur_sigma_px: float = 0.7,
    noise_sigma: float = 2.0,
    flip_fraction: float = 0.0,
    spread: Spread = "wide",
    tilt_deg: float = 40.0,
) -> StereoCalibrationViews:
    """Render calibration image sets of a camera rig: the same board poses seen by all cameras.

    As :func:`render_calibration_views`, with every pose in view of every camera. The poses
    are aimed, view by view in turn, in the image of each camera (``spread``, ``tilt_deg``
    relate to that camera); a pose that some other camera does not see whole slides towards
    the aiming camera's image centre (and is made smaller) until all do. The images are
    rendered camera by camera within each view, in the mapping's order.

    Parameters
    ----------
    cameras : mapping of str to CameraModel
        Two or more true cameras in one world frame {G}, by name.
    target : Target
    n_views : int
        Number of views V (>= 1).
    seed : int
    blur_sigma_px, noise_sigma, flip_fraction, spread, tilt_deg
        As :func:`render_calibration_views`.

    Returns
    -------
    StereoCalibrationViews
        Per camera the images and true corners; the poses in {G}.

    Raises
    ------
    InputError
        On an invalid argument, or if no pose is in view of every camera.
    """
    if not isinstance(cameras, Mapping) or len(cameras) < 2:
        got = f"{len(cameras)}" if isinstance(cameras, Mapping) else type(cameras).__name__
        raise InputError(f"cameras: expected a mapping of two or more cameras by name, got {got}")
    for name, cam in cameras.items():
        if not isinstance(name, str):
            raise InputError(f"cameras: expected names as keys, got {name!r}")
        _check_camera(cam, f"cameras[{name!r}]")
    _check_options(target, n_views, seed, blur_sigma_px, noise_sigma, flip_fraction, spread,
                   tilt_deg)  # fmt: skip
    names = list(cameras)
    rng = np.random.default_rng(seed)
    board_R, board_t, flipped = _draw_poses(
        [cameras[n] for n in names], target, n_views, rng, flip_fraction, spread, tilt_deg
    )
    images: dict[str, list[UInt8Image]] = {n: [] for n in names}
    corners: dict[str, list[FloatArray]] = {n: [] for n in names}
    for v in range(n_views):
        placement = Placement(target, board_R[v], board_t[v])
        for n in names:
            cam = cameras[n]
            images[n].append(_render_view(cam, placement, blur_sigma_px, noise_sigma, rng))
            corners[n].append(cam.project(placement.points_world_um()))
    return StereoCalibrationViews(
        images=images,
        corners_px=corners,
        board_R=board_R,
        board_t_um=board_t,
        cameras=dict(cameras),
        target=target,
        rotated_180=flipped,
        blur_px=float(blur_sigma_px),
        noise=float(noise_sigma),
    )


# --- validation -----------------------------------------------------------------------------


def _check_camera(camera: object, name: str) -> None:
    if not isinstance(camera, CameraModel):
        raise InputError(f"{name}: expected a CameraModel, got {type(camera).__name__}")


def _number(value: object, name: str, low: float, high: float) -> float:
    """``value`` as a float in [low, high], else InputError."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InputError(f"{name}: expected a number in [{low:g}, {high:g}], got {value!r}")
    x = float(value)
    if not (np.isfinite(x) and low <= x <= high):
        raise InputError(f"{name}: expected a number in [{low:g}, {high:g}], got {value!r}")
    return x


def _check_options(
    target: object,
    n_views: object,
    seed: object,
    blur_sigma_px: object,
    noise_sigma: object,
    flip_fraction: object,
    spread: object,
    tilt_deg: object,
) -> None:
    if not isinstance(target, Target):
        raise InputError(f"target: expected a Target, got {type(target).__name__}")
    if target.kind not in ("chessboard", "charuco"):
        raise InputError(f"target: expected a chessboard or ChArUco board, got {target.kind}")
    if isinstance(n_views, bool) or not isinstance(n_views, int | np.integer) or n_views < 1:
        raise InputError(f"n_views: expected an integer >= 1, got {n_views!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"seed: expected an integer >= 0, got {seed!r}")
    _number(blur_sigma_px, "blur_sigma_px", 0.0, 50.0)
    _number(noise_sigma, "noise_sigma", 0.0, 255.0)
    _number(flip_fraction, "flip_fraction", 0.0, 1.0)
    _number(tilt_deg, "tilt_deg", 0.0, 70.0)
    if spread not in ("wide", "centre"):
        raise InputError(f"spread: expected 'wide' or 'centre', got {spread!r}")


# --- poses ----------------------------------------------------------------------------------


def _rotation_from_vector(rv: FloatArray) -> FloatArray:
    """Rodrigues: the rotation by |rv| radians about rv, (3, 3)."""
    angle = float(np.linalg.norm(rv))
    if angle < 1e-15:
        return np.eye(3)
    k = rv / angle
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    R: FloatArray = np.eye(3) + np.sin(angle) * Kx + (1.0 - np.cos(angle)) * (Kx @ Kx)
    return R


def _rot_z(angle_rad: float) -> FloatArray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _in_camera(camera: CameraModel, R: FloatArray, t: FloatArray) -> tuple[FloatArray, FloatArray]:
    """A pose in {G} expressed in the camera frame."""
    Rc: FloatArray = camera.R @ R
    tc: FloatArray = camera.R @ t + camera.t_um
    return Rc, tc


def _fold_radius(dist: FloatArray) -> float:
    """Normalised radius where the radial distortion stops growing outwards (inf if never).

    Beyond it the polynomial maps points back inwards: a scene point there would be imaged
    nowhere near where a real lens puts it.
    """
    k1, k2, _, _, k3 = dist
    r = np.linspace(0.0, 4.0, 8001)
    r2 = r * r
    slope = 1.0 + r2 * (3.0 * k1 + r2 * (5.0 * k2 + 7.0 * k3 * r2))
    bad = np.flatnonzero(slope <= 0.0)
    return float(r[bad[0]]) if bad.size else float("inf")


def _board_outline_um(target: Target) -> FloatArray:
    """Points along the edge of the board (pattern and white margin), target frame, (M, 3)."""
    x0, x1, y0, y1 = target.extent_um()
    m = target.pitch_um  # Placement's default margin for boards
    x0, x1, y0, y1 = x0 - m, x1 + m, y0 - m, y1 + m
    s = np.linspace(0.0, 1.0, _OUTLINE_POINTS, endpoint=False)
    xs, ys = x0 + s * (x1 - x0), y0 + s * (y1 - y0)
    pts = np.concatenate(
        [
            np.column_stack([xs, np.full_like(xs, y0)]),
            np.column_stack([np.full_like(ys, x1), ys]),
            np.column_stack([x1 - (xs - x0), np.full_like(xs, y1)]),
            np.column_stack([np.full_like(ys, x0), y1 - (ys - y0)]),
        ]
    )
    return np.column_stack([pts, np.zeros(len(pts))])


class _ViewCheck:
    """Whether a board pose in {G} is wholly in view of a camera, with clearance."""

    def __init__(self, camera: CameraModel, outline_um: FloatArray) -> None:
        self.camera = camera
        self.outline = outline_um
        self.fold = 0.95 * _fold_radius(camera.dist)
        w, h = camera.image_size_px
        self.edge = _EDGE_FRACTION * min(w, h)
        self.hi = np.array([w - 1.0 - self.edge, h - 1.0 - self.edge])

    def __call__(self, R: FloatArray, t: FloatArray) -> bool:
        Rc, tc = _in_camera(self.camera, R, t)
        # The printed side faces the camera: the camera lies on the board's -z side.
        if float((Rc.T @ -tc)[2]) >= 0.0:
            return False
        c = self.outline @ Rc.T + tc
        if np.any(c[:, 2] <= 0.0):
            return False
        xy = c[:, :2] / c[:, 2:3]
        if np.any(np.hypot(xy[:, 0], xy[:, 1]) >= self.fold):
            return False
        q = self.camera.project(self.outline @ R.T + t)
        return bool(np.all(q >= self.edge) and np.all(q <= self.hi))


def _cells(n_views: int, spread: Spread, rng: np.random.Generator) -> list[tuple[int, int]]:
    """Cell (column, row) of a 3 x 3 grid over the image that each view aims at."""
    if spread == "centre":
        return [(1, 1)] * n_views
    corners = [(0, 0), (2, 0), (0, 2), (2, 2)]
    others = [(1, 0), (0, 1), (1, 1), (2, 1), (1, 2)]
    cells: list[tuple[int, int]] = []
    while len(cells) < n_views:
        for group in (corners, others):
            order = rng.permutation(len(group))
            cells.extend(group[i] for i in order)
    cells = cells[:n_views]
    order = rng.permutation(n_views)
    return [cells[i] for i in order]


# Where in its cell the board's centre is aimed, as fractions of the image size; a board that
# does not fit there slides towards the image centre.
_CELL_RANGE = {0: (0.0, 0.1), 1: (0.4, 0.6), 2: (0.9, 1.0)}
_CENTRE_RANGE = (5.0 / 12.0, 7.0 / 12.0)
_SLIDE_STEPS = 24


def _draw_poses(
    cameras: list[CameraModel],
    target: Target,
    n_views: int,
    rng: np.random.Generator,
    flip_fraction: float,
    spread: Spread,
    tilt_deg: float,
) -> tuple[FloatArray, FloatArray, list[bool]]:
    """Board poses in {G}, (V, 3, 3) and (V, 3), in view of every camera; and the flips."""
    n_flip = 0 if flip_fraction == 0 else max(1, round(flip_fraction * n_views))
    flipped = np.zeros(n_views, dtype=bool)
    flipped[rng.choice(n_views, size=n_flip, replace=False)] = True
    cells = _cells(n_views, spread, rng)
    outline = _board_outline_um(target)
    checks = [_ViewCheck(cam, outline) for cam in cameras]
    x0, x1, y0, y1 = target.extent_um()
    p = target.pitch_um
    board_w, board_h = x1 - x0 + 2 * p, y1 - y0 + 2 * p
    centre = target.centre_um
    max_tilt = np.deg2rad(tilt_deg / 4.0 if spread == "centre" else tilt_deg)
    Rs = np.empty((n_views, 3, 3))
    ts = np.empty((n_views, 3))
    for v in range(n_views):
        ref = cameras[v % len(cameras)]
        w, h = ref.image_size_px
        f = float(np.sqrt(ref.K[0, 0] * ref.K[1, 1]))
        fill_px = min(w / (board_w / p), h / (board_h / p))  # square size filling the image
        col, row = cells[v]
        place = "centre" if (col, row) == (1, 1) else "corner" if col != 1 and row != 1 else "edge"
        s_lo, s_hi = (fill_px * k for k in _SQUARE_FRACTION[place])
        s_min = fill_px * _SQUARE_FRACTION["corner"][0]
        middle = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
        xr = _CENTRE_RANGE if spread == "centre" else _CELL_RANGE[col]
        yr = _CENTRE_RANGE if spread == "centre" else _CELL_RANGE[row]
        pose = None
        for _ in range(25):  # fresh draws
            axis = rng.uniform(0.0, 2.0 * np.pi)
            tilt = rng.uniform(0.0, max_tilt)
            roll = np.deg2rad(rng.uniform(-_ROLL_DEG, _ROLL_DEG))
            square_px = float(np.exp(rng.uniform(np.log(s_lo), np.log(s_hi))))
            aim = np.array([rng.uniform(*xr) * (w - 1), rng.uniform(*yr) * (h - 1)])
            R0 = _rotation_from_vector(tilt * np.array([np.cos(axis), np.sin(axis), 0.0]))
            R0 = R0 @ _rot_z(roll)
            Rc = R0 @ _rot_z(np.pi) if flipped[v] else R0
            pose = _fit_pose(ref, checks, Rc, centre, aim, middle, (square_px, s_min), f * p,
                             place == "corner")  # fmt: skip
            if pose is not None:
                break
        if pose is None:
            raise InputError(
                f"target: expected a board that fits the cameras' common view, got "
                f"{target.spec} that could not be placed in view of every camera"
            )
        Rs[v], ts[v] = pose
    return Rs, ts, [bool(x) for x in flipped]


def _fit_pose(
    ref: CameraModel,
    checks: list[_ViewCheck],
    Rc: FloatArray,
    centre_um: FloatArray,
    aim_px: FloatArray,
    middle_px: FloatArray,
    sizes_px: tuple[float, float],
    f_pitch: float,
    shrink: bool,
) -> tuple[FloatArray, FloatArray] | None:
    """A pose in {G} with rotation ``Rc`` (in ``ref``'s frame) whose board centre images on the
    way from the aimed pixel to the image centre, as near the aim as every camera sees it
    whole; None if nothing fits.

    Aimed at a corner (``shrink``), the board is made smaller and smaller first, sliding a
    third of the way at most; else it slides all the way at the drawn size. Last, at the
    smallest size, it slides all the way."""
    drawn, smallest = sizes_px
    if shrink:
        schedule = [(drawn * (smallest / drawn) ** (i / 4.0), _SLIDE_STEPS // 3) for i in range(4)]
    else:
        schedule = [(drawn, _SLIDE_STEPS)]
    schedule.append((smallest, _SLIDE_STEPS))
    for size_px, slide in schedule:
        depth = f_pitch / size_px  # square_px = f * pitch / depth
        for k in range(slide + 1):
            q = aim_px + (k / _SLIDE_STEPS) * (middle_px - aim_px)
            ideal = ref.undistort_px(q)[0]
            if not np.all(np.isfinite(ideal)):
                continue  # aimed beyond the lens model's fold-over
            xy = np.linalg.solve(ref.K[:2, :2], ideal - ref.K[:2, 2])
            tc = depth * np.array([xy[0], xy[1], 1.0]) - Rc @ centre_um
            # The pose in {G}: p_ref = Rr p_G + tr, so p_G = Rr^T (Rc p + tc - tr).
            R = ref.R.T @ Rc
            t = ref.R.T @ (tc - ref.t_um)
            if all(check(R, t) for check in checks):
                return R, t
    return None


# --- images ---------------------------------------------------------------------------------


def _render_view(
    camera: CameraModel,
    placement: Placement,
    blur_sigma_px: float,
    noise_sigma: float,
    rng: np.random.Generator,
) -> UInt8Image:
    """One 8-bit image of the placed board: render, blur, noise, quantise."""
    refl = Reflectance()
    w, h = camera.image_size_px
    image = np.full((h, w), refl.background, dtype=np.float64)
    # The renderer covers the board's bounding box (pattern and white margin, with 2 px to
    # spare): outside it the board's coverage is exactly zero, so the image is the same as a
    # render of the whole image, at a fraction of the cost.
    outline = _board_outline_um(placement.target) @ placement.R.T + placement.t_um
    q = camera.project(outline)
    x0 = max(int(np.floor(q[:, 0].min())) - 2, 0)
    y0 = max(int(np.floor(q[:, 1].min())) - 2, 0)
    x1 = min(int(np.ceil(q[:, 0].max())) + 3, w)
    y1 = min(int(np.ceil(q[:, 1].max())) + 3, h)
    with np.errstate(invalid="ignore"):
        render = render_slide if placement.target.markers else render_placement
        value, alpha = render(
            camera, placement, (x0, y0, x1, y1), supersample=_SUPERSAMPLE, reflectance=refl
        )
    # Pixels the lens model cannot trace (beyond its fold-over, in the image corners) are
    # never on the board: they keep the background.
    alpha = np.where(np.isfinite(alpha) & np.isfinite(value), alpha, 0.0)
    value = np.nan_to_num(value)
    patch = image[y0:y1, x0:x1]
    image[y0:y1, x0:x1] = patch + alpha * (value - patch)
    grey = (image * _FULL_SCALE).astype(np.float32)
    if blur_sigma_px > 0:
        grey = cv2.GaussianBlur(grey, (0, 0), float(blur_sigma_px))
    if noise_sigma > 0:
        grey += np.float32(noise_sigma) * rng.standard_normal((h, w), dtype=np.float32)
    out: UInt8Image = np.clip(np.rint(grey), 0, 255).astype(np.uint8)
    return out
