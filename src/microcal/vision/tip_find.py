"""Finding a tool in an image, coarsely: where its tip is, which way it points, or why not.

A tool enters the field from its edge and tapers to its tip; against a bright field it is
darker than what lies around it. The light of the background is modelled by a smooth
surface through the brighter blocks of the image (a quadratic in x and y, fitted with the
darker blocks left out), so uneven illumination does not count as a tool; the tool is what
is clearly darker than that, beyond the texture of the background (tissue, debris), in one
elongated region that reaches the image's edge. Small dark specks (debris) and regions that
do not reach the edge are not tools.

The answer is the coarse tip (the region's end away from the edge), the axis (from the tip
towards the shank), a first half-angle and blur, or the reason there is none: no tool, two
tools, the tip out of the field.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray

__all__ = ["ToolBlob", "find_tool"]

#: Least darkness (1 - light / background) of a tool's pixel, whatever the texture.
MIN_DARKNESS = 0.12
#: Least length of a tool's region, px.
MIN_LENGTH_PX = 12.0


@dataclass(frozen=True)
class ToolBlob:
    """A tool found coarsely.

    Attributes
    ----------
    tip_px : (2,) float
        The region's end away from the image's edge, px.
    axis : (2,) float
        Unit direction from the tip towards the shank.
    half_angle_rad : float
        A first estimate of half the angle between the outline's edges.
    darkness : float
        The tool's typical darkness (1 - light / background).
    noise : float
        The background's spread in darkness (texture and noise).
    background : (H, W) float32
        The fitted light of the background.
    """

    tip_px: FloatArray
    axis: FloatArray
    half_angle_rad: float
    darkness: float
    noise: float
    background: NDArray[np.float32]


def background_light(gray: NDArray[np.float32]) -> NDArray[np.float32]:
    """The background's light: a quadratic surface through the brighter blocks, (H, W)."""
    h, w = gray.shape
    n = max(8, min(h, w) // 12)
    by, bx = h // n, w // n
    if by < 2 or bx < 2:
        return np.full_like(gray, float(np.percentile(gray, 75)))
    blocks = gray[: by * n, : bx * n].reshape(by, n, bx, n).transpose(0, 2, 1, 3)
    level = np.percentile(blocks.reshape(by, bx, -1), 75, axis=2).ravel()
    yy, xx = np.mgrid[0:by, 0:bx]
    x = ((xx.ravel() + 0.5) * n) / w - 0.5
    y = ((yy.ravel() + 0.5) * n) / h - 0.5
    A = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
    keep = level >= np.median(level)  # a tool may cover half the field: start from the light half
    for _ in range(4):
        coef, *_ = np.linalg.lstsq(A[keep], level[keep], rcond=None)
        resid = level - A @ coef
        spread = 1.4826 * float(np.median(np.abs(resid[keep]))) + 1e-6 * float(level.max())
        keep = resid > -3.0 * spread
        if keep.sum() < 8:
            keep = level >= np.median(level)
    gx = (np.arange(w, dtype=np.float32) + 0.5) / w - 0.5
    gy = (np.arange(h, dtype=np.float32) + 0.5) / h - 0.5
    X, Y = np.meshgrid(gx, gy)
    c = coef.astype(np.float32)
    out: NDArray[np.float32] = (
        c[0] + c[1] * X + c[2] * Y + c[3] * X * X + c[4] * X * Y + c[5] * Y * Y
    )
    return np.maximum(out, 1e-6 * float(level.max()) + 1e-6)


def find_tool(gray: NDArray[np.float32], scale: float = 1.0) -> ToolBlob | str:
    """The tool's coarse tip and axis in a grey image, or the reason there is none; ``scale``:
    the image's pixels per pixel of the image the lengths are meant in (0.5 for an image
    halved), which the least lengths and areas follow."""
    h, w = gray.shape
    min_len = MIN_LENGTH_PX * scale
    bg = background_light(gray)
    dark = 1.0 - cv2.GaussianBlur(gray, (0, 0), 1.0) / bg
    spread = 1.4826 * float(np.median(np.abs(dark - np.median(dark))))
    threshold = max(MIN_DARKNESS, 5.0 * spread)
    mask = (dark > threshold).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    tools = []
    for i in range(1, count):
        x, y, bw, bh, area = (int(v) for v in stats[i])
        edge = x == 0 or y == 0 or x + bw == w or y + bh == h
        if not edge or max(bw, bh) < min_len or area < 25 * scale * scale:
            continue
        tools.append(i)
    if not tools:
        return "no tool in view (nothing darker than the background reaches the image's edge)"
    if len(tools) > 1:
        big = [i for i in tools if max(int(stats[i, 2]), int(stats[i, 3])) >= 2 * min_len
               and int(stats[i, 4]) >= 60 * scale * scale]  # fmt: skip
        if len(big) > 1:
            return f"{len(big)} tools in view: expected one"
        tools = [max(tools, key=lambda i: int(stats[i, 4]))]
    ys, xs = np.nonzero(labels == tools[0])
    pts = np.column_stack([xs, ys]).astype(np.float64)
    centre = pts.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((pts - centre).T))
    axis = vecs[:, 1]
    rim = (xs == 0) | (ys == 0) | (xs == w - 1) | (ys == h - 1)
    if axis @ (pts[rim].mean(axis=0) - centre) < 0:
        axis = -axis
    t = (pts - centre) @ axis
    t0 = float(t.min())
    front = t < t0 + 2.0
    tip = centre + axis * t0
    normal = np.array([-axis[1], axis[0]])
    tip += normal * float(((pts[front] - centre) @ normal).mean())
    if rim[front].any() or not (1.0 <= tip[0] <= w - 2.0 and 1.0 <= tip[1] <= h - 2.0):
        return "the tip is out of the field (the tool reaches the image's edge at both ends)"
    # The half-angle from the widths at two distances from the tip (their difference cancels
    # what the threshold and the blur add to both).
    span = float(t.max()) - t0
    if span < min_len:
        return f"no tool in view (the dark region is {span:.0f} px long)"
    back = min(32.0 * scale, 0.6 * span)
    widths = []
    for at in (0.4 * back, back):
        ring = np.abs(t - (t0 + at)) < 1.5
        widths.append(float(np.ptp((pts[ring] - centre) @ normal)) + 1.0 if ring.any() else 0.0)
    half_angle = float(np.arctan2(0.5 * max(widths[1] - widths[0], 0.2), 0.6 * back))
    inside = dark[ys, xs]
    return ToolBlob(tip, axis, half_angle, float(np.median(inside)), max(spread, 1e-4), bg)
