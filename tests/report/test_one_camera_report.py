"""The report of a one-camera run (``microcal demo --preset patch``): the camera against its
stage with standard deviations, the tip measurement by axis and its covariance's
consistency, the models, ISO 9283 by the one-camera probe and by truth, the open loop over
the working volume and the rig's time per stage; every number cell equals results.json."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from support.report_cells import cells, lookup

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars"]  # fmt: skip


@pytest.fixture(scope="module")
def patch_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short patch demo (30 poses, one ISO cycle) with its report."""
    from microcal.workflows.patch_demo import patch_demo

    out = tmp_path_factory.mktemp("patch") / "demo"
    patch_demo(out, seed=2, poses=30, quick=True)
    return out


@pytest.mark.slow
def test_the_report_shows_the_one_camera_sections_and_not_the_stereo_ones(patch_run: Path) -> None:
    html = (patch_run / "report.html").read_text(encoding="utf-8")
    for anchor in ("scope", "measurement", "models", "pose-accuracy", "rig-time",
                   "volume-accuracy", "tip-errors", "rig-time-table"):  # fmt: skip
        assert f'id="{anchor}"' in html, anchor
    assert 'id="stereo"' not in html
    assert 'id="decoupling"' not in html
    assert "No cameras.json" not in html
    assert "No measurements.csv" not in html
    assert "Rig: the simulator, preset patch, seed 2." in html
    assert "by focus sweeps" in html
    assert "95 % region holds" in html
    for source in ("vision", "truth"):  # ISO 9283 by the probe and by truth, closed loop too
        for condition in ("uncalibrated", "matrix", "optimal", "closed_loop"):
            assert f"<h3>{condition} ({source}): mean AP" in html, (condition, source)
    scope = json.loads((patch_run / "results.json").read_text(encoding="utf-8"))["scope"]
    for value in scope["pixel_size_affine"][:2]:  # Micro-Manager's affine, as scope.json has it
        assert f"{value:.6g}" in html


@pytest.mark.slow
def test_every_number_cell_of_the_report_is_results_json_s(patch_run: Path) -> None:
    results = json.loads((patch_run / "results.json").read_text(encoding="utf-8"))
    parsed = cells(patch_run / "report.html")
    checked = set()
    for key, value, text in parsed.cells:
        if key.split(".")[0] == "calibration":
            continue  # the models' validation: calibration.json's (the other report tests)
        expected = lookup(results, key)
        assert float(value) == pytest.approx(expected, rel=1e-12, abs=1e-12), key
        digits = len(text.split(".")[1]) if "." in text else 0
        assert text == f"{expected:.{digits}f}", key
        checked.add(key)
    must = {"scope.pixel_size_um", "scope.pixel_size_sd_um", "scope.scale_um.0",
            "scope.rotation_deg", "scope.rotation_sd_deg", "scope.focus.angle_deg",
            "scope.focus.angle_sd_deg", "measurement.rms_error_um",
            "measurement.rms_error_axis_um.x", "measurement.rms_error_axis_um.z",
            "pose_accuracy.vision.closed_loop.mean_ap_p_um",
            "pose_accuracy.truth.optimal.poses.4.ap_p_um",
            "volume_accuracy.truth.optimal.mean_ap_p_um", "timing.rig_s.slide",
            "timing.rig_s.acquisition and measurement", "timing.stages_s.evaluation"}  # fmt: skip
    assert must <= checked, must - checked
    spans = dict(re.findall(r'<span class="num" data-key="([^"]+)" data-value="([^"]+)"',
                            (patch_run / "report.html").read_text(encoding="utf-8")))  # fmt: skip
    assert float(spans["measurement.mahalanobis_mean_sq"]) == pytest.approx(
        results["measurement"]["mahalanobis_mean_sq"], rel=1e-12
    )
    assert float(spans["scope.errors.scale_error_pct"]) == pytest.approx(
        results["scope"]["errors"]["scale_error_pct"], rel=1e-12
    )
    # the settle times and the tips' stated standard deviations
    assert len(parsed.images) == 2
    assert 0.0 <= results["measurement"]["in_95"] <= 1.0


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium package")
def test_the_report_renders_in_headless_chromium(patch_run: Path, tmp_path: Path) -> None:
    shot = tmp_path / "report.png"
    snap = subprocess.run(
        [CHROMIUM, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}", "--window-size=1280,2400",
         f"--screenshot={shot}", (patch_run / "report.html").as_uri()],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL, check=False,
    )  # fmt: skip
    assert snap.returncode == 0, snap.stderr[-2000:]
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert shot.stat().st_size > 50_000  # tables and figures, not a blank page
