"""The digital twin: the simulated platform served through the real protocols, driven by the
real drivers (SmarAct MCS2 over TCP, Micro-Manager with the twin's cameras), on loopback in
the module's own network namespace."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.devices.base import RealClock
from microcal.devices.rig_spec import HardwareRigSpec, MCS2Spec
from microcal.devices.smaract_mcs2 import MCS2Manipulator
from microcal.errors import DeviceError, FrameError, InputError, LimitError, MoveError
from microcal.formats.rig_file import load_rig
from microcal.formats.twin_rig_file import RIG_HEADER, twin_rig_toml
from microcal.sim import platform
from microcal.sim.scaled_clock import ScaledClock
from microcal.sim.twin import Twin
from microcal.sim.twin_rig import twin_rig
from microcal.vision.detect import detect
from microcal.vision.targets import parse_target

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "rigs" / "twin.toml"
SCALE = 20.0  # simulated seconds per wall second: moves and settling 20 times faster
A_UM = np.array([4000.0, 4000.0, 2400.0])


@pytest.fixture(scope="module")
def served():
    """A twin in the module's own network namespace (loopback only), on free ports."""
    from support.twin_served import twin_on_loopback

    with twin_on_loopback(seed=0, time_scale=SCALE) as twin:
        yield twin


@pytest.fixture(scope="module")
def rig(served, tmp_path_factory):
    """(rig, its target stage), opened through the real drivers from the twin's rig file."""
    pytest.importorskip("pymmcore_plus")
    from microcal.workflows.rigs import open_rig

    path = tmp_path_factory.mktemp("twin") / "twin.toml"
    path.write_text(twin_rig_toml(served.rig_description(), str(path)))
    spec = load_rig(str(path))
    assert isinstance(spec, HardwareRigSpec)
    with open_rig(spec) as opened:
        assert opened.target_stage is not None
        yield opened, opened.target_stage


def settle(device, target_um) -> None:
    device.move_to_um(target_um)
    device.wait_until_stopped(RealClock(), timeout_s=10.0, poll_s=0.005)


def centre_px(image, target) -> np.ndarray:
    found = detect(image, target)
    assert found.found, found.reason
    return found.q_px.mean(axis=0)


def ask(port: int, line: str, extra: int = 0) -> bytes:
    """One raw request on a fresh connection: the answer line (and ``extra`` bytes after)."""
    with socket.create_connection(("127.0.0.1", port), timeout=5.0) as sock:
        sock.sendall(line.encode("ascii") + b"\r\n")
        data = b""
        deadline = time.monotonic() + 5.0
        while (b"\r\n" not in data or len(data.partition(b"\r\n")[2]) < extra) and (
            time.monotonic() < deadline
        ):
            data += sock.recv(1 << 20)
        return data


def test_the_scaled_clock_follows_the_wall_clock_faster():
    clock = ScaledClock(50.0)
    t0, w0 = clock.now_s(), time.monotonic()
    clock.sleep(2.5)  # 50 ms of wall time
    waited = time.monotonic() - w0
    assert 0.045 < waited < 0.5
    assert clock.now_s() - t0 == pytest.approx(waited * 50.0, rel=0.2)
    clock.sleep(0)
    with pytest.raises(InputError, match="finite duration"):
        clock.sleep(-1.0)
    for bad in (0, -2.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match=r"time_scale: expected a finite number > 0"):
            ScaledClock(bad)


def test_the_mcs2_driver_moves_the_twins_manipulator(rig, served):
    opened, _ = rig
    m = opened.manipulator
    assert m.serial == "MCS2-TWIN-0"
    assert "MCS2-TWIN-0" in opened.description["manipulator"]
    target = np.array([3000.0, 3500.0, 2000.0])
    m.move_to_um(target)
    assert m.is_moving()
    waited = m.wait_until_stopped(RealClock(), timeout_s=10.0, poll_s=0.005)
    assert waited < 2.0  # 3.5 mm at 2 mm/s and 0.4 s settling, 20 times faster: ~0.11 s
    assert not m.is_moving()
    np.testing.assert_allclose(m.position_um(), target, atol=1.0)  # the position readout
    truth = json.loads(ask(served.frames_port, "TRUTH"))
    assert set(truth) == {"t_s", "position_um", "target_stage_um", "devices"}
    # the end-effector in {G}: the true kinematics of the joints, creep fading
    np.testing.assert_allclose(truth["position_um"], served.platform.truth_position_um(), atol=0.5)


def test_frames_have_the_sims_shape_and_show_the_board_where_the_manipulator_put_it(rig, served):
    opened, _ = rig
    settle(opened.manipulator, A_UM)
    before = {}
    for name, cam in opened.cameras.items():
        sim = served.platform.cameras[name]
        frame = cam.grab()
        assert frame.shape == (sim.sensor_size_px[1], sim.sensor_size_px[0])
        assert frame.dtype == sim.dtype
        assert cam.pixel_size_um == sim.pixel_size_um
        assert cam.grab_lazy is None  # whole frames (only the patch camera is read by region)
        before[name] = centre_px(frame, opened.board)
    opened.cameras["side"].exposure_s = 0.01  # through Micro-Manager to the simulated camera
    assert served.platform.cameras["side"].exposure_s == pytest.approx(0.01)
    opened.cameras["side"].exposure_s = 0.02
    settle(opened.manipulator, A_UM + [1000.0, 0.0, 0.0])
    shift = centre_px(opened.cameras["top"].grab(), opened.board) - before["top"]
    assert np.hypot(*shift) > 20.0  # about 46 px for 1 mm


def test_a_target_stage_move_brings_the_calibration_target_into_view(rig):
    opened, stage = rig
    dots = parse_target("dotgrid:40x30:250")
    settle(stage, [0.0, 0.0, 1000.0])  # the stage moved last: the cameras see its target
    for cam in opened.cameras.values():
        frame = cam.grab()
        assert detect(frame, dots).found
    assert not detect(frame, opened.board).found
    settle(opened.manipulator, A_UM)  # the manipulator moved last: the board again
    assert detect(opened.cameras["top"].grab(), opened.board).found


def test_limits_are_refused_before_sending_and_raw_commands_outside_them_by_the_twin(rig, served):
    opened, _ = rig
    sent = len(served.mcs2.log)
    with pytest.raises(LimitError, match="outside the soft limits"):
        opened.manipulator.move_to_um([9000.0, 0.0, 0.0])
    assert len(served.mcs2.log) == sent  # nothing sent
    port = served.mcs2_port
    assert ask(port, ":MOVE0 9000000000000;:SYST:ERR:NEXT?").startswith(b'-222,"Data out of range')
    assert ask(port, ":MOVE7 0;:SYST:ERR:NEXT?").startswith(b"-221,")
    assert ask(port, ":MOVE0 far;:SYST:ERR:NEXT?").startswith(b"-104,")
    assert ask(port, ":CHAN0:FOO?;:SYST:ERR:NEXT?").startswith(b"-113,")
    assert ask(port, ":CHAN4:STAT?;:SYST:ERR:COUN?") in (b"2;0\r\n", b"3;0\r\n")
    # a driver whose soft limits are wider than the twin's: the controller refuses the move
    wide = MCS2Manipulator("127.0.0.1", {"x": 0, "y": 1, "z": 2}, [[-2e4, 2e4]] * 3, port=port,
                           timeout_s=2.0)  # fmt: skip
    with wide:
        with pytest.raises(MoveError, match=r"controller error -222 \(Data out of range"):
            wide.move_to_um([9000.0, 0.0, 0.0])
        assert wide.errors() == []


def test_the_frame_server_protocol(served):
    port = served.frames_port
    info = json.loads(ask(port, "INFO"))
    assert info["format"] == "microcal.twin/1"
    assert (info["seed"], info["time_scale"]) == (0, SCALE)
    top = {c["name"]: c for c in info["cameras"]}["top"]
    assert (top["width"], top["height"], top["dtype"], top["bit_depth"]) == (1600, 1200, "uint8", 8)
    data = ask(port, "GRAB top", extra=1600 * 1200)
    header, _, pixels = data.partition(b"\r\n")
    assert header == b"OK 1200 1600 uint8 1920000"
    assert len(pixels) == 1920000
    assert ask(port, "GRAB bottom").startswith(b"ERR input no camera 'bottom' (cameras: top, side)")
    assert ask(port, "EXPOSURE side 12.5") == b"OK\r\n"
    assert served.platform.cameras["side"].exposure_s == pytest.approx(0.0125)
    assert ask(port, "EXPOSURE side -1").startswith(b"ERR input exposure")
    assert ask(port, "HELLO").startswith(b"ERR input unknown request 'HELLO'")
    served.platform.cameras["side"].exposure_s = 0.02


def test_faults_reach_the_drivers_as_a_controllers_and_a_cameras_would(served, tmp_path):
    pytest.importorskip("pymmcore_plus")
    from microcal.workflows.rigs import open_rig

    faults = {"top.faults.drop_rate": 1.0, "manipulator.faults.move_failure_rate": 1.0}
    with Twin(seed=1, overrides=faults, time_scale=SCALE, mcs2_port=0, frames_port=0) as twin:
        path = tmp_path / "twin.toml"
        path.write_text(twin_rig_toml(twin.rig_description()))
        with open_rig(load_rig(str(path))) as faulty:
            with pytest.raises(FrameError, match="frame dropped"):
                faulty.cameras["top"].grab()
            assert faulty.cameras["side"].grab().ndim == 2
            with pytest.raises(MoveError, match=r"controller error -1015 \(Movement failed"):
                faulty.manipulator.move_to_um([100.0, 100.0, 100.0])


def test_a_twin_of_the_whole_station_serves_every_device_on_its_own_channels(served, tmp_path):
    """thesis-platform: m2 on channels 6-8 and the X-Y positioner p1 on 9-10 of the one
    controller, each a device of its own identity (p1 with its z held); the board the
    cameras see is the device moved last."""
    pytest.importorskip("pymmcore_plus")
    from microcal.workflows.rigs import open_rig

    with Twin(preset="thesis-platform", seed=2, time_scale=SCALE, mcs2_port=0,
              frames_port=0) as twin:  # fmt: skip
        path = tmp_path / "station.toml"
        path.write_text(twin_rig_toml(twin.rig_description()))
        spec = load_rig(str(path))
        assert spec.manipulator_names == ("m1", "m2", "p1")
        with open_rig(spec, "p1") as opened:
            p1 = opened.manipulator
            assert p1.identity == "SmarAct MCS2 MCS2-TWIN-2 channels 9,10"
            assert p1.axes == ("x", "y", "z")
            assert p1.limits_um[2].tolist() == [0.0, 0.0]
            with pytest.raises(LimitError, match="z"):
                p1.move_to_um([1000.0, 2000.0, 500.0])
            assert opened.manipulators["m2"].identity.endswith("channels 6,7,8")
            settle(p1, [1000.0, 2000.0, 0.0])
            truth = json.loads(ask(twin.frames_port, "TRUTH"))
            np.testing.assert_allclose(truth["devices"]["p1"],
                                       twin.platform.manipulators["p1"].true_position_um(),
                                       atol=0.5)  # fmt: skip
            # only p1 moved: the others are where they began
            np.testing.assert_allclose(
                twin.platform.manipulators["m2"].joints_um(twin.clock.now_s()), 0.0, atol=1e-9
            )
            seen = centre_px(opened.cameras["top"].grab(), opened.board)
            expected = twin.platform.camera_models["top"].project(
                np.array([truth["devices"]["p1"]])
            )[0]
            np.testing.assert_allclose(seen, expected, atol=2.0)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_no_twin_running_is_one_line_saying_how_to_start_it(served, tmp_path):
    pytest.importorskip("pymmcore_plus")
    from microcal.workflows.rigs import open_rig

    port = _free_port()
    text = twin_rig_toml(twin_rig(served.platform, mcs2_port=_free_port(), frames_port=port))
    path = tmp_path / "twin.toml"
    path.write_text(text)
    with pytest.raises(DeviceError) as info:
        open_rig(load_rig(str(path)))
    message = str(info.value)
    assert message.startswith(f"no digital twin at 127.0.0.1:{port} (Connection refused)")
    assert f"start it with `microcal twin --frames-port {port}`" in message
    assert len(message.splitlines()) == 1


def test_the_example_rig_is_the_twins_for_the_default_ports():
    text = twin_rig_toml(twin_rig(platform("thesis", 0)), rig_path="examples/rigs/twin.toml")
    assert EXAMPLE.read_text(encoding="utf-8") == text  # regenerate it if the twin changed
    spec = load_rig(str(EXAMPLE))
    assert isinstance(spec, HardwareRigSpec)
    assert spec.manipulator == MCS2Spec(
        "127.0.0.1", {"x": 0, "y": 1, "z": 2},
        {"x": (-500.0, 8500.0), "y": (-500.0, 8500.0), "z": (-500.0, 5300.0)},
    )  # fmt: skip
    assert isinstance(spec.target_stage, MCS2Spec)
    assert spec.target_stage.channels == {"x": 3, "y": 4, "z": 5}
    assert spec.calibration_target == "dotgrid:40x30:250"
    assert spec.micromanager is not None
    assert spec.micromanager.options == {"address": "127.0.0.1", "port": 55561}
    assert list(spec.cameras) == ["top", "side"]
    with pytest.raises(InputError, match="loopback only"):
        Twin(host="192.168.1.20")


def test_the_command_serves_writes_its_rig_file_and_keeps_others(served, tmp_path):
    runner = CliRunner()
    out = tmp_path / "rigs" / "twin.toml"
    args = ["twin", "--port", "0", "--frames-port", "0", "--duration-s", "0.2", "--seed", "3"]
    for _ in range(2):  # the second run replaces the file it wrote
        result = runner.invoke(app, [*args, "--rig-out", str(out)])
        assert result.exit_code == 0, result.output
    assert f"rig file {out}" in result.output
    assert "digital twin stopped (duration)" in result.output
    assert out.read_text().startswith(RIG_HEADER)
    assert "microcal twin --seed 3 --port " in out.read_text()
    assert isinstance(load_rig(str(out)), HardwareRigSpec)
    notes = tmp_path / "notes.toml"
    notes.write_text("mine\n")
    result = runner.invoke(app, [*args, "--rig-out", str(notes)])
    assert result.exit_code == 2
    assert "holds a file microcal did not write" in result.output
    assert notes.read_text() == "mine\n"
    result = runner.invoke(app, [*args, "--time-scale", "0"])
    assert result.exit_code == 2
    assert "time_scale: expected a finite number > 0" in result.output


def test_the_command_stops_cleanly_on_sigterm(served):
    proc = subprocess.Popen(
        [sys.executable, "-m", "microcal", "twin", "--port", "0", "--frames-port", "0"],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("digital twin (preset thesis, seed 0, time x1): SmarAct MCS2")
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    assert proc.returncode == 0, err
    assert out.strip() == "digital twin stopped (terminated)"
