"""Typed records of run.json, journal lines and results.json: round trips, extra keys kept,
one message for an unknown format version."""

from __future__ import annotations

import json

import pytest

from microcal import FormatError
from microcal.formats.json_file import FileSchema, read_versioned_json
from microcal.formats.records import (
    ImageRecord,
    JournalLine,
    Results,
    RoiRecord,
    RunManifest,
)
from microcal.formats.results_file import load_results, read_results, update_results

LINE = {
    "pose": 4,
    "commanded_um": [1.0, 2.0, 3.0],
    "status": "ok",
    "reported_um": [1.0, 2.0, 3.0],
    "time": 1700000000.5,
    "settle_s": 2.25,
    "residual_px": None,
    "temperature_c": 22.0,
    "creep_model": {"tau_s": 3.1, "px_per_um_step": 0.002},
    "images": {
        "top": {"file": "images/top_0004.tiff", "sha256": "ab" * 32, "frames": 5,
                "offset_px": [120, 80], "full_size_px": [1600, 1200]},
        "side": {"file": "images/side_0004.tiff", "sha256": "cd" * 32, "frames": 5},
    },
}  # fmt: skip


def test_a_journal_line_round_trips_with_its_extra_keys():
    line = JournalLine.model_validate(LINE)
    assert line.pose == 4
    assert not line.failed
    assert line.temperature_c == 22.0
    assert line.images["top"].roi == RoiRecord((120, 80), (1600, 1200))
    assert line.images["side"].roi is None
    assert line.get("creep_model") == {"tau_s": 3.1, "px_per_um_step": 0.002}
    assert line.get("residual_px", "none") == "none"
    assert line.to_json() == LINE


def test_a_failed_line_and_an_old_line_without_frames():
    failed = JournalLine.model_validate({"pose": 2, "status": "failed", "reason": "timeout"})
    assert failed.failed
    assert failed.images == {}
    assert failed.temperature_c is None
    image = ImageRecord.model_validate({"file": "images/top_0001.tiff", "sha256": "0" * 64})
    assert image.frames is None
    assert image.to_json() == {"file": "images/top_0001.tiff", "sha256": "0" * 64}


def test_the_roi_record_is_the_acquisitions_offset_and_full_size():
    roi = RoiRecord.from_roi_px([10, 20, 1600, 1200])  # x0, y0, full frame w, h
    assert roi.offset_px == (10, 20)
    assert roi.full_size_px == (1600, 1200)
    assert RoiRecord.from_roi_px(roi) is roi
    assert roi.journal_keys() == {"offset_px": [10, 20], "full_size_px": [1600, 1200]}
    image = ImageRecord(file="f.tiff", sha256="0" * 64, frames=1, roi=roi)
    assert ImageRecord.model_validate(image.to_json()) == image
    with pytest.raises(ValueError, match="offset_px and full_size_px go together"):
        ImageRecord.model_validate({"file": "f", "sha256": "0", "offset_px": [1, 2]})


def test_a_manifest_round_trips_and_keeps_extra_keys():
    raw = {"format": "microcal.run/1", "rig": {"driver": "sim", "seed": 3}, "target": "t",
           "cameras": ["top", "side"], "design": {"kind": "random", "poses": 40, "seed": 2,
           "low_um": [0, 0, 0]}, "settle": "vision", "frames_per_pose": 2, "store": "roi",
           "provenance": {"command": "demo"}, "commands_sha256": "e" * 64,
           "operator": "someone"}  # fmt: skip
    manifest = RunManifest.model_validate(raw)
    assert manifest.design is not None
    assert manifest.design.kind == "random"
    assert manifest.model_extra == {"operator": "someone"}
    assert manifest.to_json() == raw
    sparse = RunManifest.model_validate({"format": "microcal.run/1", "target": "t"})
    assert sparse.rig is None
    assert sparse.to_json() == {"format": "microcal.run/1", "target": "t"}


def test_results_round_trip_and_keep_future_keys(tmp_path):
    path = tmp_path / "results.json"
    update_results(path, {
        "stereo": {"top": {"rms_px": 0.1, "model": "pinhole"}},
        "acquisition": {"poses": 3, "stored": 2, "mean_settle_s": 1.0,
                        "failed": [{"pose": 2, "reason": "timeout"}]},
        "pose_accuracy": {"truth": {"matrix": {"mean_ap_p_um": float("nan"), "max_ap_p_um": 2.0,
                                               "poses": [], "vap_um": 0.5},
                                    "closed_loop": {"mean_ap_p_um": 0.3, "iterations_mean": 2.0}}},
        "devices": {"m2": {"timing": {}}},
        "future_section": {"figure": 1.0},
    })  # fmt: skip
    update_results(path, {"pose_accuracy": {"truth": {"optimal": {"mean_ap_p_um": 1.0}}}})
    results = read_results(path)
    assert isinstance(results, Results)
    assert results.acquisition is not None
    assert results.acquisition.failed[0].reason == "timeout"
    assert results.pose_accuracy is not None
    truth = results.pose_accuracy["truth"]
    assert set(truth) == {"matrix", "closed_loop", "optimal"}
    assert truth["matrix"].mean_ap_p_um is None  # NaN is written as null
    assert truth["matrix"].vap_um == 0.5
    assert truth["matrix"].has_vap
    assert not truth["optimal"].has_vap
    assert truth["closed_loop"].model_extra == {"iterations_mean": 2.0}  # kept, not typed
    assert results.devices is not None
    assert results.devices["m2"].timing == {}
    assert results.model_extra == {"future_section": {"figure": 1.0}}
    assert results.to_json() == json.loads(path.read_text()) == load_results(path)


def test_malformed_results_name_the_key(tmp_path):
    path = tmp_path / "results.json"
    path.write_text(json.dumps({"format": "microcal.results/1",
                                "acquisition": {"poses": "many", "stored": 1}}))  # fmt: skip
    with pytest.raises(FormatError, match=r"results\.json: acquisition\.poses: Input should be"):
        load_results(path)


@pytest.mark.parametrize(
    ("fmt", "match"),
    [
        ("microcal.results/2", r"microcal\.results version '2' is not one this microcal \(.+\) reads; it reads version 1"),
        ("microcal.results/", r"microcal\.results version '' is not one"),
        ("microcal.cameras/1", r"expected format 'microcal\.results/1', got 'microcal\.cameras/1'"),
        (None, r"expected format 'microcal\.results/1', got None"),
    ],
)  # fmt: skip
def test_an_unknown_version_is_one_clear_message(tmp_path, fmt, match):
    path = tmp_path / "results.json"
    path.write_text(json.dumps({} if fmt is None else {"format": fmt}))
    with pytest.raises(FormatError, match=match):
        read_results(path)


def test_a_reader_of_several_versions_names_them(tmp_path):
    path = tmp_path / "x.json"
    path.write_text(json.dumps({"format": "microcal.thing/3"}))
    with pytest.raises(FormatError, match="it reads version 1, 2"):
        read_versioned_json(path, ("microcal.thing/1", "microcal.thing/2"))
    path.write_text("[1, 2]")
    with pytest.raises(FormatError, match="expected a JSON object, got list"):
        read_versioned_json(path, ("microcal.thing/1",))


def test_the_file_schema_base_keeps_extras_and_refuses_nan():
    class Thing(FileSchema):
        value: float

    thing = Thing.model_validate({"value": 1.0, "later": [1]})
    assert thing.model_dump() == {"value": 1.0, "later": [1]}
    with pytest.raises(ValueError, match="finite"):
        Thing.model_validate({"value": float("nan")})
