"""A tool on the end-effector in the simulated cameras (preset ``thesis-tip``)."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.sim import platform
from microcal.sim.platforms import check_overrides
from microcal.sim.tool_render import render_tool_region, tool_roi
from microcal.sim.tools import ToolPlacement
from microcal.vision.tip_target import TipTarget

POSE_UM = np.array([4000.0, 4000.0, 2400.0])


def _at(plat, d_um=POSE_UM):  # type: ignore[no-untyped-def]
    m = plat.manipulator
    m.move_to_um(d_um)
    m.wait_until_stopped(plat.clock, timeout_s=60)
    plat.clock.sleep(5.0)
    return m.true_position_um()


def test_the_preset_puts_a_pipette_where_the_board_was() -> None:
    plat = platform("thesis-tip", seed=0)
    assert plat.scene.board == TipTarget("pipette", 10.0, 1.0)
    p = _at(plat)
    (shown,) = plat.scene(plat.clock.now_s())
    assert isinstance(shown, ToolPlacement)
    np.testing.assert_allclose(shown.tip_um, p, atol=1e-9)
    assert shown.tool.kind == "pipette"
    assert shown.axis[0] > 0.9
    assert shown.axis[2] == pytest.approx(np.sin(np.radians(20.0)))


def test_each_camera_shows_the_tool_dark_on_a_bright_field_from_its_tip_to_the_edge() -> None:
    plat = platform("thesis-tip", seed=1, overrides={"board": "tip:needle:20:5"})
    p = _at(plat)
    for name, cam in plat.cameras.items():
        frame = cam.grab().astype(np.float64)
        truth = cam.last_truth
        assert truth is not None
        tip = truth.features_px[0][0]
        np.testing.assert_allclose(tip, cam.model.project(p[None])[0] + truth.offset_px, atol=1e-9)
        shank = cam.model.project((p + 2000.0 * plat.scene.tool.axis)[None])[0]  # type: ignore[union-attr]
        before = cam.model.project((p - 2000.0 * plat.scene.tool.axis)[None])[0]  # type: ignore[union-attr]
        dark = frame[round(shank[1]), round(shank[0])]
        light = frame[round(before[1]), round(before[0])]
        assert dark < 0.3 * light, name  # the needle's shank against the bright field
        roi = tool_roi(cam.model, truth.placements[0], 3.0)  # type: ignore[arg-type]
        assert roi is not None
        w, _h = cam.model.image_size_px
        assert roi[2] == w  # it reaches the image's edge along +x
        assert roi[0] <= tip[0] <= roi[2]
        assert roi[1] <= tip[1] <= roi[3]


def test_a_tool_out_of_view_is_not_rendered() -> None:
    plat = platform("thesis-tip", seed=0)
    cam = plat.cameras["top"]
    tool = plat.scene.tool
    assert tool is not None
    far = ToolPlacement(tool.tool, np.array([-2e5, 0.0, 0.0]), -tool.axis)
    assert tool_roi(cam.model, far, 3.0) is None
    value, alpha = render_tool_region(cam.model, far, (0, 0, 8, 8))
    assert float(alpha.max()) == 0.0
    assert float(value.max()) == 0.0


def test_the_tool_takes_any_tip_spec_and_refuses_a_bad_angle() -> None:
    assert check_overrides({"board": "tip:jaw"}, "thesis").board == "tip:jaw"
    with pytest.raises(InputError, match="tool_elevation_deg"):
        check_overrides({"tool_elevation_deg": 95.0}, "thesis-tip")
    with pytest.raises(InputError, match="override 'board'"):
        check_overrides({"board": "tip:spoon"}, "thesis-tip")
