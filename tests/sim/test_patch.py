"""The ``patch`` preset: a microscope's camera, its focus drive, the sample and the pipette."""

from __future__ import annotations

import math
import time

import cv2
import numpy as np
import pytest

from microcal.errors import InputError, LimitError
from microcal.sim.clock import SimClock
from microcal.sim.focus_drive import FocusDrive, FocusErrors
from microcal.sim.patch import PatchConfig, patch_rig


def test_the_preset_is_a_40x_water_objective_on_a_2048_px_camera() -> None:
    cfg = PatchConfig()
    assert cfg.um_per_px == pytest.approx(0.1625)
    assert cfg.field_um == pytest.approx((332.8, 332.8))
    assert 1.0 <= cfg.depth_of_field_um <= 1.5  # lambda n / NA^2 + n e / NA
    assert cfg.depth_of_field_um == pytest.approx(0.55 * 1.333 / 0.64 + 1.333 * 0.1625 / 0.8)
    assert 25.0 <= cfg.approach_deg <= 35.0
    rig = patch_rig(0)
    cam = rig.camera()
    assert cam.image_size_px == (2048, 2048)
    # the pixel in the object, and the tip at {G}'s origin in the field's middle
    q = cam.project(np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]))
    assert q[1, 0] - q[0, 0] == pytest.approx(10.0 / 0.1625)
    assert np.allclose(rig.truth().tip_px, 1023.5, atol=4.0)
    with pytest.raises(InputError, match="approach_deg"):
        patch_rig(0, approach_deg=95.0)


def test_the_focus_drive_has_scale_tilt_backlash_and_scatter() -> None:
    errors = FocusErrors(scale=0.003, tilt_deg=0.3, tilt_azimuth_deg=0.0, backlash_um=0.4,
                         noise_um=0.0)  # fmt: skip
    clock = SimClock()
    drive = FocusDrive(clock, np.random.default_rng(0), errors)
    assert np.allclose(drive.objective_offset_um(), 0.0)
    drive.move_to(100.0)  # from below
    up = drive.objective_offset_um()
    assert drive.position_um() == 100.0
    assert up[2] == pytest.approx(100.3 * math.cos(math.radians(0.3)))
    assert up[0] == pytest.approx(100.3 * math.sin(math.radians(0.3)))  # the view shifts
    drive.move_to(110.0)
    drive.move_to(100.0)  # from above: the backlash
    assert drive.objective_offset_um()[2] - up[2] == pytest.approx(0.4 * 1.003 * math.cos(
        math.radians(0.3)))  # fmt: skip
    assert clock.now_s() > 0.0  # moves take time
    with pytest.raises(LimitError, match="outside the focus drive's range") as info:
        drive.move_to(1e4)
    assert "\n" not in str(info.value)
    noisy = FocusDrive(SimClock(), np.random.default_rng(1), FocusErrors(noise_um=0.02))
    ends = []
    for _ in range(200):
        noisy.move_to(5.0)
        ends.append(noisy.objective_offset_um()[2])
        noisy.move_to(0.0)
    assert 0.015 < float(np.std(ends)) < 0.025


def test_a_region_of_a_frame_is_the_same_pixels_as_the_larger_frame_there() -> None:
    rig = patch_rig(3, size_px=(256, 256))
    frame = rig.grab()
    big = frame.region(60, 70, 200, 190).astype(int)
    small = frame.region(100, 100, 164, 150).astype(int)
    # the same noise and sample; the tool's blur, interpolated between levels chosen over
    # the region, within a count or two of 4095
    assert np.abs(small - big[30:80, 40:104]).max() <= 2
    assert np.mean(small == big[30:80, 40:104]) > 0.85
    away = frame.region(0, 0, 40, 40).astype(int)  # no tool there: exact
    assert np.array_equal(away, frame.region(0, 0, 80, 60)[:40, :40].astype(int))
    assert np.abs(frame.full()[100:150, 100:164].astype(int) - small).max() <= 2
    assert frame.region(250, 250, 300, 300).shape == (6, 6)  # clipped to the frame


def test_a_region_of_a_full_frame_renders_in_a_fraction_of_a_second() -> None:
    rig = patch_rig(0)
    frame = rig.grab_at_focus(0.0)
    x, y = (round(v) for v in frame.truth.tip_px)
    t0 = time.perf_counter()
    part = frame.region(x - 64, y - 64, x + 64, y + 64)
    assert time.perf_counter() - t0 < 1.0
    assert part.shape == (128, 128)
    assert part.dtype == np.uint16


def _sharpness(image: np.ndarray) -> float:
    g = cv2.GaussianBlur(image.astype(np.float32), (0, 0), 0.8)
    return float(np.mean(cv2.Sobel(g, cv2.CV_32F, 1, 0) ** 2 + cv2.Sobel(g, cv2.CV_32F, 0, 1) ** 2))


def test_the_tip_blurs_with_defocus_and_the_sample_stays_bright_field() -> None:
    rig = patch_rig(1, size_px=(256, 256))
    z = float(rig.truth().tip_um[2])
    sharp = {}
    for dz in (-3.0, 0.0, 3.0):
        frame = rig.grab_at_focus(z + dz)
        x, y = (round(v) for v in frame.truth.tip_px)
        assert abs(frame.truth.defocus_um + dz) < 0.1  # the tip's height above the focus
        # the tip's end only: the part in front of the shank, whose depth is the tip's
        sharp[dz] = _sharpness(frame.region(x - 24, y - 12, x + 3, y + 12).astype(np.float32)
                               + frame.region(x - 3, y - 12, x + 24, y + 12)[:, :27])  # fmt: skip
        whole = frame.full()
        level = float(np.median(whole)) / 4095
        assert 0.55 < level < 0.85  # light background, the tool darker
    assert sharp[0.0] > 1.5 * max(sharp[-3.0], sharp[3.0])


def test_the_stage_moves_the_sample_not_the_pipette() -> None:
    rig = patch_rig(2, size_px=(256, 256))
    before = rig.grab()
    rig.stage.move_to_um(np.array([13.0, 0.0, 0.0]))
    rig.clock.sleep(1.0)
    after = rig.grab()
    assert np.allclose(before.truth.tip_px, after.truth.tip_px)
    a = before.region(20, 160, 236, 250).astype(np.float32)  # below the pipette
    b = after.region(20, 160, 236, 250).astype(np.float32)
    shift = 13.0 / rig.config.um_per_px  # 80 px to the right
    n = round(shift)
    ncc_moved = np.corrcoef(a[:, :-n].ravel(), b[:, n:].ravel())[0, 1]
    ncc_still = np.corrcoef(a.ravel(), b.ravel())[0, 1]
    assert ncc_moved > 0.8 > ncc_still
