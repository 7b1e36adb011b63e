"""Flows that were broken: each test here failed on the code before they were mended."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from microcal import DeviceError, sim
from microcal.formats.cameras_file import write_cameras
from support.cli import run_microcal


def _true_cameras(path):
    plat = sim.platform("thesis", seed=0)
    cams = {"format": "microcal.cameras/1", "cameras": {
        n: {"image_size_px": list(m.image_size_px), "K": m.K.tolist(), "dist": m.dist.tolist(),
            "R": m.R.tolist(), "t_um": m.t_um.tolist()} for n, m in plat.camera_models.items()}}  # fmt: skip
    return write_cameras(path, cams)


def _rows(path):
    with open(path, encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_temperature_flows_from_acquisition_through_measure_to_fit(tmp_path):
    # A simulated room that warms by 20 °C/h: the journal records the temperature of every
    # pose, measure carries it to measurements.csv, and fit --temperature uses it.
    rig = tmp_path / "warm.toml"
    rig.write_text('driver = "sim"\n[overrides.manipulator]\ntemperature_drift_c_per_h = 20.0\n')
    run = tmp_path / "run"
    out = run_microcal("acquire", "--rig", rig, "--poses", "40", "--frames", "1",
                       "--settle", "fixed:20", "--store", "roi", "--out", run)  # fmt: skip
    assert out.returncode == 0, out.stderr
    out = run_microcal("measure", run, "--cameras", _true_cameras(tmp_path / "cameras.json"))
    assert out.returncode == 0, out.stderr
    rows = _rows(run / "measurements.csv")
    temps = np.array([float(r["temperature_c"]) for r in rows])
    journal = [json.loads(line) for line in (run / "journal.jsonl").read_text().splitlines()]
    np.testing.assert_allclose(temps, [j["temperature_c"] for j in journal], atol=1e-4)
    assert temps.max() - temps.min() > 0.1  # the room did warm during the run
    out = run_microcal("fit", run, "--temperature", "--out", tmp_path / "cal.json")
    assert out.returncode == 0, out.stderr
    model = json.loads((tmp_path / "cal.json").read_text())["manipulators"]["m1"]["model"]
    assert model["inputs"] == ["dx", "dy", "dz", "T"]


def test_designs_follow_the_rigs_limits(tmp_path):
    # A rig whose travel is smaller than the thesis's workspace: the design covers its own
    # limits (the old code drew over 0-8000 µm and refused every such rig).
    rig = tmp_path / "small.toml"
    rig.write_text('driver = "sim"\n[overrides.manipulator]\n'
                   "limits_um = [[0.0, 3000.0], [0.0, 3000.0], [0.0, 2000.0]]\n")  # fmt: skip
    out = run_microcal("acquire", "--rig", rig, "--poses", "30", "--frames", "1",
                       "--settle", "fixed:1", "--out", tmp_path / "run")  # fmt: skip
    assert out.returncode == 0, out.stderr
    d = np.array([[float(r[c]) for c in ("dx_um", "dy_um", "dz_um")]
                  for r in _rows(tmp_path / "run" / "commands.csv")])  # fmt: skip
    high = np.array([3000.0, 3000.0, 2000.0])
    assert np.all(d >= 0)
    assert np.all(d <= high)
    assert np.all(np.ptp(d, axis=0) > 0.5 * high)  # spread over the travel, not a corner of it
    manifest = json.loads((tmp_path / "run" / "run.json").read_text())
    assert manifest["design"]["high_um"] == high.tolist()
    assert manifest["store"] == "full"


def test_a_camera_with_the_wrong_frame_size_is_a_device_error():
    from microcal.procedures.dry_run import dry_run
    from microcal.procedures.planning import plan_run

    plat = sim.platform("thesis", seed=0)
    cam = plat.cameras["top"]
    grab = cam._grab
    cam._grab = lambda: grab()[:-2]  # type: ignore[method-assign]
    plan = plan_run("random", 20, 0, plat.manipulator.limits_um)
    with pytest.raises(DeviceError, match=r"camera top: frame is 1600 x 1198 px but the camera"):
        dry_run(plat.manipulator, plat.cameras, plat.scene.board, plan)


def test_the_iso_cube_design_lies_in_the_rigs_box():
    # ISO 9283's P1 is the centre of the box the limits span, wherever the box starts.
    from microcal.procedures.planning import plan_run

    limits = np.array([[-4000.0, 4000.0], [-500.0, 8500.0], [1000.0, 5800.0]])
    plan = plan_run("iso-cube", 5, 0, limits)
    np.testing.assert_allclose(plan.d_um[0], limits.mean(axis=1))
    assert np.all(plan.d_um >= limits[:, 0])
    assert np.all(plan.d_um <= limits[:, 1])


def test_acquire_into_a_file_is_one_line(tmp_path):
    target = tmp_path / "notes.txt"
    target.write_text("mine")
    out = run_microcal("acquire", "--rig", "sim", "--out", target, "--poses", "20")
    assert out.returncode == 2
    assert (
        out.stderr.strip()
        == f"microcal: error: --out {target}: is a file; choose a directory for the run"
    )
    assert target.read_text() == "mine"
