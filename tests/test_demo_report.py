"""`microcal demo` end to end, the run directory it writes, and the HTML report built from it."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from microcal import load_calibration
from microcal.cli import app
from microcal.formats.run_manifest import clear_demo_dir as _clear_demo_dir
from microcal.report import load_run

runner = CliRunner()
CONDITIONS = {"uncalibrated", "matrix", "optimal"}
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


_DEMO: dict[str, tuple[Path, str]] = {}


@pytest.fixture(scope="session")
def quick_demo(tmp_path_factory):
    """One ``microcal demo --quick`` run for the whole session: (directory, terminal output).

    Other modules import this fixture and share the same run; a test that changes the run
    directory works on a copy of it.
    """
    if "quick" not in _DEMO:
        out = tmp_path_factory.mktemp("demo") / "run"
        result = runner.invoke(
            app, ["demo", "--quick", "--seed", "1", "--out", str(out)], env={"COLUMNS": "200"}
        )
        assert result.exit_code == 0, result.output
        _DEMO["quick"] = (out, result.output)
    return _DEMO["quick"]


def test_demo_prints_each_step_and_the_thesis_figures(quick_demo):
    _, output = quick_demo
    for text in ("Stereo calibration", "Measured 40 of 40 poses", "3D error vs ground truth",
                 "Identification", "oracle", "thesis mean", "Pose accuracy", "Decoupling",
                 "report.html"):  # fmt: skip
        assert text in output


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
    assert {"simulated_s", "wall_s"} <= set(res["timing"])


class _Cells(HTMLParser):
    """Collects the report's number cells (data-key, data-value, text) and its images."""

    def __init__(self) -> None:
        super().__init__()
        self.cells: list[tuple[str, str, str]] = []
        self.images: list[str] = []
        self._open: tuple[str, str] | None = None
        self._text = ""

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "td" and "data-key" in a:
            self._open, self._text = (a["data-key"], a["data-value"]), ""
        if tag == "img":
            self.images.append(a.get("src", ""))

    def handle_data(self, data):
        if self._open:
            self._text += data

    def handle_endtag(self, tag):
        if tag == "td" and self._open:
            self.cells.append((*self._open, self._text.strip()))
            self._open = None


def _cells(path: Path) -> _Cells:
    parser = _Cells()
    parser.feed(path.read_text(encoding="utf-8"))
    return parser


def _lookup(data, key: str):
    for part in key.split("."):
        data = data[int(part)] if isinstance(data, list) else data[part]
    return data


def check_number_cells(out: Path, page: Path) -> set[str]:
    """Every number cell of the report ``page`` equals the file of ``out`` its key names.

    Returns the keys checked.
    """
    parsed = _cells(page)
    sources = {
        "results": json.loads((out / "results.json").read_text()),
        "cameras": json.loads((out / "cameras.json").read_text())["cameras"],
        "calibration": {
            e.model.kind: e.validation.model_dump() if e.validation is not None else {}
            for e in load_run(out).model_errors()  # matrix and polynomial, each its own
        },
    }
    checked = set()
    for key, value, text in parsed.cells:
        head, _, rest = key.partition(".")
        if head in ("cameras", "calibration"):
            expected = _lookup(sources[head], rest)
        else:
            expected = _lookup(sources["results"], key)
        assert float(value) == pytest.approx(expected, rel=1e-12, abs=1e-12), key
        digits = len(text.split(".")[1]) if "." in text else 0
        assert text == f"{expected:.{digits}f}", key
        checked.add(key)
    return checked


def test_report_numbers_equal_the_result_files(quick_demo):
    out, _ = quick_demo
    checked = check_number_cells(out, out / "report.html")
    parsed = _cells(out / "report.html")
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


def test_report_recomputes_the_validation_errors_it_plots(quick_demo):
    out, _ = quick_demo
    errors = load_run(out).model_errors()
    assert [e.kind for e in errors] == ["matrix", "polynomial"]
    for e in errors:  # measurements.csv holds positions to 1e-6 µm
        assert e.validation is not None
        assert len(e.errors_um) == e.validation.n_validate
        assert e.errors_um.mean() == pytest.approx(e.validation.mean_um, abs=1e-5)
        assert e.errors_um.max() == pytest.approx(e.validation.max_um, abs=1e-5)


def test_report_command_rebuilds_the_same_report(quick_demo, tmp_path):
    out, _ = quick_demo
    result = runner.invoke(app, ["report", str(out), "--out", str(tmp_path / "again.html")])
    assert result.exit_code == 0, result.output
    assert _cells(tmp_path / "again.html").cells == _cells(out / "report.html").cells


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
    with pytest.raises(Exception, match="earlier demo did not write"):
        _clear_demo_dir(mixed)
    assert (mixed / "notes.txt").read_text() == "mine"


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


def test_the_demos_manifest_reproduces_its_commands(quick_demo):
    # run.json's design, drawn again by make_design, gives commands.csv (written to 4 decimals).
    from microcal.formats.run_directory import RunDirectory
    from microcal.kinematics.designs import make_design

    run = RunDirectory.open(quick_demo[0])
    design = json.loads((run.path / "run.json").read_text())["design"]
    d = make_design(design["kind"], design["poses"], design["low_um"], design["high_um"],
                    design["seed"])  # fmt: skip
    np.testing.assert_allclose(run.commands()[1], d, atol=5e-5, rtol=0)
