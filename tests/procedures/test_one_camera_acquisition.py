"""The one-camera acquisition on the ``patch`` rig (small frames, a few poses): the tips in
{M} against the rig's truth, the journal, and the poses the focus cannot reach."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.devices.shifted_joints import ShiftedJoints
from microcal.errors import InputError
from microcal.journal_record import JournalRecord
from microcal.procedures.one_camera_acquisition import (
    OneCameraPose,
    TipFinder,
    WorkingVolume,
    acquire_one_camera,
    linear_map,
)
from microcal.sim.patch import PatchRig, patch_rig
from microcal.sim.patch_scope import (
    end_offset_px,
    image_axis,
    nominal_axes,
    true_frame,
    truth_in_frame,
)

SIZE = (512, 512)  # an 83 µm field


def _setup(seed: int) -> tuple[PatchRig, ShiftedJoints, TipFinder]:
    rig = patch_rig(seed, size_px=SIZE, supersample=1)  # quicker frames
    cfg = rig.config
    device = ShiftedJoints(rig.manipulator, np.full(3, 10000.0))
    return rig, device, TipFinder(true_frame(cfg), image_axis(cfg), end_offset_px(cfg), frames=11)


def test_a_few_poses_are_measured_in_the_microscope_frame_within_their_covariance() -> None:
    rig, device, finder = _setup(3)
    truth = truth_in_frame(rig, finder.frame)
    stored: list[tuple[JournalRecord, OneCameraPose, np.ndarray]] = []
    run = acquire_one_camera(
        device, rig.clock, rig.move_focus, rig.grab, finder,
        WorkingVolume(np.zeros(3), np.array([20.0, 20.0, 5.0])), 5,
        nominal_um_per_um=nominal_axes(rig.config), start_focus_um=0.4, settle_s=0.5,
        store=lambda rec, tip: stored.append((rec, tip, truth())),
    )  # fmt: skip
    assert run.ok.all()
    assert run.d_um.shape == (5, 3)
    assert [r.pose for r, _, _ in stored] == [1, 2, 3, 4, 5]
    err = run.p_um - np.array([t for _, _, t in stored])
    err -= err[0]  # the tip point's constant offset (where the sweep reads the tip)
    assert np.max(np.abs(err)) < 0.4  # µm
    assert np.all(np.linalg.eigvalsh(run.cov_um2) > 0)
    # the steps of the joints went where the nominal axes say (a 30-degree approach axis)
    step = run.p_um[1] - run.p_um[0]
    assert np.allclose(step, 20.0 * nominal_axes(rig.config)[:, 0], atol=0.5)
    assert {r.approach["approach_x"] for r in run.records} <= {1.0, -1.0}
    assert all(r.sim_time_s > 0 and r.reported_um is not None for r in run.records)


def test_poses_beyond_the_focus_range_are_journaled_as_failed_and_the_run_goes_on() -> None:
    rig, device, finder = _setup(4)
    rig.focus.limits_um = (-500.0, 30.0)
    run = acquire_one_camera(
        device, rig.clock, rig.move_focus, rig.grab, finder,
        WorkingVolume(np.array([0.0, 0.0, 300.0]), np.array([1.0, 1.0, 1.0])), 5,
        nominal_um_per_um=nominal_axes(rig.config), settle_s=0.2,
    )  # fmt: skip
    assert run.ok.tolist() == [True, True, True, True, False]
    last = run.records[-1]
    assert last.status == "failed"
    assert "focus" in (last.reason or "")
    assert "\n" not in (last.reason or "")


def test_no_tip_at_the_start_or_too_few_poses_is_one_line() -> None:
    rig, device, finder = _setup(5)
    volume = WorkingVolume(np.zeros(3), np.ones(3))
    with pytest.raises(InputError, match="5 poses or more"):
        acquire_one_camera(device, rig.clock, rig.move_focus, rig.grab, finder, volume, 4,
                           nominal_um_per_um=np.eye(3))  # fmt: skip
    with pytest.raises(InputError, match="no tip at the start pose") as info:
        acquire_one_camera(device, rig.clock, rig.move_focus, rig.grab, finder, volume, 5,
                           nominal_um_per_um=np.eye(3), start_px=(100.0, 400.0),
                           settle_s=0.0)  # fmt: skip
    assert "\n" not in str(info.value)


def test_the_linear_map_learns_the_approach_sides_and_leaves_out_a_bad_pose() -> None:
    rng = np.random.default_rng(0)
    d = rng.uniform(-100, 100, (20, 3))
    s = rng.choice([-1.0, 1.0], (20, 3))
    L = np.array([[0.87, 0.0, 0.0], [0.0, 1.0, 0.0], [-0.5, 0.0, 1.0]])
    p = d @ L.T + 0.15 * s + [1.0, 2.0, 3.0]
    p[7] += 5.0
    predict = linear_map(d, p, s)
    assert np.allclose(predict(d[3], s[3]), p[3], atol=1e-9)
    assert np.allclose(predict(np.zeros(3), -np.ones(3)), np.array([1.0, 2.0, 3.0]) - 0.15)
