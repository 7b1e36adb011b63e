"""The tip in 3D at one pose of the ``patch`` rig, on its focus and grab callables, against
the rig's truth (small frames, regions of 81 x 81 px)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.procedures.one_camera_pose import measure_tip_one_camera
from microcal.sim.patch import PatchRig, patch_rig
from microcal.vision.focus_depth import grab_stack

SIZE = (256, 256)


def _truth(rig: PatchRig) -> np.ndarray:
    """The tip's image in µm and the focus reading with it in focus."""
    z, px = rig.in_focus()
    return np.array([px[0] * rig.config.um_per_px, px[1] * rig.config.um_per_px, z])


def _axis(rig: PatchRig) -> np.ndarray:
    tip = rig.manipulator.true_position_um()
    q = rig.camera().project(np.array([tip, tip + rig.config.tool_axis * 10.0]))
    d = np.asarray(q[1] - q[0], dtype=np.float64)
    return d / np.linalg.norm(d)


def test_one_pose_by_sweep_and_by_stack_with_the_joint_covariance() -> None:
    rig = patch_rig(5, size_px=SIZE)
    pitch = rig.config.um_per_px
    cfg = rig.config
    offset = cfg.tool.end_radius_um * math.sin(math.radians(cfg.approach_deg)) / pitch
    axis = _axis(rig)
    t0 = _truth(rig)
    calib = measure_tip_one_camera(rig.move_focus, rig.grab, t0[:2] / pitch + (1.5, -1.0),
                                   t0[2] + 0.6, pitch, axis_px=axis, end_offset_px=offset,
                                   clock=rig.clock.now_s)  # fmt: skip
    stack = grab_stack(rig.grab_at_focus, calib.depth.z_um, calib.depth.apex_px, step_um=1.0,
                       tip_focus_var_um2=calib.depth.var_um2, tip_cov_px=calib.depth.cov_px)  # fmt: skip
    rig.manipulator.move_to_um(10000.0 + np.array([5.0, -4.0, 4.0]))
    rig.clock.sleep(2.0)
    truth = _truth(rig)
    near = truth[:2] / pitch + (-2.0, 1.0)
    for method in ("sweep", "stack"):
        tip = measure_tip_one_camera(rig.move_focus, rig.grab, near, truth[2] - 0.5, pitch,
                                     method=method, axis_px=axis, stack=stack,
                                     end_offset_px=offset, clock=rig.clock.now_s)  # fmt: skip
        err = tip.position_um - truth
        assert np.linalg.norm(err[:2]) < 0.4  # µm
        assert abs(err[2]) < 0.3
        assert tip.cov_um2.shape == (3, 3)
        assert np.allclose(tip.cov_um2, tip.cov_um2.T)
        assert np.all(np.linalg.eigvalsh(tip.cov_um2) > 0)
        assert np.all(np.linalg.eigvalsh(tip.cov_um2 - tip.shared_cov_um2) > 0)
        assert tip.method == method
        assert tip.frames == (13 if method == "sweep" else 1)
        assert tip.seconds > 0
    assert np.any(tip.shared_cov_um2)  # the stack's anchor and focus, alike for every pose


def test_a_missing_input_or_an_unknown_method_is_refused_in_one_line() -> None:
    rig = patch_rig(6, size_px=SIZE)
    for kwargs, match in (({}, "image axis"), ({"method": "stack"}, "reference stack"),
                          ({"method": "guess"}, "must be 'sweep' or 'stack'")):  # fmt: skip
        with pytest.raises(InputError, match=match) as info:
            measure_tip_one_camera(rig.move_focus, rig.grab, (128.0, 128.0), 0.0, 0.1625,
                                   **kwargs)  # fmt: skip
        assert "\n" not in str(info.value)
