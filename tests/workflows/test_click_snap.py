"""A second click taken onto the epipolar curve, or onto the target found near it."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.workflows.click_snap import SNAP_LINE_PX, nearest_on_curve, snap_click

CURVE = np.array([[0.0, 0.0], [100.0, 0.0], [200.0, 50.0]])


def test_the_nearest_point_of_a_polyline():
    foot, d = nearest_on_curve(CURVE, [40.0, 7.0])
    np.testing.assert_allclose(foot, [40.0, 0.0])
    assert d == pytest.approx(7.0)
    foot, d = nearest_on_curve(CURVE, [-10.0, 0.0])  # beyond the end: the end
    np.testing.assert_allclose(foot, [0.0, 0.0])
    assert d == pytest.approx(10.0)


def test_a_feature_near_the_line_and_the_click_takes_the_click():
    snapped = snap_click(CURVE, [52.0, 6.0], 1.0, [50.0, 2.0], 0.02)
    assert snapped.how == "feature"
    np.testing.assert_allclose(snapped.q_px, [50.0, 2.0])
    assert snapped.std_px == 0.02
    assert snapped.line_px == pytest.approx(2.0)
    assert snapped.moved_px == pytest.approx(np.hypot(2.0, 4.0))


@pytest.mark.parametrize(
    "feature", [[50.0, SNAP_LINE_PX + 1.0], [90.0, 0.0], None], ids=["off-line", "far", "none"]
)
def test_otherwise_the_click_goes_onto_the_line(feature):
    snapped = snap_click(CURVE, [52.0, 6.0], 1.0, feature, 0.02)
    assert snapped.how == "line"
    np.testing.assert_allclose(snapped.q_px, [52.0, 0.0])
    assert snapped.std_px == 1.0
    assert snapped.moved_px == pytest.approx(6.0)


def test_without_a_curve_in_the_view_the_click_stays():
    snapped = snap_click(np.empty((0, 2)), [52.0, 6.0], 1.0, [52.0, 6.0], 0.02)
    assert snapped.how == "click"
    np.testing.assert_allclose(snapped.q_px, [52.0, 6.0])
    assert snapped.as_dict()["line_px"] is None  # JSON has no NaN
