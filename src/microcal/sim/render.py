"""Rendering planar targets into a camera's image, with lens distortion and anti-aliasing.

For every pixel of a region of interest, S x S subsamples are traced back to the target's
plane: the pixel's position is undistorted (Newton's method at the pixel centre, linearised
within the pixel), mapped through the inverse homography of the plane, and the target's
reflectance is evaluated *box-filtered* over the subsample's footprint on the target:

- a checkerboard is the product of two square waves, and a box-filtered square wave has a
  closed form (the difference of its integral, a triangle wave), so the checker is filtered
  exactly up to the footprint's shear;
- a dot is filtered by its signed distance over the footprint width;
- a ChArUco board is a texture, sampled bilinearly at the subsamples.

The result is the area-weighted mean reflectance of each pixel; the rendering's own corner
bias is far below the detection noise (see the tests).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .._validation import FloatArray
from ..geometry.camera_kinds import AnyCamera
from ..vision.targets import Target

__all__ = ["Placement", "Reflectance", "render_placement", "roi_of"]


@dataclass(frozen=True)
class Reflectance:
    """Reflectance of the materials (0 = black, 1 = white)."""

    black: float = 0.08  # printed black squares
    white: float = 0.85  # the board's white squares and margin
    background: float = 0.35  # what lies around the board (gripper, stage)
    glass: float = 0.06  # the dot grid's glass (dark under coaxial light)
    chrome: float = 0.80  # the dot grid's chromium dots


@dataclass(frozen=True)
class Placement:
    """A target placed in the world: ``p_G = R p_target + t_um``."""

    target: Target
    R: FloatArray
    t_um: FloatArray
    margin_um: float = -1.0  # white margin around the pattern; default one pitch (boards)

    @property
    def margin(self) -> float:
        if self.margin_um >= 0:
            return self.margin_um
        return 0.0 if self.target.kind == "dotgrid" else self.target.pitch_um

    def outline_um(self) -> FloatArray:
        """Corners and edge midpoints of the region to render, in the target frame, (8, 3)."""
        x0, x1, y0, y1 = self.target.extent_um()
        m = self.margin + (self.target.pitch_um if self.target.kind == "dotgrid" else 0.0)
        xs = (x0 - m, (x0 + x1) / 2, x1 + m)
        ys = (y0 - m, (y0 + y1) / 2, y1 + m)
        pts = [(x, y, 0.0) for x in xs for y in ys if not (x == xs[1] and y == ys[1])]
        return np.array(pts)

    def points_world_um(self) -> FloatArray:
        """The target's features in {G}, (N, 3)."""
        out: FloatArray = self.target.points_um() @ self.R.T + self.t_um
        return out


def roi_of(
    camera: AnyCamera, placement: Placement, pad_px: float, offset_px: FloatArray | None = None
) -> tuple[int, int, int, int] | None:
    """Pixel box (x0, y0, x1, y1), end exclusive, covering the placement; None if not in view."""
    world = placement.outline_um() @ placement.R.T + placement.t_um
    q = camera.project(world)
    if not np.all(np.isfinite(q)):
        return None
    if offset_px is not None:
        q = q + offset_px
    w, h = camera.image_size_px
    x0 = int(np.floor(q[:, 0].min() - pad_px))
    x1 = int(np.ceil(q[:, 0].max() + pad_px)) + 1
    y0 = int(np.floor(q[:, 1].min() - pad_px))
    y1 = int(np.ceil(q[:, 1].max() + pad_px)) + 1
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1


def _square_wave_filtered(u: FloatArray, p: float, w: FloatArray) -> FloatArray:
    """Box filter (width w) of the square wave +1 on [0, p), -1 on [p, 2p), period 2p."""

    def integral(x: FloatArray) -> FloatArray:
        out: FloatArray = p - np.abs(np.mod(x, 2.0 * p) - p)
        return out

    w = np.maximum(w, 1e-9 * p)
    out: FloatArray = (integral(u + w / 2) - integral(u - w / 2)) / w
    return out


def _box_filtered_interval(u: FloatArray, a: float, b: float, w: FloatArray) -> FloatArray:
    """Fraction of the box [u - w/2, u + w/2] that lies inside [a, b]."""
    w = np.maximum(w, 1e-12)
    inside = np.minimum(u + w / 2, b) - np.maximum(u - w / 2, a)
    out: FloatArray = np.clip(inside / w, 0.0, 1.0)
    return out


@lru_cache(maxsize=8)
def _charuco_texture(cols: int, rows: int, pitch_um: float, marker_um: float) -> FloatArray:
    """The ChArUco board as an image, 48 texels per square, values 0 (black) .. 1 (white)."""
    import cv2

    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250)
    board = cv2.aruco.CharucoBoard((cols, rows), pitch_um, marker_um, dictionary)
    texels = 48
    image = board.generateImage((cols * texels, rows * texels), marginSize=0, borderBits=1)
    return np.asarray(image, dtype=np.float64) / 255.0


def _reflectance(
    placement: Placement,
    u: FloatArray,
    v: FloatArray,
    wu: FloatArray,
    wv: FloatArray,
    refl: Reflectance,
) -> tuple[FloatArray, FloatArray]:
    """Reflectance and coverage (alpha) of the target at board coordinates (u, v)."""
    t = placement.target
    p = t.pitch_um
    x0, x1, y0, y1 = t.extent_um()
    m = placement.margin
    if t.kind == "dotgrid":
        r = t.feature_um / 2
        i = np.clip(np.rint(u / p), 0, t.cols - 1)
        j = np.clip(np.rint(v / p), 0, t.rows - 1)
        dist = np.hypot(u - i * p, v - j * p)
        width = 0.5 * (wu + wv)
        cover = np.clip(0.5 + (r - dist) / np.maximum(width, 1e-12), 0.0, 1.0)
        value = refl.glass + cover * (refl.chrome - refl.glass)
        alpha = np.ones_like(u)
        return value, alpha
    board = _box_filtered_interval(u, x0 - m, x1 + m, wu) * _box_filtered_interval(
        v, y0 - m, y1 + m, wv
    )
    pattern = _box_filtered_interval(u, x0, x1, wu) * _box_filtered_interval(v, y0, y1, wv)
    if t.kind == "chessboard":
        # Square (i, j) with i = floor(u / p) is black when i + j is even; the corner at
        # the origin is an inner corner.
        # Evaluated just inside the pattern: a footprint that straddles the pattern's edge
        # takes the edge square's colour, weighted by the coverage below.
        uc = np.clip(u, x0 + wu / 2, x1 - wu / 2)
        vc = np.clip(v, y0 + wv / 2, y1 - wv / 2)
        checker = _square_wave_filtered(uc, p, wu) * _square_wave_filtered(vc, p, wv)
        inner = refl.white + (refl.black - refl.white) * (1.0 + checker) / 2.0
    else:
        tex = _charuco_texture(t.cols, t.rows, t.pitch_um, t.feature_um)
        texels = tex.shape[1] / t.cols
        tu = (u - x0) / p * texels - 0.5
        tv = (v - y0) / p * texels - 0.5
        iu = np.clip(np.floor(tu).astype(int), 0, tex.shape[1] - 2)
        iv = np.clip(np.floor(tv).astype(int), 0, tex.shape[0] - 2)
        fu = np.clip(tu - iu, 0.0, 1.0)
        fv = np.clip(tv - iv, 0.0, 1.0)
        top = tex[iv, iu] * (1 - fu) + tex[iv, iu + 1] * fu
        bottom = tex[iv + 1, iu] * (1 - fu) + tex[iv + 1, iu + 1] * fu
        texel = top * (1 - fv) + bottom * fv
        inner = refl.black + texel * (refl.white - refl.black)
    value = refl.white + pattern * (inner - refl.white)
    return value, board


_GRID_CACHE: dict[tuple[str, bytes, bytes, tuple[int, ...]], tuple[FloatArray, ...]] = {}
_GRID_CACHE_SIZE = 16


def _ideal_grid(
    camera: AnyCamera, roi: tuple[int, int, int, int]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Ideal pixel coordinates of a box of pixel centres, (h, w, 2), and their x and y steps.

    Kept for the last few boxes: a board that settles is rendered over the same box frame
    after frame, and undistorting every pixel is the costliest step of a render. A shift
    of the scene by a fraction of a pixel is applied to first order by the caller: for the
    thesis's top camera the difference from undistorting the shifted pixels is about 1e-5 px
    at a 1 px shift, a thousandth of the rendering's corner bias.
    """
    key = (camera.kind, camera.K.tobytes(), camera.dist.tobytes(), tuple(int(v) for v in roi))
    hit = _GRID_CACHE.get(key)
    if hit is not None:
        return hit[0], hit[1], hit[2]
    x0, y0, x1, y1 = roi
    gx, gy = np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64))
    q = np.column_stack([gx.ravel(), gy.ravel()])
    ideal = camera.undistort_px(q).reshape(*gx.shape, 2)
    if camera.has_distortion and min(gx.shape) > 1:
        d_dx = np.asarray(np.gradient(ideal, axis=1), dtype=np.float64)
        d_dy = np.asarray(np.gradient(ideal, axis=0), dtype=np.float64)
    else:
        d_dx = np.zeros_like(ideal)
        d_dx[..., 0] = 1.0
        d_dy = np.zeros_like(ideal)
        d_dy[..., 1] = 1.0
    if len(_GRID_CACHE) >= _GRID_CACHE_SIZE:
        _GRID_CACHE.pop(next(iter(_GRID_CACHE)))
    _GRID_CACHE[key] = (ideal, d_dx, d_dy)
    return ideal, d_dx, d_dy


def render_placement(
    camera: AnyCamera,
    placement: Placement,
    roi: tuple[int, int, int, int],
    *,
    supersample: int = 4,
    offset_px: FloatArray | None = None,
    reflectance: Reflectance | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Reflectance and coverage of one placed target over a pixel box.

    Parameters
    ----------
    camera : CameraModel or AffineCamera
    placement : Placement
    roi : (x0, y0, x1, y1)
        Pixel box, end exclusive.
    supersample : int
        S: S x S subsamples per pixel, each box-filtered over its own footprint.
    offset_px : (2,) float, optional
        Shift of the whole image (vibration of the scene against the camera), px.

    Returns
    -------
    value, alpha : (h, w) float
        Mean reflectance of the target in each pixel, and the fraction of the pixel it covers.
    """
    refl = reflectance or Reflectance()
    # Ideal (undistorted) pixel coordinates at the pixel centres and their derivatives, from
    # the neighbours (distortion varies slowly: linear within a pixel).
    ideal0, d_dx, d_dy = _ideal_grid(camera, roi)
    ideal = ideal0
    if offset_px is not None:  # the scene shifted by a fraction of a pixel: to first order
        ideal = ideal0 - d_dx * offset_px[0] - d_dy * offset_px[1]
    shape = ideal.shape[:2]
    # Homography from the target plane to ideal pixels, and its inverse.
    H = camera.plane_to_ideal_px(placement.R, placement.t_um)
    Hinv = np.linalg.inv(H)

    def to_board(ix: FloatArray, iy: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        w = Hinv[2, 0] * ix + Hinv[2, 1] * iy + Hinv[2, 2]
        u = (Hinv[0, 0] * ix + Hinv[0, 1] * iy + Hinv[0, 2]) / w
        v = (Hinv[1, 0] * ix + Hinv[1, 1] * iy + Hinv[1, 2]) / w
        return u, v, w

    # Footprint of one subsample on the board, from the Jacobian at the pixel centre.
    u0, v0, w0 = to_board(ideal[..., 0], ideal[..., 1])
    du_dix = (Hinv[0, 0] - u0 * Hinv[2, 0]) / w0
    du_diy = (Hinv[0, 1] - u0 * Hinv[2, 1]) / w0
    dv_dix = (Hinv[1, 0] - v0 * Hinv[2, 0]) / w0
    dv_diy = (Hinv[1, 1] - v0 * Hinv[2, 1]) / w0
    du_dx = du_dix * d_dx[..., 0] + du_diy * d_dx[..., 1]
    du_dy = du_dix * d_dy[..., 0] + du_diy * d_dy[..., 1]
    dv_dx = dv_dix * d_dx[..., 0] + dv_diy * d_dx[..., 1]
    dv_dy = dv_dix * d_dy[..., 0] + dv_diy * d_dy[..., 1]
    wu = (np.abs(du_dx) + np.abs(du_dy)) / supersample
    wv = (np.abs(dv_dx) + np.abs(dv_dy)) / supersample
    value = np.zeros(shape)
    alpha = np.zeros(shape)
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    for oy in offsets:
        for ox in offsets:
            u = u0 + du_dx * ox + du_dy * oy
            v = v0 + dv_dx * ox + dv_dy * oy
            val, a = _reflectance(placement, u, v, wu, wv, refl)
            value += val * a
            alpha += a
    n = supersample * supersample
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_value = np.where(alpha > 0, value / np.maximum(alpha, 1e-12), 0.0)
    return mean_value, alpha / n
