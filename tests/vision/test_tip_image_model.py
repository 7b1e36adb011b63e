"""The image fit of a tool's tip: a glass pipette in focus, its Jacobian, its covariance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.sim.tool_population import draw_tool_image
from microcal.vision.detect import to_gray
from microcal.vision.tip import default_method, detect_tip
from microcal.vision.tip_find import find_tool
from microcal.vision.tip_image_model import (
    _STEPS,
    ToolImageModel,
    _window,
    glass_loss,
    glass_loss_mean,
)
from microcal.vision.tip_target import parse_tip


def _along_across(det, truth) -> tuple[float, float]:
    e = det.apex_px - truth.tip_px
    a = truth.axis_px
    return float(e @ a), float(e[0] * -a[1] + e[1] * a[0])


def test_a_glass_pipette_in_focus_is_found_to_a_tenth_of_a_pixel():
    # Four pipettes of the population (plain and tissue backgrounds, noise on 8 bits).
    errors = []
    for seed in (10_000, 10_001, 10_002, 10_004):
        image = draw_tool_image(seed, "pipette", 0.0)
        det = detect_tip(image.image, parse_tip(image.spec), method="image fit")
        assert det.found, (seed, det.reason)
        assert det.method == "image fit"
        errors.append(_along_across(det, image.truths[0]))
        assert 0.0 < det.std_px < 0.1
    e = np.array(errors)
    assert np.all(np.abs(e.mean(axis=0)) < 0.1)
    assert np.all(np.abs(e) < 0.2)


def test_the_image_fit_finds_an_opaque_tip_too():
    image = draw_tool_image(30_001, "jaw", 0.0)
    det = detect_tip(image.image, parse_tip(image.spec), method="image fit")
    assert det.found
    assert det.method == "image fit"
    along, across = _along_across(det, image.truths[0])
    assert abs(along) < 0.1
    assert abs(across) < 0.05
    e = det.apex_px - image.truths[0].tip_px
    assert float(e @ np.linalg.solve(det.cov_px, e)) < 9.21  # within the 99 % ellipse


def test_the_method_is_chosen_per_tool_and_a_wrong_one_is_one_line():
    assert default_method(parse_tip("tip:pipette")) == "image fit"
    for kind in ("needle", "jaw", "any"):
        assert default_method(parse_tip(f"tip:{kind}")) == "fast fit"
    image = draw_tool_image(30_001, "jaw", 0.0)
    with pytest.raises(InputError, match="method: expected one of fast fit, model fit, image fit"):
        detect_tip(image.image, parse_tip("tip:jaw"), method="guess")


def test_the_jacobian_agrees_with_central_differences():
    image = draw_tool_image(10_001, "pipette", 0.0)
    gray = to_gray(image.image)
    blob = find_tool(gray)
    assert not isinstance(blob, str)
    box, mask = _window(gray.shape, blob.tip_px, blob.axis, 0.1, 0.8, 6.0, 20.0)
    normal = np.array([-blob.axis[1], blob.axis[0]])
    model = ToolImageModel(gray, parse_tip(image.spec), box, mask, blob.tip_px + 10 * blob.axis,
                           normal)  # fmt: skip
    p = model.parameters(blob.tip_px - box[:2], blob.axis, 0.1, 0.8,
                         np.array([math.log(0.4), 0.2, 0.03]))  # fmt: skip
    # forward differences (the fit's) and central ones (the covariance's) against central
    # differences of half the step
    forward, central = model.jacobian(p), model.jacobian(p, central=True)
    for i, h in enumerate(_STEPS):
        q1, q2 = p.copy(), p.copy()
        q1[i] += h / 2
        q2[i] -= h / 2
        finer = (model.residuals(q1) - model.residuals(q2)) / h
        scale = float(np.linalg.norm(finer))
        assert scale > 0, i
        assert float(np.linalg.norm(central[:, i] - finer)) < 0.1 * scale, i
        assert float(np.linalg.norm(forward[:, i] - finer)) < 0.35 * scale, i


def test_the_glass_loss_averaged_over_a_width_is_its_mean_and_smooth():
    xi = np.linspace(0.0, 1.0, 2001)
    for at, width in ((0.3, 0.1), (0.69, 0.05), (0.05, 0.2)):
        inside = np.abs(xi - at) <= width / 2
        # the loss is even in xi: an interval across 0 folds back
        if at - width / 2 < 0:
            inside |= xi <= width / 2 - at
        direct = np.mean(glass_loss(np.concatenate([xi[inside & (xi >= at - width / 2)],
                                                    xi[xi <= width / 2 - at]])))  # fmt: skip
        assert abs(float(glass_loss_mean(np.array([at]), np.array([width]))[0]) - direct) < 0.01
    # across the lumen's wall (where the loss jumps) the mean moves by small steps
    m = glass_loss_mean(np.linspace(0.6, 0.8, 201), np.full(201, 0.05))
    assert float(np.max(np.abs(np.diff(m)))) < 0.02
