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

What does not change between the subsamples of a frame (the footprint's half widths, the
clipping bounds) is computed once per frame, the checker only where the pattern covers the
subsample, and the square wave's modulo by a floor that gives ``np.mod``'s result bit for
bit (:func:`_mod`); undistorted pixel coordinates are kept per camera in tiles. A frame is
the same, bit for bit, as the straightforward evaluation gives.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..geometry.camera_kinds import AnyCamera
from ..vision.targets import Target

__all__ = ["Placement", "Reflectance", "render_placement", "render_region", "roi_of"]


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


def _mod(x: FloatArray, period: float) -> FloatArray:
    """``np.mod(x, period)`` bit for bit (period > 0), several times faster when it can be.

    With ``n = floor(x / period)`` the remainder ``x - n * period`` is rounded once, as
    ``np.mod`` rounds it, provided ``n * period`` is exact: the period's significand and the
    largest ``|n|`` must fit in 53 bits together (400 µm and any multiple of a power of two
    below it do). ``x / period`` rounded up to the next integer makes the remainder negative
    (and exact, by Sterbenz's lemma); adding one period puts it back. Any other period, or
    non-finite input, goes to ``np.mod``.
    """
    if x.dtype == np.float32 and math.isfinite(period) and period > 0:
        return _mod32(x, period)
    if not (math.isfinite(period) and period > 0) or x.size == 0:
        return np.asarray(np.mod(x, period), dtype=np.float64)
    hi = float(np.max(np.abs(x)))
    significand_bits = period.as_integer_ratio()[0].bit_length()
    if not math.isfinite(hi) or significand_bits + (int(hi / period) + 2).bit_length() > 53:
        return np.asarray(np.mod(x, period), dtype=np.float64)
    out: FloatArray = np.floor(x / period)
    out *= period
    np.subtract(x, out, out=out)
    negative = out < 0
    if negative.any():
        out[negative] += period
    return out


def _mod32(x: FloatArray, period: float) -> FloatArray:
    """``x mod period`` in [0, period) for float32 ``x`` (the fast path of
    :func:`render_region`; within a few float32 ulps of ``np.mod``)."""
    out: FloatArray = np.multiply(x, np.float32(1.0 / period))
    np.floor(out, out=out)
    out *= np.float32(period)
    np.subtract(x, out, out=out)
    np.maximum(out, 0.0, out=out)
    np.minimum(out, np.float32(period), out=out)
    return out


def _square_wave_integral(x: FloatArray, p: float) -> FloatArray:
    """The integral of the square wave of :func:`_square_wave_prepared`, a triangle wave."""
    out = _mod(x, 2.0 * p)
    out -= p
    np.abs(out, out=out)
    np.subtract(p, out, out=out)
    return out


def _square_wave_prepared(u: FloatArray, p: float, w: FloatArray, half: FloatArray) -> FloatArray:
    """Box filter (width ``w``, bounded below by 1e-9 p; ``half`` = w / 2) of the square wave
    +1 on [0, p), -1 on [p, 2p), period 2p."""
    out = _square_wave_integral(u + half, p)
    out -= _square_wave_integral(u - half, p)
    out /= w
    return out


@lru_cache(maxsize=8)
def _charuco_texture(t: Target) -> FloatArray:
    """The ChArUco board as an image, 48 texels per square, values 0 (black) .. 1 (white)."""
    import cv2

    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250)
    board = cv2.aruco.CharucoBoard(
        (t.cols, t.rows), t.pitch_um, t.feature_um, dictionary, t.marker_ids()
    )
    texels = 48
    image = board.generateImage((t.cols * texels, t.rows * texels), marginSize=0, borderBits=1)
    return np.asarray(image, dtype=np.float64) / 255.0


Shader = Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray]]


def _shader(placement: Placement, wu: FloatArray, wv: FloatArray, refl: Reflectance) -> Shader:
    """The target's reflectance and coverage (alpha) in one frame, as a function of the
    subsample's board coordinates (u, v) alone.

    ``wu``, ``wv`` (h, w) are the footprint's widths, the same for every subsample of a frame:
    what depends only on them is computed here once.
    """
    t = placement.target
    if t.kind == "chessboard":
        return _chessboard_shader(placement, wu, wv, refl)
    if t.kind == "dotgrid":
        return _dotgrid_shader(placement, wu, wv, refl)
    return _charuco_shader(placement, wu, wv, refl)


def _covered(plus: FloatArray, minus: FloatArray, a: float, b: float, w: FloatArray) -> FloatArray:
    """Fraction of the box [minus, plus] = [u - w/2, u + w/2] (w >= 1e-12) inside [a, b]."""
    inside = np.minimum(plus, b)
    inside -= np.maximum(minus, a)
    inside /= w
    # clip to [0, 1] (np.clip's result, without its wrapper's cost on small arrays)
    np.maximum(inside, 0.0, out=inside)
    out: FloatArray = np.minimum(inside, 1.0, out=inside)
    return out


def _chessboard_shader(
    placement: Placement, wu: FloatArray, wv: FloatArray, refl: Reflectance
) -> Shader:
    """A chessboard's shader: square (i, j), i = floor(u / p), is black when i + j is even
    (the corner at the origin is an inner corner), evaluated just inside the pattern (a
    footprint that straddles the pattern's edge takes the edge square's colour, weighted by
    the coverage); white margin around it.

    Where the pattern does not cover the subsample (``pattern == 0``: the white margin and
    beyond), the value is white whatever the checker, so the checker is evaluated only over
    the rows and columns where the pattern covers some pixel.
    """
    t = placement.target
    p = t.pitch_um
    x0, x1, y0, y1 = t.extent_um()
    m = placement.margin
    wu_box = np.maximum(wu, 1e-12)
    wv_box = np.maximum(wv, 1e-12)
    hu_box, hv_box = wu_box / 2, wv_box / 2
    lo_u, hi_u = x0 + wu / 2, x1 - wu / 2
    lo_v, hi_v = y0 + wv / 2, y1 - wv / 2
    wu_sq = np.maximum(wu, 1e-9 * p)
    wv_sq = np.maximum(wv, 1e-9 * p)
    hu_sq, hv_sq = wu_sq / 2, wv_sq / 2

    def shade(u: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
        up, um = u + hu_box, u - hu_box
        vp, vm = v + hv_box, v - hv_box
        board = _covered(up, um, x0 - m, x1 + m, wu_box)
        board *= _covered(vp, vm, y0 - m, y1 + m, wv_box)
        pattern = _covered(up, um, x0, x1, wu_box)
        pattern *= _covered(vp, vm, y0, y1, wv_box)
        value = np.full(u.shape, refl.white, dtype=u.dtype)
        rows = np.flatnonzero(pattern.any(axis=1))
        cols = np.flatnonzero(pattern.any(axis=0))
        if rows.size:
            box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
            uc = np.minimum(np.maximum(u[box], lo_u[box]), hi_u[box])
            vc = np.minimum(np.maximum(v[box], lo_v[box]), hi_v[box])
            checker = _square_wave_prepared(uc, p, wu_sq[box], hu_sq[box])
            checker *= _square_wave_prepared(vc, p, wv_sq[box], hv_sq[box])
            inner = refl.white + (refl.black - refl.white) * (1.0 + checker) / 2.0
            value[box] = refl.white + pattern[box] * (inner - refl.white)
        return value, board

    return shade


def _charuco_shader(
    placement: Placement, wu: FloatArray, wv: FloatArray, refl: Reflectance
) -> Shader:
    """A ChArUco board's shader: its image (:func:`_charuco_texture`) sampled bilinearly,
    white margin around the pattern."""
    t = placement.target
    p = t.pitch_um
    x0, x1, y0, y1 = t.extent_um()
    m = placement.margin
    wu_box, wv_box = np.maximum(wu, 1e-12), np.maximum(wv, 1e-12)
    hu_box, hv_box = wu_box / 2, wv_box / 2
    tex = _charuco_texture(t)
    texels = tex.shape[1] / t.cols

    def shade(u: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
        up, um = u + hu_box, u - hu_box
        vp, vm = v + hv_box, v - hv_box
        board = _covered(up, um, x0 - m, x1 + m, wu_box)
        board *= _covered(vp, vm, y0 - m, y1 + m, wv_box)
        pattern = _covered(up, um, x0, x1, wu_box)
        pattern *= _covered(vp, vm, y0, y1, wv_box)
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
        value: FloatArray = refl.white + pattern * (inner - refl.white)
        return value, board

    return shade


def _dotgrid_shader(
    placement: Placement, wu: FloatArray, wv: FloatArray, refl: Reflectance
) -> Shader:
    """A dot grid's shader: chrome dots on glass, each edge ramped over the footprint's width.

    A subsample farther than one footprint width from a dot's edge is all glass or all
    chrome (coverage exactly 0 or 1), which ``sqrt(dx² + dy²)`` tells apart as surely as the
    correctly rounded ``hypot`` (a few ulps apart); ``hypot``, much slower, is evaluated only
    for the subsamples near an edge.
    """
    t = placement.target
    p = t.pitch_um
    r = t.feature_um / 2
    width = np.maximum(0.5 * (wu + wv), 1e-12)
    outside = (r + width) * (1.0 + 1e-12)  # distances surely beyond the edge's ramp
    inside = (r - width) * (1.0 - 1e-12)  # ... and surely within it
    alpha = np.ones_like(wu)
    alpha.flags.writeable = False

    def shade(u: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
        i = np.clip(np.rint(u / p), 0, t.cols - 1)
        j = np.clip(np.rint(v / p), 0, t.rows - 1)
        dx = u - i * p
        dy = v - j * p
        rough = np.sqrt(dx * dx + dy * dy)
        cover = (rough <= inside).astype(u.dtype)  # 1 within, 0 beyond
        edge = np.flatnonzero(~((rough >= outside) | (rough <= inside)))
        dist = np.hypot(dx.ravel()[edge], dy.ravel()[edge])
        ramp = 0.5 + (r - dist) / width.ravel()[edge]
        cover.ravel()[edge] = np.clip(ramp, 0.0, 1.0)
        value: FloatArray = refl.glass + cover * (refl.chrome - refl.glass)
        return value, alpha

    return shade


_GRID_CACHE: dict[tuple[object, ...], tuple[FloatArray, ...]] = {}
_GRID_CACHE_SIZE = 16
#: Side of the tiles of undistorted pixel coordinates kept per camera, px.
_TILE_PX = 64
_TILES: dict[tuple[object, ...], dict[tuple[int, int], FloatArray]] = {}
_TILE_CAMERAS = 4


def _camera_key(camera: AnyCamera) -> tuple[object, ...]:
    """What a camera's undistortion depends on."""
    return (camera.kind, camera.K.tobytes(), camera.dist.tobytes(),
            tuple(int(v) for v in camera.image_size_px))  # fmt: skip


def _undistorted_box(camera: AnyCamera, roi: tuple[int, int, int, int]) -> FloatArray:
    """``camera.undistort_px`` of the pixel centres of a box, (h, w, 2), from tiles.

    The undistortion of a pixel does not depend on the others undistorted with it (Newton's
    method stops each point on its own), so a box is put together from tiles of
    :data:`_TILE_PX` pixels, each undistorted once per camera: a board that moves across the
    image costs the pixels it reaches once, not once per box.
    """
    key = _camera_key(camera)
    tiles = _TILES.get(key)
    if tiles is None:
        if len(_TILES) >= _TILE_CAMERAS:
            _TILES.pop(next(iter(_TILES)))
        tiles = _TILES[key] = {}
    x0, y0, x1, y1 = roi
    n = _TILE_PX
    wanted = [(ty, tx) for ty in range(y0 // n, (y1 - 1) // n + 1)
              for tx in range(x0 // n, (x1 - 1) // n + 1)]  # fmt: skip
    missing = [k for k in wanted if k not in tiles]
    if missing:
        gx, gy = np.meshgrid(np.arange(n, dtype=np.float64), np.arange(n, dtype=np.float64))
        q = np.concatenate([np.column_stack([gx.ravel() + tx * n, gy.ravel() + ty * n])
                            for ty, tx in missing])  # fmt: skip
        ideal = camera.undistort_px(q).reshape(len(missing), n, n, 2)
        for k, tile in zip(missing, ideal, strict=True):
            tiles[k] = tile
    out = np.empty((y1 - y0, x1 - x0, 2))
    for ty, tx in wanted:
        ax, ay = max(x0, tx * n), max(y0, ty * n)
        bx, by = min(x1, (tx + 1) * n), min(y1, (ty + 1) * n)
        out[ay - y0 : by - y0, ax - x0 : bx - x0] = tiles[ty, tx][
            ay - ty * n : by - ty * n, ax - tx * n : bx - tx * n
        ]
    return out


def _ideal_grid(
    camera: AnyCamera, roi: tuple[int, int, int, int]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Ideal pixel coordinates of a box of pixel centres, (h, w, 2), and their x and y steps
    (see :func:`_ideal_planes`)."""
    planes = _ideal_planes(camera, roi)
    return planes[0], planes[1], planes[2]


def _ideal_planes(
    camera: AnyCamera, roi: tuple[int, int, int, int], dtype: type[np.floating] = np.float64
) -> tuple[FloatArray, ...]:
    """Ideal pixel coordinates of a box of pixel centres, (h, w, 2), and their x and y steps.

    Kept for the last few boxes: a board that settles is rendered over the same box frame
    after frame, and undistorting every pixel is the costliest step of a render. A shift
    of the scene by a fraction of a pixel is applied to first order by the caller: for the
    thesis's top camera the difference from undistorting the shifted pixels is about 1e-5 px
    at a 1 px shift, a thousandth of the rendering's corner bias.
    """
    roi = (int(roi[0]), int(roi[1]), int(roi[2]), int(roi[3]))
    key = (*_camera_key(camera), roi, np.dtype(dtype).str)
    hit = _GRID_CACHE.get(key)
    if hit is not None:
        return hit
    if dtype != np.float64:  # the same planes, computed in float64, in another precision
        planes64 = _ideal_planes(camera, roi)
        entry = (*planes64[:3], *(p.astype(dtype) for p in planes64[3:]))
        if len(_GRID_CACHE) >= _GRID_CACHE_SIZE:
            _GRID_CACHE.pop(next(iter(_GRID_CACHE)))
        _GRID_CACHE[key] = entry
        return entry
    x0, y0, x1, y1 = roi
    if camera.has_distortion:
        ideal = _undistorted_box(camera, roi)
    else:
        gx, gy = np.meshgrid(np.arange(x0, x1, dtype=np.float64),
                             np.arange(y0, y1, dtype=np.float64))  # fmt: skip
        ideal = camera.undistort_px(np.column_stack([gx.ravel(), gy.ravel()]))
        ideal = ideal.reshape(*gx.shape, 2)
    if camera.has_distortion and min(ideal.shape[:2]) > 1:
        d_dx = np.asarray(np.gradient(ideal, axis=1), dtype=np.float64)
        d_dy = np.asarray(np.gradient(ideal, axis=0), dtype=np.float64)
    else:
        d_dx = np.zeros_like(ideal)
        d_dx[..., 0] = 1.0
        d_dy = np.zeros_like(ideal)
        d_dy[..., 1] = 1.0
    if len(_GRID_CACHE) >= _GRID_CACHE_SIZE:
        _GRID_CACHE.pop(next(iter(_GRID_CACHE)))
    planes = tuple(np.ascontiguousarray(a[..., i]) for a in (ideal, d_dx, d_dy) for i in (0, 1))
    entry = (ideal, d_dx, d_dy, *planes)
    _GRID_CACHE[key] = entry
    return entry


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
    return _render(camera, placement, roi, supersample, offset_px, reflectance, np.float64)


def render_region(
    camera: AnyCamera,
    placement: Placement,
    roi: tuple[int, int, int, int],
    *,
    supersample: int = 4,
    offset_px: FloatArray | None = None,
    reflectance: Reflectance | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """:func:`render_placement` in float32: the simulated cameras' path.

    The same geometry (the ideal pixel coordinates are undistorted in float64 and kept per
    camera) and the same box-filtered shading, evaluated in single precision: a board
    coordinate of 10 mm is then exact to about 1 nm, a thousandth of a pixel's footprint,
    and an 8- to 16-bit frame cannot tell the difference. About twice as fast; the values
    differ from :func:`render_placement`'s by a few float32 ulps (see the tests).

    Parameters and returns as :func:`render_placement`; ``value`` and ``alpha`` are
    float32 (h, w).
    """
    value, alpha = _render(camera, placement, roi, supersample, offset_px, reflectance, np.float32)
    return value.astype(np.float32, copy=False), alpha.astype(np.float32, copy=False)


def _render(
    camera: AnyCamera,
    placement: Placement,
    roi: tuple[int, int, int, int],
    supersample: int,
    offset_px: FloatArray | None,
    reflectance: Reflectance | None,
    dtype: type[np.floating],
) -> tuple[FloatArray, FloatArray]:
    """:func:`render_placement` with the shading evaluated in ``dtype``."""
    refl = reflectance or Reflectance()
    # Ideal (undistorted) pixel coordinates at the pixel centres and their derivatives, from
    # the neighbours (distortion varies slowly: linear within a pixel), as (h, w) planes.
    ix, iy, dx_x, dx_y, dy_x, dy_y = _ideal_planes(camera, roi, dtype)[3:]
    if offset_px is not None:  # the scene shifted by a fraction of a pixel: to first order
        ox, oy = dtype(offset_px[0]), dtype(offset_px[1])
        ix = ix - dx_x * ox - dy_x * oy
        iy = iy - dx_y * ox - dy_y * oy
    shape = ix.shape
    # Homography from the target plane to ideal pixels, and its inverse.
    H = camera.plane_to_ideal_px(placement.R, placement.t_um)
    Hinv = np.linalg.inv(H).astype(dtype)

    def affine(a: float, b: float, c: float) -> FloatArray:
        """``a * ix + b * iy + c``, (h, w)."""
        out = a * ix
        out += b * iy
        out += c
        return out

    def slope(a: float, b: float, of: FloatArray, w: FloatArray) -> FloatArray:
        """``(a - of * b) / w``, (h, w): a derivative of the inverse homography."""
        out = of * b
        np.subtract(a, out, out=out)
        out /= w
        return out

    def chain(a: FloatArray, b: FloatArray, c: FloatArray, d: FloatArray) -> FloatArray:
        """``a * c + b * d``, (h, w)."""
        out = a * c
        out += b * d
        return out

    # The board coordinates of the pixel centres and the footprint of one subsample there,
    # from the Jacobian at the centre.
    w0 = affine(Hinv[2, 0], Hinv[2, 1], Hinv[2, 2])
    u0 = affine(Hinv[0, 0], Hinv[0, 1], Hinv[0, 2])
    u0 /= w0
    v0 = affine(Hinv[1, 0], Hinv[1, 1], Hinv[1, 2])
    v0 /= w0
    du_dix = slope(Hinv[0, 0], Hinv[2, 0], u0, w0)
    du_diy = slope(Hinv[0, 1], Hinv[2, 1], u0, w0)
    dv_dix = slope(Hinv[1, 0], Hinv[2, 0], v0, w0)
    dv_diy = slope(Hinv[1, 1], Hinv[2, 1], v0, w0)
    du_dx = chain(du_dix, du_diy, dx_x, dx_y)
    du_dy = chain(du_dix, du_diy, dy_x, dy_y)
    dv_dx = chain(dv_dix, dv_diy, dx_x, dx_y)
    dv_dy = chain(dv_dix, dv_diy, dy_x, dy_y)
    wu = np.abs(du_dx)
    wu += np.abs(du_dy)
    wu /= supersample
    wv = np.abs(dv_dx)
    wv += np.abs(dv_dy)
    wv /= supersample
    shade = _shader(placement, wu, wv, refl)
    value = np.zeros(shape, dtype=dtype)
    alpha = np.zeros(shape, dtype=dtype)
    offsets = ((np.arange(supersample) + 0.5) / supersample - 0.5).astype(dtype)
    # The subsample (ox, oy) is at u0 + du_dx * ox + du_dy * oy: the first two terms are
    # shared by the subsamples of a column, the last by those of a row.
    u_cols = [u0 + du_dx * ox for ox in offsets]
    v_cols = [v0 + dv_dx * ox for ox in offsets]
    for oy in offsets:
        u_row, v_row = du_dy * oy, dv_dy * oy
        for u_col, v_col in zip(u_cols, v_cols, strict=True):
            u = u_col + u_row
            v = v_col + v_row
            val, a = shade(u, v)
            value += np.multiply(val, a, out=u)
            alpha += a
    n = supersample * supersample
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_value = np.where(alpha > 0, value / np.maximum(alpha, 1e-12), 0.0)
    return mean_value, alpha / n
