"""The digital twin of the one-camera ``patch`` microscope: its camera, X-Y stage and focus
as Micro-Manager devices and its pipette's manipulator through the MCS2 driver, opened from
the rig file it writes, on loopback in the module's own network namespace."""

from __future__ import annotations

import json
import socket
import time

import numpy as np
import pytest

from microcal.devices.base import RealClock
from microcal.devices.rig_spec import HardwareRigSpec, MMStageSpec
from microcal.devices.twin_protocol import KEPT_FRAMES
from microcal.errors import DeviceError, InputError, LimitError
from microcal.formats.rig_file import load_rig
from microcal.formats.twin_rig_file import twin_rig_toml
from microcal.sim.twin import Twin
from microcal.vision.lazy_frame import grab_frame
from microcal.vision.tip_target import TipTarget

SCALE = 50.0  # simulated seconds per wall second


@pytest.fixture(scope="module")
def served():
    """A twin of the patch preset in the module's own network namespace, on free ports."""
    from support.twin_served import twin_on_loopback

    with twin_on_loopback(preset="patch", seed=3, time_scale=SCALE) as twin:
        yield twin


@pytest.fixture(scope="module")
def rig(served, tmp_path_factory):
    """The rig opened through the real drivers from the twin's rig file."""
    pytest.importorskip("pymmcore_plus")
    from microcal.workflows.rigs import open_rig

    path = tmp_path_factory.mktemp("twin") / "patch.toml"
    path.write_text(twin_rig_toml(served.rig_description(), str(path)))
    with open_rig(load_rig(str(path))) as opened:
        yield opened


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


def settle(device, target_um) -> None:
    device.move_to_um(target_um)
    device.wait_until_stopped(RealClock(), timeout_s=10.0, poll_s=0.005)


def test_the_rig_file_names_one_camera_a_microscope_and_the_manipulator(served, tmp_path):
    path = tmp_path / "patch.toml"
    path.write_text(twin_rig_toml(served.rig_description(), str(path)))
    text = path.read_text()
    assert f"microcal twin --preset patch --seed 3 --port {served.mcs2_port}" in text
    spec = load_rig(str(path))
    assert isinstance(spec, HardwareRigSpec)
    assert list(spec.cameras) == ["scope"]
    assert spec.cameras["scope"].pixel_size_um == 6.5
    assert spec.target_stage is None
    assert spec.board == "tip:pipette:10:1"
    assert spec.microscope == MMStageSpec(
        "XYStage", {"x": (-5000.0, 5000.0), "y": (-5000.0, 5000.0), "z": (-500.0, 500.0)},
        "Focus",
    )  # fmt: skip
    assert spec.manipulator.limits_um == {"x": (0.0, 20000.0), "y": (0.0, 20000.0),
                                          "z": (0.0, 20000.0)}  # fmt: skip


def test_the_opened_rig_has_one_camera_the_microscope_and_the_pipettes_manipulator(rig):
    assert list(rig.cameras) == ["scope"]
    assert rig.cameras["scope"].sensor_size_px == (2048, 2048)
    assert rig.cameras["scope"].dtype == np.uint16  # 12 bits; the core reports 16 (uint16)
    assert rig.microscope is not None
    assert rig.microscope.axes == ("x", "y", "z")
    assert rig.description["microscope"] == "Micro-Manager XYStage + Focus"
    assert rig.manipulator.identity == "SmarAct MCS2 MCS2-TWIN-3 channels 0,1,2"
    assert isinstance(rig.board, TipTarget)
    assert rig.board.kind == "pipette"


def test_a_frame_is_read_by_region_and_shows_the_pipettes_tip_in_focus(rig, served):
    patch = served.patch
    reading, _ = patch.in_focus()  # the focus reading that puts the tip in focus
    settle(rig.microscope, [0.0, 0.0, round(reading, 3)])
    assert rig.cameras["scope"].grab_lazy is not None  # the twin says: read by region
    frame = grab_frame(rig.cameras["scope"])
    assert frame.shape == (2048, 2048)
    kept = served.frames._kept[max(served.frames._kept)]  # the twin's own frame
    tip_px = kept.truth.tip_px
    x, y = int(tip_px[0]), int(tip_px[1])
    box = (x - 60, y - 60, x + 60, y + 60)
    near = frame.region(*box)
    assert near.dtype == np.uint16
    assert near.shape == (120, 120)
    np.testing.assert_array_equal(near, kept.region(*box))  # the twin's pixels, unchanged
    assert abs(kept.truth.defocus_um) < 0.5  # the tip in focus
    # the pipette moved out of the box (the focus, the stage, the tissue as they were): the
    # region changes where the glass was, by far more than the frames' noise
    settle(rig.manipulator, rig.manipulator.position_um() + [0.0, 40.0, 0.0])
    after = grab_frame(rig.cameras["scope"]).region(*box).astype(float)
    change = np.abs(after - near.astype(float))
    assert np.percentile(change, 99) > 400.0, np.percentile(change, 99)
    assert np.median(change) < 80.0  # elsewhere, the noise
    assert frame.region(2040, 2040, 2100, 2100).shape == (8, 8)  # clipped to the frame


def test_the_microscopes_stage_and_focus_move_read_back_and_take_their_time(rig, served):
    patch, scope = served.patch, rig.microscope
    t0 = served.clock.now_s()
    settle(scope, [250.0, -120.0, 12.5])
    assert served.clock.now_s() - t0 > 0.1  # 250 µm at 2 mm/s, settled: simulated time
    np.testing.assert_allclose(scope.position_um(), [250.0, -120.0, 12.5], atol=0.05)
    np.testing.assert_allclose(patch.stage.joints_um(served.clock.now_s())[:2], [250.0, -120.0],
                               atol=1e-9)  # fmt: skip
    assert patch.focus.position_um() == 12.5
    moves = patch.focus.moves
    settle(scope, [250.0, -120.0, 10.0])  # down: approached from below (two moves)
    assert patch.focus.moves == moves + 2
    settle(scope, [250.0, -120.0, 10.0])  # where it is: nothing moves
    assert patch.focus.moves == moves + 2


def test_positions_outside_the_travel_are_refused_in_one_line_and_nothing_moves(rig, served):
    from microcal.devices.twin_camera import FrameClient

    patch = served.patch
    before = patch.focus.position_um(), patch.stage.joints_um(served.clock.now_s()).copy()
    with pytest.raises(LimitError) as soft:  # the rig file's limits: refused before sending
        rig.microscope.move_to_um([0.0, 0.0, 900.0])
    assert len(str(soft.value).splitlines()) == 1
    client = FrameClient("127.0.0.1", served.frames_port, timeout_s=5.0)
    try:  # a client with wider limits: the twin refuses
        with pytest.raises(
            LimitError, match=r"focus: 900 um is outside the focus drive's range -500 to 500 um"
        ):
            client.stage("MOVE Focus 900", 0)
        with pytest.raises(LimitError, match="outside the soft limits"):
            client.stage("MOVE XYStage 6000 0", 0)
        with pytest.raises(DeviceError, match=r"move: stage Focus takes 1 finite number"):
            client.stage("MOVE Focus 1 2", 0)
        with pytest.raises(DeviceError, match=r"no stage 'Z' \(stages: XYStage, Focus\)"):
            client.stage("POS Z", 1)
    finally:
        client.close()
    assert patch.focus.position_um() == before[0]
    np.testing.assert_array_equal(patch.stage.joints_um(served.clock.now_s()), before[1])


def test_the_mcs2_driver_moves_the_pipette_and_truth_follows(rig, served):
    m = rig.manipulator
    target = m.position_um().round(0) + [20.0, -10.0, 5.0]
    settle(m, target)
    np.testing.assert_allclose(m.position_um(), target, atol=0.2)
    truth = json.loads(ask(served.frames_port, "TRUTH"))
    assert set(truth) >= {"t_s", "position_um", "devices", "stage_um", "objective_um"}
    np.testing.assert_allclose(truth["devices"]["m1"],
                               served.patch.manipulator.true_position_um(), atol=0.05)  # fmt: skip


def test_snap_and_region_keep_the_last_frames_and_refuse_the_rest(served):
    port = served.frames_port
    info = json.loads(ask(port, "INFO"))
    assert [c["name"] for c in info["cameras"]] == ["scope"]
    assert info["cameras"][0]["dtype"] == "uint16"
    assert [s["name"] for s in info["stages"]] == ["XYStage", "Focus"]
    first = ask(port, "SNAP scope").split()
    assert first[0] == b"OK"
    assert first[2:] == [b"2048", b"2048", b"uint16"]
    data = ask(port, f"REGION {int(first[1])} 10 20 14 23", extra=24)
    assert data.startswith(b"OK 3 4 uint16 24\r\n")
    for _ in range(KEPT_FRAMES):
        ask(port, "SNAP scope")
    assert ask(port, f"REGION {int(first[1])} 0 0 4 4").startswith(
        f"ERR input region: frame {int(first[1])} is not kept".encode()
    )
    last = int(ask(port, "SNAP scope").split()[1])
    assert ask(port, f"REGION {last} 0 0 4000 4").startswith(b"ERR input region: the box")
    assert ask(port, f"REGION {last} 5 5 5 9").startswith(b"ERR input region: the box")
    assert ask(port, "REGION x 0 0 4 4").startswith(b"ERR input region: expected integers")
    assert ask(port, "BUSY XYStage") in (b"OK 0.0\r\n", b"OK 1.0\r\n")


def test_closing_the_rig_closes_the_microscope_and_the_camera(served, tmp_path):
    pytest.importorskip("pymmcore_plus")
    from microcal.workflows.rigs import open_rig

    path = tmp_path / "patch.toml"
    path.write_text(twin_rig_toml(served.rig_description(), str(path)))
    opened = open_rig(load_rig(str(path)))
    opened.close()
    for what in (lambda: opened.microscope.move_to_um([0.0, 0.0, 0.0]),
                 lambda: grab_frame(opened.cameras["scope"])):  # fmt: skip
        with pytest.raises(DeviceError, match="closed") as closed:
            what()
        assert len(str(closed.value).splitlines()) == 1


def test_the_patch_twin_takes_no_overrides():
    with pytest.raises(InputError, match="the twin serves the patch preset as it is"):
        Twin(preset="patch", overrides={"exposure_s": 0.01})
