"""The tool's blurred transmission computed by region (sim.tool_layer)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal.sim.patch import patch_rig
from microcal.sim.tool_layer import ToolLayer, _kernel, _mirrored_matrix
from microcal.sim.tools import render_tools


@pytest.mark.parametrize("sigma", [0.7, 3.0, 40.0])
def test_the_mirrored_convolution_is_opencvs_gaussian_blur(sigma: float) -> None:
    img = np.random.default_rng(1).random((37, 53)).astype(np.float32)
    ay = _mirrored_matrix(0, 37, 0, 37, 37, _kernel(sigma))
    ax = _mirrored_matrix(0, 53, 0, 53, 53, _kernel(sigma))
    # 40 px: the kernel is wider than the image, mirrored more than once
    np.testing.assert_allclose(ay @ img.astype(np.float64) @ ax.T,
                               cv2.GaussianBlur(img, (0, 0), sigma), atol=2e-6)  # fmt: skip


@pytest.mark.parametrize("seed", [0, 3])
def test_the_whole_frame_is_the_one_render_tools_gives(seed: int) -> None:
    rig = patch_rig(seed, size_px=(384, 320))
    rig.move_focus(-6.0)  # the tip out of focus: many levels of blur
    frame = rig.grab()
    cfg = rig.config
    old, _ = render_tools(frame.camera, [frame._placement], cfg.optics,
                          supersample=cfg.supersample)  # fmt: skip
    layer = ToolLayer(frame.camera, frame._placement, cfg.optics, cfg.supersample)
    new = layer.transmission((0, 0, 384, 320))
    assert float(old.min()) < 0.9  # the tool is in the frame
    np.testing.assert_allclose(new, old, atol=1e-6)
    for box in [(150, 120, 250, 220), (0, 0, 40, 40), (300, 140, 384, 200), (192, 150, 383, 170)]:
        x0, y0, x1, y1 = box
        np.testing.assert_allclose(layer.transmission(box), new[y0:y1, x0:x1], atol=1e-6)


def test_a_region_read_alone_is_the_same_region_of_the_whole_frame() -> None:
    rig = patch_rig(1, size_px=(512, 512))
    rig.move_focus(-3.0)
    frame = rig.grab()
    boxes = [(200, 220, 330, 300), (256, 240, 512, 270), (0, 0, 64, 64)]
    alone = [frame.region(*box) for box in boxes]  # read before the whole frame is made
    full = frame.full()
    for (x0, y0, x1, y1), got in zip(boxes, alone, strict=True):
        want = full[y0:y1, x0:x1]
        diff = np.abs(got.astype(int) - want.astype(int))  # float32 rounding at a count's half
        assert int(diff.max()) <= 1
        assert float(np.mean(diff > 0)) < 1e-3
