"""``microcal demo --preset patch``: its directory is checked before anything runs."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.errors import InputError
from microcal.report.patch_lines import patch_demo_lines
from microcal.workflows.patch_demo import PATCH_FILES, patch_demo

runner = CliRunner()


def test_a_directory_with_other_files_is_refused_in_one_line_and_left_alone(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("mine", encoding="utf-8")
    (tmp_path / "results.json").write_text("{}", encoding="utf-8")
    with pytest.raises(InputError, match=r"notes\.txt") as info:
        patch_demo(tmp_path, poses=30)
    assert "\n" not in str(info.value)
    assert (tmp_path / "results.json").read_text(encoding="utf-8") == "{}"
    result = runner.invoke(app, ["demo", "--preset", "patch", "--out", str(tmp_path)])
    assert result.exit_code != 0
    assert "earlier patch demo did not write" in result.output
    assert (tmp_path / "notes.txt").exists()


def test_too_few_poses_are_refused_before_the_directory_is_made(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="30 or more"):
        patch_demo(tmp_path / "new", poses=25)
    assert not (tmp_path / "new").exists()


def test_the_files_it_writes() -> None:
    assert {"journal.jsonl", "scope.json", "calibration.json", "results.json", "report.html"} == (
        PATCH_FILES
    )


@pytest.mark.slow
def test_a_short_run_writes_its_files_and_meets_the_issue_s_figures(tmp_path: Path) -> None:
    from microcal.formats.results_file import load_results

    run = patch_demo(tmp_path / "demo", seed=1, poses=30, quick=True, method="stack")
    out = run.out
    assert {p.name for p in out.iterdir()} == PATCH_FILES
    lines = (out / "journal.jsonl").read_text(encoding="utf-8").splitlines()
    assert len(lines) == 30
    results = load_results(out / "results.json")
    assert results["preset"] == "patch"
    pa = results["pose_accuracy"]
    assert pa["truth"]["optimal"]["mean_ap_p_um"] < 1.0  # µm, the issue's open-loop bound
    assert pa["truth"]["closed_loop"]["mean_ap_p_um"] < 0.5
    assert results["timing"]["calibration_rig_s"] < 600  # s of rig time
    assert set(results["timing"]["rig_s"]) >= {"slide", "acquisition and measurement"}
    said = "\n".join(patch_demo_lines(run.result))
    assert "closed loop: " in said
    assert "; ended: " in said  # in words, not a record
    assert "{'" not in said
