"""The fast tip fit (the default): accuracy on rendered tools, its Jacobian, its covariance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from microcal.sim.tool_population import draw_tool_image
from microcal.vision.detect import to_gray
from microcal.vision.tip import detect_tip
from microcal.vision.tip_fast import MODEL_ERROR_PER_BLUR, _Patch, coarse_tool
from microcal.vision.tip_target import parse_tip

FIRST_SEED = {"pipette": 10_000, "needle": 20_000, "jaw": 30_000}


def _errors(kind: str, focus_dof: float, seeds: range) -> np.ndarray:
    """(n, 2) errors along and across the true axis."""
    out = []
    for seed in seeds:
        image = draw_tool_image(seed, kind, focus_dof)
        det = detect_tip(image.image, parse_tip(image.spec), method="fast fit")
        assert det.found, (seed, det.reason)
        assert det.method == "fast fit"
        e = det.apex_px - image.truths[0].tip_px
        a = image.truths[0].axis_px
        out.append([float(e @ a), float(e[0] * -a[1] + e[1] * a[0])])
    return np.array(out)


@pytest.mark.parametrize("kind", ["pipette", "needle", "jaw"])
def test_the_fast_fit_finds_each_tool_in_focus_to_a_tenth_of_a_pixel(kind):
    first = FIRST_SEED[kind]
    e = _errors(kind, 0.0, range(first + 20, first + 32))
    assert np.all(np.abs(e.mean(axis=0)) < 0.1)
    assert float(np.sqrt(np.mean(np.sum((e - e.mean(axis=0)) ** 2, axis=1) / 2))) < 0.15
    assert np.all(np.abs(e[:, 1]) < 0.1)  # across the axis, symmetry holds it


@pytest.mark.parametrize("kind", ["needle", "jaw"])
def test_the_fast_fit_at_one_depth_of_field_off_errs_by_under_half_a_pixel(kind):
    first = FIRST_SEED[kind] + 100
    e = _errors(kind, 1.0, range(first + 12, first + 20))
    assert float(np.sqrt(np.mean(np.sum(e**2, axis=1) / 2))) < 0.5


@pytest.mark.parametrize("kind", ["pipette", "jaw"])
def test_the_layers_derivatives_agree_with_central_differences(kind):
    image = draw_tool_image(FIRST_SEED[kind] + 1, kind, 1.0)
    gray = to_gray(image.image)
    truth = image.truths[0]
    axis = truth.axis_px
    patch = _Patch(gray, parse_tip(image.spec), truth.tip_px, axis, 0.1, 2.0)
    p = np.array([*truth.tip_px + 0.3, math.atan2(axis[1], axis[0]) + 0.02, 0.1,
                  math.log(1.2), 1.5, 0.03])  # fmt: skip
    _, jac = patch.layers(p, True)
    assert jac is not None
    for i in range(p.size):
        h = 1e-5
        up, down = p.copy(), p.copy()
        up[i] += h
        down[i] -= h
        central = (patch.layers(up, False)[0] - patch.layers(down, False)[0]) / (2 * h)
        # the glass's table is bilinear: its derivative tables agree to a few per cent
        tol = 0.08 if kind == "pipette" else 1e-4
        for layer in range(central.shape[0]):
            miss = np.linalg.norm(jac[layer, :, i] - central[layer])
            assert miss <= tol * np.linalg.norm(central[layer]) + 1e-9, (i, layer)


def test_the_stated_covariance_holds_the_model_error_and_covers_the_tip():
    image = draw_tool_image(30_101, "jaw", 1.0)
    det = detect_tip(image.image, parse_tip(image.spec))
    assert det.found
    floor = MODEL_ERROR_PER_BLUR[1] * det.blur_px
    assert float(np.linalg.eigvalsh(det.cov_px).min()) >= 0.9 * floor**2
    e = det.apex_px - image.truths[0].tip_px
    assert float(e @ np.linalg.solve(det.cov_px, e)) < 9.21  # within the 99 % ellipse


def test_the_coarse_search_on_the_halved_image_is_in_whole_image_pixels():
    image = draw_tool_image(20_003, "needle", 0.0)
    blob = coarse_tool(to_gray(image.image))
    assert not isinstance(blob, str)
    truth = image.truths[0]
    step = blob.tip_px - truth.tip_px
    assert abs(float(step[0] * truth.axis_px[1] - step[1] * truth.axis_px[0])) < 2.0
    assert float(blob.axis @ truth.axis_px) > 0.99


def test_a_faint_end_far_from_the_coarse_tip_is_followed():
    # The coarse search ends some 50 px behind this pipette's faint end on its background.
    image = draw_tool_image(600_003, "pipette", 0.0)
    blob = coarse_tool(to_gray(image.image))
    assert not isinstance(blob, str)
    assert float(np.linalg.norm(blob.tip_px - image.truths[0].tip_px)) > 30.0
    det = detect_tip(image.image, parse_tip(image.spec), method="fast fit")
    assert det.found, det.reason
    assert float(np.linalg.norm(det.apex_px - image.truths[0].tip_px)) < 0.3
