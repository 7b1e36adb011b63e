"""The tip's depth from focus on the ``patch`` preset: the sweep, the reference stack, the
baseline, and their refusals (small frames, regions of 81 x 81 px)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from microcal.errors import DetectionError, InputError, LimitError
from microcal.sim.patch import PatchFrame, PatchRig, patch_rig
from microcal.vision.focus_depth import (
    ALIGN_ACROSS_SIGMA_PX,
    QUADRATIC_ALIGN_SIGMA_PX,
    SWEEP_APEX_SIGMA_PX,
    axis_cov_px,
    build_stack,
    depth_by_best_plane,
    depth_by_stack,
    depth_by_sweep,
    depth_from_stack_at,
    grab_stack,
    sweep_dither_um,
    sweep_positions_um,
)

SIZE = (256, 256)


def _box(c: np.ndarray) -> tuple[int, int, int, int]:
    x, y = round(float(c[0])), round(float(c[1]))
    return x - 40, y - 40, x + 41, y + 41


def _offset_px(rig: PatchRig) -> float:
    cfg = rig.config
    return cfg.tool.end_radius_um * math.sin(math.radians(cfg.approach_deg)) / cfg.um_per_px


@pytest.mark.parametrize("seed", [0, 1])
def test_the_sweep_finds_the_tips_depth_and_image(seed: int) -> None:
    rig = patch_rig(seed, size_px=SIZE)
    rig.manipulator.move_to_um(10000.0 + np.array([4.0, -3.0, 6.0]))
    rig.clock.sleep(2.0)
    z, px = rig.in_focus()
    prior = z + (0.7 if seed else -0.8)
    t0 = rig.clock.now_s()
    est = depth_by_sweep(rig.grab_at_focus, _box(px + (2.0, -1.0)), (1.0, 0.0), prior,
                         end_offset_px=_offset_px(rig), clock=rig.clock.now_s)  # fmt: skip
    assert abs(est.z_um - z) < 0.15  # a tenth of the depth of field
    assert 0.01 < est.sigma_um < 0.2
    assert np.linalg.norm(est.apex_px - px) < 1.5  # px, 0.25 µm
    assert est.frames == 13 <= 15
    assert est.method == "sweep"
    assert est.seconds == pytest.approx(rig.clock.now_s() - t0)
    assert np.allclose(est.focus_um, sweep_positions_um(prior))


@pytest.mark.parametrize("across_px", [6.0, 12.0])  # the tip 1 and 2 µm beside the expected line
def test_the_sweep_follows_a_tool_that_lies_beside_where_it_was_expected(across_px) -> None:
    rig = patch_rig(2, size_px=SIZE)
    rig.manipulator.move_to_um(10000.0 + np.array([4.0, -3.0, 6.0]))
    rig.clock.sleep(2.0)
    z, px = rig.in_focus()
    est = depth_by_sweep(rig.grab_at_focus, _box(px + (2.0, across_px)), (1.0, 0.0), z,
                         end_offset_px=_offset_px(rig), clock=rig.clock.now_s)  # fmt: skip
    assert abs(est.apex_px[1] - px[1]) < 0.5  # across the tool: not pulled towards the line
    assert abs(est.z_um - z) < 0.15


def test_a_tool_beside_the_region_is_refused_not_measured_wrong() -> None:
    rig = patch_rig(0, size_px=SIZE)
    rig.manipulator.move_to_um(10000.0 + np.array([4.0, -3.0, 6.0]))
    rig.clock.sleep(2.0)
    z, px = rig.in_focus()
    with pytest.raises(DetectionError, match="focus sweep"):
        depth_by_sweep(rig.grab_at_focus, _box(px + (2.0, 30.0)), (1.0, 0.0), z,
                       end_offset_px=_offset_px(rig), clock=rig.clock.now_s)  # fmt: skip


def test_the_stack_interpolates_between_planes_and_the_baseline_rounds_to_one() -> None:
    rig = patch_rig(2, size_px=SIZE)
    z0, px0 = rig.in_focus()
    stack = grab_stack(rig.grab_at_focus, z0, px0, step_um=0.5, tip_focus_var_um2=0.003)
    coarse = grab_stack(rig.grab_at_focus, z0, px0, step_um=1.0)
    assert stack.planes.shape == (17, 49, 49)
    assert stack.step_um == 0.5
    rig.manipulator.move_to_um(10000.0 + np.array([6.0, 5.0, -4.0]))
    rig.clock.sleep(2.0)
    z, px = rig.in_focus()
    focus = z + 0.62  # above the tip, where the rising shank is sharp
    frame = rig.grab_at_focus(focus)
    est = depth_by_stack(frame, focus, stack, px + (-2.0, 2.0))
    assert abs(est.z_um - z) < 0.25
    assert est.sigma_um > math.sqrt(0.003)
    assert np.linalg.norm(est.apex_px - px) < 2.0
    t0 = rig.clock.now_s()
    again = depth_from_stack_at(rig.grab_at_focus, z - 0.38, stack, px, clock=rig.clock.now_s)
    assert abs(again.z_um - z) < 0.25
    assert again.frames == 1
    assert again.seconds >= rig.clock.now_s() - t0 > 0.02  # a move and a frame
    base = depth_by_best_plane(frame, focus, coarse, px)
    assert (focus - base.z_um) % 1.0 == pytest.approx(0.0, abs=1e-9) or (
        focus - base.z_um
    ) % 1.0 == pytest.approx(1.0, abs=1e-9)  # whole planes
    assert base.sigma_um == pytest.approx(1.0 / math.sqrt(12.0))


def test_a_tip_outside_the_sweep_or_the_stack_or_the_field_is_refused_in_one_line() -> None:
    rig = patch_rig(4, size_px=SIZE)
    z, px = rig.in_focus()
    with pytest.raises(DetectionError, match="not inside the sweep") as info:
        depth_by_sweep(rig.grab_at_focus, _box(px), (1.0, 0.0), z + 9.0, frames=7)
    assert "\n" not in str(info.value)
    with pytest.raises(InputError, match="outside the field"):
        depth_by_sweep(rig.grab_at_focus, (230, 230, 311, 311), (1.0, 0.0), z)
    with pytest.raises(LimitError, match="focus drive's range"):
        depth_by_sweep(rig.grab_at_focus, _box(px), (1.0, 0.0), 600.0)
    with pytest.raises(InputError, match="frames"):
        depth_by_sweep(rig.grab_at_focus, _box(px), (1.0, 0.0), z, frames=21)
    with pytest.raises(InputError, match="axis_px"):
        depth_by_sweep(rig.grab_at_focus, _box(px), (0.0, 0.0), z)
    stack = grab_stack(rig.grab_at_focus, z, px, reach_um=2.0, step_um=0.5)
    for beyond in (2.6, 6.0):  # just beyond the stack's last plane, and far beyond it
        frame = rig.grab_at_focus(z + beyond)
        with pytest.raises(DetectionError, match="outside the stack's focus range"):
            depth_by_stack(frame, z + beyond, stack, px)
    with pytest.raises(InputError, match="one per offset"):
        build_stack([frame, frame], [0.0, 1.0, 2.0], px)


def test_the_quadratic_between_three_planes_reads_a_coarse_stack_and_states_its_shared_part() -> (
    None
):
    rig = patch_rig(3, size_px=SIZE)
    z0, px0 = rig.in_focus()
    anchor_cov = np.eye(2) * 0.3
    coarse = grab_stack(rig.grab_at_focus, z0, px0, step_um=1.0, tip_focus_var_um2=0.001,
                        tip_cov_px=anchor_cov)  # fmt: skip
    rig.manipulator.move_to_um(10000.0 + np.array([-5.0, 4.0, 3.0]))
    rig.clock.sleep(2.0)
    z, px = rig.in_focus()
    errors = {"quadratic": [], "linear": []}
    for above in (0.55, 0.8, 1.3):  # between the planes and near one
        frame = rig.grab_at_focus(z + above)
        for how, errs in errors.items():
            est = depth_by_stack(frame, z + above, coarse, px + (1.0, -1.0), interpolation=how)
            errs.append(abs(est.z_um - z))
            assert np.linalg.norm(est.apex_px - px) < 2.5
            assert np.allclose(est.shared_cov_px, anchor_cov)  # the anchor, alike for all tips
            own = est.cov_px - est.shared_cov_px
            assert np.all(np.diag(own) > 0)
            assert own[0, 1] == 0.0
            assert est.shared_var_um2 == pytest.approx(0.001)
    assert max(errors["quadratic"]) < 0.3  # µm, a 1 µm stack
    assert np.mean(errors["quadratic"]) <= np.mean(errors["linear"]) + 0.02
    with pytest.raises(InputError, match="interpolation must be") as info:
        depth_by_stack(frame, z + 1.3, coarse, px, interpolation="cubic")
    assert "\n" not in str(info.value)


def test_the_sweep_reads_the_tip_without_an_offset_along_the_tool_or_in_depth() -> None:
    """The darkness's profile along the tool is placed where its pixels lie, so the tip
    images of several tools and poses scatter about the truth along the axis (a tool along a
    pixel row put every pixel on its bin's lower edge: 0.5 px ahead), and the depth line,
    less the glass edges' offset, about the tip's focus, not 0.03 µm above it; the stated
    covariance is along and across the tool's image axis."""
    along, across, depth = [], [], []
    for seed in (20, 21, 22):
        rig = patch_rig(seed, size_px=SIZE)
        for k, d in enumerate(([4.0, -3.0, 6.0], [-6.0, 5.0, -3.0])):
            rig.manipulator.move_to_um(10000.0 + np.array(d))
            rig.clock.sleep(2.0)
            z, px = rig.in_focus()
            est = depth_by_sweep(rig.grab_at_focus, _box(px + (1.0 - 2 * k, 1.0)), (1.0, 0.0),
                                 z + 0.3, end_offset_px=_offset_px(rig), clock=rig.clock.now_s)  # fmt: skip
            along.append(est.apex_px[0] - px[0])
            across.append(est.apex_px[1] - px[1])
            depth.append(est.z_um - z)
            assert np.allclose(est.cov_px, np.diag(SWEEP_APEX_SIGMA_PX) ** 2)
    assert abs(float(np.mean(along))) < 0.2  # px; 0.5 px ahead with the bins at their middles
    assert float(np.std(along)) < 0.3
    assert float(np.sqrt(np.mean(np.square(across)))) < 0.8
    assert abs(float(np.mean(depth))) < 0.015  # µm; 0.024 µm above without the offset


def test_the_stack_states_its_alignment_along_and_across_the_tool() -> None:
    rig = patch_rig(2, size_px=SIZE)
    z0, px0 = rig.in_focus()
    plain = grab_stack(rig.grab_at_focus, z0, px0, step_um=0.5)
    axis = np.array([math.cos(0.3), math.sin(0.3)])
    tilted = build_stack([rig.grab_at_focus(z0 + o) for o in plain.offsets_um], plain.offsets_um,
                         px0, axis_px=axis * 3.0)  # fmt: skip
    frame = rig.grab_at_focus(z0 + 0.2)
    a = depth_by_stack(frame, z0 + 0.2, plain, px0).cov_px  # no axis: the along figure each way
    b = depth_by_stack(frame, z0 + 0.2, tilted, px0).cov_px
    along = math.hypot(QUADRATIC_ALIGN_SIGMA_PX[0], QUADRATIC_ALIGN_SIGMA_PX[1] * 0.5)
    assert np.allclose(a, np.eye(2) * along**2)
    assert axis @ b @ axis == pytest.approx(along**2)
    normal = np.array([-axis[1], axis[0]])
    assert normal @ b @ normal == pytest.approx(ALIGN_ACROSS_SIGMA_PX**2)
    assert np.allclose(axis_cov_px(axis, 2.0, 1.0), 4.0 * np.outer(axis, axis)
                       + np.outer(normal, normal))  # fmt: skip


def test_the_sweep_reads_alike_with_an_axis_a_millionth_of_a_radian_off_a_pixel_row() -> None:
    """A tool along a pixel row puts every pixel on an edge of the profile's bins; an axis
    turned by 1e-6 rad puts them inside. Each bin is placed where its pixels lie, so both
    read the same tip from the same frames (bins placed at their middles read them 0.4-0.5 px
    apart along the tool)."""
    rig = patch_rig(5, size_px=SIZE)
    rig.manipulator.move_to_um(10000.0 + np.array([3.0, 2.0, -4.0]))
    rig.clock.sleep(2.0)
    z, px = rig.in_focus()
    frames: dict[float, PatchFrame] = {}  # the same frames for both

    def grab(z_um: float) -> PatchFrame:
        return frames.setdefault(z_um, rig.grab_at_focus(z_um))

    found = []
    for axis in ((1.0, 0.0), (math.cos(1e-6), math.sin(1e-6))):
        found.append(depth_by_sweep(grab, _box(px + (1.0, 0.0)), axis, z + 0.2,
                                    end_offset_px=_offset_px(rig), clock=rig.clock.now_s))  # fmt: skip
    d = found[0].apex_px - found[1].apex_px
    assert abs(d[0]) < 0.05  # px along: 0.4-0.5 with the bins at their middles
    assert abs(d[1]) < 0.1  # px across (pixels on the strips' side edges go one way or other)
    assert abs(found[0].z_um - found[1].z_um) < 0.02  # µm


def test_the_sweep_s_frames_fall_elsewhere_about_each_tip_s_focus() -> None:
    """Centres a hundredth of a micron apart move the frames by fractions of the step spread
    over the whole step, the same each time for the same centre (a good prior would otherwise
    put every tip's focus on a frame and repeat the error of reading it there)."""
    step = 0.5
    centres = 12.34 + 0.01 * np.arange(200)
    moved = np.array([sweep_dither_um(float(c), step) for c in centres])
    assert np.all((moved >= -step / 2) & (moved < step / 2))
    counts, _ = np.histogram(moved, bins=5, range=(-step / 2, step / 2))
    assert counts.min() >= 25  # of 40 each, were they even
    assert sweep_dither_um(12.34, step) == sweep_dither_um(12.34, step)
    positions = sweep_positions_um(12.34, 13, step)
    assert np.allclose(np.diff(positions), step)
    assert positions[6] == pytest.approx(12.34 + sweep_dither_um(12.34, step))
