"""``stereo-calibrate --rig``: the target stage moves the calibration target by the known steps,
the cameras grab each view, the frames are kept, and the calibration holds against the truth
and repeats exactly from the kept frames."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.devices.rig_spec import SimRigSpec
from microcal.errors import DeviceError, InputError, LimitError
from microcal.formats.cameras_file import load_cameras
from microcal.formats.rig_file import load_rig
from microcal.procedures.rig_stereo import RigViewsConfig, calibrate_on_rig, default_steps_um
from microcal.sim import platform
from microcal.sim.platforms import TRAVEL_CENTRE_UM
from microcal.workflows.rigs import open_rig
from microcal.workflows.stereo import stereo_calibrate_rig
from support.shared import made_once

runner = CliRunner()
FAST = RigViewsConfig(frames_per_view=2, settle="fixed", fixed_s=0.5, camera_model="pinhole")


def one_line_error(result, *fragments):
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


# the module's tests share what a fixture makes once: one worker runs them all
pytestmark = pytest.mark.xdist_group("rig-stereo")


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A calibration on the simulated rig (seed 4), its files and the truth; made once per
    session and shared by its workers (the calibration pickled beside its files)."""

    def make(folder):
        cal, out, views = stereo_calibrate_rig("sim", folder / "cameras.json", seed=4, config=FAST)
        (folder / "calibration.pickle").write_bytes(pickle.dumps((cal, out, views)))

    folder = made_once(tmp_path_factory, "rig-stereo-seed-4", make)
    cal, out, views = pickle.loads((folder / "calibration.pickle").read_bytes())
    return cal, out, views, platform("thesis", seed=4).camera_models


@pytest.mark.slow
def test_the_cameras_project_points_of_the_travel_as_the_true_ones_do(calibrated):
    _, out, _, truth = calibrated
    models = load_cameras(out)
    rng = np.random.default_rng(11)
    points = TRAVEL_CENTRE_UM + rng.uniform(-1500, 1500, (200, 3))
    for name, true_model in truth.items():
        error = np.linalg.norm(models[name].project(points) - true_model.project(points), axis=1)
        # 8 frames a view (the default) give 0.013 / 0.004 px on seed 0; 2 frames, more noise
        assert np.sqrt(np.mean(error**2)) < 0.1, (name, np.sqrt(np.mean(error**2)))


@pytest.mark.slow
def test_every_view_is_kept_and_the_calibration_repeats_exactly_from_the_files(
    calibrated, tmp_path
):
    cal, out, views, _ = calibrated
    names = sorted(p.name for p in views.iterdir())
    assert names == ["side_01.tiff", "side_02.tiff", "side_03.tiff", "side_04.tiff",
                     "side_05.tiff", "steps.csv", "top_01.tiff", "top_02.tiff", "top_03.tiff",
                     "top_04.tiff", "top_05.tiff"]  # fmt: skip
    again = tmp_path / "again.json"
    result = runner.invoke(app, [
        "stereo-calibrate", "--target", "dotgrid:40x30:250", "--camera-model", "pinhole",
        "--images", f"top={views}/top_*.tiff", "--images", f"side={views}/side_*.tiff",
        "--known-displacements", str(views / "steps.csv"), "--out", str(again),
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    first, second = json.loads(out.read_text()), json.loads(again.read_text())
    for name in ("top", "side"):
        for key in ("K", "dist", "R", "t_um", "rms_px"):
            assert first["cameras"][name][key] == second["cameras"][name][key], (name, key)
    assert set(first["provenance"]["inputs"]) == set(second["provenance"]["inputs"])
    assert all(c.views_rejected == [] for c in cal.cameras.values())


def test_a_step_beyond_the_stage_limits_is_refused_before_anything_moves():
    with open_rig(SimRigSpec(seed=2)) as rig:
        assert rig.target_stage is not None
        assert rig.calibration_target is not None
        steps = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 9000.0]])
        with pytest.raises(LimitError, match="z"):
            calibrate_on_rig(rig.target_stage, rig.cameras, rig.clock, rig.calibration_target,
                             steps, config=FAST)  # fmt: skip
        assert rig.target_stage.last_move_s == -np.inf  # type: ignore[attr-defined]


class _Lost:
    """A camera that stops answering after ``good`` grabs."""

    def __init__(self, camera, good):
        self.camera, self.good = camera, good

    def grab(self):
        self.good -= 1
        if self.good < 0:
            raise DeviceError("side: camera lost")
        return self.camera.grab()


def test_a_camera_lost_midway_is_an_error_and_the_stage_goes_back_where_it_started():
    with open_rig(SimRigSpec(seed=2)) as rig:
        stage = rig.target_stage
        assert stage is not None
        assert rig.calibration_target is not None
        cameras = {"top": rig.cameras["top"], "side": _Lost(rig.cameras["side"], 5)}
        with pytest.raises(DeviceError, match="camera lost"):
            calibrate_on_rig(stage, cameras, rig.clock, rig.calibration_target,  # type: ignore[arg-type]
                             default_steps_um(), config=FAST)  # fmt: skip
        assert np.allclose(stage.position_um(), 0.0, atol=0.05)
        assert not stage.is_moving()


def test_the_board_is_seen_again_once_the_manipulator_moves():
    plat = platform("thesis", seed=1)
    assert [p.target for p in plat.scene(0.0)] == [plat.scene.board]
    plat.target_stage.move_to_um([0.0, 0.0, 1000.0])  # type: ignore[union-attr]
    seen = plat.scene(plat.clock.now_s())
    assert [p.target for p in seen] == [plat.scene.calibration_target]
    plat.manipulator.move_to_um([100.0, 100.0, 100.0])
    assert [p.target for p in plat.scene(plat.clock.now_s())] == [plat.scene.board]


def test_cli_refusals_are_one_line(tmp_path):
    one_line_error(runner.invoke(app, ["stereo-calibrate", "--out", str(tmp_path / "c.json")]),
                   "give --target and --images", "--rig")  # fmt: skip
    foreign = tmp_path / "views"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    one_line_error(runner.invoke(app, ["stereo-calibrate", "--rig", "sim", "--views", str(foreign),
                                       "--out", str(tmp_path / "c.json")]),
                   "notes.txt", "new or empty directory")  # fmt: skip
    theirs = tmp_path / "theirs.json"
    theirs.write_text("{}")
    one_line_error(runner.invoke(app, ["stereo-calibrate", "--rig", "sim", "--out", str(theirs)]),
                   "did not write")  # fmt: skip
    assert theirs.read_text() == "{}"
    assert (foreign / "notes.txt").read_text() == "mine"


def test_a_hardware_rig_without_a_target_stage_is_refused_before_connecting(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text(
        'driver = "hardware"\n[manipulator]\nkind = "smaract-mcs2"\naddress = "192.0.2.1"\n'
        "channels = {x = 0, y = 1, z = 2}\nlimits_um = {x = [0, 1], y = [0, 1], z = [0, 1]}\n"
        '[cameras.top]\nkind = "aravis"\naddress = "192.0.2.2"\n'
        '[cameras.side]\nkind = "aravis"\naddress = "192.0.2.3"\n'
    )
    assert load_rig(str(rig)).target_stage is None  # type: ignore[union-attr]
    with pytest.raises(InputError, match=r"no target stage; add \[target_stage\]"):
        stereo_calibrate_rig(rig, tmp_path / "c.json")
    assert not (tmp_path / "c-views").exists()
