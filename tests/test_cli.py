"""The command line, driven with typer's CliRunner."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from conftest import run_microcal
from microcal import __version__, load_calibration
from microcal.cli import app

runner = CliRunner()


def test_help_lists_commands():
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    assert "demo" in result.output


def test_version():
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0
    assert __version__ in result.output


def test_demo_says_what_it_ran_and_reports_figures(tmp_path):
    out = tmp_path / "demo"
    result = runner.invoke(
        app, ["demo", "--quick", "--seed", "1", "--out", str(out)], env={"COLUMNS": "200"}
    )
    assert result.exit_code == 0, result.output
    results = json.loads((out / "results.json").read_text())
    assert results["format"] == "microcal.results/1"
    for key in ("stereo", "measurement", "models", "pose_accuracy", "decoupling", "timing"):
        assert key in results
    for src in ("vision", "truth"):
        assert set(results["pose_accuracy"][src]) == {"uncalibrated", "matrix", "optimal"}
    assert load_calibration(out / "calibration.json").manipulator("m1").model.kind == "polynomial"
    assert "Pose accuracy" in result.output
    assert "Decoupling" in result.output
    assert "does not yet write the run directory nor the HTML report" in result.output
    for text in ("Stereo calibration", "Measured 60 of 60 poses", "3D error vs ground truth",
                 "Identification", "oracle", "thesis mean"):  # fmt: skip
        assert text in result.output


def test_demo_help_has_an_example():
    result = runner.invoke(app, ["demo", "--help"])
    assert result.exit_code == 0
    assert "Example: microcal demo" in result.output


@pytest.mark.parametrize(
    "args",
    [["demo", "--poses", "5"], ["demo", "--seed", "abc"], ["demo", "--no-such-option"], ["nope"]],
)
def test_user_errors_exit_2_without_traceback(args):
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    assert "Traceback" not in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["demo", "--poses", "5"], "Invalid value for '--poses'"),
        (["demo", "--seed", "abc"], "Invalid value for '--seed'"),
        (["demo", "--bogus"], "No such option: --bogus"),
        (["nope"], "No such command 'nope'"),
    ],
)
def test_entry_point_prints_one_line_for_user_errors(args, message):
    out = run_microcal(*args)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert lines[0].startswith("microcal: error: ")
    assert message in lines[0]
    assert "--help" in lines[0]


def test_installed_entry_point_runs():
    out = run_microcal("--version")
    assert out.returncode == 0, out.stderr
    assert __version__ in out.stdout
