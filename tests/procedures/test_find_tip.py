"""Finding a new tool: a tip anywhere in the field, or outside it, is found and centred; none
leaves the manipulator where it began."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.procedures.find_tip import find_tip
from microcal.sim.tools import (
    Background,
    Optics,
    Tool,
    ToolPlacement,
    ToolScene,
    microscope_camera,
    tool_axis,
    tool_image,
)
from microcal.vision.tip_target import parse_tip

CAMERA = microscope_camera(0.65)  # 256 x 256 px, 166 µm wide, centred on {G}'s origin


class Rig:
    """A needle on an ideal three-axis stage (its joints skewed against the image a little)
    under the microscope; ``present=False``: no tool mounted."""

    def __init__(self, tip_start_um, present: bool = True) -> None:
        self.joints = np.zeros(3)
        self.tip0 = np.asarray(tip_start_um, dtype=np.float64)
        self.present = present
        self.rng = np.random.default_rng(0)
        a = np.radians(4.0)
        self.M = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])

    def tip_um(self):
        return self.tip0 + self.M @ self.joints

    def move_to(self, joints):
        self.joints = np.asarray(joints, dtype=np.float64).copy()

    def position(self):
        return self.joints.copy()

    def grab(self):
        tools = [ToolPlacement(Tool("needle", taper_deg=12, tip_um=2.0), self.tip_um(),
                               tool_axis(10.0, 30.0))] if self.present else []  # fmt: skip
        scene = ToolScene(tools, Optics(0.3, focus_depth_um=1000.0), Background("plain", seed=1))
        return tool_image(CAMERA, scene, self.rng)[0]


def _search(rig: Rig):
    return find_tip(rig.move_to, rig.position, rig.grab, parse_tip("tip:needle"),
                    image_size_px=CAMERA.image_size_px, field_um=166.0)  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("tip", [[-60.0, 50.0, 0.0], [40.0, -30.0, 0.0], [283.0, 0.0, 0.0]])
def test_a_tool_in_the_field_or_200_um_outside_it_is_found_and_centred(tip):
    rig = Rig(tip)
    found = _search(rig)
    assert found.found, found.reason
    truth = CAMERA.project(rig.tip_um())[0]
    centre = (np.array(CAMERA.image_size_px) - 1) / 2
    assert np.hypot(*(truth - centre)) < 1.5
    assert np.hypot(*(found.apex_px - truth)) < 0.3
    np.testing.assert_allclose(found.jacobian_px_per_um[:, 0], (rig.M @ [1.0, 0, 0])[:2]
                               * [1 / 0.65, -1 / 0.65], atol=0.02)  # fmt: skip


def test_no_tool_refuses_and_leaves_the_manipulator_where_it_began():
    rig = Rig([0.0, 0.0, 0.0], present=False)
    rig.joints = np.array([5.0, 6.0, 7.0])
    found = _search(rig)
    assert not found.found
    assert "no tool's tip within 400 µm" in found.reason
    np.testing.assert_array_equal(rig.joints, [5.0, 6.0, 7.0])
