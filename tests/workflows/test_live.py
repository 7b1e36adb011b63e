"""The work behind the station page, without a browser: frames, overlays, clicks to a 3D
target, moves refused before anything moves, the stop that holds, a lost camera in words."""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from microcal.errors import DeviceError, InputError, LimitError
from microcal.workflows.live import LiveStation, open_live_station
from support.station_files import write_truth_calibration


@pytest.fixture(scope="module")
def calibration(tmp_path_factory) -> str:
    return str(write_truth_calibration(tmp_path_factory.mktemp("live") / "calibration.json"))


@pytest.fixture
def live(calibration):
    station = open_live_station("sim", calibration, seed=0, frames=2)
    yield station
    station.close()


def _pixels(live: LiveStation, p_um) -> dict[str, np.ndarray]:
    p = np.asarray(p_um, dtype=float)[None, :]
    return {n: m.project(p)[0] for n, m in live.models.items()}


def test_the_layout_is_data_the_cameras_and_the_target(live):
    layout = live.layout()
    assert [c["name"] for c in layout["cameras"]] == ["top", "side"]
    assert layout["cameras"][0] | {} == {"name": "top", "width_px": 1600, "height_px": 1200}
    assert layout["target"]["kind"] == "chessboard"
    assert layout["click_to_target"] == "rays"
    assert layout["simulated"] is True


def test_frames_come_downscaled_or_as_a_full_resolution_region(live):
    data = live.frame_jpeg("top", 640)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert image.shape == (480, 640)
    region = cv2.imdecode(np.frombuffer(live.frame_jpeg("side", region=(600, 500, 160)), np.uint8),
                          cv2.IMREAD_GRAYSCALE)  # fmt: skip
    assert region.shape == (160, 160)
    assert live.state()["sharpness"]["top"] > 0
    with pytest.raises(InputError, match=r"camera 'left': this rig has top, side"):
        live.frame_jpeg("left")
    with pytest.raises(InputError, match=r"width: expected 16 to 2048 px, got 5"):
        live.frame_jpeg("top", 5)


def test_overlays_put_the_predicted_tip_where_the_calibration_says(live):
    overlays = live.overlays()
    p, _ = live.predicted_um()
    for name, q in _pixels(live, p).items():
        e = overlays[name]["predicted"]
        assert abs(e["x"] - q[0]) < 1e-6
        assert abs(e["y"] - q[1]) < 1e-6
        assert len(overlays[name]["limits"]) == 12


def test_two_clicks_give_the_point_and_a_covariance(live):
    p = np.array([3600.0, 2600.0, 1800.0])
    q = _pixels(live, p)
    curves = live.epipolar("top", q["top"])
    gap = np.min(np.linalg.norm(np.array(curves["side"]) - q["side"], axis=1))
    assert gap < 10.0  # within the spacing of the curve's samples
    target = live.target_from_clicks(q, {"top": 1.25, "side": 1.0})
    np.testing.assert_allclose(target.target_um, p, atol=1e-6)
    assert target.refusal is None
    assert max(target.residual_px.values()) < 1e-6
    std = np.sqrt(np.diagonal(target.cov_um2))
    assert np.all((std > 1.0) & (std < 200.0))
    with pytest.raises(InputError, match=r"a click gives a ray, not a point; click in a second"):
        live.target_from_clicks({"top": q["top"]}, {})


def test_a_target_outside_the_limits_is_refused_before_anything_moves(live):
    before = live.manipulator.position_um()
    target = live.target_from_clicks(_pixels(live, [3000.0, 3000.0, 9000.0]), {"top": 1, "side": 1})
    assert target.refusal is not None
    assert "outside the soft limits" in target.refusal
    with pytest.raises(
        LimitError, match=r"outside the soft limits \[-500, 5300\] µm; nothing was moved"
    ):
        live.go(target.target_um)
    assert live.moves_started == 0
    assert not live.moving
    np.testing.assert_allclose(live.manipulator.position_um(), before, atol=0.5)
    with pytest.raises(InputError, match=r"mode: expected 'open' or 'closed', got 'fast'"):
        live.go([3000.0, 3000.0, 1500.0], "fast")  # type: ignore[arg-type]


@pytest.mark.slow
def test_the_closed_loop_brings_the_tip_to_the_clicked_point_by_truth(live):
    target = live.target_from_clicks(_pixels(live, [3600.0, 2600.0, 1800.0]), {"top": 1, "side": 1})
    live.go(target.target_um, "closed", 0.5)
    with pytest.raises(InputError, match=r"busy: going closed loop; wait, or stop"):
        live.go(target.target_um)
    assert live.wait(120.0)
    state = live.state()
    arrival = state["arrival"]
    assert state["error"] == ""
    assert arrival["mode"] == "closed"
    assert arrival["truth_error_um"] < 1.0
    assert arrival["residual_um"] < 1.0


def test_stop_halts_at_once_and_nothing_moves_after_it(live):
    moves: list[float] = []
    inner = live.manipulator.device
    real_move = inner._move
    stopped = threading.Event()

    def move(d):
        moves.append(time.monotonic())
        real_move(d)

    inner._move = move  # type: ignore[method-assign]
    real_sleep = live.station.rig.clock.sleep

    def slow_sleep(s):  # the settling before the first measurement: press stop meanwhile
        if not stopped.is_set():
            stopped.set()
            live.stop()
        real_sleep(s)

    live.station.rig.clock.sleep = slow_sleep  # type: ignore[method-assign]
    live.go([3000.0, 2000.0, 1500.0], "closed", 0.5)
    assert live.wait(60.0)
    halted_at = len(moves)
    state = live.state()
    assert state["error"] == "stopped by the stop control"
    assert state["halted"]
    assert state["activity"] == "idle"
    assert halted_at <= 2  # the approach from below and the move it began with, no correction
    live.station.rig.clock.sleep = real_sleep  # type: ignore[method-assign]


def test_a_lost_camera_is_told_in_words_and_nothing_moves(live):
    def lost():
        raise DeviceError("top: the camera stopped answering (cable?)")

    live.cameras["top"].inner._grab = lost  # type: ignore[method-assign]
    with pytest.raises(DeviceError, match="stopped answering"):
        live.frame_jpeg("top")
    assert live.state()["camera_errors"] == {"top": "top: the camera stopped answering (cable?)"}
    live.measure()
    assert live.wait(30.0)
    assert "stopped answering" in live.state()["error"]
    assert live.frame_jpeg("side")  # the other camera goes on


def test_one_camera_is_the_same_station_with_other_data(calibration):
    from microcal.workflows.station import open_calibrated_rig

    c = open_calibrated_rig("sim", calibration, seed=0)
    rig = dataclasses.replace(c.device, cameras={"top": c.device.cameras["top"]})
    live = LiveStation(rig, c.entry, {"top": c.models["top"]}, "one camera")
    try:
        assert [cam["name"] for cam in live.layout()["cameras"]] == ["top"]
        assert live.layout()["click_to_target"] == "focal plane"
        assert live.epipolar("top", [800.0, 600.0]) == {}
        # one click: on the focal plane (through the tip when the station opened) + offset
        top = live.models["top"]
        tip, _ = live.predicted_um()
        assert live.layout()["focal_plane"]["source"] == "the tip when the station opened"
        assert live.focal_plane.depth_um == pytest.approx(top.depth_um(tip[None, :])[0])
        on = live.target_from_clicks({"top": [800.0, 600.0]}, {"top": 0.5})
        deeper = live.target_from_clicks({"top": [800.0, 600.0]}, {"top": 0.5}, offset_um=50.0)
        for t, depth in ((on, live.focal_plane.depth_um), (deeper, live.focal_plane.depth_um + 50)):
            np.testing.assert_allclose(top.project(t.target_um[None, :])[0], [800, 600], atol=1e-6)
            assert top.depth_um(t.target_um[None, :])[0] == pytest.approx(depth, abs=1e-3)
            assert t.residual_px["top"] < 1e-6
            assert np.all(np.linalg.eigvalsh(t.cov_um2) > 0)
        with pytest.raises(InputError, match=r"offset: expected a number of µm"):
            live.target_from_clicks({"top": [800.0, 600.0]}, {"top": 0.5}, offset_um=float("nan"))
        from microcal.workflows.live_runs import StationRuns

        live.calibration_path = Path(calibration)
        runs = StationRuns(live, root=Path(calibration).with_name("runs"))
        for kind in ("acquire", "check"):
            with pytest.raises(InputError, match=f"^{kind}: this station has one camera"):
                runs.start(kind)
        assert runs.state() is None
    finally:
        live.close()
        c.opened.close()


def test_the_calibrations_health_its_checks_and_the_report_beside_it(tmp_path):
    from microcal.errors import FormatError
    from microcal.formats.check_file import append_history, history_path
    from microcal.formats.hashing import sha256_file

    cal = write_truth_calibration(tmp_path / "calibration.json")
    digest = sha256_file(cal, link_ok=True)
    for when, verdict, offset in (("2026-12-01T09:00:00+00:00", "valid", [0.1, 0.0, 0.2]),
                                  ("2026-12-03T09:00:00+00:00", "offset", [2.0, 1.0, 0.5])):  # fmt: skip
        append_history(history_path(cal), {"calibration_sha256": digest, "manipulator": "m1",
                                           "created": when, "verdict": verdict, "offset_um": offset,
                                           "flag": False, "poses": []})  # fmt: skip
    (tmp_path / "report.html").write_text("<h1>report</h1>", encoding="utf-8")
    live = open_live_station("sim", str(cal), seed=0, frames=1)
    try:
        health = live.layout()["health"]
        assert [c["verdict"] for c in health["checks"]] == ["valid", "offset"]
        assert health["checks"][1]["offset_um"] == [2.0, 1.0, 0.5]
        assert health["validation_rms_um"] == 0.0
        assert health["report"] is True
        assert live.report_html() == b"<h1>report</h1>"
        (tmp_path / "report.html").unlink()
        (tmp_path / "report.html").symlink_to(cal)
        with pytest.raises(FormatError):
            live.report_html()
    finally:
        live.close()
    history_path(cal).write_text("not json\n", encoding="utf-8")
    live = open_live_station("sim", str(cal), seed=0, frames=1)
    try:
        health = live.layout()["health"]
        assert health["checks"] == []
        assert "line 1 is not JSON" in health["history_error"]
    finally:
        live.close()


def test_one_camera_with_a_bare_tip_is_refused_in_words(calibration):
    from microcal.vision.targets import parse_spec
    from microcal.workflows.station import open_calibrated_rig

    c = open_calibrated_rig("sim", calibration, seed=0)
    try:
        rig = dataclasses.replace(c.device, cameras={"top": c.device.cameras["top"]},
                                  board=parse_spec("tip:pipette:10:1"))  # fmt: skip
        with pytest.raises(InputError, match=r"one-camera station measures a board"):
            LiveStation(rig, c.entry, {"top": c.models["top"]}, "one camera")
    finally:
        c.opened.close()
