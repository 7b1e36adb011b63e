"""``microcal tool-centre``: measure where a tool's tip sits in its board's frame and write it
into a calibration (a changed tool needs only this, not a new calibration).

The rig's device carries a board (its calibration's target) and a tool. At the ten check
poses of the calibration (:func:`~microcal.procedures.check.planned_check`, approached as the
calibration was made) each camera grabs its frames; the board and the tip are measured
(:func:`~microcal.procedures.tool_centre.measure_carried`) and the offset fitted
(:func:`~microcal.procedures.tool_centre.fit_carried`). The new calibration is the old one
with the device's ``tool_centre`` set (any earlier one replaced), written to a new file:
nothing of the old calibration is lost.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..formats.calibration_file import (
    CALIBRATION_FORMAT,
    Calibration,
    load_calibration,
    write_calibration,
)
from ..formats.json_file import check_json_output
from ..formats.provenance import provenance
from ..procedures.check import planned_check
from ..procedures.tool_centre import CarriedPose, fit_carried, measure_carried
from ..vision.targets import Target, parse_spec
from ..vision.tip_target import TipTarget
from ..vision.tool_centre import ToolCentre
from .station import open_calibrated_rig

__all__ = ["ToolCentreOutcome", "measure_tool_centre"]


@dataclasses.dataclass(frozen=True)
class ToolCentreOutcome:
    """What ``microcal tool-centre`` measured and wrote.

    Attributes
    ----------
    tool : ToolCentre
    poses : list of CarriedPose
        Every pose measured, the failed ones with their reason.
    out : Path
        The calibration written.
    """

    tool: ToolCentre
    poses: list[CarriedPose]
    out: Path


def _tip_spec(text: str) -> TipTarget:
    try:
        tip = parse_spec(text)
    except InputError as exc:
        raise InputError(f"--tip {text}: {str(exc).partition(': ')[2] or exc}") from None
    if not isinstance(tip, TipTarget):
        raise InputError(
            f"--tip {text}: is a board; expected the tool's tip (tip:jaw, tip:needle:20:5)"
        )
    return tip


def measure_tool_centre(
    rig: str | os.PathLike[str],
    calibration: str | os.PathLike[str],
    out: str | os.PathLike[str],
    tip: str,
    *,
    manipulator: str | None = None,
    seed: int | None = None,
    frames: int = 30,
    settle_s: float = 2.0,
    progress: Callable[[int, int], None] | None = None,
) -> ToolCentreOutcome:
    """Measure the tool-centre point on the rig and write the calibration with it to ``out``.

    Raises
    ------
    InputError
        A ``--tip`` that is not a tip spec, a rig whose target is not a board, an ``out``
        that is the calibration itself or not ours to replace.
    DetectionError
        Fewer than two poses with both board and tip (each pose's reason in the line).
    """
    target = _tip_spec(tip)
    out_path = check_json_output(out, CALIBRATION_FORMAT, "calibration-tool.json")
    if out_path.resolve() == Path(calibration).resolve():
        raise InputError("--out: write the calibration with the tool to a new file")
    cal = load_calibration(calibration)
    c = open_calibrated_rig(rig, calibration, manipulator=manipulator, seed=seed)
    with c.opened:
        device = c.device
        board = device.board
        if not isinstance(board, Target):
            raise InputError(
                f"tool centre: the rig's target is {board.spec}, a tip; the tool-centre point "
                f"needs the board the tool carries as the rig's target"
            )
        man, clock = device.manipulator, device.clock
        c.entry.check_device(man.identity)
        d_all, approach = planned_check(c.entry, man)
        poses: list[CarriedPose] = []
        near: np.ndarray | None = None
        for i, d in enumerate(d_all):
            if approach.any():
                man.move_to_um(d - approach)
                man.wait_until_stopped(clock)
            man.move_to_um(d)
            man.wait_until_stopped(clock)
            clock.sleep(settle_s)
            grabbed = {n: [cam.grab() for _ in range(frames)] for n, cam in device.cameras.items()}
            pose = measure_carried(grabbed, c.models, board, target, near=near)
            if pose.status == "ok" and near is None:
                near = pose.R
            poses.append(pose)
            if progress:
                progress(i + 1, len(d_all))
    tool = fit_carried(poses)
    entry = c.entry
    updated = dataclasses.replace(entry, extra={**entry.extra, "tool_centre": tool.to_json()})
    prov = provenance({"calibration": calibration}, command="tool-centre", tip=target.spec,
                      offset_um=tool.offset_um.tolist())  # fmt: skip
    write_calibration(out_path, Calibration({**cal.manipulators, entry.name: updated},
                                            cal.cameras, prov))  # fmt: skip
    return ToolCentreOutcome(tool, poses, out_path)
