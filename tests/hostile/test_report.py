"""Hostile inputs of ``microcal report``: names that would be markup or links, files of
shapes the report cannot show, and inputs large enough to make its page or its time grow
faster than what it shows.

Every run directory is built here from scratch: a results.json, a cameras.json, a journal,
a calibration with its history of checks, each holding only what the case needs.
"""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from microcal.formats.calibration_file import Calibration, write_calibration
from microcal.formats.check_file import history_path
from microcal.formats.hashing import sha256_file
from microcal.kinematics.manipulator_calibration import ManipulatorCalibration
from microcal.kinematics.models import fit_matrix_model
from support.hostile import Sandbox, kept_outside, refused_cleanly, run_traced

#: Text that is markup if a page prints it as it is.
MARKUP = '<script>alert(1)</script><img src=x onerror="alert(2)">'
#: Text that is mathematics (and a parse error) if matplotlib draws it as it is.
MATH = r"$\frac{$"
#: The links a report may hold: its own sections, and a device's report beside it.
OWN_LINK = re.compile(r"#[a-z-]+|[A-Za-z0-9_][A-Za-z0-9_.-]*/report\.html")


class Page(HTMLParser):
    """A report's tags: every link and every attribute, and any script."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.links: list[str] = []
        self.attributes: list[tuple[str, str]] = []
        self.scripts = 0
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.scripts += tag == "script"
        self.attributes += [(k, v or "") for k, v in attrs]
        self.links += [v or "" for k, v in attrs if k == "href"]


def report(box: Sandbox) -> str:
    """``microcal report`` of the case, which must succeed; its page."""
    outcome = kept_outside(box, lambda: run_traced("report", box.case))
    assert outcome.ran.returncode == 0, outcome.ran.stderr
    return (box.case / "report.html").read_text(encoding="utf-8")


def write_json(path: Path, data: object) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


def results(**sections: Any) -> dict[str, Any]:
    return {"format": "microcal.results/1", **sections}


def pose(k: int = 0) -> dict[str, Any]:
    return {"desired_um": [100.0 * k, 0.0, 0.0], "ap_um": [0.1, 0.2, 0.3], "ap_p_um": 0.4,
            "rp_um": 0.1, "n": 5}  # fmt: skip


def pose_accuracy(n_poses: int = 1) -> dict[str, Any]:
    return {"mean_ap_p_um": 4.0, "max_ap_p_um": 7.0, "poses": [pose(k) for k in range(n_poses)]}


def decoupling() -> dict[str, Any]:
    return {"undesired_um": {a: [-1.0, 1.0] for a in "xyz"}, "omega": dict.fromkeys("xyz", 3.0),
            "samples_um": [[0, 0, 0], [10, 0.1, 0], [0, 0, 0], [0, 10, 0], [0, 0, 0], [0, 0, 10]],
            "segment": [0, 0, 1, 1, 2, 2]}  # fmt: skip


def camera(k: int, n: int, name_figures: bool = False) -> dict[str, Any]:
    """Camera ``k`` of a ring of ``n`` looking at the origin (centres all apart)."""
    angle = 2 * np.pi * k / n
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, s, 0.0], [0.0, 0.0, -1.0], [-s, c, 0.0]])
    t = -R @ (np.array([c, s, 0.0]) * -60000.0)
    cam: dict[str, Any] = {
        "image_size_px": [640, 480],
        "K": [[8000.0, 0.0, 320.0], [0.0, 8000.0, 240.0], [0.0, 0.0, 1.0]],
        "dist": [0.0] * 5, "R": R.tolist(), "t_um": t.tolist(), "rms_px": 0.1, "views_used": 3,
    }  # fmt: skip
    if name_figures:
        cam["per_view_rms_px"] = {"v1.png": 0.1, "v2.png": 0.2}
    return cam


def cameras(names: list[str], **extra: Any) -> dict[str, Any]:
    cams = {name: camera(k, len(names), name_figures=k < 12) for k, name in enumerate(names)}
    return {"format": "microcal.cameras/1", "cameras": cams, **extra}


def calibration(root: Path) -> Path:
    """A calibration.json of one matrix model fitted to a synthetic run."""
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 8000, (60, 3))
    p = d @ np.array([[1.01, 0.002, 0], [0, 0.99, 0.003], [0.001, 0, 1.0]]).T + [100, 200, 300]
    model = fit_matrix_model(d, p + rng.normal(0, 0.01, p.shape))
    validation = {"n_fit": 40, "n_validate": 20, "mean_um": 0.5, "std_um": 0.2, "max_um": 1.0,
                  "rms_um": 0.55}  # fmt: skip
    m1 = ManipulatorCalibration("m1", model, validation)
    return write_calibration(root / "calibration.json", Calibration({"m1": m1}))


def checks(calibration_json: Path, entries: list[dict[str, Any]]) -> None:
    digest = sha256_file(calibration_json)
    history_path(calibration_json).write_text(
        "".join(json.dumps({"calibration_sha256": digest, **e}) + "\n" for e in entries)
    )


def check(**changes: Any) -> dict[str, Any]:
    return {"verdict": "valid", "against": "calibration", "offset_um": [0.1, 0.0, 0.0],
            "offset_std_um": [0.1, 0.1, 0.1], "p_value": 0.5, "flag": "",
            "created": "2026-12-03T07:00:00+00:00", **changes}  # fmt: skip


def device_report(folder: Path) -> None:
    """A device's report.html as microcal writes it (its generator tag)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "report.html").write_text(
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="generator" content="microcal 0.1">\n</head></html>\n'
    )


# --- 1. links and markup ------------------------------------------------------------------
@pytest.mark.parametrize(
    "name", ["javascript:alert(1)", "../outside", "linked", "foreign"],
    ids=["javascript-scheme", "dot-dot", "symbolic-link", "not-a-microcal-report"],
)  # fmt: skip
def test_a_device_name_never_becomes_a_link_of_its_own(tmp_path, name):
    box = Sandbox.make(tmp_path)
    device_report(box.case / "m1")  # a device's own report: linked
    if name == "linked":
        device_report(box.outside / "elsewhere")
        (box.case / "linked").symlink_to(box.outside / "elsewhere")
    elif name == "foreign":
        (box.case / "foreign").mkdir()
        (box.case / "foreign" / "report.html").write_text("<p>someone's page</p>")
    elif name == "../outside":
        (box.outside / "report.html").write_text('<meta name="generator" content="microcal">')
    else:
        device_report(box.case / name)
    devices = {"m1": {"pose_accuracy": {"truth": {"optimal": pose_accuracy()}}}, name: {}}
    write_json(box.case / "results.json", results(devices=devices))
    page = Page(report(box))
    assert "m1/report.html" in page.links
    assert all(OWN_LINK.fullmatch(link) for link in page.links), page.links
    assert not any(name in link for link in page.links), page.links


def test_names_from_every_file_are_text_in_the_page_and_in_its_figures(tmp_path):
    box = Sandbox.make(tmp_path)
    hostile = MARKUP + MATH
    # a camera's name must be a name (refused below); every other text is shown as text
    cams = cameras(["top", "side"], stereo={"method": hostile, "notes": [hostile],
                   "views_rejected": [{"view": hostile, "reason": hostile}]})  # fmt: skip
    cams["cameras"]["top"]["per_view_rms_px"] = {hostile: 0.1, "v2": 0.2}
    cams["cameras"]["top"]["views_rejected"] = [{"image": hostile, "reason": hostile}]
    cams["provenance"] = {hostile: hostile}
    write_json(box.case / "cameras.json", cams)
    write_json(box.case / "results.json", results(
        pose_accuracy={"vision": {hostile: pose_accuracy()}},
        decoupling={"vision": {hostile: decoupling()}},
        meet={hostile: {"targets_um": [[0, 0, 0]]}},
        devices={hostile: {}},
        stereo={hostile: {"rms_px": 0.1}},
    ))  # fmt: skip
    cal = calibration(box.case)
    checks(cal, [check(verdict=hostile, manipulator=hostile, flag=hostile),
                 check(manipulator="m2")])  # fmt: skip
    (box.case / "journal.jsonl").write_text(
        json.dumps({"pose": 1, "status": "failed", "reason": hostile}) + "\n"
    )
    text = report(box)
    page = Page(text)
    assert page.scripts == 0
    assert not [a for a in page.attributes if a[0].startswith("on")], page.attributes
    assert all(OWN_LINK.fullmatch(link) for link in page.links), page.links
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in text


def test_a_camera_named_with_markup_is_not_a_name(tmp_path):
    box = Sandbox.make(tmp_path)
    write_json(box.case / "cameras.json", cameras([MARKUP, "side"]))
    refused_cleanly(box, lambda: run_traced("report", box.case), "cameras.json", "is not a name")


# --- 2. files of shapes the report cannot show: one line naming the file and the key -------
AP = ("pose_accuracy", "vision", "optimal", "poses", 0, "ap_um")
DC = ("decoupling", "vision", "optimal")


def _edit(doc: dict[str, Any], keys: tuple[str | int, ...], value: object) -> dict[str, Any]:
    at: Any = doc
    for key in keys[:-1]:
        at = at[key]
    if value is None:
        del at[keys[-1]]
    else:
        at[keys[-1]] = value
    return doc


@pytest.mark.parametrize(
    ("keys", "value", "needle"),
    [
        (AP, [1.0], "poses.0.ap_um"),
        (AP, None, "poses.0.ap_um"),
        ((*DC, "undesired_um"), {"x": [1.0, 2.0]}, "undesired_um"),
        ((*DC, "undesired_um", "y"), [1.0], "undesired_um.y"),
        ((*DC, "omega"), {}, "omega"),
        ((*DC, "samples_um"), [[0, 0, 0], [1, 2], [0, 0, 0], [0, 1, 0], [0, 0, 0], [0, 0, 1]],
         "samples_um.1"),
        ((*DC, "samples_um"), [[0, 0], [1, 2]] * 3, "samples_um.0"),
        ((*DC, "segment"), None, "segment"),
        (DC, {}, "decoupling.vision.optimal"),
        (("devices", "m1", *AP), [], "devices.m1.pose_accuracy"),
    ],
    ids=["ap-short", "ap-missing", "axis-missing", "range-short", "omega-empty", "samples-ragged",
         "samples-two-columns", "segment-missing", "condition-empty", "device-ap-empty"],
)  # fmt: skip
def test_a_results_json_the_report_cannot_show_is_one_line_naming_the_key(
    tmp_path, keys, value, needle
):
    box = Sandbox.make(tmp_path)
    doc = results(pose_accuracy={"vision": {"optimal": pose_accuracy()}},
                  decoupling={"vision": {"optimal": decoupling()}},
                  devices={"m1": {"pose_accuracy": {"vision": {"optimal": pose_accuracy()}}}})  # fmt: skip
    write_json(box.case / "results.json", _edit(doc, keys, value))
    refused_cleanly(box, lambda: run_traced("report", box.case), "results.json", needle)


@pytest.mark.parametrize(
    ("grid", "needle"),
    [([[0.1, 0.2], [0.3]], "uncertainty_map_px"), ([[], []], "uncertainty_map_px")],
    ids=["ragged", "empty-rows"],
)
def test_a_cameras_json_uncertainty_map_that_is_no_grid_is_one_line(tmp_path, grid, needle):
    box = Sandbox.make(tmp_path)
    cams = cameras(["top", "side"])
    cams["cameras"]["top"]["diagnostics"] = {"uncertainty_map_px": grid}
    write_json(box.case / "cameras.json", cams)
    refused_cleanly(box, lambda: run_traced("report", box.case), "cameras.json", needle)


def test_a_camera_without_its_uncertainty_figures_is_shown_without_them(tmp_path):
    box = Sandbox.make(tmp_path)
    cams = cameras(["top", "side"])
    cams["cameras"]["top"]["lens_model"] = {"name": "k1", "reason": "the simplest"}
    cams["cameras"]["top"]["diagnostics"] = {"verdict": ["few views"]}
    write_json(box.case / "cameras.json", cams)
    assert "- px at the centre" in report(box)


@pytest.mark.parametrize(
    ("entry", "needle"),
    [(check(offset_um=[0.1, 0.2]), "offset_um"), (check(offset_std_um=[0.1]), "offset_std_um")],
    ids=["offset-of-two", "std-of-one"],
)
def test_a_check_history_of_offsets_without_three_axes_is_one_line(tmp_path, entry, needle):
    box = Sandbox.make(tmp_path)
    checks(calibration(box.case), [check(), entry])
    refused_cleanly(
        box, lambda: run_traced("report", box.case), "calibration.checks.jsonl", "check 2", needle
    )


@pytest.mark.parametrize(
    "content", [b"\xff\xfe\x00 not text\n", b"[" * 100_000 + b"\n"], ids=["binary", "nested-deep"]
)
def test_a_check_history_that_is_no_text_or_too_deep_is_one_line(tmp_path, content):
    box = Sandbox.make(tmp_path)
    history_path(calibration(box.case)).write_bytes(content)
    refused_cleanly(box, lambda: run_traced("report", box.case), "calibration.checks.jsonl")


def test_a_calibrations_matrix_model_that_is_no_model_names_the_file_and_key(tmp_path):
    box = Sandbox.make(tmp_path)
    cal = calibration(box.case)
    doc = json.loads(cal.read_text())
    doc["manipulators"]["m1"]["matrix_model"] = "x" * 10_000
    write_json(cal, doc)
    line = refused_cleanly(box, lambda: run_traced("report", box.case), "calibration.json",
                           "manipulators.m1.matrix_model")  # fmt: skip
    assert len(line) < 400, line


# --- 3. the page and its time grow with what it shows, no faster ------------------------
def test_a_long_journal_of_failures_shows_the_first_and_counts_the_rest(tmp_path):
    box = Sandbox.make(tmp_path)
    lines = [{"pose": k, "status": "failed", "reason": "top: frame dropped"}
             for k in range(1, 20_001)]  # fmt: skip
    (box.case / "journal.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    text = report(box)
    assert "… and 19900 more failed poses (the first 100 shown)." in text
    assert len(text.encode()) < 200_000


def test_hundreds_of_cameras_fill_one_bounded_table_and_figures_of_eight(tmp_path):
    box = Sandbox.make(tmp_path)
    write_json(box.case / "cameras.json", cameras([f"cam{k:03d}" for k in range(150)]))
    text = report(box)
    assert "… and 50 more cameras (the first 100 shown)." in text
    assert "The figures show the first 8 of the 150 cameras." in text
    assert len(text.encode()) < 400_000


def test_long_texts_and_long_tables_of_results_json_are_cut(tmp_path):
    box = Sandbox.make(tmp_path)
    doc = results(pose_accuracy={"vision": {"optimal": pose_accuracy(1000)}},
                  provenance={f"key{k}": "v" * 1000 for k in range(1000)},
                  meet={"closed": {"mode": "x", "targets_um": [[0, 0, 0]]}},
                  devices={f"m{k}": {} for k in range(500)})  # fmt: skip
    write_json(box.case / "results.json", doc)
    (box.case / "journal.jsonl").write_text(
        json.dumps({"pose": 1, "status": "failed", "reason": "dropped " * 100_000}) + "\n"
    )
    text = report(box)
    for line in ("… and 900 more poses (the first 100 shown).",
                 "… and 901 more provenance entries (the first 100 shown).",
                 "… and 400 more devices (the first 100 shown)."):  # fmt: skip
        assert line in text, line
    assert "dropped dropped" in text
    assert "dropped " * 200 not in text
    assert len(text.encode()) < 400_000


def test_a_long_check_history_shows_the_latest_checks(tmp_path):
    box = Sandbox.make(tmp_path)
    checks(calibration(box.case), [check(p_value=k / 1000) for k in range(400)])
    text = report(box)
    assert "… and 300 earlier checks (the latest 100 shown)." in text
    assert '<td class="num">301</td>' in text
    assert '<td class="num">300</td>' not in text
