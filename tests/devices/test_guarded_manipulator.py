"""A stop that holds: after halt() the device is stopped and no move is sent until resume()."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import sim
from microcal.devices.guarded_manipulator import HALTED, GuardedManipulator
from microcal.errors import DeviceError, LimitError


def test_halt_stops_and_refuses_every_later_move():
    plat = sim.platform("thesis", seed=0)
    inner = plat.manipulator
    guarded = GuardedManipulator(inner)
    assert guarded.name == inner.name
    assert guarded.axes == inner.axes
    np.testing.assert_array_equal(guarded.limits_um, inner.limits_um)
    guarded.move_to_um([1000.0, 1000.0, 1000.0])
    guarded.wait_until_stopped(plat.clock)
    np.testing.assert_allclose(guarded.position_um(), [1000.0, 1000.0, 1000.0], atol=1.0)
    stops = []
    real_stop = inner.stop
    inner.stop = lambda: (stops.append(1), real_stop())[1]  # type: ignore[method-assign]
    guarded.halt()
    assert guarded.halted
    assert stops == [1]
    before = inner.position_um()
    with pytest.raises(DeviceError, match=HALTED):
        guarded.move_to_um([2000.0, 2000.0, 2000.0])
    np.testing.assert_allclose(inner.position_um(), before, atol=0.5)  # sensor noise only
    guarded.resume()
    guarded.move_to_um([2000.0, 2000.0, 2000.0])
    guarded.wait_until_stopped(plat.clock)
    np.testing.assert_allclose(guarded.position_um(), [2000.0, 2000.0, 2000.0], atol=1.0)


def test_the_soft_limits_still_come_first_and_close_reaches_the_device():
    plat = sim.platform("thesis", seed=0)
    guarded = GuardedManipulator(plat.manipulator)
    with pytest.raises(LimitError):
        guarded.move_to_um([1e6, 0.0, 0.0])
    guarded.close()
    assert plat.manipulator.closed
