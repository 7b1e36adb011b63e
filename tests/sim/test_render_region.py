"""The cameras' rendering path: float32 regions (render_region) and the background frames."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import sim
from microcal.sim.render import render_placement, render_region, roi_of


def _thesis_board(seed: int = 0):
    plat = sim.platform("thesis", seed=seed)
    plat.manipulator.move_to_um([4000, 4000, 2400])
    plat.manipulator.wait_until_stopped(plat.clock)
    return plat, plat.cameras["top"], plat.scene(plat.clock.now_s())[0]


def test_region_in_float32_matches_float64_render():
    _, cam, placement = _thesis_board()
    roi = roi_of(cam.model, placement, 10.0)
    offset = np.array([0.3, -0.4])
    v64, a64 = render_placement(cam.model, placement, roi, supersample=2, offset_px=offset)
    v32, a32 = render_region(cam.model, placement, roi, supersample=2, offset_px=offset)
    assert v32.dtype == np.float32
    assert a32.dtype == np.float32
    # reflectance 0..1: single precision leaves ~1e-4 where an edge crosses a subsample
    np.testing.assert_allclose(v32, v64, atol=1e-3)
    np.testing.assert_allclose(a32, a64, atol=1e-3)
    assert np.abs(v32 - v64).mean() < 1e-5


@pytest.mark.slow
def test_a_region_rendered_alone_equals_that_region_of_the_whole_frame():
    _, cam, placement = _thesis_board()
    x0, y0, x1, y1 = roi_of(cam.model, placement, 10.0)
    w, h = cam.model.image_size_px
    full, full_alpha = render_region(cam.model, placement, (0, 0, w, h), supersample=2)
    # a box across the board's edge, not aligned with the 64 px tiles of undistorted pixels
    box = (x0 + 7, y0 - 5, (x0 + x1) // 2 + 3, (y0 + y1) // 2 + 1)
    alone, alone_alpha = render_region(cam.model, placement, box, supersample=2)
    part = (slice(box[1], box[3]), slice(box[0], box[2]))
    # inside the box the pixels are computed alike; on its border the distortion's slope
    # comes from one side (np.gradient), a difference of ~1e-6 px in the footprint
    np.testing.assert_allclose(alone, full[part], atol=1e-3)
    np.testing.assert_allclose(alone_alpha, full_alpha[part], atol=1e-3)
    np.testing.assert_allclose(alone[1:-1, 1:-1], full[part][1:-1, 1:-1], atol=1e-5)


def test_frames_have_the_noise_model_inside_and_outside_the_rendered_box():
    _, cam, _ = _thesis_board(seed=3)
    frames = np.array([cam.grab() for _ in range(40)], dtype=np.float64)
    (x0, y0, x1, y1) = cam._rois[0]
    fm = cam.formation
    k = (2**cam.bit_depth - 1) / fm.full_well_e
    gain = fm.full_well_e * fm.illumination * k
    # background far from the board (top-left corner): level x vignetting x gain, and the
    # noise std sqrt(DN k + (read noise k)^2), frame to frame
    corner = frames[:, 10:60, 10:60]
    vig = cam._vignette[10:60, 10:60].astype(np.float64)
    dn = cam.reflectance.background * vig * gain
    std = np.sqrt(dn * k + (fm.read_noise_e * k) ** 2)
    # the mean over 40 frames x 2500 pixels: its own scatter is ~0.3 DN
    assert abs(corner.mean() - dn.mean()) < 0.3
    assert abs(corner.std(axis=0, ddof=1).mean() / std.mean() - 1) < 0.15
    # inside the rendered box the noise is fresh in every frame: two frames differ there
    # as two independent draws do
    inside = frames[:, y0:y1, x0:x1]
    d = (inside[1:] - inside[:-1]).std() / np.sqrt(2)
    assert 0.7 < d / std.mean() < 1.6
    # outside it the noise is fresh too (frames averaged there lose their noise as
    # independent frames do): no two frames alike
    distinct = {frames[i, 10:60, 10:60].tobytes() for i in range(len(frames))}
    assert len(distinct) == len(frames)
    outside = frames[:, 10:60, 10:60]
    d = (outside[1:] - outside[:-1]).std() / np.sqrt(2)
    assert 0.7 < d / std.mean() < 1.6


def test_same_seed_same_frames_with_the_float32_path():
    a = [_thesis_board(seed=5)[1].grab() for _ in range(2)]
    b = [_thesis_board(seed=5)[1].grab() for _ in range(2)]
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
