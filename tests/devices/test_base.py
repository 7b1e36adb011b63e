"""One contract per device kind, run against every backend with its real protocol peer.

Manipulators: the simulator, the SmarAct MCS2 driver (fake controller over TCP) and the
Micro-Manager bridge (pymmcore-plus Python devices). Cameras: the simulator, Aravis against
Debian's fake GigE Vision camera and against viva-genicam's, and the Micro-Manager bridge.
Backends whose peer or library is missing here are skipped with the reason. Every device
closes once and for good (idempotent, refusing every operation afterwards, as a context
manager too); both clocks wait the same way and refuse the same durations.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator

import numpy as np
import pytest

from microcal.devices.base import Camera, Clock, Manipulator, RealClock
from microcal.errors import DeviceError, InputError, LimitError
from microcal.sim import platform
from microcal.sim.clock import SimClock

LIMITS = [[0.0, 8000.0], [0.0, 8000.0], [0.0, 4800.0]]


@pytest.fixture(params=["sim", "smaract-mcs2", "micromanager"])
def manipulator(request) -> Iterator[tuple[Manipulator, Clock]]:
    if request.param == "sim":
        plat = platform("thesis", seed=0)
        yield plat.manipulator, plat.clock
    elif request.param == "smaract-mcs2":
        from microcal.devices.smaract_mcs2 import MCS2Manipulator

        request.getfixturevalue("fake_mcs2")
        with MCS2Manipulator("127.0.0.1", {"x": 0, "y": 1, "z": 2}, LIMITS, timeout_s=0.5) as m:
            yield m, RealClock()
    else:
        from microcal.devices.micromanager import MMManipulator

        core = request.getfixturevalue("mm_core")
        yield MMManipulator(core, xy_stage="XY", focus="Z", limits_um=LIMITS), RealClock()


@pytest.fixture(params=["sim", "aravis-arv-fake", "aravis-viva", "micromanager"])
def camera(request) -> Iterator[Camera]:
    if request.param == "sim":
        yield platform("thesis", seed=0).cameras["top"]
    elif request.param.startswith("aravis"):
        from microcal.devices.aravis_camera import AravisCamera

        start = request.getfixturevalue("gige_cameras")
        if request.param == "aravis-arv-fake":
            start("127.0.0.1")
        else:
            start("127.0.0.2", viva=(1226, 1028))
        address = "127.0.0.1" if request.param == "aravis-arv-fake" else "127.0.0.2"
        cam = AravisCamera(address, name="top", exposure_s=0.005, timeout_s=2.0)
        yield cam
        cam.close()
    else:
        from microcal.devices.micromanager import MMCamera

        yield MMCamera(request.getfixturevalue("mm_core"), "TopCam", name="top")


@pytest.fixture(params=["real", "sim"])
def clock(request) -> Clock:
    return RealClock() if request.param == "real" else SimClock(start_s=12.5)


# --- clocks ------------------------------------------------------------------------------------
def test_now_is_monotonic_and_sleep_advances_it(clock):
    t0 = clock.now_s()
    assert isinstance(t0, float)
    clock.sleep(0.0)
    clock.sleep(-0.0)
    t1 = clock.now_s()
    assert t1 >= t0
    clock.sleep(0.01)
    t2 = clock.now_s()
    assert t2 - t1 >= 0.01 - 1e-9
    reads = [clock.now_s() for _ in range(100)]
    assert all(b >= a for a, b in itertools.pairwise(reads))


@pytest.mark.parametrize("duration", [-1.0, -1e-9, math.nan, math.inf, -math.inf])
def test_sleep_refuses_negative_and_non_finite_durations_alike(clock, duration):
    before = clock.now_s()
    with pytest.raises(InputError, match=r"sleep: expected a finite duration >= 0 s, got "):
        clock.sleep(duration)
    assert clock.now_s() - before < 0.5  # refused at once, nothing waited (sim: time unchanged)
    if isinstance(clock, SimClock):
        assert clock.now_s() == before


# --- manipulators ------------------------------------------------------------------------------
def test_move_outside_the_limits_is_refused_and_nothing_moves(manipulator):
    m, clock = manipulator
    m.wait_until_stopped(clock, timeout_s=10.0)
    before = m.position_um()
    with pytest.raises(LimitError, match=r"axis y = 9000.000 µm is outside the soft limits"):
        m.move_to_um([100.0, 9000.0, 100.0])
    assert not m.is_moving()
    np.testing.assert_allclose(m.position_um(), before, atol=0.5)  # sensor noise: 0.05 µm in sim


def test_bad_command_shape_is_an_input_error(manipulator):
    m, _ = manipulator
    with pytest.raises(InputError, match=r"d_um: expected shape \(3,\)"):
        m.move_to_um([1.0, 2.0])


def test_move_settles_where_commanded(manipulator):
    m, clock = manipulator
    target = np.array([1500.0, 2500.0, 700.0])
    m.move_to_um(target)
    assert m.is_moving()  # finite speed everywhere: a 2.5 mm move takes time
    waited = m.wait_until_stopped(clock, timeout_s=30.0, poll_s=0.01)
    assert waited > 0
    p = m.position_um()
    assert p.shape == (3,)
    assert p.dtype == np.float64
    np.testing.assert_allclose(p, target, atol=0.5)  # the device's own sensors


def test_stop_ends_the_motion(manipulator):
    m, clock = manipulator
    m.move_to_um([8000.0, 8000.0, 4800.0])
    m.stop()
    m.wait_until_stopped(clock, timeout_s=5.0, poll_s=0.01)
    assert not m.is_moving()
    assert np.all(m.position_um() < [7999.0, 7999.0, 4799.0])


def test_wait_has_a_timeout(manipulator):
    m, clock = manipulator
    m.move_to_um([8000.0, 8000.0, 4800.0])
    from microcal.errors import DeviceTimeoutError

    timeout = 0.0 if isinstance(clock, SimClock) else 0.001
    with pytest.raises(DeviceTimeoutError, match="still moving after"):
        m.wait_until_stopped(clock, timeout_s=timeout, poll_s=0.0005)
    m.stop()


def test_close_is_idempotent_and_every_operation_after_it_is_refused(manipulator):
    m, clock = manipulator
    assert not m.closed
    m.close()
    assert m.closed
    m.close()  # again: nothing happens
    assert m.closed
    for operation in (
        lambda: m.move_to_um([100.0, 100.0, 100.0]),
        m.position_um,
        m.is_moving,
        m.stop,
        lambda: m.wait_until_stopped(clock, timeout_s=1.0),
    ):
        with pytest.raises(DeviceError, match=rf"^{m.name}: .* on a closed manipulator; open"):
            operation()


def test_a_manipulator_is_a_context_manager_that_closes(manipulator):
    m, _ = manipulator
    with m as same:
        assert same is m
        assert m.position_um().shape == (3,)
    assert m.closed
    with pytest.raises(DeviceError, match="closed"):
        m.position_um()


def test_the_context_manager_closes_when_the_block_fails(manipulator):
    m, _ = manipulator
    with pytest.raises(LimitError), m:
        m.move_to_um([99999.0, 0.0, 0.0])
    assert m.closed


# --- cameras -----------------------------------------------------------------------------------
def test_frames_have_the_sensor_size_and_dtype(camera):
    frame = camera.grab()
    w, h = camera.sensor_size_px
    assert frame.shape == (h, w)
    assert frame.dtype == camera.dtype
    assert camera.dtype == (np.uint8 if camera.bit_depth == 8 else np.uint16)
    assert int(frame.max()) < 2**camera.bit_depth


def test_each_frame_is_the_callers_own(camera):
    first = camera.grab()
    kept = first.copy()
    for _ in range(3):
        camera.grab()
    np.testing.assert_array_equal(first, kept)  # not a view of a reused buffer


def test_exposure_is_validated_and_applied(camera):
    old = camera.exposure_s
    with pytest.raises(InputError, match="exposure_s: expected > 0"):
        camera.exposure_s = 0.0
    assert camera.exposure_s == old
    camera.exposure_s = 0.004
    assert camera.exposure_s == pytest.approx(0.004)
    assert camera.grab().shape[::-1] == tuple(camera.sensor_size_px)


def test_camera_close_is_idempotent_and_grabs_after_it_are_refused(camera):
    assert not camera.closed
    camera.close()
    camera.close()  # again: nothing happens
    assert camera.closed
    with pytest.raises(DeviceError, match=rf"^{camera.name}: grab on a closed camera; open"):
        camera.grab()
    with pytest.raises(DeviceError, match="on a closed camera"):
        camera.exposure_s = 0.004


def test_a_camera_is_a_context_manager_that_closes(camera):
    with camera as same:
        assert same is camera
        assert camera.grab().shape[::-1] == tuple(camera.sensor_size_px)
    assert camera.closed
    with pytest.raises(DeviceError, match="closed"):
        camera.grab()
