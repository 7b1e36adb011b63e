"""The report speaks to the rig it describes: the thesis's figures only for the thesis preset.

Each test copies the files of the session's quick demo (the simulator's thesis preset) and
rewrites the rig entry of its run.json, so one demo serves every rig.
"""

from __future__ import annotations

import json
import re
import shutil
from html.parser import HTMLParser
from pathlib import Path

import pytest

from microcal.report import build_report
from microcal.report.data import RUN_FILES
from microcal.thesis import figures as thesis
from support.report_cells import cells, check_number_cells

#: A hardware rig as run.json records it (examples/rigs/smaract-gige.toml).
HARDWARE = {
    "driver": "hardware",
    "board": "chessboard:4x3:400",
    "manipulator": {
        "kind": "smaract-mcs2",
        "address": "192.168.1.200",
        "port": 55551,
        "channels": {"x": 0, "y": 1, "z": 2},
        "limits_um": {"x": [0.0, 8000.0], "y": [0.0, 8000.0], "z": [0.0, 4800.0]},
    },
    "cameras": {
        "top": {"kind": "aravis", "address": "192.168.1.11", "exposure_ms": 10.0},
        "side": {"kind": "aravis", "address": "192.168.1.12", "exposure_ms": 10.0},
    },
}

#: Every thesis figure the report of a thesis-preset run sets beside the run's, as printed.
THESIS_CELLS = (
    {f"{thesis.REPROJECTION_ERROR_TOP_PX:.3f}", f"{thesis.REPROJECTION_ERROR_SIDE_PX:.3f}"}
    | {f"±{thesis.CLAIMED_ACCURACY_UM} claimed"}
    | {f"{v:.2f}" for stats in thesis.VALIDATION_UM.values() for v in stats.values()}
    | {f"{v:.2f}" for pair in thesis.POSE_ACCURACY_UM.values() for v in pair}
    | {f"{v:.2f}" for axes in thesis.DECOUPLING_UM.values() for pair in axes.values() for v in pair}
    | {f"{v:.1f}" for axes in thesis.OMEGA_UM.values() for v in axes.values()}
)
#: The headings and notes that name the thesis's columns, tables and figures.
THESIS_TEXTS = (
    "Figures in brackets or grey\ncolumns are the thesis's",
    "<th>thesis</th>",
    "<th>thesis, px</th>",
    "<td>thesis</td>",
    "(thesis Fig 4.2)",
    "(the thesis claimed ±3.0 µm without measuring it)",
    "(thesis Figs 5.3 and 5.4)",
    "(thesis Tables 5-2 to 5-4)",
    "(thesis 7.83 / 23.52)",
    "(thesis Figs 5.5 to 5.8)",
    "and the thesis's only by ratio",
)


class _Tables(HTMLParser):
    """The number of cells (th and td) of every row, per table."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: list[list[int]] = []
        self.thesis_cells: list[str] = []
        self._in_thesis = False
        self._text = ""

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self.tables[-1].append(0)
        elif tag in ("td", "th"):
            self.tables[-1][-1] += 1
            self._in_thesis = tag == "td" and dict(attrs).get("class") == "thesis"
            self._text = ""

    def handle_data(self, data):
        if self._in_thesis:
            self._text += data

    def handle_endtag(self, tag):
        if tag == "td" and self._in_thesis:
            self.thesis_cells.append(self._text.strip())
            self._in_thesis = False


def _tables(html: str) -> _Tables:
    parser = _Tables()
    parser.feed(html)
    return parser


def _run_on(quick_demo, tmp_path: Path, rig: dict | None, *, manifest: bool = True) -> Path:
    """A copy of the demo's files whose run.json names ``rig`` (no rig entry for None), with
    its report; without run.json if not ``manifest``."""
    out, _ = quick_demo
    run = tmp_path / "run"
    run.mkdir()
    for name in RUN_FILES:
        shutil.copy(out / name, run / name)
    data = json.loads((run / "run.json").read_text())
    if rig is None:
        del data["rig"]
    else:
        data["rig"] = rig
    (run / "run.json").write_text(json.dumps(data, indent=2))
    if not manifest:
        (run / "run.json").unlink()
    (run / "report.html").write_text(build_report(run), encoding="utf-8")
    return run


@pytest.mark.slow
def test_a_thesis_preset_run_is_compared_with_the_thesis(quick_demo, tmp_path):
    out, _ = quick_demo
    rig = json.loads((out / "run.json").read_text())["rig"]
    assert rig == {"driver": "sim", "preset": "thesis", "seed": 0, "overrides": {}}
    run = _run_on(quick_demo, tmp_path, rig)
    html = (run / "report.html").read_text(encoding="utf-8")
    for phrase in THESIS_TEXTS:
        assert phrase in html, phrase
    tables = _tables(html)
    assert set(tables.thesis_cells) == THESIS_CELLS
    assert tables.tables[0][0] == 3  # the summary: figure, microcal, thesis
    assert "Rig:" not in html


@pytest.mark.slow
@pytest.mark.parametrize(
    ("rig", "manifest", "rig_line"),
    [
        (
            HARDWARE,
            True,
            "Rig: hardware: manipulator smaract-mcs2; cameras top (aravis), side (aravis).",
        ),
        (
            {"driver": "sim", "preset": "bench", "seed": 4, "overrides": {}},
            True,
            "Rig: the simulator, preset bench, seed 4.",
        ),
        (None, True, "Rig: not recorded in run.json."),
        (None, False, "Rig: not recorded (no run.json)."),
    ],
    ids=["hardware", "other-preset", "no-rig-entry", "no-run-json"],
)
def test_another_rig_is_reported_without_the_thesis(quick_demo, tmp_path, rig, manifest, rig_line):
    out, _ = quick_demo
    run = _run_on(quick_demo, tmp_path, rig, manifest=manifest)
    html = (run / "report.html").read_text(encoding="utf-8")
    text = html.replace(str(run), "RUN_DIR")  # the provenance names the directory
    assert "thesis" not in text.lower(), re.findall(r".{0,60}thesis.{0,40}", text, re.I | re.S)
    for phrase in THESIS_TEXTS:
        assert phrase not in html, phrase
    assert rig_line in html
    tables = _tables(html)
    assert tables.thesis_cells == []
    for rows in tables.tables:  # no column left empty or filled with dashes for the thesis
        assert len(set(rows)) == 1, rows
    assert tables.tables[0][0] == 2  # the summary: figure, microcal
    # the run's own figures, all of them, each equal to its file
    ours = check_number_cells(run, run / "report.html")
    assert ours == check_number_cells(out, out / "report.html")
    assert len(cells(run / "report.html").images) == len(cells(out / "report.html").images)
