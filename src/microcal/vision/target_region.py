"""Where in an image a small patterned target lies (its textured region), so that a
detector made for patterns that fill the image can search a target that covers a part of it.

A dot grid numbered from markers is found by its period and its dots' levels (see
:mod:`~microcal.vision.marker_grid`), both taken over the whole searched image: a slide that
overfills the field fills it, but an end-effector's target covers a few hundred pixels of a
large, mostly empty frame, where the background's noise, stretched to the image's range,
would make thousands of false dots. The textured region is found on a copy shrunk 4 times
(the noise averaged down, the pattern kept): the local standard deviation over a few pixels,
above a level halfway between the image's typical (median) one and its high (99th
percentile) one, joined over a pitch and a half (a slide's large dots are textured only at
their edges), the largest connected patch, and its box grown by a margin. A patch covering
more than half of the image is the whole image (a slide that overfills the field).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["textured_box"]

#: The shrink factor of the copy searched.
_SHRINK = 4
#: A region covering more than this share of the image is the whole image (a slide).
_MAX_SHARE = 0.5


def textured_box(
    gray: NDArray[np.float32], pitch_px: float, margin_px: float = 40.0
) -> tuple[int, int, int, int] | None:
    """The box (x0, y0, x1, y1) of the image's largest textured patch, or None when the
    texture covers most of the image (or there is none): search the whole image then.

    Parameters
    ----------
    gray : (H, W) float32
    pitch_px : float
        The pattern's period, px: the textured edges of neighbouring features (a slide's
        large dots have flat insides and flat ground between them) are joined over it.
    margin_px : float
        Added on every side (clipped to the image).
    """
    h, w = gray.shape
    if min(h, w) < 16 * _SHRINK:
        return None
    small = cv2.resize(gray, None, fx=1 / _SHRINK, fy=1 / _SHRINK, interpolation=cv2.INTER_AREA)
    small = small.astype(np.float32)
    mean = cv2.blur(small, (5, 5))
    var = cv2.blur(small * small, (5, 5)) - mean * mean
    std = np.sqrt(np.maximum(var, 0.0))
    typical, high = np.percentile(std, (50, 99))
    if high <= 2.0 * typical:  # texture everywhere, or nowhere
        return None
    mask = (std > 0.5 * (typical + high)).astype(np.uint8)
    join = 2 * int(np.ceil(0.75 * pitch_px / _SHRINK)) + 1  # a pitch and a half across
    mask = cv2.dilate(mask, np.ones((max(join, 5), max(join, 5)), np.uint8))
    n, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n < 2:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    bx, by, bw, bh = (int(v) * _SHRINK for v in stats[k, :4])
    if bw * bh > _MAX_SHARE * w * h:
        return None
    m = int(np.ceil(margin_px))
    return max(0, bx - m), max(0, by - m), min(w, bx + bw + m), min(h, by + bh + m)
