"""The tip from the tool's profiles (not yet the detection's default): where it stands."""

from __future__ import annotations

import numpy as np

from microcal.sim.tool_population import draw_tool_image
from microcal.vision.detect import to_gray
from microcal.vision.tip_find import find_tool
from microcal.vision.tip_profile import profile_tip
from microcal.vision.tip_target import parse_tip


def test_a_needle_in_focus_is_found_on_its_axis_and_near_its_tip():
    along, across = [], []
    for seed in range(20_000, 20_012):
        image = draw_tool_image(seed, "needle", 0.0)
        gray = to_gray(image.image)
        blob = find_tool(gray)
        assert not isinstance(blob, str), blob
        fit = profile_tip(gray, blob, parse_tip(image.spec))
        assert not isinstance(fit, str), fit
        truth = image.truths[0]
        e = fit.apex_px - truth.tip_px
        along.append(float(e @ truth.axis_px))
        across.append(float(e[0] * -truth.axis_px[1] + e[1] * truth.axis_px[0]))
        assert float(fit.axis @ truth.axis_px) > 0.999
    # Across the axis it is as good as the model fit; along it, not yet (tissue backgrounds and
    # a steep tool leave up to 0.8 px): the reason it is not the default.
    assert max(np.abs(across)) < 0.15
    assert float(np.median(np.abs(along))) < 0.1
    assert max(np.abs(along)) < 1.0
