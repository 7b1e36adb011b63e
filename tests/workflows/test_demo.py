"""`microcal demo` end to end: what it prints, the run directory and the files it writes, and
what it replaces."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from microcal import load_calibration
from microcal.cli import app
from microcal.workflows.demo import clear_demo_dir as _clear_demo_dir

runner = CliRunner()
CONDITIONS = {"uncalibrated", "matrix", "optimal"}


@pytest.mark.slow
def test_demo_prints_each_step_and_the_thesis_figures(quick_demo):
    _, output = quick_demo
    for text in ("Stereo calibration", "Measured 40 of 40 poses", "3D error vs ground truth",
                 "Identification", "oracle", "thesis mean", "Pose accuracy", "Decoupling",
                 "report.html", "wall time per stage"):  # fmt: skip
        assert text in output


@pytest.mark.slow
def test_demo_writes_the_run_directory(quick_demo):
    out, _ = quick_demo
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["format"] == "microcal.run/1"
    assert manifest["provenance"]["command"] == "demo"
    assert manifest["settle"] == "vision"
    journal = [json.loads(line) for line in (out / "journal.jsonl").read_text().splitlines()]
    assert [r["pose"] for r in journal] == list(range(1, 41))
    assert all(r["status"] == "ok" for r in journal)
    for record in journal:
        for cam, image in record["images"].items():
            assert (out / image["file"]).is_file(), (cam, image)
            assert "offset_px" in image  # stored as the region around the board
    assert len(list((out / "images").glob("*.tiff"))) == 80
    assert len((out / "commands.csv").read_text().splitlines()) == 41
    rows = (out / "measurements.csv").read_text().splitlines()
    assert len(rows) == 41
    assert not list(out.rglob("*.tmp"))


@pytest.mark.slow
def test_demo_files_hold_the_keys_other_tools_read(quick_demo):
    """Every key docs/formats.md lists as read by other tools."""
    out, _ = quick_demo
    cams = json.loads((out / "cameras.json").read_text())
    assert cams["format"] == "microcal.cameras/1"
    assert set(cams["stereo"]) >= {"rms_px", "baseline_um"}
    for cam in cams["cameras"].values():
        assert set(cam) >= {"image_size_px", "K", "dist", "R", "t_um", "rms_px", "views_used",
                            "views_rejected"}  # fmt: skip
    cal = json.loads((out / "calibration.json").read_text())
    assert cal["format"] == "microcal.calibration/1"
    assert set(cal["cameras"]) == set(cams["cameras"])
    for name, cam in cams["cameras"].items():  # per-point residuals only in cameras.json
        assert len(cam["residuals_px"]) == cam["views_used"]
        assert "residuals_px" not in cal["cameras"][name]
        assert cal["cameras"][name]["K"] == cam["K"]
    m1 = cal["manipulators"]["m1"]
    assert set(m1["model"]) >= {"kind", "inputs", "terms", "coefficients", "covariance"}
    validation_keys = {"n_fit", "n_validate", "mean_um", "std_um", "max_um", "rms_um"}
    assert set(m1["validation"]) >= validation_keys
    assert load_calibration(out / "calibration.json").manipulator("m1").model.kind == "polynomial"
    res = json.loads((out / "results.json").read_text())
    assert res["format"] == "microcal.results/1"
    assert set(res["stereo"]) == set(cams["cameras"])
    assert all("rms_px" in v for v in res["stereo"].values())
    assert res["measurement"]["rms_error_um"] > 0
    for kind in ("matrix", "polynomial"):
        assert set(res["models"][kind]["validation"]) >= validation_keys
    for src in ("vision", "truth"):
        assert set(res["pose_accuracy"][src]) == CONDITIONS
        for r in res["pose_accuracy"][src].values():
            assert {"mean_ap_p_um", "max_ap_p_um", "poses"} <= set(r)
            assert set(r["poses"][0]) >= {"desired_um", "mean_arrival_um", "ap_um", "ap_p_um",
                                          "rp_um"}  # fmt: skip
        assert set(res["decoupling"][src]) == CONDITIONS
        for r in res["decoupling"][src].values():
            assert set(r["undesired_um"]) == set("xyz")
            assert all(len(v) == 2 for v in r["undesired_um"].values())
            assert set(r["omega"]) == set("xyz")
    assert {"simulated_s", "wall_s", "stages_s"} <= set(res["timing"])
    # the stages in the order they ran (their times are measured, never compared here)
    assert list(res["timing"]["stages_s"]) == [
        "start", "stereo calibration", "acquisition", "measurement", "identification",
        "evaluation", "files and report",
    ]  # fmt: skip
    assert all(t >= 0 for t in res["timing"]["stages_s"].values())


def test_demo_replaces_only_an_earlier_demo(tmp_path):
    earlier = tmp_path / "earlier"
    (earlier / "images").mkdir(parents=True)
    (earlier / "run.json").write_text(json.dumps({"provenance": {"command": "demo"}}))
    (earlier / "images" / "top_0001.tiff").write_bytes(b"x")
    (earlier / "report.html").write_text("old")
    _clear_demo_dir(earlier)
    assert list(earlier.iterdir()) == []
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "run.json").write_text(json.dumps({"provenance": {"command": "acquire"}}))
    result = runner.invoke(app, ["demo", "--quick", "--out", str(foreign)])
    assert result.exit_code == 2
    assert "choose a new or empty directory" in result.stderr
    assert (foreign / "run.json").exists()  # nothing lost
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    (mixed / "run.json").write_text(json.dumps({"provenance": {"command": "demo"}}))
    (mixed / "notes.txt").write_text("mine")
    with pytest.raises(Exception, match=r"earlier demo did not write \(notes.txt\)"):
        _clear_demo_dir(mixed)
    assert (mixed / "notes.txt").read_text() == "mine"


def test_files_other_commands_write_into_a_demo_directory_are_replaced_with_it(tmp_path):
    """``check`` keeps its history beside calibration.json; the next demo replaces it with the
    calibration it belonged to (and leaves a lock another command may hold alone)."""
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / "run.json").write_text(json.dumps({"provenance": {"command": "demo"}}))
    (earlier / "calibration.json").write_text("{}")
    (earlier / "calibration.checks.jsonl").write_text("{}\n")
    (earlier / "calibration.mat").write_bytes(b"MATLAB")
    (earlier / ".calibration.json.lock").write_text("123\n")
    _clear_demo_dir(earlier)
    assert sorted(p.name for p in earlier.iterdir()) == [".calibration.json.lock"]


@pytest.mark.slow
def test_the_demos_manifest_reproduces_its_commands(quick_demo):
    # run.json's design, drawn again by make_design, gives commands.csv (written to 4 decimals).
    from microcal.formats.run_directory import RunDirectory
    from microcal.kinematics.designs import make_design

    run = RunDirectory.open(quick_demo[0])
    design = json.loads((run.path / "run.json").read_text())["design"]
    d = make_design(design["kind"], design["poses"], design["low_um"], design["high_um"],
                    design["seed"])  # fmt: skip
    np.testing.assert_allclose(run.commands()[1], d, atol=5e-5, rtol=0)
