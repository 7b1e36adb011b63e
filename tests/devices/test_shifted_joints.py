"""A manipulator with its joints counted from a chosen origin."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.devices.shifted_joints import ShiftedJoints
from microcal.errors import LimitError
from microcal.sim.patch import patch_rig


def test_commands_positions_and_limits_are_shifted_alike() -> None:
    rig = patch_rig(0, size_px=(128, 128))
    inner = rig.manipulator
    device = ShiftedJoints(inner, [10000.0, 10000.0, 10000.0])
    assert np.allclose(device.limits_um, inner.limits_um - 10000.0)
    device.move_to_um([12.0, -5.0, 3.0])
    device.wait_until_stopped(rig.clock)
    assert np.allclose(inner.position_um(), [10012.0, 9995.0, 10003.0], atol=0.1)
    assert np.allclose(device.position_um(), [12.0, -5.0, 3.0], atol=0.1)
    assert device.identity == inner.identity
    with pytest.raises(LimitError):
        device.move_to_um([-10001.0, 0.0, 0.0])
