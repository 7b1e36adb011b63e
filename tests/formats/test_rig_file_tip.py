"""A rig file takes a tool's tip wherever it takes the end-effector's board (the hardware
rig's ``board``, a further device's ``board``, a simulated rig's ``[overrides] board``); a
malformed tip spec is one line naming the key and the fix."""

from __future__ import annotations

import pytest

from microcal.devices.rig_spec import HardwareRigSpec, SimRigSpec
from microcal.errors import FormatError, InputError
from microcal.formats.rig_file import load_rig, rig_from_record
from microcal.vision.effector_target import parse_effector_target
from microcal.vision.targets import Target
from microcal.vision.tip_target import TipTarget

RIG = """
driver = "hardware"
board = "BOARD"
[manipulator]
kind = "smaract-mcs2"
address = "127.0.0.1"
channels = { x = 0, y = 1, z = 2 }
limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }
[cameras.top]
kind = "aravis"
address = "127.0.0.1"
[cameras.side]
kind = "aravis"
address = "127.0.0.2"
"""

SIM = """
driver = "sim"
preset = "thesis-tip"
seed = 0
[overrides]
board = "BOARD"
"""


@pytest.mark.parametrize("spec", ["tip", "tip:pipette", "tip:needle:20:5", "tip:jaw:30:40",
                                  "TIP:Needle", "chessboard:4x3:400"])  # fmt: skip
def test_a_hardware_rig_carries_a_tip_or_a_board(tmp_path, spec):
    path = tmp_path / "rig.toml"
    path.write_text(RIG.replace("BOARD", spec))
    rig = load_rig(str(path))
    assert isinstance(rig, HardwareRigSpec)
    assert rig.board == spec
    record = rig.to_dict()
    assert record["board"] == spec
    assert rig_from_record(record, "run.json") == rig  # a resume reads it back
    target = parse_effector_target(rig.board)
    assert isinstance(target, TipTarget if spec.lower().startswith("tip") else Target)


def test_a_further_device_carries_a_tip_of_its_own(tmp_path):
    path = tmp_path / "rig.toml"
    extra = ('[manipulators.m2]\nkind = "smaract-mcs2"\naddress = "127.0.0.3"\n'
             'channels = { x = 0, y = 1, z = 2 }\n'
             'limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }\n'
             'board = "tip:pipette:10:1"\n')  # fmt: skip
    path.write_text(RIG.replace("BOARD", "tip:needle:20:5") + extra)
    rig = load_rig(str(path))
    assert isinstance(rig, HardwareRigSpec)
    assert rig.board_of("m1") == "tip:needle:20:5"
    assert rig.board_of("m2") == "tip:pipette:10:1"


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("tip:needel:20:5", r"board: target 'tip:needel:20:5': expected tip\[:KIND\]\[:TAPER_DEG\]"
                            r"\[:TIP_UM\] .*got kind 'needel'; did you mean tip:needle:20:5\?"),
        ("tip:pipet", r"board: .*; did you mean tip:pipette\?"),
        ("needle:20:5", r"board: target 'needle:20:5': a tool's tip is written tip\[:KIND\]"
                        r"\[:TAPER_DEG\]\[:TIP_UM\]; did you mean tip:needle:20:5\?"),
        ("pipette", r"board: .*did you mean tip:pipette\?"),
        ("tip:needle:200:5", r"board: target 'tip:needle:200:5': expected a taper of 0\.5 to 90 "
                             r"degrees, got 200"),
        ("tip:needle:20:0", r"board: .*expected a tip of 0 to 1000 µm, got 0"),
        ("tip:needle:x", r"board: .*expected tip\[:KIND\].*e\.g\. tip:pipette:10:1"),
        ("tip:knife", r"board: .*with KIND pipette, needle, jaw or any, got kind 'knife'"),
    ],
)  # fmt: skip
def test_a_malformed_tip_is_one_line_naming_the_key_and_the_fix(tmp_path, spec, message):
    for text, key in ((RIG, "board"), (SIM, "overrides.board")):
        path = tmp_path / "rig.toml"
        path.write_text(text.replace("BOARD", spec))
        with pytest.raises(FormatError, match=message) as info:
            load_rig(str(path))
        line = str(info.value)
        assert len(line.splitlines()) == 1
        assert line.startswith(f"{path}: {key}: ")


def test_the_calibration_target_is_a_board_not_a_tip(tmp_path):
    path = tmp_path / "rig.toml"
    stage = ('[target_stage]\nkind = "smaract-mcs2"\naddress = "127.0.0.3"\n'
             'channels = { x = 0, y = 1, z = 2 }\n'
             'limits_um = { x = [0, 1], y = [0, 1], z = [0, 1] }\n')  # fmt: skip
    path.write_text('calibration_target = "tip:needle"\n' + RIG.replace("BOARD", "tip") + stage)
    with pytest.raises(FormatError, match=r"calibration_target: target 'tip:needle': a tool's "
                                          r"tip, not a board"):  # fmt: skip
        load_rig(str(path))


def test_a_simulated_rig_takes_a_tip_override(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(SIM.replace("BOARD", "tip:needle:20:5"))
    rig = load_rig(str(path))
    assert isinstance(rig, SimRigSpec)
    assert rig.overrides == {"board": "tip:needle:20:5"}


def test_a_spec_built_in_python_checks_its_devices_tips(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(RIG.replace("BOARD", "tip:needle"))
    rig = load_rig(str(path))
    assert isinstance(rig, HardwareRigSpec)
    m2 = {"m2": rig.manipulator}
    assert HardwareRigSpec(rig.manipulator, rig.cameras, "tip", manipulators=m2,
                           boards={"m2": "tip:jaw"}).board_of("m2") == "tip:jaw"  # fmt: skip
    with pytest.raises(InputError, match=r"did you mean tip:needle\?"):
        HardwareRigSpec(rig.manipulator, rig.cameras, "tip", manipulators=m2,
                        boards={"m2": "tip:neddle"})  # fmt: skip
