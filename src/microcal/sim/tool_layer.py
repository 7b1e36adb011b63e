"""One tool's blurred transmission over a whole frame, computed only where it is read.

The tool's outline is blurred by a Gaussian whose sigma follows the depth along the tool
(:func:`~microcal.sim.tools.render_tools`): levels of blur over the frame, each pixel
interpolated between the two levels around its own sigma. Far along a patch pipette's shank
the blur reaches hundreds of pixels, and blurring a whole 2048 x 2048 frame at some forty
such levels took minutes. Here each level is a separable convolution written as two small
matrices (with the frame box's mirrored border, as OpenCV's default one), applied only to
the pixels that use that level and only to the tool's own pixels (the outline is zero
elsewhere), so a region costs what its pixels and the tool under them cost, and any region
has the same pixels as the same region of the whole frame.

The levels are those of the whole frame's box (the frame grown by the blur margin), so the
whole frame is the one :func:`~microcal.sim.tools.render_tools` gives, within float32
rounding.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..geometry.affine_camera import AffineCamera
from .tools import (
    Optics,
    ToolPlacement,
    _darkness,
    _Silhouette,
    _silhouette,
    um_per_px,
)

__all__ = ["ToolLayer"]

Box = tuple[int, int, int, int]
#: The ratio between successive levels of blur (that of render_tools).
_LEVEL_RATIO = 1.15


class ToolLayer:
    """A placed tool's transmission on one frame (1 where there is no tool).

    Parameters
    ----------
    camera : AffineCamera
        The frame's camera (its image size gives the frame).
    placement : ToolPlacement
    optics : Optics
    supersample : int
        S x S subsamples per pixel for the outline.
    """

    def __init__(
        self, camera: AffineCamera, placement: ToolPlacement, optics: Optics, supersample: int
    ) -> None:
        self._camera, self._placement, self._optics = camera, placement, optics
        self._supersample = int(supersample)
        self._sil: _Silhouette | None = _silhouette(camera, placement)
        w, h = camera.image_size_px
        self._pitch = um_per_px(camera, placement.tip_um)
        margin = self._margin_px()
        self._frame_box: Box = (-margin, -margin, int(w) + margin, int(h) + margin)
        self._levels: FloatArray | None = None
        self._tool_box: Box | None = None
        if self._sil is not None:
            self._tool_box = self._outline_box(self._sil)
            self._levels = self._blur_levels(self._sil)

    # -- set-up ----------------------------------------------------------------------------
    def _margin_px(self) -> int:
        p, o = self._placement, self._optics
        far = float(self._camera.depth_um(p.tip_um + p.axis * 1e5)[0]) - o.focus_depth_um
        near = float(self._camera.depth_um(p.tip_um)[0]) - o.focus_depth_um
        blur = float(np.max(o.blur_sigma_px(np.array([near, far]), self._pitch)))
        return min(int(4 * blur) + 4, 64)

    def _along(self, xs: FloatArray, ys: FloatArray) -> FloatArray:
        """Pixels' distance along the tool's image axis from its vertex, px (0 before it)."""
        sil = self._sil
        assert sil is not None
        out: FloatArray = np.maximum(
            (xs - sil.vertex[0]) * sil.axis[0] + (ys - sil.vertex[1]) * sil.axis[1], 0
        )
        return out

    def _sigma(self, along: FloatArray) -> FloatArray:
        sil, o = self._sil, self._optics
        assert sil is not None
        return o.blur_sigma_px(
            sil.depth0_um + along * sil.depth_per_px - o.focus_depth_um, self._pitch
        )

    def _blur_levels(self, sil: _Silhouette) -> FloatArray:
        """The levels of blur over the frame box: its pixels' least and greatest sigma, and
        the geometric steps between (one level when they are nearly equal)."""
        x0, y0, x1, y1 = self._frame_box
        ys = np.arange(y0, y1, dtype=np.float64)
        if self._camera.has_distortion:  # pragma: no cover - the patch camera has none
            raise ValueError("a tool layer needs a camera without distortion")
        # sigma is a function of the clipped distance along the axis, smallest where the
        # depth is the focus's: per row, the ends and the two pixels around that point
        zero = (self._optics.focus_depth_um - sil.depth0_um) / sil.depth_per_px
        cand = [np.full_like(ys, float(x0)), np.full_like(ys, float(x1 - 1))]
        if abs(sil.axis[0]) > 1e-12:
            at = sil.vertex[0] + (zero - (ys - sil.vertex[1]) * sil.axis[1]) / sil.axis[0]
            for x in (np.floor(at), np.floor(at) + 1):
                cand.append(np.clip(x, x0, x1 - 1))
        xs = np.stack(cand)
        sigma = self._sigma(self._along(xs, np.broadcast_to(ys, xs.shape)))
        lo, hi = float(sigma.min()), float(sigma.max())
        if hi - lo < 0.02 * lo + 1e-3:
            return np.array([max(0.5 * (lo + hi), 1e-3)])
        n = max(2, math.ceil(math.log(hi / lo) / math.log(_LEVEL_RATIO)) + 1)
        return np.geomspace(lo, hi, n)

    def _outline_box(self, sil: _Silhouette) -> Box | None:
        """A box, within the frame box, outside which the outline takes no light."""
        x0, y0, x1, y1 = self._frame_box
        poly = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)
        for normal in sil.normals:  # the wedge between the two edges, a pixel and a half wide
            poly = _clip_half_plane(poly, normal, float(normal @ sil.vertex) + 1.5)
            if len(poly) == 0:
                break
        boxes = []
        if len(poly):
            boxes.append((poly.min(axis=0), poly.max(axis=0)))
        half = np.linalg.norm(np.linalg.inv(sil.end_inverse), axis=1) + 2.0
        boxes.append((sil.end_centre - half, sil.end_centre + half))
        lo = np.min([b[0] for b in boxes], axis=0)
        hi = np.max([b[1] for b in boxes], axis=0)
        bx0, by0 = max(x0, math.floor(lo[0]) - 1), max(y0, math.floor(lo[1]) - 1)
        bx1, by1 = min(x1, math.ceil(hi[0]) + 2), min(y1, math.ceil(hi[1]) + 2)
        return (bx0, by0, bx1, by1) if bx1 > bx0 and by1 > by0 else None

    # -- rendering -------------------------------------------------------------------------
    def transmission(self, box: Box) -> NDArray[np.float32]:
        """The tool's transmission over ``box`` (x0, y0, x1, y1; inside the frame),
        (h, w) float32."""
        x0, y0, x1, y1 = box
        out = np.ones((y1 - y0, x1 - x0), dtype=np.float32)
        if self._sil is None or self._tool_box is None or self._levels is None or out.size == 0:
            return out
        levels = self._levels
        xs = np.arange(x0, x1, dtype=np.float64)
        ys = np.arange(y0, y1, dtype=np.float64)
        gx, gy = np.meshgrid(xs, ys)
        if len(levels) == 1:
            idx, frac = np.zeros(out.shape, dtype=int), np.zeros(out.shape, dtype=np.float32)
        else:
            k = np.log(self._sigma(self._along(gx, gy)) / levels[0]) / math.log(
                levels[1] / levels[0]
            )
            k = np.clip(k, 0, len(levels) - 1 - 1e-9)
            idx = np.floor(k).astype(int)
            frac = (k - idx).astype(np.float32)
        used = np.unique(idx) if len(levels) == 1 else np.unique(np.concatenate([idx, idx + 1]))
        plans = []
        for j in used.tolist():
            mask = (idx == j) | ((idx + 1 == j) if len(levels) > 1 else False)
            rows, cols = np.nonzero(mask)
            out_box = (x0 + int(cols.min()), y0 + int(rows.min()),
                       x0 + int(cols.max()) + 1, y0 + int(rows.max()) + 1)  # fmt: skip
            plans.append((j, out_box, self._input_box(out_box, _radius(levels[j]))))
        inputs = [p[2] for p in plans if p[2] is not None]
        if not inputs:
            return out
        ibox = (min(b[0] for b in inputs), min(b[1] for b in inputs),
                max(b[2] for b in inputs), max(b[3] for b in inputs))  # fmt: skip
        dark, _, _ = _darkness(self._camera, self._placement, self._sil, ibox, self._supersample)
        dark = dark.astype(np.float32).astype(np.float64)
        blurred = np.zeros(out.shape, dtype=np.float32)
        for j, obox, inbox in plans:
            if inbox is None:
                continue
            level = self._blur_level(dark, ibox, inbox, obox, float(levels[j]))
            ox0, oy0, ox1, oy1 = obox
            view = np.s_[oy0 - y0 : oy1 - y0, ox0 - x0 : ox1 - x0]
            here = idx[view] == j
            blurred[view] += np.where(here, level * (1 - frac[view]), 0).astype(np.float32)
            if len(levels) > 1:
                above = idx[view] + 1 == j
                blurred[view] += np.where(above, level * frac[view], 0).astype(np.float32)
        return (1.0 - blurred).astype(np.float32)

    def _input_box(self, out_box: Box, radius: int) -> Box | None:
        """The part of the outline's box that reaches ``out_box`` through a kernel of
        ``radius`` (mirrored at the frame box's edges)."""
        assert self._tool_box is not None
        fx0, fy0, fx1, fy1 = self._frame_box
        tx0, ty0, tx1, ty1 = self._tool_box
        xa, xb = _reach(out_box[0] - fx0, out_box[2] - fx0, radius, fx1 - fx0)
        ya, yb = _reach(out_box[1] - fy0, out_box[3] - fy0, radius, fy1 - fy0)
        bx0, bx1 = max(tx0, xa + fx0), min(tx1, xb + fx0)
        by0, by1 = max(ty0, ya + fy0), min(ty1, yb + fy0)
        return (bx0, by0, bx1, by1) if bx1 > bx0 and by1 > by0 else None

    def _blur_level(
        self, dark: FloatArray, dark_box: Box, in_box: Box, out_box: Box, sigma: float
    ) -> FloatArray:
        """The outline blurred at ``sigma`` over ``out_box``, from its pixels in ``in_box``."""
        fx0, fy0, fx1, fy1 = self._frame_box
        part = dark[in_box[1] - dark_box[1] : in_box[3] - dark_box[1],
                    in_box[0] - dark_box[0] : in_box[2] - dark_box[0]]  # fmt: skip
        kernel = _kernel(sigma)
        ay = _mirrored_matrix(out_box[1] - fy0, out_box[3] - fy0, in_box[1] - fy0,
                              in_box[3] - fy0, fy1 - fy0, kernel)  # fmt: skip
        ax = _mirrored_matrix(out_box[0] - fx0, out_box[2] - fx0, in_box[0] - fx0,
                              in_box[2] - fx0, fx1 - fx0, kernel)  # fmt: skip
        out: FloatArray = (ay @ part) @ ax.T
        return out


def _radius(sigma: float) -> int:
    return len(_kernel(sigma)) // 2


def _kernel(sigma: float) -> FloatArray:
    """OpenCV's Gaussian kernel for a float32 image at ``sigma`` (its size and values)."""
    size = round(sigma * 4 * 2 + 1) | 1
    out: FloatArray = cv2.getGaussianKernel(size, sigma, cv2.CV_32F).ravel().astype(np.float64)
    return out


def _mirror(v: NDArray[np.int64], n: int) -> NDArray[np.int64]:
    """Indices mirrored into [0, n) without repeating the edge (OpenCV's default border)."""
    if n == 1:
        return np.zeros_like(v)
    period = 2 * (n - 1)
    r = np.mod(v, period)
    out: NDArray[np.int64] = np.where(r < n, r, period - r)
    return out


def _reach(a: int, b: int, radius: int, n: int) -> tuple[int, int]:
    """The input indices [lo, hi) that outputs [a, b) see through a kernel of ``radius``."""
    virtual = np.arange(a - radius, b + radius, dtype=np.int64)
    if len(virtual) >= 2 * n:
        return 0, n
    m = _mirror(virtual, n)
    return int(m.min()), int(m.max()) + 1


def _mirrored_matrix(a: int, b: int, c: int, d: int, n: int, kernel: FloatArray) -> FloatArray:
    """The convolution by ``kernel`` (mirrored border, axis length ``n``) from inputs [c, d)
    to outputs [a, b), (b - a, d - c)."""
    r = len(kernel) // 2
    outs = np.arange(a, b, dtype=np.int64)
    taps = outs[:, None] + np.arange(-r, r + 1, dtype=np.int64)[None, :]
    src = _mirror(taps, n) - c
    inside = (src >= 0) & (src < d - c)
    rows = np.broadcast_to(np.arange(b - a)[:, None], taps.shape)[inside]
    weights = np.broadcast_to(kernel[None, :], taps.shape)[inside]
    flat = np.bincount(rows * (d - c) + src[inside], weights, minlength=(b - a) * (d - c))
    out: FloatArray = flat.reshape(b - a, d - c).astype(np.float64)
    return out


def _clip_half_plane(poly: FloatArray, normal: FloatArray, limit: float) -> FloatArray:
    """A convex polygon (k, 2) cut to ``normal . q <= limit`` (Sutherland-Hodgman)."""
    out = []
    side = poly @ normal - limit
    for i in range(len(poly)):
        p, q, sp, sq = poly[i], poly[(i + 1) % len(poly)], side[i], side[(i + 1) % len(poly)]
        if sp <= 0:
            out.append(p)
        if (sp < 0 < sq) or (sq < 0 < sp):
            out.append(p + (q - p) * (sp / (sp - sq)))
    return np.array(out).reshape(-1, 2)
