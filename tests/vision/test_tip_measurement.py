"""A tool's tip measured in 3D: each camera's apex, triangulated, is the same point."""

from __future__ import annotations

import math

import numpy as np
import pytest

from microcal.geometry.affine_camera import AffineCamera
from microcal.sim.tools import (
    Background,
    Optics,
    Tool,
    ToolPlacement,
    ToolScene,
    microscope_camera,
    tool_axis,
    tool_image,
)
from microcal.vision.measurement import measure_one
from microcal.vision.tip_target import parse_tip


def _tilted(camera: AffineCamera, degrees: float, name: str) -> AffineCamera:
    a = math.radians(degrees)
    turn = np.array([[1.0, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    return AffineCamera(camera.K, camera.dist, turn @ camera.R, camera.t_um,
                        camera.image_size_px, name=name)  # fmt: skip


TOP = microscope_camera(0.65, name="top")
SIDE = _tilted(TOP, 40.0, "side")


@pytest.mark.parametrize(
    ("kind", "elevation", "spec"),
    [("needle", 10.0, "tip:needle:12"), ("jaw", 0.0, "tip:jaw:12"),
     ("needle", 10.0, "tip:needle:12:2")],  # with its size: from the vertex along the axis
)  # fmt: skip
@pytest.mark.slow
def test_the_tip_point_triangulated_from_two_views_is_the_tools_own(kind, elevation, spec):
    rng = np.random.default_rng(4)
    errors = []
    for _ in range(3):
        tip = np.append(rng.uniform(-15, 15, 2), rng.uniform(-3, 3))
        placement = ToolPlacement(Tool(kind, taper_deg=12.0, tip_um=2.0),  # type: ignore[arg-type]
                                  tip, tool_axis(elevation, float(rng.uniform(0, 360))))  # fmt: skip
        frames = {}
        for cam in (TOP, SIDE):
            optics = Optics(0.3, focus_depth_um=float(cam.depth_um(tip)[0]))
            scene = ToolScene([placement], optics, Background("plain", seed=1))
            frames[cam.name] = [tool_image(cam, scene, rng)[0] for _ in range(2)]
        m = measure_one(frames, {"top": TOP, "side": SIDE}, parse_tip(spec))
        assert m.status == "ok", m.reason
        errors.append(m.p_um - tip)
        assert np.all(np.isfinite(m.cov_um2))
    e = np.array(errors)
    assert float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) < 0.3  # µm, 0.65 µm pixels


def test_a_camera_without_the_tip_is_named_and_the_pose_fails_cleanly():
    tip = np.zeros(3)
    placement = ToolPlacement(Tool("needle", tip_um=2.0), tip, tool_axis(0.0, 0.0))
    rng = np.random.default_rng(0)
    optics = Optics(0.3, focus_depth_um=1000.0)
    seen = tool_image(TOP, ToolScene([placement], optics), rng)[0]
    empty = tool_image(SIDE, ToolScene([], optics), rng)[0]
    m = measure_one({"top": [seen], "side": [empty]}, {"top": TOP, "side": SIDE},
                    parse_tip("tip:needle"))  # fmt: skip
    assert m.status == "failed"
    assert "side: no tool in view" in m.reason


def test_a_tool_leaving_the_field_mid_run_fails_that_pose_alone_with_its_reason():
    from microcal.vision.measurement import measure_poses

    rng = np.random.default_rng(8)
    tips = [np.array([0.0, 0.0, 0.0]), np.array([300.0, 0.0, 0.0]), np.array([10.0, 5.0, 0.0])]
    frames = {}
    for k, tip in enumerate(tips):
        placement = ToolPlacement(Tool("needle", taper_deg=12.0, tip_um=2.0), tip,
                                  tool_axis(5.0, 200.0))  # fmt: skip
        for cam in (TOP, SIDE):
            optics = Optics(0.3, focus_depth_um=float(cam.depth_um(tip)[0]))
            frames[k, cam.name] = [tool_image(cam, ToolScene([placement], optics), rng)[0]]
    results = measure_poses([0, 1, 2], np.array(tips), lambda p, c: frames[p, c],
                            {"top": TOP, "side": SIDE}, parse_tip("tip:needle:12"))  # fmt: skip
    assert [m.status for m in results] == ["ok", "failed", "ok"]
    assert "top: " in results[1].reason
    assert "out of the field" in results[1].reason or "no tool" in results[1].reason
    for m, tip in zip(results[::2], tips[::2], strict=True):
        assert np.linalg.norm(m.p_um - tip) < 0.5
