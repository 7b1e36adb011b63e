"""The camera's map to the X-Y stage, its distortion and the focus axis, fitted to a slide's
features at known stage and focus positions (no rendering: the truth's own projections)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.sim.stage_slide import ScopeTruth, StageSlideScope
from microcal.vision.stage_affine import SlideView, fit_stage_affine

TRUTH = ScopeTruth(um_per_px=0.1625, rotation_deg=2.0, stage_skew_deg=0.15, k1=1.5e-3,
                   k2=-3e-4, focus_tilt_deg=0.7, focus_azimuth_deg=120.0,
                   slide_rotation_deg=-3.0, slide_offset_um=(1.5, -2.0))  # fmt: skip


def _views(truth: ScopeTruth, positions: list[tuple[float, float, float]], noise_px: float,
           seed: int = 0) -> tuple[list[SlideView], StageSlideScope]:  # fmt: skip
    scope = StageSlideScope(truth, image_size_px=(400, 300))
    rng = np.random.default_rng(seed)
    views = []
    for x, y, z in positions:
        scope.move_stage(np.array([x, y]))
        scope.move_focus(z)
        q = scope.camera().project(scope.placement().points_world_um())
        inside = np.all((q > 5) & (q < np.array([395, 295])), axis=1)
        ids = np.flatnonzero(inside)
        views.append(
            SlideView(np.array([x, y]), z, ids, q[ids] + rng.normal(0, noise_px, (len(ids), 2)))
        )
    return views, scope


GRID = [(x, y, 0.0) for x in (-12.0, 0.0, 12.0) for y in (-10.0, 0.0, 10.0)]
FOCUS = [(0.0, 0.0, z) for z in (-0.8, -0.4, 0.4, 0.8)] + [(12.0, 10.0, z) for z in (-0.8, 0.8)]


def test_the_truth_is_recovered_with_covering_uncertainties():
    views, scope = _views(TRUTH, GRID + FOCUS, noise_px=0.02)
    cal = fit_stage_affine(views, scope.target.points_um(), (400, 300))
    A = TRUTH.affine_um()
    assert cal.affine_um[:, 2].tolist() == [0.0, 0.0]  # Micro-Manager's: no translation
    scale_true = np.linalg.norm(A[:, :2], axis=0)
    assert np.all(np.abs(cal.scale_um / scale_true - 1) < 1e-4)
    assert np.all(np.abs(cal.scale_um - scale_true) < 4 * cal.scale_sd_um)
    rot_true = math.degrees(math.atan2(A[1, 0], A[0, 0]))
    assert abs(cal.rotation_deg - rot_true) < 0.005
    assert abs(cal.rotation_deg - rot_true) < 4 * cal.rotation_sd_deg
    assert cal.mirrored  # image y down, stage y up
    assert abs(cal.skew_deg - TRUTH.stage_skew_deg) < 0.01  # the stage's own skew
    assert abs(cal.focus_angle_deg - TRUTH.focus_tilt_deg) < 0.01
    assert abs(cal.focus_angle_deg - TRUTH.focus_tilt_deg) < 4 * cal.focus_angle_sd_deg
    np.testing.assert_allclose(cal.drift_px_per_um, TRUTH.drift_px_per_um(), atol=2e-3)
    corner = math.hypot(400, 300) / 2 * (TRUTH.k1 + TRUTH.k2)  # 0.3 px
    assert abs(cal.distortion_corner_px - corner) < 0.01
    assert np.all(np.abs(cal.distortion - [TRUTH.k1, TRUTH.k2]) < 4 * cal.distortion_sd)
    assert cal.rms_px == pytest.approx(0.02 * math.sqrt(2), rel=0.15)
    assert cal.micromanager_affine == pytest.approx(A.ravel().tolist(), rel=2e-4, abs=2e-5)


def test_a_stage_error_per_view_widens_the_stated_uncertainty():
    """An error of a stage position moves a whole view: the views are the clusters."""
    views, scope = _views(TRUTH, GRID + FOCUS, noise_px=0.01)
    rng = np.random.default_rng(4)
    M = TRUTH.pixels_per_stage()
    shaken = [SlideView(v.stage_um, v.focus_um, v.ids, v.q_px + M @ rng.normal(0, 0.02, 2))
              for v in views]  # fmt: skip
    calm = fit_stage_affine(views, scope.target.points_um(), (400, 300))
    cal = fit_stage_affine(shaken, scope.target.points_um(), (400, 300))
    assert cal.pixel_size_sd_um > 3 * calm.pixel_size_sd_um


@pytest.mark.parametrize(
    ("positions", "error"),
    [
        (GRID[:3], r"^stage calibration: the slide was found in 3 views .* needs 4 or more$"),
        ([(x, 0.0, z) for x in (-5.0, 0.0, 5.0) for z in (0.0, 0.5)], r"lie on one line"),
        (GRID, r"every view is at one focus position"),
    ],
)
def test_too_little_to_fit_is_one_line(positions, error):
    views, scope = _views(TRUTH, positions, noise_px=0.02)
    with pytest.raises(InputError, match=error) as exc:
        fit_stage_affine(views, scope.target.points_um(), (400, 300))
    assert "\n" not in str(exc.value)
