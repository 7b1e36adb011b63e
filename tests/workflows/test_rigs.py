"""Opening a rig from its spec: every device closed once, those opened before a failure too,
and closing errors never hide the error that ended the block."""

from __future__ import annotations

import pytest

from microcal.devices.rig_spec import (
    AravisCameraSpec,
    HardwareRigSpec,
    MCS2Spec,
    SimRigSpec,
)
from microcal.errors import DeviceError
from microcal.workflows.rigs import open_rig

LIMITS = {"x": [0.0, 8000.0], "y": [0.0, 8000.0], "z": [0.0, 4800.0]}


def test_open_rig_takes_a_spec_and_closing_it_closes_every_device_once():
    rig = open_rig(SimRigSpec(seed=1))
    devices = [rig.manipulator, *rig.cameras.values()]
    with rig as same:
        assert same is rig
        assert rig.cameras["top"].grab().ndim == 2
    assert rig.closed
    assert all(d.closed for d in devices)
    rig.close()  # again: harmless
    with pytest.raises(DeviceError, match="on a closed manipulator"):
        rig.manipulator.position_um()
    with pytest.raises(DeviceError, match="expected a SimRigSpec or HardwareRigSpec"):
        open_rig({"driver": "sim"})  # type: ignore[arg-type]


def test_a_device_that_fails_to_open_closes_those_opened_before(fake_mcs2, monkeypatch):
    from microcal.devices.smaract_mcs2 import MCS2Manipulator

    closed = []
    original = MCS2Manipulator._close
    monkeypatch.setattr(MCS2Manipulator, "_close", lambda self: closed.append(original(self)))
    spec = HardwareRigSpec(
        MCS2Spec("127.0.0.1", {"x": 0, "y": 1, "z": 2}, LIMITS, timeout_s=0.5),  # type: ignore[arg-type]
        {"top": AravisCameraSpec("127.0.0.9"), "side": AravisCameraSpec("127.0.0.10")},
    )
    with pytest.raises(DeviceError, match=r"Aravis|top: cannot open the camera at 127\.0\.0\.9"):
        open_rig(spec)
    assert fake_mcs2.connections == 1  # the controller answered ...
    assert len(closed) == 1  # ... and was closed again


def test_the_simulated_rig_has_ground_truth_and_a_temperature():
    with open_rig(SimRigSpec(seed=2)) as rig:
        assert rig.truth is not None
        assert rig.truth().shape == (3,)
        assert rig.temperature is not None
        assert 15.0 < rig.temperature() < 30.0


def test_a_device_that_fails_to_close_does_not_keep_the_others_open(monkeypatch):
    rig = open_rig(SimRigSpec())
    released = []
    rig.resources.append(lambda: released.append(True))

    def broken() -> None:
        raise DeviceError("top: camera not answering")

    monkeypatch.setattr(rig.cameras["top"], "_close", broken)
    with pytest.raises(DeviceError, match=r"rig: closing top \(top: camera not answering\) failed"):
        rig.close()
    assert all(d.closed for d in (*rig.cameras.values(), rig.manipulator))
    assert released == [True]
    rig.close()  # already closed: nothing again
    assert released == [True]


def test_closing_errors_do_not_hide_the_error_that_ended_the_block(monkeypatch):
    rig = open_rig(SimRigSpec())

    def broken() -> None:
        raise DeviceError("side: camera not answering")

    monkeypatch.setattr(rig.cameras["side"], "_close", broken)
    with pytest.raises(KeyError, match="the run's own error"), rig:
        raise KeyError("the run's own error")
    assert rig.closed
    assert rig.manipulator.closed
