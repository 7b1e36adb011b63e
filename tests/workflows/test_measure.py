"""``microcal measure``: what the journal and run.json record is what is measured.

A damaged journal line, swapped or edited inputs, a worse measurement that would replace a
better one, nothing measured; the temperature carried from the journal to the fit; user
errors. The session's 12-pose simulated run is copied per test.
"""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from support.cli import invoke_microcal
from support.runs import fails_cleanly, write_true_cameras


def _measurements_status(run: Path) -> list[str]:
    lines = (run / "measurements.csv").read_text().splitlines()
    column = lines[0].split(",").index("status")
    return [line.split(",")[column] for line in lines[1:]]


@pytest.fixture
def run(acquired_run, tmp_path) -> Path:
    """This test's own copy of the session's 12-pose run."""
    return shutil.copytree(acquired_run[0], tmp_path / "run")


@pytest.fixture
def cameras(acquired_run) -> Path:
    return acquired_run[1]


def test_measure_names_a_damaged_journal_line_and_measures_the_rest(run, cameras):
    journal = run / "journal.jsonl"
    lines = journal.read_text().splitlines()
    lines[2] = lines[2][:-5]  # pose 3's line cut
    journal.write_text("\n".join(lines) + "\n")
    out = invoke_microcal("measure", run, "--cameras", cameras)
    assert out.returncode == 0, out.stderr
    assert "journal.jsonl: line 3 (pose 3): not JSON (damaged)" in out.stdout
    assert "measured 11 of 12 poses" in out.stdout
    assert "pose 3 failed: top: not in the journal, so its images cannot be verified" in out.stdout


def test_swapped_images_fail_their_poses_with_the_reason(run, cameras):
    a, b = run / "images" / "top_0003.tiff", run / "images" / "top_0004.tiff"
    data_a, data_b = a.read_bytes(), b.read_bytes()
    a.write_bytes(data_b)
    b.write_bytes(data_a)
    out = invoke_microcal("measure", run, "--cameras", cameras)
    assert out.returncode == 0, out.stderr
    assert "measured 10 of 12 poses" in out.stdout
    for pose in (3, 4):
        assert (f"pose {pose} failed: top: {run / 'images' / f'top_000{pose}.tiff'}: changed since "
                f"it was recorded") in out.stdout  # fmt: skip
    assert _measurements_status(run).count("ok") == 10


@pytest.mark.parametrize("edit", ["changed value", "deleted row"])
def test_edited_commands_are_refused_by_measure(run, cameras, edit):
    path = run / "commands.csv"
    rows = path.read_text().splitlines()
    if edit == "changed value":
        rows[3] = rows[3].rsplit(",", 1)[0] + ",1234.5"
    else:
        del rows[6]
    path.write_text("\n".join(rows) + "\n")
    out = invoke_microcal("measure", run, "--cameras", cameras)
    fails_cleanly(out, "commands.csv: edited since the run began", "restore the original")
    assert not (run / "measurements.csv").exists()


@pytest.mark.slow
def test_a_worse_measurement_never_replaces_a_better_one(run, cameras):
    assert invoke_microcal("measure", run, "--cameras", cameras).returncode == 0
    good = (run / "measurements.csv").read_bytes()
    for pose in range(1, 9):  # the images of 8 poses moved away since
        (run / "images" / f"side_{pose:04d}.tiff").unlink()
    out = invoke_microcal("measure", run, "--cameras", cameras)
    fails_cleanly(out, "only 4 of 12 poses measured, fewer than the 12 of the measurements.csv "
                   "it would replace; kept", "--force")  # fmt: skip
    assert (run / "measurements.csv").read_bytes() == good
    out = invoke_microcal("measure", run, "--cameras", cameras, "--force")
    assert out.returncode == 0, out.stderr
    assert _measurements_status(run).count("ok") == 4


@pytest.mark.slow
def test_measure_that_measures_nothing_writes_nothing(run, cameras):
    out = invoke_microcal("measure", run, "--cameras", cameras, "--target", "chessboard:5x4:400")
    fails_cleanly(out, "no pose measured, all 12 failed", "check --cameras and --target")
    assert not (run / "measurements.csv").exists()


def _rows(path):
    with open(path, encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow
def test_temperature_flows_from_acquisition_through_measure_to_fit(tmp_path):
    # A simulated room that warms by 20 °C/h: the journal records the temperature of every
    # pose, measure carries it to measurements.csv, and fit --temperature uses it.
    rig = tmp_path / "warm.toml"
    rig.write_text('driver = "sim"\n[overrides.manipulator]\ntemperature_drift_c_per_h = 20.0\n')
    run = tmp_path / "run"
    out = invoke_microcal("acquire", "--rig", rig, "--poses", "40", "--frames", "1",
                          "--settle", "fixed:20", "--store", "roi", "--out", run)  # fmt: skip
    assert out.returncode == 0, out.stderr
    out = invoke_microcal(
        "measure", run, "--cameras", write_true_cameras(tmp_path / "cameras.json")
    )
    assert out.returncode == 0, out.stderr
    rows = _rows(run / "measurements.csv")
    temps = np.array([float(r["temperature_c"]) for r in rows])
    journal = [json.loads(line) for line in (run / "journal.jsonl").read_text().splitlines()]
    np.testing.assert_allclose(temps, [j["temperature_c"] for j in journal], atol=1e-4)
    assert temps.max() - temps.min() > 0.1  # the room did warm during the run
    out = invoke_microcal("fit", run, "--temperature", "--out", tmp_path / "cal.json")
    assert out.returncode == 0, out.stderr
    model = json.loads((tmp_path / "cal.json").read_text())["manipulators"]["m1"]["model"]
    # the run's approach directions join by default (fit says so)
    assert model["inputs"] == ["dx", "dy", "dz", "T", "sx", "sy", "sz"]
    assert "note: fitting the direction terms sx, sy, sz" in out.stdout


def one_line_error(out, message):
    assert out.returncode == 2, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert message in lines[0]


def test_measure_user_errors(tmp_path):
    one_line_error(
        invoke_microcal("measure", tmp_path / "none", "--cameras", tmp_path / "c.json"),
        "not a directory",
    )
    (tmp_path / "c.json").write_text('{"format": "microcal.calibration/1", "manipulators": {}}')
    one_line_error(
        invoke_microcal("measure", tmp_path, "--cameras", tmp_path / "c.json"), "holds no cameras"
    )
