"""A tool carried beside the board on one end-effector (the thesis's gripper: a board glued on
it and the jaw that does the work).

The cameras see both: the board where the end-effector is (its inner-corner centroid at the
end-effector's true position, as without a tool) and the tool, its tip point at a fixed offset
in the board's frame, ``tip = p + R_board @ offset_um``, its shank along a fixed direction.
That offset is the simulator's truth of the tool-centre point
(:mod:`microcal.vision.tool_centre`). A changed tool (a new pipette) is the same board with
another offset.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..vision.tip_target import TipTarget
from .render import Placement
from .tools import Tool, ToolPlacement, tool_axis

__all__ = ["CarriedTool", "carried_tool"]


@dataclass(frozen=True)
class CarriedTool:
    """A tool fixed to the board's end-effector.

    Attributes
    ----------
    placement : ToolPlacement
        The tool, its shank's direction in {G} (its ``tip_um`` is replaced at each frame).
    offset_um : (3,) float
        The tip point in the board's frame (origin at the board's inner-corner centroid,
        axes the board's), µm: the tool-centre point's truth.
    """

    placement: ToolPlacement
    offset_um: FloatArray

    def at(self, board: Placement) -> ToolPlacement:
        """The tool where the board ``board`` is."""
        centre = board.R @ board.target.centre_um + board.t_um
        return dataclasses.replace(self.placement, tip_um=centre + board.R @ self.offset_um)


def carried_tool(
    target: TipTarget,
    offset_um: FloatArray,
    elevation_deg: float,
    azimuth_deg: float,
) -> CarriedTool:
    """The simulated tool of a tip spec (a jaw for ``any``; a taper of 10 degrees and a 1 µm
    end where the spec gives none), ``offset_um`` (3,) from the board, its shank rising
    ``elevation_deg`` above {G}'s x-y plane towards ``azimuth_deg`` (from +x towards +y)."""
    tool = Tool(
        "jaw" if target.kind == "any" else target.kind,
        taper_deg=target.taper_deg or 10.0,
        tip_um=target.tip_um or 1.0,
    )
    axis = tool_axis(elevation_deg, azimuth_deg)
    offset = np.asarray(offset_um, dtype=np.float64).reshape(3)
    return CarriedTool(ToolPlacement(tool, np.zeros(3), axis), offset)
