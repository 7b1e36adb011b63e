"""The lines ``microcal tool-centre`` and ``microcal find-tip`` print."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..procedures.find_tip import TipSearch
    from ..procedures.tool_centre import CarriedPose
    from ..vision.tool_centre import ToolCentre

__all__ = ["tip_search_lines", "tool_centre_lines"]


def _xyz(v: np.ndarray, digits: int = 2) -> str:
    return "(" + ", ".join(f"{x:+.{digits}f}" for x in v) + ")"


def _pm(cov_um2: np.ndarray) -> str:
    """``value ± a, b, c``'s right side: the standard deviations of a covariance."""
    return ", ".join(f"{x:.2f}" for x in np.sqrt(np.diagonal(cov_um2)))


def tool_centre_lines(tool: ToolCentre, poses: Sequence[CarriedPose]) -> list[str]:
    """The offset with its standard deviation, and each failed pose's reason."""
    out = [f"pose {i + 1}: not used: {p.reason}" for i, p in enumerate(poses) if p.status != "ok"]
    out.append(f"tool centre in the board's frame: {_xyz(tool.offset_um)} ± "
               f"{_pm(tool.cov_um2)} µm from {tool.poses} of {len(poses)} poses "
               f"(residual RMS {tool.rms_um:.2f} µm)")  # fmt: skip
    if tool.board_R is not None:
        out.append(f"tip from the board's point in {{G}}: {_xyz(tool.offset_g_um)} ± "
                   f"{_pm(tool.offset_g_cov_um2)} µm")  # fmt: skip
    return out


def tip_search_lines(s: TipSearch, camera: str, seen_px: Mapping[str, np.ndarray]) -> list[str]:
    """Where the tip is (joints, and its apex in each camera that sees it), or why not."""
    joints = ", ".join(f"{v:.1f}" for v in s.joints_um)
    if not s.found:
        return [f"no tip found: {s.reason}; the manipulator is back where it began "
                f"(joints {joints} µm)"]  # fmt: skip
    out = [f"tip centred in {camera}: apex ({s.apex_px[0]:.1f}, {s.apex_px[1]:.1f}) px "
           f"after {s.moves} moves; joints ({joints}) µm"]  # fmt: skip
    for name, apex in seen_px.items():
        if name != camera:
            out.append(f"  {name}: apex ({apex[0]:.1f}, {apex[1]:.1f}) px")
    return out
