"""A one-camera microscope's rig file: its [microscope] names Micro-Manager's X-Y stage and
focus devices; one camera without a focus device is refused in one line."""

from __future__ import annotations

import pytest

from microcal.devices.rig_spec import MMStageSpec
from microcal.errors import FormatError
from microcal.formats.rig_file import load_rig, rig_from_record
from microcal.workflows.rigs import open_rig

ONE_CAMERA = """driver = "hardware"
[micromanager]
python_devices = "support.mm_devices:load"
[manipulator]
kind = "micromanager"
xy_stage = "XY"
limits_um = { x = [0, 8000], y = [0, 8000] }
[cameras.scope]
kind = "micromanager"
device = "TopCam"
"""
MICROSCOPE = """[microscope]
xy_stage = "XY"
focus = "Z"
limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }
"""
REFUSAL = (
    "cameras: expected two cameras or more (e.g. [cameras.top], [cameras.side]), or one "
    'camera with the microscope\'s focus device: add [microscope] with focus = "ZStage" (its '
    "Micro-Manager label), xy_stage and limits_um"
)


@pytest.mark.parametrize(
    "extra",
    ["", '[microscope]\nxy_stage = "XY"\nlimits_um = { x = [0, 8000], y = [0, 8000] }\n'],
    ids=["no microscope", "microscope without focus"],
)
def test_one_camera_without_a_focus_device_is_one_line(tmp_path, extra):
    path = tmp_path / "scope.toml"
    path.write_text(ONE_CAMERA + extra)
    with pytest.raises(FormatError) as exc:
        load_rig(str(path))
    assert str(exc.value) == f"{path}: {REFUSAL}"


def test_the_microscope_table_names_the_stage_and_the_focus(tmp_path):
    path = tmp_path / "scope.toml"
    path.write_text(ONE_CAMERA + MICROSCOPE)
    spec = load_rig(str(path))
    assert spec.microscope == MMStageSpec("XY", {"x": (0, 8000), "y": (0, 8000), "z": (0, 4800)},
                                          focus="Z")  # fmt: skip
    record = spec.to_dict()
    assert record["microscope"]["focus"] == "Z"
    assert record["microscope"]["xy_stage"] == "XY"
    assert rig_from_record(record, "run.json") == spec  # a resumed run reads it back
    path.write_text(ONE_CAMERA + MICROSCOPE.replace("focus =", "fokus ="))
    with pytest.raises(FormatError, match=r"microscope\.fokus: not a setting \(did you mean"):
        load_rig(str(path))


def test_the_microscope_opens_as_three_joints_and_closes_with_the_rig(tmp_path):
    pytest.importorskip("pymmcore_plus", reason="needs pymmcore-plus (pip install 'microcal[mm]')")
    path = tmp_path / "scope.toml"
    path.write_text(ONE_CAMERA + MICROSCOPE)
    rig = open_rig(load_rig(str(path)))
    try:
        scope = rig.microscope
        assert scope is not None
        assert scope.n_axes == 3
        assert rig.description["microscope"] == "Micro-Manager XY + Z"
        scope.move_to_um([100.0, 200.0, 30.0])
        scope.wait_until_stopped(rig.clock)
        assert scope.position_um().tolist() == pytest.approx([100.0, 200.0, 30.0])
    finally:
        rig.close()
    assert scope.closed
