"""The tip target: its spec, the model fit and the reference match on rendered tools, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.sim.render import Placement, render_placement
from microcal.sim.tool_population import (
    NUMERICAL_APERTURE,
    UM_PER_PX,
    draw_tool_image,
    population_camera,
)
from microcal.sim.tools import Optics, ToolPlacement, ToolScene, tool_image
from microcal.vision.detect import detect
from microcal.vision.targets import parse_spec, parse_target
from microcal.vision.tip import TipDetection, detect_tip
from microcal.vision.tip_reference import build_reference, match_tip
from microcal.vision.tip_target import TipTarget, parse_tip


def test_tip_specs_parse_and_print_back():
    assert parse_tip("tip") == TipTarget("any")
    t = parse_tip("tip:pipette:10:1")
    assert (t.kind, t.taper_deg, t.tip_um) == ("pipette", 10.0, 1.0)
    assert parse_tip(t.spec) == t
    assert isinstance(parse_spec("tip:needle"), TipTarget)
    assert parse_spec("chessboard:4x3:400") == parse_target("chessboard:4x3:400")


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("tip:scalpel", "KIND pipette, needle, jaw or any"),
        ("tip:pipette:200", "taper of 0.5 to 90 degrees"),
        ("tip:needle:10:0", "tip of 0 to 1000 µm"),
        ("tip:needle:x", "expected tip"),
    ],
)
def test_bad_tip_specs_are_one_line_errors(spec, message):
    with pytest.raises(InputError, match=message):
        parse_tip(spec)


def test_a_tip_spec_where_a_board_is_needed_says_so():
    with pytest.raises(InputError, match="a tool's tip, not a board"):
        parse_target("tip:pipette")


def _errors(kind: str, focus_dof: float, seeds: range) -> np.ndarray:
    out = []
    for seed in seeds:
        image = draw_tool_image(seed, kind, focus_dof)
        det = detect_tip(image.image, parse_tip(image.spec), method="model fit")
        assert det.found, (seed, det.reason)
        assert det.method == "model fit"
        out.append(det.apex_px - image.truths[0].tip_px)
    return np.array(out)


@pytest.mark.parametrize("kind", ["needle", "jaw"])
def test_the_model_fit_finds_an_opaque_tip_in_focus_to_a_tenth_of_a_pixel(kind):
    e = _errors(kind, 0.0, range(300, 306))
    assert np.all(np.abs(e.mean(axis=0)) < 0.1)
    assert float(np.sqrt(np.mean(np.sum((e - e.mean(axis=0)) ** 2, axis=1) / 2))) < 0.15


def test_the_model_fit_at_one_depth_of_field_off_stays_within_half_a_pixel():
    e = _errors("needle", 1.0, range(310, 314))
    assert np.all(np.hypot(e[:, 0], e[:, 1]) < 0.5)


def test_the_detection_gives_the_axis_and_a_covariance():
    image = draw_tool_image(320, "needle", 0.0)
    det = detect_tip(image.image, parse_tip(image.spec))
    truth = image.truths[0]
    assert float(det.axis @ truth.axis_px) > 0.999
    assert det.cov_px.shape == (2, 2)
    assert np.all(np.linalg.eigvalsh(det.cov_px) > 0)
    assert 0.0 < det.std_px < 0.2
    # a region of interest gives whole-image pixels
    x, y = np.round(truth.tip_px).astype(int)
    boxed = detect_tip(image.image, parse_tip(image.spec), roi=(x - 60, y - 60, x + 60, y + 60))
    assert boxed.found
    assert np.allclose(boxed.apex_px, det.apex_px, atol=0.1)


@pytest.mark.parametrize(
    ("case", "reason"),
    [
        ("none", "no tool in view"),
        ("two", "2 tools in view"),
        ("outside", "the tip is out of the field"),
    ],
)
def test_what_is_not_one_tip_in_the_field_is_refused_with_its_reason(case, reason):
    image = draw_tool_image(7, "needle", 0.0, case)  # type: ignore[arg-type]
    det = detect_tip(image.image, parse_tip("tip:needle"))
    assert not det.found
    assert reason in det.reason


def test_a_tip_far_out_of_focus_is_refused_as_too_defocused():
    image = draw_tool_image(11, "needle", 4.0)
    det = detect_tip(image.image, parse_tip(image.spec), max_blur_px=2.0)
    assert not det.found
    assert "too defocused" in det.reason or "no tool" in det.reason


def test_a_tip_spec_on_a_board_image_finds_no_tip_and_a_board_spec_on_a_tool_image_no_board():
    camera = population_camera()
    board = parse_target("chessboard:4x3:20")
    placement = Placement(board, np.diag([1.0, -1.0, -1.0]), np.array([-30.0, 25.0, 0.0]))
    value, alpha = render_placement(camera, placement, (0, 0, 256, 256))
    image = np.clip((0.35 * (1 - alpha) + value * alpha) * 250, 0, 255).astype(np.uint8)
    det = detect_tip(image, parse_tip("tip:pipette"))
    assert not det.found
    assert det.reason
    tool = draw_tool_image(3, "needle", 0.0)
    assert not detect(tool.image, board).found


def test_nothing_found_is_a_detection_not_an_error():
    det = detect_tip(np.full((64, 64), 128, np.uint8), TipTarget())
    assert not det.found
    assert np.all(np.isnan(det.apex_px))
    assert "no tool" in det.reason
    assert TipDetection.none("x").reason == "x"
    with pytest.raises(InputError, match="expected"):
        detect_tip(np.zeros((2, 2, 2, 2)), TipTarget())


def test_the_reference_matches_the_tool_with_its_focus_and_an_uncertainty():
    image = draw_tool_image(330, "needle", 0.0)
    scene = image.scene
    placement = scene.placements[0]
    moved = ToolPlacement(placement.tool, placement.tip_um + [8.0, -5.0, 0.0], placement.axis)
    dof = Optics(NUMERICAL_APERTURE).depth_of_field_um(UM_PER_PX)
    offsets = np.linspace(-2, 2, 9) * dof
    rng = np.random.default_rng(3)
    frames = []
    for f in offsets:
        optics = Optics(NUMERICAL_APERTURE, focus_depth_um=1000.0 + f)
        frame, _ = tool_image(population_camera(), ToolScene([moved], optics,
                                                                  scene.background), rng)  # fmt: skip
        frames.append(frame)
    anchor = detect_tip(frames[4], parse_tip(image.spec)).apex_px
    reference = build_reference(frames, offsets, anchor)
    det = match_tip(image.image, reference)
    assert det.found
    assert det.method == "reference"
    assert det.score > 0.9
    assert np.hypot(*(det.apex_px - image.truths[0].tip_px)) < 0.3
    assert abs(det.focus_offset_um) < 0.6 * dof
    assert 0.0 < det.std_px < 0.2
    # no tool: refused with the best correlation
    none = draw_tool_image(7, "needle", 0.0, "none")
    refused = match_tip(none.image, reference)
    assert not refused.found
    assert "correlation" in refused.reason
