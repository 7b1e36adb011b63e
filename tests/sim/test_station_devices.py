"""Several devices in one {G} (preset thesis-platform): the simulator shows each device's board,
rigs and rig files name the devices, acquire moves the one asked for, two tools meet and a tool
goes to an offset from another, and a station demo writes every device's files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.devices.rig import platform_rig
from microcal.devices.rig_spec import SimRigSpec
from microcal.errors import FormatError, InputError, LimitError
from microcal.experiments.demo import device_workspace
from microcal.formats.rig_file import load_rig, rig_from_record
from microcal.kinematics.manipulator_calibration import ManipulatorCalibration
from microcal.procedures.meet import meet_targets_um, meet_test
from microcal.procedures.station import Station
from microcal.sim import platform
from microcal.vision.probe import VisionProbe
from microcal.workflows.rigs import open_rig

runner = CliRunner()


def _measure(plat, frames: int = 2) -> np.ndarray:
    probe = VisionProbe(plat.cameras, plat.camera_models, plat.scene.board, frames)
    return probe.measure_with_covariance(np.zeros(3), frames)[0]


def _move(device, d_um, clock) -> None:
    device.move_to_um(d_um)
    device.wait_until_stopped(clock)
    clock.sleep(5.0)


def test_the_thesis_preset_is_unchanged_by_the_further_devices():
    one, three = platform("thesis", seed=4), platform("thesis-platform", seed=4)
    assert list(one.manipulators) == ["m1"]
    assert list(three.manipulators) == ["m1", "m2", "p1"]
    # the same seed gives m1 and the cameras of the thesis preset, frame for frame
    for plat in (one, three):
        _move(plat.manipulator, [2000.0, 3000.0, 1000.0], plat.clock)
    np.testing.assert_array_equal(one.cameras["top"].grab(), three.cameras["top"].grab())
    np.testing.assert_array_equal(one.truth_position_um(), three.truth_position_um())


def test_the_cameras_see_the_device_moved_last_or_the_one_shown():
    plat = platform("thesis-platform", seed=1)
    m1, m2, p1 = (plat.manipulators[n] for n in ("m1", "m2", "p1"))
    _move(m1, [3000.0, 3000.0, 2000.0], plat.clock)
    _move(m2, [5000.0, 2000.0, 1500.0], plat.clock)
    # the devices are far apart: a measurement that saw another board would be off by mm
    assert np.linalg.norm(m1.true_position_um() - m2.true_position_um()) > 1000
    np.testing.assert_allclose(_measure(plat), m2.true_position_um(), atol=3.0)
    plat.scene.show("m1", plat.clock.now_s())
    np.testing.assert_allclose(_measure(plat), m1.true_position_um(), atol=3.0)
    _move(p1, [1000.0, 4000.0, 0.0], plat.clock)
    np.testing.assert_allclose(_measure(plat), p1.true_position_um(), atol=3.0)


def test_the_second_manipulator_and_the_positioner_are_other_devices():
    plat = platform("thesis-platform", seed=0)
    d = np.array([[1000.0, 2000.0, 500.0], [6000.0, 1000.0, 1500.0]])
    m1, m2, p1 = (plat.manipulators[n].truth for n in ("m1", "m2", "p1"))
    assert np.all(np.abs(m2.position_um(d) - m1.position_um(d)) > 100)  # another base
    # m2's map is not m1's shifted: their differences vary over the travel by µm
    gap = m2.position_um(d) - m1.position_um(d)
    assert np.ptp(gap, axis=0).max() > 5.0
    assert plat.manipulators["p1"].limits_um[2].tolist() == [0.0, 0.0]  # an X-Y stage: z held
    assert p1.static.held_um == {"dz": 0.0}
    assert p1 is not m1


def test_a_rig_selects_its_devices_by_name_and_refuses_others():
    with open_rig(SimRigSpec("thesis-platform"), "m2") as rig:
        assert rig.selected == "m2"
        assert rig.manipulator.identity == "simulated m2"
        assert rig.truth is not None
        np.testing.assert_array_equal(rig.truth(), rig.truths["m2"]())
        assert rig.select("p1").manipulator.name == "p1"
        with pytest.raises(InputError, match=r"--manipulator m9: .*it has m1, m2, p1"):
            rig.select("m9")
        assert rig.for_calibration("m1").selected == "m1"
    with pytest.raises(
        InputError, match=r"--manipulator m2: this rig has no such device \(it has m1\)"
    ):
        open_rig(SimRigSpec("thesis"), "m2")
    with open_rig(SimRigSpec("thesis")) as rig:
        assert rig.for_calibration("left") is rig  # a rig's only device, whatever it is called


HARDWARE = """
driver = "hardware"
[manipulator]
kind = "smaract-mcs2"
address = "127.0.0.1"
channels = {{ x = 0, y = 1, z = 2 }}
limits_um = {{ x = [0, 8000], y = [0, 8000], z = [0, 4800] }}
[manipulators.{name}]
kind = "smaract-mcs2"
address = "127.0.0.2"
channels = {{ x = 0, y = 1, z = 2 }}
limits_um = {{ x = [0, 6000], y = [0, 6000], z = [0, 2000] }}
{extra}
[cameras.top]
kind = "aravis"
address = "10.0.0.11"
[cameras.side]
kind = "aravis"
address = "10.0.0.12"
"""


def test_rig_files_name_further_devices(tmp_path: Path):
    path = tmp_path / "rig.toml"
    path.write_text(HARDWARE.format(name="p1", extra=""), encoding="utf-8")
    spec = load_rig(str(path))
    assert spec.manipulator_names == ("m1", "p1")
    assert spec.manipulators["p1"].address == "127.0.0.2"
    again = rig_from_record(spec.to_dict(), "run.json")
    assert again == spec
    path.write_text(HARDWARE.format(name="m1", extra=""), encoding="utf-8")
    with pytest.raises(FormatError, match=r"manipulators.m1: expected a name such as m2"):
        load_rig(str(path))
    path.write_text(HARDWARE.format(name="p1", extra="adress = 1"), encoding="utf-8")
    with pytest.raises(FormatError, match=r"manipulators.p1.adress: not a setting \(did you mean"):
        load_rig(str(path))
    # a rig of one device records no further ones (old run.json records stay equal)
    path.write_text(HARDWARE.format(name="p1", extra="").split("[manipulators.p1]")[0]
                    + "[cameras.top]\nkind = 'aravis'\naddress = '1'\n[cameras.side]\n"
                    "kind = 'aravis'\naddress = '2'\n", encoding="utf-8")  # fmt: skip
    assert "manipulators" not in load_rig(str(path)).to_dict()


@pytest.mark.slow
def test_acquire_moves_the_device_asked_for_and_resumes_only_on_it(tmp_path: Path):
    rig = tmp_path / "platform.toml"
    rig.write_text('driver = "sim"\npreset = "thesis-platform"\n', encoding="utf-8")
    out = tmp_path / "run"
    args = ["acquire", "--rig", str(rig), "--manipulator", "p1", "--design", "grid",
            "--poses", "16", "--frames", "1", "--settle", "fixed:1", "--out", str(out)]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "run.json").read_text(encoding="utf-8"))
    assert manifest["manipulator"] == "p1"
    assert manifest["device"] == "simulated p1"
    assert manifest["held_joints_um"] == {"dz": 0.0}  # an X-Y positioner
    # the design spans the positioner's own x, y travel, its z held
    commands = np.loadtxt(out / "commands.csv", delimiter=",", skiprows=1)[:, 1:4]
    assert np.all(commands[:, 2] == 0.0)
    assert np.ptp(commands[:, :2], axis=0).min() == 7000.0
    # measured with the true cameras and fitted: the model leaves the held joint out
    from microcal.formats.cameras_file import write_cameras

    models = platform("thesis-platform", seed=0).camera_models
    write_cameras(tmp_path / "cameras.json", {"format": "microcal.cameras/1", "cameras": {
        n: {"image_size_px": list(m.image_size_px), "K": m.K.tolist(), "dist": m.dist.tolist(),
            "R": m.R.tolist(), "t_um": m.t_um.tolist()} for n, m in models.items()}})  # fmt: skip
    measured = runner.invoke(
        app, ["measure", str(out), "--cameras", str(tmp_path / "cameras.json")]
    )
    assert measured.exit_code == 0, measured.output
    cal_path = tmp_path / "calibration.json"
    fitted = runner.invoke(app, ["fit", str(out), "--model", "matrix", "--out", str(cal_path)])
    assert fitted.exit_code == 0, fitted.output
    entry = json.loads(cal_path.read_text(encoding="utf-8"))["manipulators"]["p1"]
    assert entry["model"]["held_joints_um"] == {"dz": 0.0}
    assert entry["model"]["terms"] == ["dx", "dy", "1"]
    # the same measurements away from their run.json cannot say z is held: refused
    (tmp_path / "alone").mkdir()
    csv = tmp_path / "alone" / "measurements.csv"
    csv.write_bytes((out / "measurements.csv").read_bytes())
    alone = runner.invoke(app, ["fit", str(csv), "--model", "matrix",
                                "--out", str(tmp_path / "other.json")])  # fmt: skip
    assert alone.exit_code != 0
    assert "'dz' has the same value in every sample" in alone.output
    resumed = runner.invoke(app, ["acquire", "--out", str(out), "--resume",
                                  "--manipulator", "m2"])  # fmt: skip
    assert resumed.exit_code != 0
    assert "--manipulator m2: this run was begun with --manipulator p1" in resumed.output
    wrong = runner.invoke(app, ["acquire", "--rig", str(rig), "--manipulator", "m3",
                                "--out", str(tmp_path / "other")])  # fmt: skip
    assert wrong.exit_code != 0
    assert "it has m1, m2, p1" in wrong.output
    assert not (tmp_path / "other").exists()


def _true_stations(plat, names, shift_um=None):
    rig = platform_rig(plat)
    stations = []
    for name in names:
        model = plat.manipulators[name].truth.static
        cal = ManipulatorCalibration(name, model)
        if shift_um is not None and name == names[-1]:
            from microcal.procedures.check import offset_updated

            cal = ManipulatorCalibration(name, offset_updated(model, -np.asarray(shift_um)))
        stations.append(Station(rig.select(name), cal, plat.camera_models, frames=2, settle_s=2.0))
    return stations


@pytest.mark.slow
def test_two_tools_meet_and_a_wrong_calibration_shows_in_the_gap():
    plat = platform("thesis-platform", seed=2)
    first, second = _true_stations(plat, ["m1", "m2"])
    ws = device_workspace(plat.manipulators["m1"].limits_um)
    targets = meet_targets_um(first.calibration, second.calibration, ws, ws)
    assert targets.shape == (5, 3)
    result = meet_test(first, second, targets[:2], mode="open")
    assert result.truth_um is not None
    # with the true static maps only hysteresis and creep are left (0.4-0.6 µm per axis)
    assert np.all(result.truth_um < 2.5)
    assert np.all(np.isfinite(result.vision_um))
    assert np.all(result.vision_um < 4.0)
    summary = result.as_dict()
    assert summary["truth"]["mean_um"] == pytest.approx(np.mean(result.truth_um))
    # m2's calibration 6 µm off along y: the tools miss each other by about that much
    plat = platform("thesis-platform", seed=2)
    first, second = _true_stations(plat, ["m1", "m2"], shift_um=[0.0, 6.0, 0.0])
    off = meet_test(first, second, targets[:2], mode="open")
    assert off.truth_um is not None
    assert np.all(np.abs(off.truth_um - 6.0) < 2.0)
    assert np.all(np.abs(off.vision_um - 6.0) < 3.0)
    closed = meet_test(first, second, targets[:1], mode="closed")
    assert closed.truth_um is not None
    assert closed.truth_um[0] < 1.0  # both servoed onto the same camera measurement
    with pytest.raises(InputError, match="same station"):
        meet_test(first, first, targets)
    with pytest.raises(LimitError):
        meet_test(first, second, [[50000.0, 0.0, 0.0]])
    for frames in (0, -1, 2.5):
        with pytest.raises(InputError, match="frames: expected a whole number >= 1"):
            meet_test(first, second, targets, frames=frames)
    with pytest.raises(InputError, match="where_um: frames: expected a whole number >= 1"):
        first.where_um(0)


def test_a_tool_goes_to_an_offset_from_a_point_on_the_sample():
    plat = platform("thesis-platform", seed=3)
    tool, stage = _true_stations(plat, ["m1", "p1"])
    stage.move_to_um([4000.0, 4000.0, 1200.0])  # the X-Y stage goes to its surface's nearest
    point = np.array([150.0, -80.0, 0.0])  # on the sample, from the positioner's board
    stand_off = np.array([0.0, 0.0, 200.0])
    arrival = tool.move_relative_um(stage, point + stand_off)
    true_gap = (
        plat.manipulators["m1"].true_position_um() - plat.manipulators["p1"].true_position_um()
    )
    assert np.linalg.norm(true_gap - point - stand_off) < 3.0
    assert np.linalg.norm(arrival.measured_um - arrival.target_um) < 4.0
    with pytest.raises(InputError, match="other is this station"):
        tool.move_relative_um(tool)


@pytest.mark.slow
def test_the_station_demo_writes_every_device_in_one_frame(tmp_path: Path):
    import time

    from microcal.formats.calibration_file import load_calibration
    from microcal.workflows.demo import run_station_demo_files

    out = tmp_path / "station"
    result = run_station_demo_files(
        out, 0, None, time.monotonic(), poses=24, frames_per_pose=1, frames_per_view=2,
        evaluate=False, meet_cycles=1, camera_model="pinhole", meet_modes=("open",),
        fixed_settle_s=3.0,
    )  # fmt: skip
    cal = load_calibration(out / "calibration.json")
    assert sorted(cal.manipulators) == ["m1", "m2", "p1"]
    assert cal.cameras
    for name in ("m1", "m2", "p1"):
        run = json.loads((out / name / "run.json").read_text(encoding="utf-8"))
        assert run.get("manipulator", "m1") == name
        assert sorted(load_calibration(out / name / "calibration.json").manipulators) == [name]
        assert (out / name / "report.html").is_file()
    # one {G}: every device's calibration holds the same cameras
    assert load_calibration(out / "p1" / "calibration.json").cameras == cal.cameras
    results = json.loads((out / "results.json").read_text(encoding="utf-8"))
    assert sorted(results["devices"]) == ["m1", "m2", "p1"]
    truth = results["meet"]["open"]["truth"]
    assert len(truth["distances_um"]) == 5
    # 24 poses calibrate coarsely, but in one frame: the devices' bases are 400-700 µm apart,
    # so a device calibrated in another frame, or measured by another's board, misses by far
    assert truth["mean_um"] < 10.0
    vision = results["meet"]["open"]["vision"]
    assert abs(vision["mean_um"] - truth["mean_um"]) < 2.0
    assert result.meet["open"].truth_um is not None
    html = (out / "report.html").read_text(encoding="utf-8")
    assert "Devices in one frame" in html
    assert 'href="p1/report.html"' in html
    # the positioner is an X-Y stage: its model and report say it holds z
    assert cal.manipulators["p1"].model.held_um == {"dz": 0.0}
    p1_html = (out / "p1" / "report.html").read_text(encoding="utf-8")
    assert "The device holds dz at 0 µm (it has no such axis)" in p1_html
    # an earlier station demo is replaced: what it wrote goes, each device's run begins anew
    from microcal.workflows.demo import start_station_demo

    start_station_demo(out, 1, 30, 1)
    assert sorted(p.name for p in out.iterdir()) == ["m1", "m2", "p1"]
    assert json.loads((out / "m2" / "run.json").read_text(encoding="utf-8"))["design"]["seed"] == 2
    # a directory with someone else's files is refused before anything is written
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine", encoding="utf-8")
    with pytest.raises(InputError, match="holds files that an earlier station demo did not write"):
        run_station_demo_files(other, 0, None, 0.0, poses=30, frames_per_pose=1)
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt"]


def test_fit_names_the_entry_after_the_runs_device(tmp_path: Path):
    from microcal.formats.run_manifest import new_manifest
    from microcal.workflows.calibration_update import manifest_beside, measured_device

    run = tmp_path / "run"
    run.mkdir()
    # no run.json: a plain CSV
    assert measured_device(manifest_beside(run / "measurements.csv")) == "m1"
    manifest = new_manifest(rig=SimRigSpec("thesis-platform").to_dict(), target="chessboard:4x3:400",
                            cameras=["top", "side"], design={"kind": "file", "poses": 1},
                            settle="vision", frames_per_pose=1, store="full", command="acquire",
                            device="simulated p1", manipulator="p1")  # fmt: skip
    (run / "run.json").write_text(json.dumps({"format": "microcal.run/1", **manifest}))
    assert measured_device(manifest_beside(run / "measurements.csv")) == "p1"
    assert "manipulator" not in new_manifest(
        rig={},
        target="t",
        cameras=[],
        design={},
        settle="vision",
        frames_per_pose=1,
        store="full",
        command="acquire",
    )  # a run of m1 (the only device of most rigs) records no name: its run.json is unchanged


def test_a_station_demo_directory_is_checked_whole_before_anything_goes(tmp_path: Path):
    from microcal.workflows.demo import start_station_demo

    mine = tmp_path / "mine"
    mine.mkdir()
    for name in ("calibration.json", "report.html"):  # the user's own, no station results
        (mine / name).write_text("keep", encoding="utf-8")
    with pytest.raises(InputError, match="holds files that an earlier station demo did not"):
        start_station_demo(mine, 0, 24, 1)
    assert sorted(p.name for p in mine.iterdir()) == ["calibration.json", "report.html"]
    out = tmp_path / "station"
    start_station_demo(out, 0, 24, 1)  # an earlier (begun) station demo
    (out / "m2" / "notes.txt").write_text("mine", encoding="utf-8")
    with pytest.raises(InputError, match="holds files that an earlier demo did not write"):
        start_station_demo(out, 1, 24, 1)
    assert (out / "m1" / "run.json").is_file()  # nothing was cleared before the refusal
    assert (out / "m2" / "notes.txt").read_text(encoding="utf-8") == "mine"


def test_the_selected_device_is_seen_first_and_has_its_own_room_sensor():
    spec = SimRigSpec("thesis-platform", overrides={"m2.temperature_c": 25.0})
    with open_rig(spec, "p1") as rig:
        assert rig.cameras["top"].scene.visible().name == "p1"  # a dry run checks p1's board
        assert rig.temperature is not None
        assert rig.temperature() == pytest.approx(22.0)
        m2 = rig.select("m2")
        assert m2.temperature is not None
        assert m2.temperature() == pytest.approx(25.0)


def test_each_device_has_its_own_check_history():
    from microcal.formats.check_file import of_device

    history = [{"offset_um": [0, 0, 0]}, {"manipulator": "m2"}, {"manipulator": "m1"}]
    assert of_device(history, "m1", single=True) == [history[0], history[2]]
    assert of_device(history, "m1", single=False) == [history[2]]  # unnamed: not m1's
    assert of_device(history, "m2", single=False) == [history[1]]


@pytest.mark.slow
def test_the_x_y_positioner_goes_to_the_nearest_point_of_its_surface_open_and_closed():
    plat = platform("thesis-platform", seed=5)
    (stage,) = _true_stations(plat, ["p1"])
    device = plat.manipulators["p1"]
    on_surface = device.truth.static.predict_um([3000.0, 2500.0, 0.0])[0]
    for mode in ("open", "closed"):
        # 3 µm above the surface it carries the sample over: it cannot go there, so it goes
        # to the nearest point, and the closed loop corrects only along the surface
        arrival = stage.move_to_um(on_surface + [0.0, 0.0, 3.0], mode)
        assert arrival.d_um[2] == 0.0
        assert np.linalg.norm(device.true_position_um() - on_surface) < 1.0, mode
    assert arrival.status in ("tolerance", "resolution")


def test_each_device_may_carry_its_own_board_and_two_in_view_must_be_told_apart(tmp_path: Path):
    import dataclasses

    from microcal.vision.targets import parse_target

    path = tmp_path / "rig.toml"
    path.write_text(HARDWARE.format(name="m2", extra='board = "charuco:5x4:400:id10"'),
                    encoding="utf-8")  # fmt: skip
    spec = load_rig(str(path))
    assert spec.boards == {"m2": "charuco:5x4:400:id10"}
    assert spec.board_of("m2") == "charuco:5x4:400:id10"
    assert spec.board_of("m1") == spec.board
    assert rig_from_record(spec.to_dict(), "run.json") == spec
    path.write_text(HARDWARE.format(name="m2", extra='board = "charuco:5x4"'), encoding="utf-8")
    with pytest.raises(FormatError, match=r"manipulators.m2.board: target 'charuco:5x4'"):
        load_rig(str(path))
    text = HARDWARE.format(name="m2", extra="").replace("[manipulator]\n",
                                                        '[manipulator]\nboard = "x"\n')  # fmt: skip
    path.write_text(text, encoding="utf-8")
    with pytest.raises(
        FormatError, match=r"manipulator.board: its target is the top-level 'board'"
    ):
        load_rig(str(path))
    # a rig whose devices' targets are all in view (hardware): the same board twice is refused
    plat = platform("thesis-platform", seed=2)
    in_view = dataclasses.replace(platform_rig(plat), show=None)
    first, second = (
        Station(in_view.select(n), ManipulatorCalibration(n, plat.manipulators[n].truth.static),
                plat.camera_models, frames=1)
        for n in ("m1", "m2")
    )  # fmt: skip
    with pytest.raises(InputError, match=r"m1 and m2 carry targets the cameras cannot tell apart"):
        meet_test(first, second, [[3000.0, 3000.0, 2000.0]])
    with pytest.raises(InputError, match=r"board = \"charuco:5x4:400:id10\""):
        first.move_relative_um(second)
    # boards of their own: selecting a device makes its board the one measured
    a, b = parse_target("charuco:5x4:400"), parse_target("charuco:5x4:400:id10")
    own = dataclasses.replace(in_view, board=a, boards={"m1": a, "m2": b})
    assert own.select("m2").board == b
    assert own.select("m2").select("m1").board == a
    first.rig, second.rig = own, own.select("m2")
    first.check_told_apart(second)  # no error
