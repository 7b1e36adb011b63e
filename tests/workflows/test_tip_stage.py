"""The calibrated tip as Micro-Manager stages through pymmcore-plus: a position in {G} set on
TipXY and TipZ moves the simulated tip there (open loop, through the compensator)."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.errors import LimitError
from support.station_files import write_truth_calibration

pytest.importorskip("pymmcore_plus", reason="needs pymmcore-plus (pip install 'microcal[mm]')")


@pytest.fixture
def tip_core(tmp_path):
    from microcal.devices.micromanager import open_core

    cal = write_truth_calibration(tmp_path / "calibration.json")
    core = open_core(python_devices="microcal.workflows.tip_stage:load",
                     options={"rig": "sim", "calibration": str(cal), "seed": 0})  # fmt: skip
    yield core
    core.unloadAllDevices()


def _truth(core) -> np.ndarray:
    tip = core._pydevices["TipXY"]._tip.mover  # the rig behind the devices
    return np.asarray(tip.calibrated.device.truth())


def test_the_tip_goes_to_a_position_in_g_set_through_micro_manager(tip_core):
    core = tip_core
    core.setXYPosition("TipXY", 3000.0, 2000.0)
    core.setPosition("TipZ", 1500.0)
    core.waitForSystem()
    np.testing.assert_allclose(_truth(core), [3000.0, 2000.0, 1500.0], atol=1.5)
    x, y = core.getXYPosition("TipXY")
    np.testing.assert_allclose([x, y, core.getPosition("TipZ")], [3000.0, 2000.0, 1500.0], atol=0.5)
    core.setPosition("TipZ", 2200.0)  # x and y stay
    core.waitForSystem()
    np.testing.assert_allclose(_truth(core), [3000.0, 2000.0, 2200.0], atol=1.5)


def test_a_position_outside_the_soft_limits_moves_nothing(tip_core):
    core = tip_core
    before = _truth(core)
    with pytest.raises(
        LimitError, match=r"axis z = .* is outside the soft limits .*; nothing was moved"
    ):
        core.setPosition("TipZ", 9000.0)
    np.testing.assert_allclose(_truth(core), before, atol=0.5)
    core.setXYPosition("TipXY", 2500.0, 2500.0)  # the refused z is not kept
    core.waitForSystem()
    assert abs(_truth(core)[2] - before[2]) < 3.0
