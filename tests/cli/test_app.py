"""The command line, driven with typer's CliRunner."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from microcal import __version__
from microcal.cli import app
from support.cli import run_microcal

runner = CliRunner()


COMMANDS = [
    "demo",
    "calibrate-cameras",
    "stereo-calibrate",
    "scope-calibrate",
    "acquire",
    "measure",
    "fit",
    "solve",
    "evaluate",
    "report",
    "check",
    "goto",
    "scope-show",
    "study",
    "tool-centre",
    "find-tip",
    "twin",
    "ui",
]


def test_help_lists_every_command_on_one_line_in_workflow_order():
    result = runner.invoke(app, ["--help"], env={"COLUMNS": "100"})
    assert result.exit_code == 0
    listed = result.output.split("Commands:")[1].strip().splitlines()
    assert [line.split()[0] for line in listed] == COMMANDS
    assert not any(line.endswith("...") for line in listed)
    assert "Example: microcal demo" in result.output


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_help_has_an_example(command):
    result = runner.invoke(app, [command, "--help"], env={"COLUMNS": "100"})
    assert result.exit_code == 0
    assert f"Example: microcal {command}" in result.output


# One row per user error: (arguments, what the one line must say). Files named here do not
# exist unless the test creates them: "{tmp}" is a fresh directory, "{bad}" a file of junk.
BAD_INVOCATIONS = [
    (["nope"], "No such command 'nope'"),
    (["demo", "--poses", "5"], "Invalid value for '--poses'"),
    (["demo", "--seed", "abc"], "Invalid value for '--seed'"),
    (["demo", "--bogus"], "No such option: --bogus"),
    (["goto", "--calibration", "{tmp}/c.json", "-10", "0", "0"], "put -- before negative"),
    (["demo", "--out", "{bad}"], "is a file"),
    (["stereo-calibrate", "--target", "chessboard:9x6:25000"], "give --target and --images"),
    (
        [
            "stereo-calibrate",
            "--target",
            "pizza:3x3:1",
            "--images",
            "top={tmp}/*.tif",
            "--images",
            "side={tmp}/*.tif",
        ],
        "pizza",
    ),
    (
        [
            "stereo-calibrate",
            "--target",
            "chessboard:9x6:25000",
            "--images",
            "top={tmp}/*.tif",
            "--images",
            "side={tmp}/*.tif",
        ],
        "no file",
    ),
    (
        ["stereo-calibrate", "--target", "chessboard:9x6:25000", "--images", "nocamera"],
        "CAMERA=GLOB",
    ),
    (["acquire"], "Missing option '--out'"),
    (["acquire", "--out", "{tmp}/r", "--rig", "{tmp}/rig.toml"], "no such file"),
    (["acquire", "--out", "{tmp}/r", "--rig", "{bad}"], "not valid TOML"),
    (["acquire", "--out", "{tmp}/r", "--design", "{tmp}/none.csv"], "none.csv"),
    (
        ["acquire", "--out", "{tmp}/r", "--design", "rnadom"],
        "not a design (did you mean random? designs: random, sobol,",
    ),
    (["acquire", "--out", "{tmp}/r", "--settle", "soon"], "--settle"),
    (["acquire", "--out", "{tmp}/r", "--store", "some"], "--store"),
    (["acquire", "--out", "{tmp}/r", "--poses", "1"], "poses: expected 12 to 20000"),
    (["measure", "{tmp}/none", "--cameras", "{tmp}/c.json"], "not a directory"),
    (["measure", "{tmp}", "--cameras", "{tmp}/c.json"], "c.json"),
    (["measure", "{tmp}"], "--cameras: measuring a run needs its cameras' calibration"),
    (["fit", "{tmp}/none.csv"], "none.csv"),
    (["fit", "{bad}"], "missing column"),
    (["fit", "{bad}", "--model", "cubic"], "Invalid value for '--model'"),
    (["fit", "{bad}", "--penter", "x"], "Invalid value for '--penter'"),
    (["solve", "{tmp}/cal.json", "1", "2", "3"], "cal.json"),
    (["solve", "{bad}", "1", "2", "3"], "not a JSON file"),
    (["solve", "{bad}", "1", "two", "3"], "Invalid value"),
    (["evaluate", "--rig", "{tmp}/rig.toml"], "Missing option '--calibration'"),
    (["evaluate", "--calibration", "{tmp}/cal.json"], "cal.json"),
    (["evaluate", "--calibration", "{bad}"], "not a JSON file"),
    (["evaluate", "--poses", "everywhere"], "Invalid value for '--poses'"),
    (["evaluate", "--test", "speed"], "Invalid value for '--test'"),
    (["report", "{tmp}/none"], "not a directory"),
    (["report", "{tmp}"], "holds none of"),
    (["report"], "Missing argument"),
]


@pytest.mark.parametrize(
    ("args", "message"), BAD_INVOCATIONS, ids=lambda v: " ".join(v) if isinstance(v, list) else ""
)
def test_every_user_error_is_one_line_and_exit_2(tmp_path, args, message):
    bad = tmp_path / "junk.txt"
    bad.write_text("not [ a valid { anything\n")
    argv = [a.format(tmp=tmp_path, bad=bad) for a in args]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    result = runner.invoke(app, argv, env={"COLUMNS": "200"})
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("microcal: error: ")
    assert message in lines[0]
    assert "Traceback" not in result.output
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # nothing half-written


def test_version():
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0
    assert __version__ in result.output


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


def test_an_opencv_error_that_escapes_is_one_line(tmp_path, monkeypatch):
    """Any cv2.error that no procedure turned into a microcal error still ends in one line."""
    import cv2

    def refuse(*args, **kwargs):
        raise cv2.error("OpenCV(4.10) /src/x.cpp:1: error: (-215:Assertion failed) !_src.empty()")

    monkeypatch.setattr("microcal.workflows.measure.measure_run", refuse)
    result = runner.invoke(app, ["measure", str(tmp_path), "--cameras", str(tmp_path / "c.json")])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("microcal: error: OpenCV could not use an input (")
    assert "Traceback" not in result.output


@pytest.mark.parametrize(("interrupted", "code"), [(True, 130), (False, 2)])
def test_a_stopped_run_exits_130_when_asked_and_2_after_a_fault(tmp_path, monkeypatch,
                                                                interrupted, code):  # fmt: skip
    from microcal.procedures.acquisition import RunStoppedError

    def stopped(request):
        yield "starting"
        raise RunStoppedError("run stopped (a reason); 3 of 9 poses stored; resume with: "
                              "microcal acquire --out x --resume", interrupted=interrupted)  # fmt: skip

    monkeypatch.setattr("microcal.workflows.adaptive_acquire.acquire_any", stopped)
    result = runner.invoke(app, ["acquire", "--out", str(tmp_path / "run")])
    assert result.exit_code == code
    assert result.stderr.strip().splitlines()[-1].startswith("microcal: error: run stopped (")
    assert "resume with: microcal acquire --out x --resume" in result.stderr
