"""Tools in the simulator: their outline, their look under bright field, defocus and backgrounds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.sim.tools import (
    Background,
    Optics,
    Tool,
    ToolPlacement,
    ToolScene,
    microscope_camera,
    render_tools,
    tool_axis,
    tool_image,
)
from microcal.thesis.cameras import thesis_cameras

CAMERA = microscope_camera(0.65)
FOCUS = Optics(0.3, focus_depth_um=1000.0)


def _placed(kind: str, elevation: float = 0.0, azimuth: float = 20.0, **tool: float):
    return ToolPlacement(Tool(kind, **tool), np.zeros(3), tool_axis(elevation, azimuth))  # type: ignore[arg-type]


@pytest.mark.parametrize("elevation", [0.0, 20.0, 35.0])
def test_a_cone_seen_at_an_angle_widens_as_sin_beta_equals_sin_alpha_over_cos_elevation(elevation):
    from microcal.sim.tools import _silhouette

    placement = _placed("needle", elevation, taper_deg=10.0, tip_um=2.0)
    sil = _silhouette(CAMERA, placement)
    assert sil is not None
    beta = math.atan(sil.tan_half)
    expected = math.asin(math.sin(math.radians(5.0)) / math.cos(math.radians(elevation)))
    assert beta == pytest.approx(expected, abs=1e-9)
    # the vertex's image is where the truth says, ahead of the tip along the axis
    _, truths = render_tools(CAMERA, [placement], FOCUS, roi=(100, 100, 160, 160))
    assert np.allclose(sil.vertex, truths[0].vertex_px, atol=1e-9)
    ahead = truths[0].tip_px - truths[0].vertex_px
    assert ahead @ truths[0].axis_px > 0


def test_an_opaque_needle_is_dark_inside_and_clear_outside():
    trans, truths = render_tools(CAMERA, [_placed("needle", tip_um=2.0)], FOCUS)
    t = truths[0]
    inside = np.round(t.tip_px + t.axis_px * 40).astype(int)
    ahead = np.round(t.tip_px - t.axis_px * 10).astype(int)
    assert trans[inside[1], inside[0]] == pytest.approx(0.06, abs=0.02)
    assert trans[ahead[1], ahead[0]] == pytest.approx(1.0, abs=1e-3)
    assert t.in_field
    assert t.defocus_um == pytest.approx(0.0)


def test_a_pipette_shows_two_dark_walls_and_a_lighter_lumen():
    trans, truths = render_tools(CAMERA, [_placed("pipette", taper_deg=14.0)], FOCUS)
    t = truths[0]
    normal = np.array([-t.axis_px[1], t.axis_px[0]])
    centre = t.tip_px + t.axis_px * 100  # 65 µm back: about 16 µm wide, 25 px
    profile = []
    for s in np.linspace(-16, 16, 65):
        x, y = centre + normal * s
        profile.append(trans[round(y), round(x)])
    profile = np.array(profile)
    middle = profile[28:37].mean()
    walls = min(profile[:28].min(), profile[37:].min())
    assert walls < middle - 0.2  # dark edges around a lighter lumen
    assert profile[0] == pytest.approx(1.0, abs=0.01)
    assert profile[-1] == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize("elevation", [3.0, 15.0])
def test_a_thin_pipette_end_is_rendered_as_with_many_subsamples(elevation):
    # The opening's ring, seen nearly edge-on, is thinner than a subsample: the darkness around
    # the tip (which sets where a detector puts it) must not depend on the subsampling.
    placed = [_placed("pipette", elevation, 37.0, taper_deg=11.0, tip_um=0.6)]
    fine, truths = render_tools(CAMERA, placed, FOCUS, roi=(112, 112, 144, 144), supersample=16)
    coarse, _ = render_tools(CAMERA, placed, FOCUS, roi=(112, 112, 144, 144), supersample=4)
    tip = truths[0].tip_px - 112
    yy, xx = np.mgrid[0:32, 0:32]
    near = np.hypot(xx - tip[0], yy - tip[1]) < 3.0
    dark_fine = float((1.0 - fine)[near].sum())
    dark_coarse = float((1.0 - coarse)[near].sum())
    assert dark_coarse == pytest.approx(dark_fine, rel=0.04)


def test_defocus_follows_the_numerical_aperture():
    optics = Optics(0.3)
    pitch = 0.65
    dof = optics.depth_of_field_um(pitch)
    assert dof == pytest.approx(0.55 / 0.09 + 0.65 / 0.3)
    in_focus = float(optics.blur_sigma_px(0.0, pitch))
    assert in_focus == pytest.approx(0.21 * 0.55 / 0.3 / pitch)
    off = float(optics.blur_sigma_px(2 * dof, pitch))
    geometric = 2 * dof * math.tan(math.asin(0.3)) / 2 / pitch
    assert off == pytest.approx(math.hypot(in_focus, geometric))
    # a higher aperture blurs faster
    assert float(Optics(0.6).blur_sigma_px(10.0, pitch)) > float(optics.blur_sigma_px(10.0, pitch))


def test_a_tool_leaving_the_focal_plane_blurs_along_its_length():
    placement = _placed("needle", elevation=30.0, tip_um=2.0)
    trans, truths = render_tools(CAMERA, [placement], FOCUS)
    t = truths[0]
    normal = np.array([-t.axis_px[1], t.axis_px[0]])

    def edge_width(back_px: float) -> float:
        centre = t.tip_px + t.axis_px * back_px
        s = np.linspace(-25, 25, 201)
        pts = centre + np.outer(s, normal)
        v = trans[np.round(pts[:, 1]).astype(int), np.round(pts[:, 0]).astype(int)]
        return float(np.count_nonzero((v > 0.15) & (v < 0.9)))

    assert edge_width(80) > 2 * edge_width(10)


def test_backgrounds_textures_and_uneven_light_and_noise_are_seeded():
    scene = ToolScene([_placed("jaw", tip_um=2.0)], FOCUS, Background("tissue", seed=3))
    a, _ = tool_image(CAMERA, scene, np.random.default_rng(1))
    b, _ = tool_image(CAMERA, scene, np.random.default_rng(1))
    assert np.array_equal(a, b)
    plain = Background("plain", gradient=(0.4, 0.0)).image((64, 64))
    assert plain[:, -1].mean() / plain[:, 0].mean() == pytest.approx(1.2 / 0.8, rel=1e-3)
    tissue = Background("tissue", contrast=0.1, seed=1).image((128, 128))
    assert 0.02 < float(tissue.std() / tissue.mean()) < 0.2
    debris = Background("debris", seed=2).image((128, 128))
    assert debris.min() < 0.8 * float(np.median(debris))  # specks 30 % darker at the most


def test_two_tools_are_both_rendered_and_reported():
    p1 = ToolPlacement(Tool("needle", tip_um=2.0), np.array([-30.0, 0, 0]), tool_axis(0, 180))
    p2 = ToolPlacement(Tool("pipette"), np.array([30.0, 0, 0]), tool_axis(0, 0))
    trans, truths = render_tools(CAMERA, [p1, p2], FOCUS)
    assert len(truths) == 2
    assert (trans[:, :100] < 0.5).any()
    assert (trans[:, 160:] < 0.9).any()


def test_a_perspective_camera_with_distortion_puts_the_tip_where_project_does():
    top, _ = thesis_cameras()
    centre = np.array([5000.0, 4800.0, 2700.0])
    optics = Optics(0.02, focus_depth_um=float(top.depth_um(centre)[0]))
    placement = ToolPlacement(Tool("needle", taper_deg=20, tip_um=40.0), centre,
                              tool_axis(20, 30))  # fmt: skip
    q = top.project(centre)[0]
    roi = (int(q[0]) - 40, int(q[1]) - 40, int(q[0]) + 40, int(q[1]) + 40)
    trans, truths = render_tools(top, [placement], optics, roi=roi)
    assert np.allclose(truths[0].tip_px, q)
    assert trans.min() < 0.2
    assert trans.max() == pytest.approx(1.0, abs=1e-3)


def test_bad_tools_are_one_line_errors():
    with pytest.raises(InputError, match="tool: expected one of pipette, needle, jaw"):
        Tool("scalpel")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="numerical_aperture"):
        Optics(1.2)
    with pytest.raises(InputError, match="axis"):
        ToolPlacement(Tool("needle"), np.zeros(3), np.zeros(3))
