"""A tool carried beside the board: the simulator renders both on one end-effector."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.sim import platform
from microcal.sim.carried_tool import carried_tool
from microcal.sim.render import Placement
from microcal.sim.tools import ToolPlacement
from microcal.vision.tip_target import parse_tip


def test_the_gripper_preset_shows_the_board_and_the_jaw_at_its_offset():
    plat = platform("thesis-gripper", seed=0)
    scene = plat.scene
    seen = scene(0.0)
    assert [type(p) for p in seen] == [Placement, ToolPlacement]
    board, tool = seen
    centre = board.R @ board.target.centre_um + board.t_um
    np.testing.assert_allclose(tool.tip_um - centre, plat.config.tool_offset_um, atol=1e-9)
    assert tool.tool.kind == "jaw"


def test_a_carried_tool_follows_the_board_and_turns_with_it():
    carried = carried_tool(parse_tip("tip:needle:20:5"), np.array([100.0, 0.0, 0.0]), 10.0, 0.0)
    from microcal.vision.targets import parse_target

    c, s = np.cos(0.3), np.sin(0.3)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    target = parse_target("chessboard:4x3:400")
    board = Placement(target, R, np.array([10.0, 20.0, 30.0]))
    tip = carried.at(board).tip_um
    np.testing.assert_allclose(tip, R @ target.centre_um + [10, 20, 30] + R @ [100.0, 0, 0])


@pytest.mark.parametrize(
    ("overrides", "says"),
    [
        ({"tool": "chessboard:4x3:400"}, "expected a tool's tip spec"),
        ({"tool": "tip:jaw", "board": "tip:needle"}, "beside a board"),
        ({"tool_offset_um": [1.0, float("nan"), 0.0]}, "three finite numbers"),
    ],
)
def test_a_carried_tool_that_cannot_be_is_one_line(overrides, says):
    with pytest.raises(InputError, match=says):
        platform("thesis-gripper", seed=0, overrides=overrides)
