"""The dry run of an acquisition: every device checked before anything moves."""

from __future__ import annotations

import pytest

from microcal import DeviceError, sim


def test_a_camera_with_the_wrong_frame_size_is_a_device_error():
    from microcal.procedures.dry_run import dry_run
    from microcal.procedures.planning import plan_run

    plat = sim.platform("thesis", seed=0)
    cam = plat.cameras["top"]
    grab = cam._grab
    cam._grab = lambda: grab()[:-2]  # type: ignore[method-assign]
    plan = plan_run("random", 20, 0, plat.manipulator.limits_um)
    with pytest.raises(DeviceError, match=r"camera top: frame is 1600 x 1198 px but the camera"):
        dry_run(plat.manipulator, plat.cameras, plat.scene.board, plan)
