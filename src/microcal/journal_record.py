"""The journal record of one acquired pose, as the acquisition makes it.

The acquisition (:func:`microcal.procedures.acquisition.acquire`) hands each pose's record to
its ``store`` callback; the run directory's writer appends :meth:`JournalRecord.to_json` to
``journal.jsonl`` with the pose's images, and the demo reads the record directly. The
journal's reader has its own schema (``microcal.formats.records.JournalLine``), which keeps
whatever keys a line holds.

The record is a plain value of the foundations (no numpy arrays, no file types), so that the
procedures that make it and the files that store it both depend on it and not on each other.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from .json_value import JsonValue

__all__ = ["CreepFigures", "JournalRecord", "PoseStatus"]

#: How a pose's acquisition ended: stored, or failed (nothing to measure).
PoseStatus = Literal["ok", "failed"]


@dataclass(frozen=True)
class CreepFigures:
    """The creep the vision settling learned: ``|b| exp(-t / tau)`` after a move.

    Attributes
    ----------
    tau_s : float
        Time constant, s (rounded to 0.1 ms as journaled).
    px_per_um_step : float or None
        Amplitude per µm of move, px.
    """

    tau_s: float
    px_per_um_step: float | None

    def to_json(self) -> dict[str, JsonValue]:
        """The journal's ``creep_model`` object."""
        return {"tau_s": self.tau_s, "px_per_um_step": self.px_per_um_step}


@dataclass(frozen=True)
class JournalRecord:
    """One pose of an acquisition: what was commanded, how it settled, what was read.

    Attributes
    ----------
    pose : int
        1-based, as in the image names.
    commanded_um : list of float
        The joints commanded, µm.
    approach : dict of str -> float or None
        Per journal column of a joint's approach direction (``approach_x`` ...): the
        direction the joint last moved in, +1 or -1; None before the joint has moved.
    status : {"ok", "failed"}
    wall_time_s : float
        Wall-clock time the pose began, s since the epoch (the journal's ``time``).
    sim_time_s : float
        The rig's clock then, s.
    move_s, settle_s : float
        How long the move and the settling took, s.
    residual_px : float or None
        The last change of the vision check's block means, px (None for a fixed wait).
    reported_um : list of float or None
        The joints the device reported once settled, µm (a stored pose).
    reason : str or None
        Why the pose failed.
    roi_px : dict of str -> (x0, y0, w, h)
        Per camera whose frames are a region around the board: the region's offset and the
        FULL frame's width and height. Not a journal key: the writer records it with each
        image (``offset_px``, ``full_size_px``).
    readings : dict of str -> float
        The rig's sensors read at the pose, by journal column (``temperature_c``).
    creep_model : CreepFigures or None
        The creep learned so far (vision settling).
    """

    pose: int
    commanded_um: list[float]
    approach: dict[str, float | None]
    status: PoseStatus
    wall_time_s: float
    sim_time_s: float
    move_s: float
    settle_s: float
    residual_px: float | None
    reported_um: list[float] | None = None
    reason: str | None = None
    roi_px: dict[str, tuple[int, int, int, int]] = field(default_factory=dict)
    readings: dict[str, float] = field(default_factory=dict)
    creep_model: CreepFigures | None = None

    @property
    def failed(self) -> bool:
        """The acquisition of this pose failed (nothing to measure)."""
        return self.status == "failed"

    def journaled(self, column: str) -> float | None:
        """The value of an extra input's journal column (an approach direction or a sensor's
        reading); None when the record has none."""
        if column in self.approach:
            return self.approach[column]
        return self.readings.get(column)

    def to_json(self) -> dict[str, JsonValue]:
        """The journal line without its images (the writer adds them), keys in the journal's
        order: pose, commands, approach directions, status, timing, readings, creep."""
        out: dict[str, JsonValue] = {"pose": self.pose, "commanded_um": self.commanded_um}
        out |= self.approach
        out["status"] = self.status
        if self.reported_um is not None:
            out["reported_um"] = self.reported_um
        if self.reason is not None:
            out["reason"] = self.reason
        out |= {
            "time": self.wall_time_s,
            "sim_time_s": self.sim_time_s,
            "move_s": self.move_s,
            "settle_s": self.settle_s,
            "residual_px": self.residual_px,
        }
        out |= self.readings
        if self.creep_model is not None:
            out["creep_model"] = self.creep_model.to_json()
        return out
