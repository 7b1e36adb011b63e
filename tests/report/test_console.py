"""Terminal output: progress where the output is a terminal and where it is not."""

from __future__ import annotations

import io
from types import SimpleNamespace

import numpy as np
from rich.console import Console

from microcal.procedures.acquisition import AcquisitionConfig
from microcal.report.console import staged_progress
from microcal.workflows.acquire import disk_use_line


def _lines(console: Console) -> list[str]:
    file = console.file
    assert isinstance(file, io.StringIO)
    return file.getvalue().splitlines()


def test_without_a_terminal_each_step_is_a_line_with_the_time_left():
    console = Console(file=io.StringIO(), force_terminal=False, width=80)
    now = iter(float(t) for t in range(100))
    with staged_progress(console, clock=lambda: next(now)) as progress:
        for k in range(1, 5):
            progress("pose accuracy, open loop", k, 4)
    lines = _lines(console)
    assert len(lines) == 4
    assert lines[0] == "pose accuracy, open loop: 1/4, 0 s elapsed, about 0 s left"
    assert lines[1] == "pose accuracy, open loop: 2/4, 1 s elapsed, about 1 s left"
    assert lines[3] == "pose accuracy, open loop: 4/4, 3 s elapsed"


def test_a_long_stage_writes_about_twenty_lines_not_one_per_step():
    console = Console(file=io.StringIO(), force_terminal=False, width=80)
    with staged_progress(console) as progress:
        for k in range(1, 10_001):
            progress("study", k, 10_000)
    lines = _lines(console)
    assert 20 <= len(lines) <= 21
    assert lines[-1].startswith("study: 10000/10000")


def test_on_a_terminal_the_bar_leaves_no_line_behind():
    console = Console(file=io.StringIO(), force_terminal=True, width=80)
    with staged_progress(console) as progress:
        progress("measuring", 1, 2)
        progress("measuring", 2, 2)
    assert "measuring: 1/2" not in console.file.getvalue()  # a bar, not lines


def test_the_disk_a_run_takes_is_said_before_it_starts():
    cams = {n: SimpleNamespace(sensor_size_px=(1600, 1200), bit_depth=12) for n in ("a", "b")}
    full = disk_use_line(cams, 170, AcquisitionConfig(frames_per_pose=20))
    # 170 poses x 2 cameras x 20 frames x 1600 x 1200 px x 2 bytes = 26.1 GB
    assert full.startswith("images: up to 26 GB on disk (170 poses x 2 camera(s) x 20 frame(s)")
    assert "--store roi" in full
    small = disk_use_line(cams, 2, AcquisitionConfig(frames_per_pose=1))
    assert "--store roi" not in small
    roi = disk_use_line(cams, 170, AcquisitionConfig(frames_per_pose=20, store_roi=True))
    assert roi.startswith("images: at most 26 GB")


def _printed(table, width: int = 80) -> str:
    from microcal.report.console import print_table

    console = Console(file=io.StringIO(), width=width, force_terminal=False)
    print_table(console, table)
    return console.file.getvalue()


def test_a_table_wider_than_80_columns_is_split_and_no_cell_is_cut():
    from microcal.report.text_tables import TextTable

    rng = np.random.default_rng(3)
    for trial in range(40):
        n_cols = int(rng.integers(2, 14))
        cols = ["camera", *(f"figure {k} µm" for k in range(1, n_cols))]
        rows = [
            [
                f"cam{r}",
                *(f"{v:.{int(rng.integers(1, 9))}f}" for v in rng.normal(0, 1e4, n_cols - 1)),
            ]
            for r in range(3)
        ]
        out = _printed(TextTable(f"trial {trial}", cols, rows))
        assert max(len(line) for line in out.splitlines()) <= 80, out
        assert "…" not in out, out
        for row in rows:
            for cell in row:
                assert cell in out, (cell, out)  # whole, on one line


def test_the_fit_command_prints_within_80_columns(quick_demo, tmp_path):
    from support.cli import invoke_microcal

    run, _ = quick_demo
    out = invoke_microcal("fit", run, "-o", tmp_path / "c.json")  # 80 columns
    assert out.returncode == 0, out.stderr
    table_lines = [line for line in out.stdout.splitlines() if line[:1] in "┏┃┡│└"]
    assert table_lines
    assert max(len(line) for line in table_lines) <= 80
    assert "…" not in out.stdout


def test_a_column_no_row_fills_takes_no_room():
    from microcal.report.text_tables import TextTable

    table = TextTable("cams", ["camera", "RMS px", "held-out px"], [["top", "0.06", ""],
                      ["side", "0.05", " "]])  # fmt: skip
    out = _printed(table)
    assert "held-out" not in out
    assert "0.06" in out
    assert "top" in out
    kept = _printed(TextTable("cams", ["camera", "held-out px"], [["top", ""], ["side", "0.1"]]))
    assert "held-out" in kept


def test_a_log_gets_whole_tables_unless_columns_says_otherwise(monkeypatch):
    from microcal.report.console import LOG_WIDTH, output_console
    from microcal.report.text_tables import TextTable

    monkeypatch.delenv("COLUMNS", raising=False)
    console = output_console()  # pytest's standard output is not a terminal
    assert not console.is_terminal
    assert console.width == LOG_WIDTH
    wide = TextTable("camera", ["camera", *(f"figure {k}" for k in range(10))],
                     [["left", *("0.123456" for _ in range(10))]])  # fmt: skip
    assert "(1/2)" in _printed(wide, 80)  # what rich's 80 columns gave a log
    assert "(1/2)" not in _printed(wide, LOG_WIDTH)
    long_line = "word " * 60  # a line is not broken, however long
    console.file = io.StringIO()
    console.print(long_line)
    assert console.file.getvalue().count("\n") == 1
    monkeypatch.setenv("COLUMNS", "100")
    assert output_console().width == 100


def test_the_range_note_names_joints_outside_the_identified_range_only():
    from microcal.kinematics.manipulator_calibration import ManipulatorCalibration
    from microcal.kinematics.models import fit_matrix_model
    from microcal.report.text_tables import range_note

    d = np.random.default_rng(0).uniform(0, 100, (20, 3))
    figures = {"n_fit": 20, "n_validate": 0, "mean_um": 0.1, "std_um": 0.1, "max_um": 0.2,
               "rms_um": 0.1}  # fmt: skip
    rng = np.array([[0.0, 100.0], [0.0, 100.0], [-10.0, 10.0]])
    entry = ManipulatorCalibration("m1", fit_matrix_model(d, d), figures,
                                   {"joint_range_um": rng.tolist()})  # fmt: skip
    assert entry.outside_joint_range_um(np.array([50.0, 50.0, 0.0])) is None
    bare = ManipulatorCalibration("m1", fit_matrix_model(d, d), figures)
    assert bare.outside_joint_range_um(np.array([50.0, 50.0, 0.0])) is None
    outside = entry.outside_joint_range_um(np.array([50.0, 101.0, 0.0]))
    assert outside is not None
    note = range_note(outside, "the joints it arrived at")
    assert note == ("note: the joints it arrived at lie outside the range the model was "
                    "identified on 0:100,0:100,-10:10 µm; the model extrapolates there")  # fmt: skip
