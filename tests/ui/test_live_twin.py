"""The station's work on the digital twin: the same LiveStation, opened from the twin's rig
file, reaches the cameras through the Micro-Manager twin cameras and the manipulator through
the MCS2 driver, in the test's own network namespace (loopback only)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from support.station_files import write_truth_calibration

SCALE = 20.0  # simulated seconds per wall second


@pytest.fixture(scope="module")
def twin_station(tmp_path_factory):
    from support.twin_served import skip_without_namespace, twin_on_loopback

    skip_without_namespace()
    pytest.importorskip("pymmcore_plus")
    from microcal.workflows.live import open_live_station

    folder = tmp_path_factory.mktemp("twin-station")
    calibration = write_truth_calibration(folder / "calibration.json", seed=0)
    rig = folder / "twin.toml"
    with twin_on_loopback(rig, seed=0, time_scale=SCALE) as twin:
        live = open_live_station(str(rig), str(calibration), frames=2, settle_s=0.5)
        try:
            yield twin, live
        finally:
            live.close()


@pytest.mark.slow
def test_the_twins_cameras_are_seen_and_the_closed_loop_arrives_by_truth(twin_station):
    twin, live = twin_station
    assert live.layout()["simulated"] is False  # a rig file of devices, as on hardware
    for name in ("top", "side"):
        image = cv2.imdecode(np.frombuffer(live.frame_jpeg(name, 640), np.uint8),
                             cv2.IMREAD_GRAYSCALE)  # fmt: skip
        assert image.shape[1] == 640
        assert float(image.std()) > 1.0  # a picture, not a blank
    p = np.array([3600.0, 2600.0, 1800.0])
    clicks = {n: m.project(p[None, :])[0] for n, m in live.models.items()}
    target = live.target_from_clicks(clicks, {"top": 1.0, "side": 1.0})
    assert target.refusal is None
    live.go(target.target_um, "closed", 0.5)
    assert live.wait(300.0)
    state = live.state()
    assert state["error"] == ""
    assert state["arrival"]["residual_um"] < 1.0
    truth = twin.platform.manipulators["m1"].true_position_um()
    assert float(np.linalg.norm(truth - target.target_um)) < 1.0
