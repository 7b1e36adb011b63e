"""Three cameras (preset thesis-3cam): the simulator, and measurement when a camera loses frames."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import FormatError, InputError, sim
from microcal.geometry import AffineCamera, CameraModel
from microcal.vision.measurement import measure_one, measure_poses
from microcal.vision.targets import parse_target

BOARD = parse_target("chessboard:4x3:400")


@pytest.fixture(scope="module")
def rendered():
    """Six poses of the thesis-3cam platform, three frames per camera, and their truth."""
    plat = sim.platform("thesis-3cam", seed=5)
    d = np.random.default_rng(6).uniform([500, 500, 500], [7500, 7500, 4300], (6, 3))
    frames, truth = {}, []
    for i, di in enumerate(d):
        plat.manipulator.move_to_um(di)
        plat.manipulator.wait_until_stopped(plat.clock)
        plat.clock.sleep(5.0)
        truth.append(plat.truth_position_um())
        for n, cam in plat.cameras.items():
            frames[(i, n)] = [cam.grab() for _ in range(3)]
    return plat, d, frames, np.array(truth)


def test_presets_name_their_cameras():
    assert list(sim.platform("thesis").cameras) == ["top", "side"]
    three = sim.platform("thesis-3cam")
    assert list(three.cameras) == ["top", "side", "front"]
    tele = sim.platform("telecentric")
    assert all(isinstance(c.model, AffineCamera) for c in tele.cameras.values())
    assert all(isinstance(c.model, CameraModel) for c in three.cameras.values())
    # The front camera mirrors the top one across the side camera's axis (35 degrees each).
    side = three.cameras["side"].model.R[2]
    for name in ("top", "front"):
        axis = three.cameras[name].model.R[2]
        assert np.degrees(np.arccos(axis @ side)) == pytest.approx(35.0, abs=0.5)


def test_the_thesis_preset_is_unchanged_by_the_third_camera():
    two = sim.platform("thesis", seed=3)
    three = sim.platform("thesis-3cam", seed=3)
    for name in ("top", "side"):
        np.testing.assert_array_equal(two.cameras[name].grab(), three.cameras[name].grab())


def test_an_override_of_a_camera_the_preset_lacks_is_refused():
    with pytest.raises(InputError, match=r"override 'front.bit_depth': there is no 'front' on"):
        sim.platform("thesis", overrides={"front.bit_depth": 12})
    assert (
        sim.platform("thesis-3cam", overrides={"front.bit_depth": 12}).cameras["front"].bit_depth
        == 12
    )
    with pytest.raises(InputError, match=r"preset: expected one of .*got 'telecentrc' \(did you"):
        sim.platform("telecentrc")


def _lose(frames, lost):
    def load(i, n):
        if (i, n) in lost:
            raise FormatError(f"{n}_{i:04d}.tiff: frame dropped")
        return frames[(i, n)]

    return load


@pytest.mark.slow
def test_three_cameras_measure_and_a_lost_frame_leaves_two(rendered):
    plat, d, frames, truth = rendered
    cams = plat.camera_models
    full = measure_poses(list(range(6)), d, _lose(frames, set()), cams, BOARD)
    lost = measure_poses(list(range(6)), d, _lose(frames, {(2, "front"), (4, "top")}), cams, BOARD)
    assert [m.status for m in full] == ["ok"] * 6
    assert [m.status for m in lost] == ["ok"] * 6
    assert lost[2].reason == "measured without front: front_0002.tiff: frame dropped"
    assert sorted(lost[2].vp_px) == ["side", "top"]
    assert lost[4].reason.startswith("measured without top")
    for i in (2, 4):
        # A camera fewer: a larger covariance (its trace), and still near the truth.
        assert np.trace(lost[i].cov_um2) > 1.2 * np.trace(full[i].cov_um2)
        err = lost[i].p_um - truth[i]
        assert err @ np.linalg.solve(lost[i].cov_um2, err) < 25.0  # chi-square(3) 5 sigma
    for i in (0, 1, 3, 5):
        assert lost[i].reason == ""
    # Metric: RMS 3D error of the six poses against the truth with the true cameras, µm.
    e = np.array([m.p_um for m in full]) - truth
    assert np.sqrt(np.mean(np.sum(e**2, axis=1))) < 1.5


def test_two_of_three_lost_fails_with_each_reason(rendered):
    plat, d, frames, _ = rendered
    res = measure_poses(
        list(range(6)), d, _lose(frames, {(1, "front"), (1, "side")}), plat.camera_models, BOARD
    )
    assert res[1].status == "failed"
    assert res[1].reason == (
        "side: side_0001.tiff: frame dropped; front: front_0001.tiff: frame dropped"
    )
    assert np.isnan(res[1].p_um).all()
    assert all(m.status == "ok" for k, m in enumerate(res) if k != 1)


def test_measure_one_with_a_camera_missing(rendered):
    plat, _, frames, truth = rendered
    cams = plat.camera_models
    got = {n: frames[(0, n)] for n in cams}
    three = measure_one(got, cams, BOARD)
    two = measure_one({"top": got["top"], "side": got["side"], "front": []}, cams, BOARD)
    assert three.status == two.status == "ok"
    assert two.reason == "measured without front: no image"
    assert np.trace(two.cov_um2) > np.trace(three.cov_um2)
    one = measure_one({"top": got["top"]}, cams, BOARD)
    assert one.status == "failed"
    assert one.reason == "side: no image; front: no image"
    assert np.linalg.norm(three.p_um - truth[0]) < 3.0


def test_measurement_needs_two_cameras(rendered):
    plat, d, frames, _ = rendered
    from microcal.errors import DetectionError

    with pytest.raises(DetectionError, match=r"expected 2 or more calibrated cameras, got 1"):
        measure_poses([0], d[:1], _lose(frames, set()), {"top": plat.camera_models["top"]}, BOARD)


@pytest.mark.slow
def test_a_three_camera_rig_acquires_and_measures_through_the_commands(tmp_path):
    """acquire with the example rig (front camera losing frames), then measure with cameras.json
    of the true cameras: every pose measured, each by the cameras whose frames it has."""
    from pathlib import Path

    from typer.testing import CliRunner

    from microcal.cli import app
    from microcal.formats.cameras_file import cameras_to_dict, write_cameras
    from microcal.formats.measurements import read_measurements
    from microcal.vision.stereo_calibration import CameraCalibration, StereoCalibration

    rig = Path(__file__).resolve().parents[2] / "examples" / "rigs" / "sim-3cam.toml"
    run = tmp_path / "run"
    runner = CliRunner()
    got = runner.invoke(app, ["acquire", "--rig", str(rig), "--poses", "12", "--frames", "2",
                              "--store", "roi", "--out", str(run)])  # fmt: skip
    assert got.exit_code == 0, got.output
    names = sorted(p.name for p in (run / "images").iterdir())
    assert {n.split("_")[0] for n in names} == {"top", "side", "front"}
    models = sim.platform("thesis-3cam", seed=5).camera_models
    cal = StereoCalibration("true", {n: CameraCalibration(m, 0.0, {}, 0) for n, m in models.items()},
                            0.0, 0.0)  # fmt: skip
    cams = write_cameras(tmp_path / "cameras.json", cameras_to_dict(cal, {}))
    got = runner.invoke(app, ["measure", str(run), "--cameras", str(cams)])
    assert got.exit_code == 0, got.output
    m = read_measurements(run / "measurements.csv")
    assert len(m.pose) == 12
    assert m.n_failed == 0
    assert np.all(np.isfinite(m.p_um))
