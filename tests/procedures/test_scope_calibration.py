"""The microscope camera's calibration against its X-Y stage on the rendered slide: the
procedure moves the stage and the focus, finds the slide (defocused frames numbered from the
focused one) and fits; it leaves the stage and focus where they were."""

from __future__ import annotations

import math

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.procedures.scope_calibration import calibrate_scope, depth_for, scope_plan
from microcal.sim.stage_slide import SIM_OBJECTIVES, StageSlideScope, random_truth


def test_the_rendered_slide_gives_the_affine_within_the_issue_s_bounds():
    truth = random_truth(3, "40x")
    scope = StageSlideScope(truth, image_size_px=(256, 256), seed=3)
    obj = SIM_OBJECTIVES["40x"]
    plan = scope_plan(256 * obj.um_per_px, depth_for(obj.numerical_aperture), focus_steps=3)
    scope.move_stage(np.array([5.0, -3.0]))
    scope.move_focus(0.0)
    run = calibrate_scope(scope.move_stage, scope.move_focus, scope.grab, scope.target, plan,
                          start_stage_um=np.array([5.0, -3.0]))  # fmt: skip
    cal = run.calibration
    # the views far right see the marker dots at the image's edge, and some are numbered a
    # few pitches off: they miss the stage's moves and are numbered again from the first fit
    assert run.missed == []
    assert cal.views == len(plan.positions) == 15
    assert run.renumbered
    assert all("numbered again" in line for line in run.renumbered)
    A = truth.affine_um()[:, :2]
    assert np.all(np.abs(cal.scale_um / np.linalg.norm(A, axis=0) - 1) < 1e-3)  # 0.1 %
    assert abs(cal.rotation_deg - math.degrees(math.atan2(A[1, 0], A[0, 0]))) < 0.05
    assert abs(cal.focus_angle_deg - truth.focus_tilt_deg) < 0.05
    assert cal.rms_px < 0.05
    assert run.curvature is None
    assert run.frames == 15
    np.testing.assert_array_equal(scope.stage_um, [5.0, -3.0])  # back where it started
    assert scope.focus_um == 0.0


def test_a_slide_never_found_is_one_line_naming_the_first_miss():
    truth = random_truth(0, "40x")
    scope = StageSlideScope(truth, image_size_px=(128, 128))
    plan = scope_plan(20.0, 0.5, grid=2, focus_steps=2)
    blank = lambda: np.full((128, 128), 0.5, np.float32)  # noqa: E731
    moves = []
    with pytest.raises(InputError) as exc:
        calibrate_scope(moves.append, scope.move_focus, blank, scope.target, plan)
    # the 4 positions of the square, the 3 of the focus steps (which share one move each),
    # and back to the start
    assert len(moves) == 4 + 3 + 1
    text = str(exc.value)
    assert text.startswith("stage calibration: the slide was found in 0 views")
    assert "(first miss: view 1 (stage -4.0, -4.0 µm, focus +0.00 µm): " in text
    assert "\n" not in text
