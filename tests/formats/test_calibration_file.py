"""calibration.json: round trip, validation on load, atomic writes, MATLAB export."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io

from microcal import FormatError, InputError, load_calibration
from microcal.formats.calibration_file import (
    Calibration,
    ManipulatorCalibration,
    export_mat,
    write_calibration,
)
from microcal.formats.measurements import read_measurements, write_measurements
from microcal.formats.provenance import provenance
from microcal.procedures.identification import identify
from microcal.sim.synthetic_run import synthetic_run


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    run = synthetic_run(170, seed=11)
    csv = tmp_path_factory.mktemp("run") / "measurements.csv"
    write_measurements(csv, run.d_um, run.measured_um)
    ident = identify(run.d_um, run.measured_um, "polynomial")
    m = ManipulatorCalibration("m1", ident.model, ident.validation)
    return Calibration({"m1": m}, provenance=provenance({"measurements": csv}))


def test_round_trip(tmp_path, calibration):
    path = write_calibration(tmp_path / "calibration.json", calibration)
    back = load_calibration(path)
    m = back.manipulator("m1")
    assert back.manipulator() is m
    u = np.array([[100.0, 2000.0, 300.0]])
    np.testing.assert_array_equal(m.predict_um(u), calibration.manipulator("m1").predict_um(u))
    raw = json.loads(path.read_text())
    assert raw["format"] == "microcal.calibration/1"
    v = raw["manipulators"]["m1"]["validation"]
    assert {"n_fit", "n_validate", "mean_um", "std_um", "max_um", "rms_um"} <= set(v)
    model = raw["manipulators"]["m1"]["model"]
    assert {"kind", "inputs", "terms", "coefficients", "covariance"} <= set(model)
    assert len(raw["provenance"]["inputs"]["measurements"]["sha256"]) == 64


def test_unknown_manipulator_is_named(tmp_path, calibration):
    with pytest.raises(InputError, match=r"manipulator 'm7' is not calibrated; it has \['m1'\]"):
        calibration.manipulator("m7")


def _corrupt(tmp_path, calibration, edit):
    path = write_calibration(tmp_path / "c.json", calibration)
    raw = json.loads(path.read_text())
    edit(raw)
    path.write_text(json.dumps(raw))
    return path


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda r: r.update(format="microcal.calibration/9"), r"microcal.calibration version '9' is not one this microcal \(.*\) reads; it reads version 1"),
        (lambda r: r.update(format="microcal.cameras/1"), "expected format 'microcal.calibration/1', got 'microcal.cameras/1'"),
        (lambda r: r.pop("manipulators"), "manipulators: Field required"),
        (lambda r: r["manipulators"]["m1"]["model"].update(kind="spline"), r"manipulators.m1.model.kind: Input should be 'matrix' or 'polynomial'"),
        (lambda r: r["manipulators"]["m1"]["model"]["coefficients"].pop(), r"manipulators.m1.model: expected coefficients \(3, 10\)"),
        (lambda r: r["manipulators"]["m1"]["validation"].update(mean_um="big"), "manipulators.m1.validation.mean_um: Input should be a valid number"),
        (lambda r: r["manipulators"]["m1"]["model"]["coefficients"][0].__setitem__(0, "NaN"), "manipulators.m1.model.coefficients.0.0"),
    ],
)  # fmt: skip
def test_malformed_files_name_the_key(tmp_path, calibration, edit, match):
    path = _corrupt(tmp_path, calibration, edit)
    with pytest.raises(FormatError, match=match):
        load_calibration(path)


def test_not_json_and_missing(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(FormatError, match="not a JSON file"):
        load_calibration(bad)
    with pytest.raises(FormatError, match="no such file"):
        load_calibration(tmp_path / "none.json")


def test_provenance_hashes_each_input(tmp_path):
    import hashlib

    from microcal.formats.calibration_file import sha256_file
    from microcal.formats.hashing import sha256_file as the_one

    data = tmp_path / "m.csv"
    data.write_bytes(b"pose\n" * 300_000)  # more than one read block
    assert sha256_file is the_one
    prov = provenance({"measurements": data}, command="fit")
    assert prov["inputs"]["measurements"] == {
        "path": str(data),
        "sha256": hashlib.sha256(data.read_bytes()).hexdigest(),
    }
    assert prov["command"] == "fit"


def test_write_is_atomic(tmp_path, calibration, monkeypatch):
    path = write_calibration(tmp_path / "calibration.json", calibration)
    before = path.read_bytes()

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("os.replace", boom)
    with pytest.raises(FormatError, match=r"cannot be written \(disk full\); nothing was replaced"):
        write_calibration(path, calibration)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["calibration.json"]


def test_mat_export(tmp_path, calibration):
    path = export_mat(tmp_path / "calibration.mat", calibration)
    data = scipy.io.loadmat(path, simplify_cells=True)
    m1 = data["m1"]
    np.testing.assert_allclose(m1["coefficients"], calibration.manipulator("m1").model.coefficients)
    assert list(m1["terms"])[:3] == ["dx", "dy", "dz"]
    assert m1["validation"]["n_fit"] == 110


def test_measurements_csv_round_trip_and_errors(tmp_path):
    d = np.arange(12.0).reshape(4, 3)
    p = d + 0.5
    path = write_measurements(
        tmp_path / "m.csv",
        d,
        p,
        status=["ok", "failed", "ok", "ok"],
        reason=["", "no chessboard in top", "", ""],
    )
    meas = read_measurements(path)
    assert meas.pose.tolist() == [1, 3, 4]
    assert meas.n_failed == 1
    assert meas.failed_reasons == {2: "no chessboard in top"}
    np.testing.assert_allclose(meas.p_um, p[[0, 2, 3]])
    text = path.read_text().replace("pose,status", "pose,state")
    path.write_text(text)
    with pytest.raises(FormatError, match=r"missing column\(s\) \['status'\]"):
        read_measurements(path)
    path.write_text("pose,status,dx_um,dy_um,dz_um,x_um,y_um,z_um\n1,ok,1,2,x,4,5,6\n")
    with pytest.raises(FormatError, match="line 2: dz_um = 'x' is not a number"):
        read_measurements(path)


def test_cameras_are_typed_models_and_a_malformed_one_fails_on_load(tmp_path, calibration):
    from dataclasses import replace

    from microcal.thesis.cameras import thesis_cameras

    top, side = thesis_cameras()
    cams = {c.name: {"model": "pinhole", "image_size_px": list(c.image_size_px), "K": c.K.tolist(),
                     "dist": c.dist.tolist(), "R": c.R.tolist(), "t_um": c.t_um.tolist()}
            for c in (top, side)}  # fmt: skip
    path = write_calibration(tmp_path / "calibration.json", replace(calibration, cameras=cams))
    models = load_calibration(path).camera_models()
    assert set(models) == {"top", "side"}
    np.testing.assert_array_equal(models["top"].P, top.P)
    raw = json.loads(path.read_text())
    raw["cameras"]["side"]["K"] = [[1.0, 0.0]]
    path.write_text(json.dumps(raw))
    with pytest.raises(FormatError, match=r"calibration.json.*side"):
        load_calibration(path)


def test_a_tool_centre_is_carried_and_read_back(tmp_path, calibration):
    from microcal.formats.calibration_file import tool_centre_of
    from microcal.vision.tool_centre import fit_tool_centre

    rng = np.random.default_rng(1)
    board = rng.uniform(0, 8000, (6, 3))
    tool = fit_tool_centre(board, board + [35.0, -12.0, 120.0] + rng.normal(0, 0.2, (6, 3)))
    m = calibration.manipulator("m1")
    with_tool = ManipulatorCalibration("m1", m.model, m.validation, {"tool_centre": tool.to_json()})
    path = write_calibration(tmp_path / "c.json", Calibration({"m1": with_tool}))
    back = tool_centre_of(load_calibration(path).manipulator("m1"))
    assert back is not None
    np.testing.assert_allclose(back.offset_um, tool.offset_um)
    np.testing.assert_allclose(back.cov_um2, tool.cov_um2)
    assert tool_centre_of(m) is None
    raw = json.loads(path.read_text())
    raw["manipulators"]["m1"]["tool_centre"]["cov_um2"][1][1] = -1.0
    path.write_text(json.dumps(raw))
    with pytest.raises(FormatError, match=r"manipulators.m1.tool_centre.cov_um2"):
        load_calibration(path)
