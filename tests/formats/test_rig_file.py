"""The documented rig files parse into typed specs whose records are run.json's; mistakes are one
line naming the key; the simulator's can be checked with --dry-run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.devices.rig_spec import (
    AravisCameraSpec,
    HardwareRigSpec,
    MCS2Spec,
    MicroManagerSpec,
    MMCameraSpec,
    MMStageSpec,
    SimRigSpec,
)
from microcal.errors import FormatError, InputError
from microcal.formats.rig_file import load_rig

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "rigs"
LIMITS = {"x": [0.0, 8000.0], "y": [0.0, 8000.0], "z": [0.0, 4800.0]}

# The records run.json files hold (as load_rig's dicts gave them before the typed specs):
# a resumed run compares the new rig's record with the stored one.
SMARACT_GIGE_RECORD = {
    "driver": "hardware",
    "board": "chessboard:4x3:400",
    "manipulator": {"kind": "smaract-mcs2", "limits_um": LIMITS, "address": "192.168.1.200",
                    "port": 55551, "channels": {"x": 0, "y": 1, "z": 2}, "timeout_s": 2.0,
                    "reconnects": 2, "speed_um_s": 2000.0},
    "cameras": {
        "top": {"kind": "aravis", "address": "192.168.1.11", "exposure_ms": 10.0,
                "pixel_format": "Mono8", "timeout_s": 2.0, "pixel_size_um": 3.45},
        "side": {"kind": "aravis", "address": "192.168.1.12", "exposure_ms": 10.0,
                 "pixel_format": "Mono8", "timeout_s": 2.0, "pixel_size_um": 3.45},
    },
}  # fmt: skip
MICROMANAGER_RECORD = {
    "driver": "hardware",
    "board": "chessboard:4x3:400",
    "manipulator": {"kind": "micromanager", "limits_um": LIMITS, "port": 55551, "timeout_s": 2.0,
                    "reconnects": 2, "xy_stage": "XYStage", "focus": "ZStage"},
    "cameras": {
        "top": {"kind": "micromanager", "device": "TopCamera", "exposure_ms": 10.0,
                "pixel_format": "Mono8", "timeout_s": 2.0, "pixel_size_um": 3.45},
        "side": {"kind": "micromanager", "device": "SideCamera", "exposure_ms": 10.0,
                 "pixel_format": "Mono8", "timeout_s": 2.0, "pixel_size_um": 3.45},
    },
    "micromanager": {"config": str(EXAMPLES / "MMConfig_rig.cfg")},
}  # fmt: skip
SIM_FAULTS_RECORD = {
    "driver": "sim",
    "preset": "thesis",
    "seed": 3,
    "overrides": {
        "top.faults.drop_rate": 0.05,
        "top.faults.occlusion_rate": 0.02,
        "manipulator.faults.timeout_rate": 0.01,
    },
}

SIM_3CAM_RECORD = {
    "driver": "sim",
    "preset": "thesis-3cam",
    "seed": 5,
    "overrides": {"front.faults.drop_rate": 0.05},
}

MCS2_RIG = """
driver = "hardware"
[manipulator]
kind = "smaract-mcs2"
address = "127.0.0.1"
channels = { x = 0, y = 1, z = 2 }
limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }
[cameras.top]
kind = "aravis"
address = "127.0.0.1"
region_px = [0, 0, 320, 240]
[cameras.side]
kind = "aravis"
address = "127.0.0.2"
exposure_ms = 5
"""


@pytest.mark.parametrize(
    ("name", "record"),
    [
        ("smaract-gige.toml", SMARACT_GIGE_RECORD),
        ("micromanager.toml", MICROMANAGER_RECORD),
        ("sim-faults.toml", SIM_FAULTS_RECORD),
        ("sim-3cam.toml", SIM_3CAM_RECORD),
    ],
)
def test_example_rig_files_parse_into_specs_with_the_run_json_record(name, record):
    rig = load_rig(str(EXAMPLES / name))
    assert rig.to_dict() == record
    assert json.loads(json.dumps(rig.to_dict())) == record  # as stored and read back


def test_example_specs_are_typed():
    rig = load_rig(str(EXAMPLES / "smaract-gige.toml"))
    assert isinstance(rig, HardwareRigSpec)
    assert isinstance(rig.manipulator, MCS2Spec)
    assert rig.manipulator.axes == ("x", "y", "z")
    assert rig.manipulator.limits_array().tolist() == list(LIMITS.values())
    assert all(isinstance(c, AravisCameraSpec) for c in rig.cameras.values())
    assert list(rig.cameras) == ["top", "side"]
    assert rig.cameras["top"].exposure_s == pytest.approx(0.01)
    mm = load_rig(str(EXAMPLES / "micromanager.toml"))
    assert isinstance(mm, HardwareRigSpec)
    assert isinstance(mm.manipulator, MMStageSpec)
    assert isinstance(mm.cameras["side"], MMCameraSpec)
    assert mm.uses_micromanager


def test_sim_alone_is_the_default_simulated_platform():
    assert load_rig("sim") == SimRigSpec()
    assert load_rig("sim").to_dict() == {
        "driver": "sim", "preset": "thesis", "seed": 0, "overrides": {}
    }  # fmt: skip


def test_defaults_live_in_the_specs_and_records_are_json(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(MCS2_RIG)
    rig = load_rig(str(path))
    assert isinstance(rig, HardwareRigSpec)
    assert rig == HardwareRigSpec(
        MCS2Spec("127.0.0.1", {"x": 0, "y": 1, "z": 2}, LIMITS),  # type: ignore[arg-type]
        {
            "top": AravisCameraSpec("127.0.0.1", region_px=(0, 0, 320, 240)),
            "side": AravisCameraSpec("127.0.0.2", exposure_ms=5.0),
        },
    )
    m = rig.manipulator
    assert isinstance(m, MCS2Spec)
    assert (m.port, m.timeout_s, m.reconnects, m.speed_um_s) == (55551, 2.0, 2, None)
    assert rig.board == "chessboard:4x3:400"
    record = rig.to_dict()
    assert "exposure_ms" not in record["cameras"]["top"]  # as written: not given
    assert record["cameras"]["top"]["region_px"] == [0, 0, 320, 240]
    assert json.loads(json.dumps(record)) == record  # a resume compares equal records


def test_micromanager_config_path_is_relative_to_the_rig_file():
    rig = load_rig(str(EXAMPLES / "micromanager.toml"))
    assert isinstance(rig, HardwareRigSpec)
    assert rig.micromanager == MicroManagerSpec(config=str(EXAMPLES / "MMConfig_rig.cfg"))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace('region_px = [0, 0, 320, 240]', 'device = "Cam"'),
         r"cameras\.top\.device: not a setting of kind 'aravis' \(its settings: address,"),
        (lambda t: t.replace('address = "127.0.0.1"\nchannels', 'focus = "Z"\nchannels'),
         r"manipulator\.focus: not a setting of kind 'smaract-mcs2'"),
        (lambda t: t.replace('address = "127.0.0.1"\nchannels', 'channels'),
         r"manipulator: smaract-mcs2 needs 'address'"),
        (lambda t: t.replace("exposure_ms = 5", 'pixel_format = "RGB8"'),
         r"cameras\.side\.pixel_format: expected one of Mono8, Mono10"),
        (lambda t: t.replace("[0, 4800]", "[4800, 0]"),
         r"manipulator\.limits_um\.z: expected \[low, high\] with low < high"),
        (lambda t: t.replace("exposure_ms = 5", "exposure_ms = nan"), r"cameras\.side\.exposure_ms"),
        (lambda t: t.split("[cameras.side]")[0], r"cameras: expected two cameras"),
        (lambda t: t + '[target_stage]\nkind = "smaract-mcs2"\naddress = "127.0.0.1"\n'
                       'channels = { x = 3, y = 4, z = 5 }\n'
                       'limits_um = { x = [0, 1], y = [0, 1], z = [0, 1] }\n',
         r"target_stage: give the stage and the target it carries together"),
        (lambda t: 'calibration_target = "dotgrid:40x30:250"\n' + t + '[target_stage]\n'
                   'kind = "smaract-mcs2"\naddress = "127.0.0.1"\nchanels = { x = 3 }\n'
                   'limits_um = { x = [0, 1] }\n',
         r"target_stage\.chanels: not a setting \(did you mean 'channels'"),
        (lambda t: t.replace('kind = "aravis"', 'kind = "micromanager"\ndevice = "C"', 1)
         .replace('address = "127.0.0.1"\nregion_px = [0, 0, 320, 240]\n', ""),
         r"micromanager: Micro-Manager devices need the core"),
    ],
)  # fmt: skip
def test_rig_file_mistakes_are_one_line_naming_the_key(tmp_path, edit, message):
    path = tmp_path / "rig.toml"
    path.write_text(edit(MCS2_RIG))
    with pytest.raises(FormatError, match=message) as info:
        load_rig(str(path))
    assert len(str(info.value).splitlines()) == 1
    assert str(info.value).startswith(f"{path}: ")


def test_specs_built_in_python_check_themselves():
    with pytest.raises(InputError, match=r"limits_um: expected a \[low, high\] for each of"):
        MMStageSpec("XY", {"x": (0.0, 1.0), "y": (0.0, 1.0)}, focus="Z")
    with pytest.raises(InputError, match=r"timeout_s: expected a finite number > 0, got -1"):
        MCS2Spec("host", {"x": 0}, {"x": (0.0, 1.0)}, timeout_s=-1)
    with pytest.raises(InputError, match="micromanager: give exactly one of 'config'"):
        MicroManagerSpec(config="a.cfg", python_devices="m:f")
    with pytest.raises(InputError, match="seed: expected an integer >= 0, got -1"):
        SimRigSpec(seed=-1)


def test_sim_example_dry_run(tmp_path):
    result = CliRunner().invoke(
        app,
        [
            "acquire",
            "--rig",
            str(EXAMPLES / "sim-faults.toml"),
            "--out",
            str(tmp_path / "r"),
            "--poses",
            "40",
            "--dry-run",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "dry run: nothing moved, nothing written" in result.output
    assert not (tmp_path / "r").exists()
