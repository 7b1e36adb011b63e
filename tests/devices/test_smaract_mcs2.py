"""The SmarAct MCS2 driver against the fake controller, on loopback in the test's namespace."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from microcal.devices.base import RealClock
from microcal.devices.smaract_mcs2 import MCS2Manipulator
from microcal.errors import DeviceError, DeviceTimeoutError, LimitError, MoveError

LIMITS = [[0, 8000], [0, 8000], [0, 4800]]
CHANNELS = {"x": 0, "y": 1, "z": 2}


def driver(**kwargs) -> MCS2Manipulator:
    m = MCS2Manipulator("127.0.0.1", CHANNELS, LIMITS, timeout_s=0.5, **kwargs)
    m.connect()
    return m


def test_connects_sets_closed_loop_absolute_mode_and_moves_in_pm(fake_mcs2):
    m = driver()
    assert m.serial == "MCS2-FAKE0001"
    assert all(ch.mode == 0 for ch in fake_mcs2.channels)
    m.move_to_um([1000.0, 2000.5, 300.000001])
    assert ":MOVE0 1000000000" in fake_mcs2.log
    assert ":MOVE1 2000500000" in fake_mcs2.log
    assert ":MOVE2 300000001" in fake_mcs2.log
    assert m.is_moving()  # 2 mm at 20 mm/s: 0.1 s
    waited = m.wait_until_stopped(RealClock(), timeout_s=5.0, poll_s=0.01)
    assert 0.02 < waited < 1.0
    np.testing.assert_allclose(m.position_um(), [1000.0, 2000.5, 300.000001], atol=1e-6)
    m.close()


def test_axis_to_channel_mapping_is_the_rig_files(fake_mcs2):
    m = MCS2Manipulator("127.0.0.1", {"x": 2, "y": 0, "z": 1}, LIMITS, timeout_s=0.5)
    m.connect()
    m.move_to_um([10.0, 20.0, 30.0])
    m.wait_until_stopped(RealClock(), timeout_s=5.0, poll_s=0.01)
    assert [c.target_pm for c in fake_mcs2.channels] == [20e6, 30e6, 10e6]
    np.testing.assert_allclose(m.position_um(), [10.0, 20.0, 30.0])


def test_soft_limits_are_enforced_before_anything_is_sent(fake_mcs2):
    m = driver()
    before = list(fake_mcs2.log)
    with pytest.raises(LimitError, match=r"axis z = 5000.000 µm is outside the soft limits"):
        m.move_to_um([100.0, 100.0, 5000.0])
    assert fake_mcs2.log == before


def test_stop_halts_every_channel_where_it_is(fake_mcs2):
    for ch in fake_mcs2.channels:
        ch.speed_pm_s = 1e9  # 1 mm/s: 8 s for the move below
    m = driver()
    m.move_to_um([8000.0, 8000.0, 4800.0])
    time.sleep(0.1)
    m.stop()
    assert not m.is_moving()
    p = m.position_um()
    assert np.all(p > 0)
    assert np.all(p < 1000)


def test_a_controller_error_is_a_device_error_with_its_message(fake_mcs2):
    m = driver()
    fake_mcs2.faults.refuse_with = (-1002, "Invalid parameter")
    with pytest.raises(
        MoveError, match=r"controller error -1002 \(Invalid parameter\) after ':MOVE0"
    ):
        m.move_to_um([10.0, 10.0, 10.0])


def test_a_failed_move_raises_move_error_naming_the_axis(fake_mcs2):
    m = driver()
    fake_mcs2.faults.fail_move_channel = 1
    m.move_to_um([100.0, 100.0, 100.0])
    with pytest.raises(
        MoveError, match=r"axis y \(channel 1\): movement failed; controller: -1015"
    ):
        m.wait_until_stopped(RealClock(), timeout_s=5.0, poll_s=0.01)
    assert fake_mcs2.errors == []  # read out with the failure


def test_a_connection_dropped_mid_move_is_opened_again(fake_mcs2):
    m = driver()
    fake_mcs2.faults.drop_after_move = 2  # drops after the y move: the z move reconnects
    m.move_to_um([500.0, 600.0, 700.0])
    m.wait_until_stopped(RealClock(), timeout_s=5.0, poll_s=0.01)
    np.testing.assert_allclose(m.position_um(), [500.0, 600.0, 700.0])
    assert m.reconnections == 1
    assert fake_mcs2.connections == 2


def test_a_silent_controller_times_out_and_never_hangs(fake_mcs2):
    m = driver()
    fake_mcs2.faults.silent = True
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeoutError, match=r"no answer to ':CHAN0:POS\?' within 0.5 s"):
        m.position_um()
    with pytest.raises(DeviceTimeoutError):
        m.wait_until_stopped(RealClock(), timeout_s=5.0, poll_s=0.01, retries=2)
    assert time.monotonic() - t0 < 4.0


def test_an_answer_without_end_is_refused_after_a_bounded_read(fake_mcs2):
    m = driver()
    fake_mcs2.faults.endless = True
    with pytest.raises(DeviceError, match=r"runs past 4096 bytes without a line end"):
        m.position_um()
    assert len(m._buffer) == 0  # the connection and what it sent are dropped
    fake_mcs2.faults.endless = False
    np.testing.assert_allclose(m.position_um(), [0.0, 0.0, 0.0])  # a new connection answers


def test_slow_answers_within_the_timeout_are_fine(fake_mcs2):
    fake_mcs2.faults.delay_s = 0.2
    m = driver()
    np.testing.assert_allclose(m.position_um(), [0.0, 0.0, 0.0])


def test_no_controller_at_the_address_is_one_clear_error(netns):
    m = MCS2Manipulator("127.0.0.1", CHANNELS, LIMITS, port=55551, timeout_s=0.5)
    with pytest.raises(DeviceError, match=r"cannot connect to 127.0.0.1:55551"):
        m.connect()


def test_controller_that_goes_away_for_good_gives_up_after_the_reconnections(fake_mcs2):
    m = driver(reconnects=2)
    fake_mcs2.close()
    with pytest.raises(DeviceError, match=r"cannot connect|connection .* lost"):
        m.position_um()


def test_the_namespace_has_only_loopback(netns):
    # a socket to a non-loopback address has no route here: nothing can leave the machine
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    with pytest.raises(OSError, match="unreachable"):
        s.sendto(b"x", ("192.0.2.1", 3956))
    s.close()


def test_close_ends_the_connection_for_good_and_commands_after_it_are_refused(fake_mcs2):
    m = driver()
    m.close()
    m.close()  # again: nothing happens
    log = list(fake_mcs2.log)
    with pytest.raises(DeviceError, match=r"mcs2: position query on a closed manipulator"):
        m.position_um()
    with pytest.raises(DeviceError, match=r"on a closed manipulator"):
        m.errors()  # a driver-specific query: refused too, not reconnected
    with pytest.raises(DeviceError, match=r"connect on a closed manipulator"):
        m.connect()
    assert fake_mcs2.log == log
    assert fake_mcs2.connections == 1


def test_as_a_context_manager_it_connects_and_closes(fake_mcs2):
    with MCS2Manipulator("127.0.0.1", CHANNELS, LIMITS, timeout_s=0.5) as m:
        assert m.serial == "MCS2-FAKE0001"
        np.testing.assert_allclose(m.position_um(), [0.0, 0.0, 0.0])
    assert m.closed
    with driver() as connected:  # connected already: not connected twice
        connected.position_um()
    assert fake_mcs2.connections == 2


def test_a_lost_connection_reconnects_but_does_not_close_the_driver(fake_mcs2):
    m = driver()
    fake_mcs2.faults.drop_after_move = 1
    m.move_to_um([10.0, 10.0, 10.0])
    assert not m.closed
    assert m.reconnections == 1
