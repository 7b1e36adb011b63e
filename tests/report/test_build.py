"""The HTML report of a run: its numbers are the files', ``microcal report`` rebuilds it, a run
only acquired and the check history are shown, and it opens in a browser."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import numpy as np
import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.kinematics.manipulator_calibration import ManipulatorCalibration
from microcal.kinematics.models import fit_matrix_model
from microcal.report import load_run
from support.report_cells import cells, check_number_cells

runner = CliRunner()
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CONDITIONS = {"uncalibrated", "matrix", "optimal"}


@pytest.mark.slow
def test_report_numbers_equal_the_result_files(quick_demo):
    out, _ = quick_demo
    checked = check_number_cells(out, out / "report.html")
    parsed = cells(out / "report.html")
    must = {"stereo.top.rms_px", "stereo.side.rms_px", "measurement.rms_error_um",
            "models.matrix.validation.mean_um", "models.polynomial.validation.max_um",
            "calibration.polynomial.mean_um", "calibration.matrix.mean_um"}  # fmt: skip
    for src in ("vision", "truth"):
        for c in CONDITIONS:
            must |= {f"pose_accuracy.{src}.{c}.mean_ap_p_um", f"pose_accuracy.{src}.{c}.max_ap_p_um",
                     f"pose_accuracy.{src}.{c}.poses.7.ap_p_um",
                     f"decoupling.{src}.{c}.undesired_um.y.0", f"decoupling.{src}.{c}.omega.z"}  # fmt: skip
    assert must <= checked, must - checked
    # 4 stereo (per view, residuals, residuals over the image, coverage), design, settle,
    # uncertainty, prediction, 3 decoupling (vision and truth)
    assert len(parsed.images) == 11
    assert all(src.startswith("data:image/png;base64,") for src in parsed.images)


@pytest.mark.slow
def test_report_recomputes_the_validation_errors_it_plots(quick_demo):
    out, _ = quick_demo
    errors = load_run(out).model_errors()
    assert [e.kind for e in errors] == ["matrix", "polynomial"]
    for e in errors:  # measurements.csv holds positions to 1e-6 µm
        assert e.validation is not None
        assert len(e.errors_um) == e.validation.n_validate
        assert e.errors_um.mean() == pytest.approx(e.validation.mean_um, abs=1e-5)
        assert e.errors_um.max() == pytest.approx(e.validation.max_um, abs=1e-5)


@pytest.mark.slow
def test_report_command_rebuilds_the_same_report(quick_demo, tmp_path):
    out, _ = quick_demo
    result = runner.invoke(app, ["report", str(out), "--out", str(tmp_path / "again.html")])
    assert result.exit_code == 0, result.output
    assert cells(tmp_path / "again.html").cells == cells(out / "report.html").cells


@pytest.mark.slow
def test_report_of_a_run_that_is_only_acquired(quick_demo, tmp_path):
    out, _ = quick_demo
    part = tmp_path / "part"
    part.mkdir()
    for name in ("run.json", "commands.csv", "journal.jsonl"):
        shutil.copy(out / name, part / name)
    journal = (part / "journal.jsonl").read_text().splitlines()
    failed = json.loads(journal[3]) | {"status": "failed", "reason": "top: frame dropped"}
    journal[3] = json.dumps(failed)
    (part / "journal.jsonl").write_text("\n".join(journal) + "\n")
    result = runner.invoke(app, ["report", str(part)])
    assert result.exit_code == 0, result.output
    html = (part / "report.html").read_text()
    assert "No measurements.csv" in html
    assert "No cameras.json" in html
    assert re.search(
        r"<td class=\"num\">4</td><td>acquisition</td><td>top: frame dropped</td>", html
    )


@pytest.mark.parametrize(
    ("setup", "args", "message"),
    [
        (None, ["report", "{tmp}/missing"], "not a directory"),
        ("empty", ["report", "{tmp}/empty"], "holds none of run.json"),
        ("bad-results", ["report", "{tmp}/bad"], "results.json"),
        ("empty", ["report", "{tmp}/empty", "--out", "{tmp}"], "is a directory"),
        (None, ["report"], "Missing argument"),
    ],
)
def test_report_user_errors_are_one_line(tmp_path, setup, args, message):
    if setup == "empty":
        (tmp_path / "empty").mkdir()
    if setup == "bad-results":
        (tmp_path / "bad").mkdir()
        (tmp_path / "bad" / "results.json").write_text("{not json")
    result = runner.invoke(app, [a.format(tmp=tmp_path) for a in args])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert message in lines[0]
    assert "Traceback" not in result.output


CHECK_IMAGES = """<script>
window.addEventListener("load", () => {
  const imgs = Array.from(document.images);
  const ok = imgs.filter((i) => i.complete && i.naturalWidth > 0).length;
  document.body.setAttribute("data-images", ok + "/" + imgs.length);
});
</script>
"""


CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--hide-scrollbars"]  # fmt: skip


@pytest.mark.slow
@pytest.mark.skipif(
    CHROMIUM is None, reason="needs Debian's chromium package (.ci/run installs it)"
)
def test_report_opens_in_headless_chromium(quick_demo, tmp_path):
    out, _ = quick_demo
    page = tmp_path / "report.html"
    html = (out / "report.html").read_text(encoding="utf-8")
    page.write_text(html.replace("</body>", CHECK_IMAGES + "</body>"), encoding="utf-8")
    flags = [CHROMIUM, *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile'}"]
    dom = subprocess.run(
        [*flags, "--enable-logging=stderr", "--v=0", "--virtual-time-budget=5000",
         "--dump-dom", page.as_uri()],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL, check=False,
    )  # fmt: skip
    assert dom.returncode == 0, dom.stderr[-2000:]
    console = [line for line in dom.stderr.splitlines() if ":CONSOLE" in line]
    assert console == []
    match = re.search(r'data-images="(\d+)/(\d+)"', dom.stdout)
    assert match, dom.stdout[:500]
    assert match.group(1) == match.group(2) == "11"
    shot = tmp_path / "report.png"
    snap = subprocess.run(
        [*flags, "--window-size=1200,3000", f"--screenshot={shot}", (out / "report.html").as_uri()],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL, check=False,
    )  # fmt: skip
    assert snap.returncode == 0, snap.stderr[-2000:]
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert shot.stat().st_size > 50_000  # a page of tables and plots, not a blank one


def _matrix_model(seed: int = 0):
    rng = np.random.default_rng(seed)
    d = rng.uniform(0, 4800, (60, 3))
    p = d @ np.array([[1.01, 0.002, 0], [0, 0.99, 0.003], [0.001, 0, 1.0]]).T + [100, 200, 300]
    return fit_matrix_model(d, p + rng.normal(0, 0.01, p.shape))


def test_the_report_shows_the_check_history_and_the_iso_characteristics(tmp_path):
    import json

    from microcal.formats.calibration_file import Calibration, write_calibration
    from microcal.formats.check_file import history_path
    from microcal.formats.hashing import sha256_file
    from microcal.formats.results_file import update_results
    from microcal.report.build import build_report

    validation = {"n_fit": 40, "n_validate": 20, "mean_um": 0.5, "std_um": 0.2, "max_um": 1.0,
                  "rms_um": 0.55}  # fmt: skip
    m1 = ManipulatorCalibration("m1", _matrix_model(), validation)
    cal = write_calibration(tmp_path / "calibration.json", Calibration({"m1": m1}))
    digest = sha256_file(cal)
    lines = [{"calibration_sha256": digest, "verdict": v, "against": "calibration",
              "offset_um": [o, 0.0, 0.0], "offset_std_um": [0.1, 0.1, 0.1], "p_value": 0.5,
              "flag": "", "created": "2026-12-03T07:00:00+00:00"}
             for v, o in (("valid", 0.05), ("offset", 1.2))]  # fmt: skip
    lines.append({**lines[0], "calibration_sha256": "0" * 64, "verdict": "refit"})  # another file
    history_path(cal).write_text("".join(json.dumps(x) + "\n" for x in lines))
    update_results(tmp_path / "results.json", {"distance_accuracy": {"vision": {"optimal": {
        "commanded_um": 5000.0, "mean_um": 5000.2, "ad_um": [0.1, 0.1, 0.1], "ad_p_um": 0.2,
        "rd_um": [0.3, 0.3, 0.3], "rd_p_um": 0.4, "n": 3}}}})  # fmt: skip
    html = build_report(tmp_path)
    assert "Checks of the calibration" in html
    assert html.count('<td class="num">1.20, 0.00, 0.00</td>') == 1
    assert ">refit<" not in html  # the line of another calibration file is not its history
    assert "distance AD_P / RD (7.4)" in html
    assert "0.20 / 0.40 µm over 5000 µm" in html


def test_the_glossary_of_the_report_is_the_documentations():
    """Every term the report explains is in docs/glossary.md with the same meaning."""
    from pathlib import Path

    from microcal.report.glossary import GLOSSARY

    page = (Path(__file__).parents[2] / "docs" / "glossary.md").read_text(encoding="utf-8")
    for term, meaning in GLOSSARY.items():
        assert f"- **{term}**: {meaning}" in page, term
    for word in ("oracle", "vAP", "sx sy sz", "uncalibrated", "matrix", "optimal"):
        assert any(word in term for term in GLOSSARY), word


def test_files_kept_beside_the_run_are_named_and_the_report_is_complete(quick_demo, tmp_path):
    """One cameras.json and calibration.json for several devices' runs, beside them (the
    station layout of docs/hardware.md): named with --cameras and --calibration, the report
    shows the stereo calibration as from the run's own files."""
    import shutil

    from support.cli import invoke_microcal

    run, _ = quick_demo
    beside = tmp_path / "runs" / "m1"
    shutil.copytree(run, beside)
    for name in ("cameras.json", "calibration.json"):
        (beside / name).rename(tmp_path / name)
    (beside / "report.html").unlink()
    bare = invoke_microcal("report", beside)
    assert bare.returncode == 0, bare.stderr
    page = (beside / "report.html").read_text(encoding="utf-8")
    assert "No cameras.json in this run directory" in page
    assert "--cameras FILE" in page
    named = invoke_microcal("report", beside, "--cameras", tmp_path / "cameras.json",
                            "--calibration", tmp_path / "calibration.json")  # fmt: skip
    assert named.returncode == 0, named.stderr
    page = (beside / "report.html").read_text(encoding="utf-8")
    assert "Method: known displacements" in page
    assert "No cameras.json" not in page
    assert "reprojection residuals over the image" in page  # the figures from cameras.json
    assert "No calibration.json" not in page
    missing = invoke_microcal("report", beside, "--cameras", tmp_path / "nothere.json")
    assert missing.returncode == 2
    assert "--cameras" in missing.stderr
    assert "no such file" in missing.stderr


def test_the_report_shows_the_consistency_figures_of_cameras_json(quick_demo, tmp_path):
    import json
    import shutil

    from support.cli import invoke_microcal

    run, _ = quick_demo
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    cameras = json.loads((copy / "cameras.json").read_text(encoding="utf-8"))
    cameras["stereo"]["consistency"] = {
        "pitch": {"x": {"nominal_um": 250.0, "mean_um": 250.01, "error": 4e-5,
                        "rms_error": 0.001, "worst_cell_error": 2e-4, "segments": 900}},
    }  # fmt: skip
    (copy / "cameras.json").write_text(json.dumps(cameras), encoding="utf-8")
    done = invoke_microcal("report", copy)
    assert done.returncode == 0, done.stderr
    page = (copy / "report.html").read_text(encoding="utf-8")
    assert "Consistency, without a reference" in page
    assert "target pitch triangulated along x: 250.01 µm against 250 µm (+0.004 %" in page
