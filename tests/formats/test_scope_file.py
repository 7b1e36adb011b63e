"""The scope file: one set per objective; a second objective leaves the first as it was; a
name the file does not hold is one line naming the ones it does."""

from __future__ import annotations

import json
import threading

import pytest

from microcal.errors import FormatError, InputError
from microcal.formats.scope_file import load_objective, objective_names, write_objective


def _set(pixel_um: float) -> dict:
    return {
        "pixel_size_affine": [-pixel_um, 0.001, 0.0, 0.002, pixel_um, 0.0],
        "pixel_size_um": pixel_um,
        "rotation_deg": 179.5,
        "distortion": {"model": "radial2", "k": [1e-3, 0.0]},
        "focus": {"angle_deg": 0.5},
        "anything_else": [1, 2],  # a later microcal's key is kept
    }


def test_two_objectives_in_one_file_each_chosen_by_name(tmp_path):
    path = tmp_path / "scope.json"
    write_objective(path, "40x", _set(0.1625), {"software": "x"})
    first = json.loads(path.read_text())["objectives"]["40x"]
    write_objective(path, "10x", _set(0.65))
    raw = json.loads(path.read_text())
    assert raw["format"] == "microcal.scope/1"
    assert raw["objectives"]["40x"] == first  # untouched by the second objective
    assert objective_names(path) == ["10x", "40x"]
    assert load_objective(path, "10x")["pixel_size_um"] == 0.65
    assert load_objective(path, "40x")["pixel_size_affine"][0] == -0.1625
    assert load_objective(path, "40x")["anything_else"] == [1, 2]
    write_objective(path, "40x", _set(0.16))  # a new calibration replaces its own set only
    assert load_objective(path, "40x")["pixel_size_um"] == 0.16
    assert load_objective(path, "10x")["pixel_size_um"] == 0.65


def test_an_objective_not_in_the_file_is_one_line_naming_those_that_are(tmp_path):
    path = tmp_path / "scope.json"
    write_objective(path, "10x", _set(0.65))
    write_objective(path, "40x", _set(0.1625))
    with pytest.raises(InputError) as exc:
        load_objective(path, "20x")
    assert str(exc.value) == (
        f"objective '20x' is not in {path}; it holds 10x, 40x (calibrate it with microcal "
        "scope-calibrate --objective NAME)"
    )


@pytest.mark.parametrize("name", ["", "40x/oil", "../x", "a" * 41, "40 x"])
def test_a_bad_objective_name_is_refused_and_nothing_is_written(tmp_path, name):
    path = tmp_path / "scope.json"
    with pytest.raises(InputError, match=r"^--objective .*: expected a name of letters"):
        write_objective(path, name, _set(0.65))
    assert not path.exists()


def test_a_foreign_file_or_a_bad_set_is_refused_and_left_alone(tmp_path):
    path = tmp_path / "scope.json"
    path.write_text('{"format": "microcal.calibration/1", "manipulators": {}}')
    before = path.read_text()
    with pytest.raises(FormatError, match=r"expected format 'microcal\.scope/1'"):
        write_objective(path, "40x", _set(0.65))
    assert path.read_text() == before
    bad = _set(0.65) | {"pixel_size_affine": [1.0, 2.0]}
    with pytest.raises(FormatError, match=r"^objective 40x: pixel_size_affine: "):
        write_objective(tmp_path / "new.json", "40x", bad)
    assert not (tmp_path / "new.json").exists()


def test_objectives_written_at_once_all_land(tmp_path):
    path = tmp_path / "scope.json"
    names = [f"{m}x" for m in (4, 10, 20, 40, 60, 100)]
    threads = [threading.Thread(target=write_objective, args=(path, n, _set(6.5 / int(n[:-1]))))
               for n in names]  # fmt: skip
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert objective_names(path) == sorted(names)
