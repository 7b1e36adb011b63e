"""Typed records of what crosses modules through files: run.json, a journal line, results.json
(with a model's validation figures), a check of the calibration's history.

Each is a :class:`~microcal.formats.json_file.FileSchema`: the keys microcal reads are typed
and validated (a malformed key is reported by its path), any other key is kept and written
back, so files written by a newer microcal (or with keys added by hand) load and round-trip.

The region of interest of a stored image is one record, :class:`RoiRecord`, whatever carries
it: acquisition hands the run writer ``(x0, y0, w, h)`` (the region's offset and the size of
the full frame, in its journal record's ``roi_px``), the journal stores ``offset_px`` and
``full_size_px`` beside the image's file, and the reader pastes the region back into a full
frame from it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

from pydantic import Field, field_validator, model_validator
from pydantic import JsonValue as AnyJson

from .._validation import name_problem
from ..json_value import JsonValue
from .json_file import FileSchema

__all__ = [
    "MAX_FRAMES_PER_POSE",
    "MAX_FRAME_PIXELS",
    "MAX_FRAME_SIDE_PX",
    "RESULTS_FORMAT",
    "RESULTS_FORMATS",
    "RUN_FORMAT",
    "RUN_FORMATS",
    "AcquisitionResult",
    "CheckRecord",
    "CrossValidationRecord",
    "DecouplingResult",
    "DesignRecord",
    "DeviceResults",
    "DistanceResult",
    "DriftResult",
    "FailedPose",
    "ImageRecord",
    "JournalLine",
    "MeasurementResult",
    "MeetFigures",
    "MeetResult",
    "ModelResult",
    "PoseAccuracyResult",
    "PoseResult",
    "Results",
    "RoiRecord",
    "RunManifest",
    "StabilisationResult",
    "StereoResult",
    "ValidationRecord",
]

RUN_FORMAT: Final = "microcal.run/1"
RUN_FORMATS = (RUN_FORMAT,)  # the versions of run.json this microcal reads
RESULTS_FORMAT: Final = "microcal.results/1"
RESULTS_FORMATS = (RESULTS_FORMAT,)

# What a run's files may declare, checked before anything is allocated from it (a run
# directory is data that is copied and shared):
#: The most frames a pose stores per camera (run.json's ``frames_per_pose``, ``--frames``).
MAX_FRAMES_PER_POSE: Final = 100
#: The largest full frame a stored region is pasted back into: each side, px ...
MAX_FRAME_SIDE_PX: Final = 32768
#: ... and in all, px (a 134-megapixel sensor).
MAX_FRAME_PIXELS: Final = 2**27


# --- the journal ---------------------------------------------------------------------------
@dataclass(frozen=True)
class RoiRecord:
    """Where a stored image region lies in the camera's full frame.

    Attributes
    ----------
    offset_px : (x0, y0) int
        The region's top-left pixel in the full frame.
    full_size_px : (w, h) int
        Width and height of the full frame (not of the region).
    """

    offset_px: tuple[int, int]
    full_size_px: tuple[int, int]

    @classmethod
    def from_roi_px(cls, roi_px: Sequence[int] | RoiRecord) -> RoiRecord:
        """From acquisition's ``[x0, y0, w, h]``: offset x0, y0 and the FULL frame's w, h."""
        if isinstance(roi_px, RoiRecord):
            return roi_px
        x0, y0, w, h = (int(v) for v in roi_px)
        return cls((x0, y0), (w, h))

    def journal_keys(self) -> dict[str, list[int]]:
        """The keys of an image entry in the journal: ``offset_px`` and ``full_size_px``."""
        return {"offset_px": list(self.offset_px), "full_size_px": list(self.full_size_px)}


class ImageRecord(FileSchema):
    """One camera's image file of one pose, as the journal records it.

    In the journal the region sits flat beside the file (``offset_px``, ``full_size_px``);
    here it is :attr:`roi`, None for a full frame.
    """

    file: str  # relative to the run directory
    sha256: str
    frames: int | None = None  # pages of the file
    roi: RoiRecord | None = None

    @model_validator(mode="before")
    @classmethod
    def _roi_from_journal(cls, data: object) -> object:
        if isinstance(data, dict) and ("offset_px" in data or "full_size_px" in data):
            data = dict(data)
            offset, full = data.pop("offset_px", None), data.pop("full_size_px", None)
            if offset is None or full is None:
                raise ValueError("offset_px and full_size_px go together (a stored region)")
            data["roi"] = {"offset_px": offset, "full_size_px": full}
        return data

    def to_json(self) -> dict[str, JsonValue]:
        """The journal's object: ``file``, ``sha256``, ``frames``, the region's keys, extras."""
        out: dict[str, JsonValue] = {"file": self.file, "sha256": self.sha256}
        if self.frames is not None:
            out["frames"] = self.frames
        if self.roi is not None:
            out |= self.roi.journal_keys()
        return out | dict(self.model_extra or {})


class JournalLine(FileSchema):
    """One line of ``journal.jsonl``: one pose of an acquisition.

    Other keys of the line (``commanded_um``, ``reported_um``, ``time``, ``move_s``,
    ``residual_px``, ``creep_model``, ...) are kept as extras; :meth:`get` reads any key.
    """

    pose: int  # 1-based, as in the image names
    status: str  # "ok" or "failed"
    reason: str | None = None  # when failed
    settle_s: float | None = None
    temperature_c: float | None = None  # when the rig has a thermometer
    images: dict[str, ImageRecord] = Field(default_factory=dict)

    @property
    def failed(self) -> bool:
        """The acquisition of this pose failed (nothing to measure)."""
        return self.status == "failed"

    def get(self, key: str, default: object = None) -> object:
        """A key of the line, typed or extra (``default`` when absent or null)."""
        if key in type(self).model_fields:
            value: object = getattr(self, key)
        else:
            value = (self.model_extra or {}).get(key)
        return default if value is None else value

    def to_json(self) -> dict[str, JsonValue]:
        """The journal's object (the keys the line was read with)."""
        out = self.model_dump(exclude={"images"}, exclude_unset=True)
        return out | {"images": {cam: image.to_json() for cam, image in self.images.items()}}


# --- run.json ------------------------------------------------------------------------------
class DesignRecord(FileSchema):
    """How a run's commands were made: enough to draw them again.

    ``kind`` is a design's name (``random``, ``sobol``...), an evaluation trajectory
    (``table-5-2``...) or ``file``; extras such as ``low_um``, ``high_um`` are kept.
    """

    kind: str
    poses: int
    seed: int | None = None


class RunManifest(FileSchema):
    """``run.json``: what a run was made with (every key but ``format`` is optional on read)."""

    format: Literal["microcal.run/1"] = RUN_FORMAT
    rig: dict[str, AnyJson] | None = None  # the rig as recorded; a resume must name the same
    target: str | None = None  # the end-effector board's spec
    cameras: list[str] = Field(default_factory=list)
    design: DesignRecord | None = None
    settle: str | None = None  # "vision" or "fixed:SECONDS"
    frames_per_pose: int | None = None
    store: str | None = None  # "full" frames or "roi"
    provenance: dict[str, AnyJson] = Field(default_factory=dict)
    commands_sha256: str | None = None
    device: str | None = None  # the manipulator's identity as it answered (serial, channels)
    manipulator: str | None = None  # the rig's device the run moved (None: m1)
    #: Joints the device holds still and their value, µm (an X-Y positioner's ``dz``).
    held_joints_um: dict[str, float] | None = None

    @field_validator("cameras")
    @classmethod
    def _camera_names(cls, cameras: list[str]) -> list[str]:
        for name in cameras:  # each becomes a file name (images/NAME_0001.tiff)
            problem = name_problem(name)
            if problem is not None:
                raise ValueError(problem)
        return cameras

    @field_validator("manipulator")
    @classmethod
    def _device_name(cls, name: str | None) -> str | None:
        problem = None if name is None else name_problem(name)
        if problem is not None:
            raise ValueError(problem)
        return name

    @field_validator("frames_per_pose")
    @classmethod
    def _frames(cls, frames: int | None) -> int | None:
        if frames is not None and not 1 <= frames <= MAX_FRAMES_PER_POSE:
            raise ValueError(f"expected 1 to {MAX_FRAMES_PER_POSE} frames per camera and pose")
        return frames

    def to_json(self) -> dict[str, JsonValue]:
        """The object of run.json: ``format`` first, then the keys that were given."""
        return {"format": self.format, **self.model_dump(exclude={"format"}, exclude_unset=True)}


# --- results.json --------------------------------------------------------------------------
class StereoResult(FileSchema):
    """``stereo.NAME``: one camera's calibration figures."""

    rms_px: float | None = None
    model: str | None = None


class MeasurementResult(FileSchema):
    """``measurement``: the 3D measurement against ground truth (simulator only)."""

    rms_error_um: float | None = None
    rms_error_axis_um: dict[str, float] | None = None
    mahalanobis_mean_sq: float | None = None


class CrossValidationRecord(FileSchema):
    """``cross_validation`` of a validation: k-fold figures and how often each term was
    selected (per axis)."""

    folds: int | None = None
    mean_um: float | None = None
    std_um: float | None = None
    max_um: float | None = None
    term_frequency: dict[str, dict[str, float]] = Field(default_factory=dict)


class ValidationRecord(FileSchema):
    """A model's ``validation`` object (calibration.json, results.json): how well it
    predicts the poses it was not fitted to (Eq 5.1), µm."""

    method: str | None = None
    n_fit: int | None = None
    n_validate: int | None = None
    mean_um: float | None = None
    std_um: float | None = None
    max_um: float | None = None
    rms_um: float | None = None
    p95_um: float | None = None
    rms_axis_um: dict[str, float] | None = None
    cross_validation: CrossValidationRecord | None = None


class ModelResult(FileSchema):
    """``models.KIND``: an identified model's validation figures (as in calibration.json)."""

    validation: ValidationRecord = Field(default_factory=ValidationRecord)


class FailedPose(FileSchema):
    """``acquisition.failed[i]``."""

    pose: int
    reason: str = ""


class AcquisitionResult(FileSchema):
    """``acquisition``: how the run's acquisition went."""

    poses: int
    stored: int
    mean_settle_s: float | None = None
    failed: list[FailedPose] = Field(default_factory=list)


class PoseResult(FileSchema):
    """``pose_accuracy.SOURCE.CONDITION.poses[i]``: one commanded pose (ISO 9283 7.2), µm."""

    desired_um: list[float] = Field(default_factory=list)
    mean_arrival_um: list[float] | None = None
    ap_um: list[float | None] = Field(default_factory=list)
    ap_p_um: float | None = None
    rp_um: float | None = None  # None with a single attained pose
    n: int | None = None


class PoseAccuracyResult(FileSchema):
    """``pose_accuracy.SOURCE.CONDITION``: ISO 9283 pose accuracy of one condition, and
    where the multi-directional test joined it (the demo), its ``vap_um``."""

    mean_ap_p_um: float | None = None
    max_ap_p_um: float | None = None
    poses: list[PoseResult] = Field(default_factory=list)
    vap_um: float | None = None
    max_vap_um: float | None = None

    @property
    def has_vap(self) -> bool:
        """Whether the file gives the multi-directional variation (null when not measured)."""
        return "vap_um" in self.model_fields_set


class DecouplingResult(FileSchema):
    """``decoupling.SOURCE.CONDITION``: undesired displacement ranges and Ω per axis, and
    the samples of the path as measured (null where a sample was not)."""

    undesired_um: dict[str, list[float | None]] = Field(default_factory=dict)
    omega: dict[str, float | None] = Field(default_factory=dict)
    samples_um: list[list[float | None]] | None = None
    segment: list[int] | None = None


class DistanceResult(FileSchema):
    """``distance_accuracy.SOURCE.CONDITION``: ISO 9283 distance accuracy (7.4), µm."""

    commanded_um: float | None = None
    mean_um: float | None = None
    ad_um: list[float | None] | None = None
    ad_p_um: float | None = None
    rd_um: list[float | None] | None = None
    rd_p_um: float | None = None
    n: int | None = None


class StabilisationResult(FileSchema):
    """``stabilisation.SOURCE.CONDITION``: ISO 9283 pose stabilisation time (7.5), s."""

    band_um: float | None = None
    window_s: float | None = None
    times_s: list[float | None] = Field(default_factory=list)
    mean_s: float | None = None
    max_s: float | None = None


class DriftResult(FileSchema):
    """``drift.SOURCE.CONDITION``: ISO 9283 drift of pose accuracy (7.7)."""

    t_s: list[float] = Field(default_factory=list)
    ap_p_um: list[float | None] = Field(default_factory=list)
    drift_ap_um: float | None = None


class DeviceResults(FileSchema):
    """The sections of one evaluation's results: a results.json, or one device's in a
    station's ``devices``. Every section is optional; figures may be null (NaN)."""

    stereo: dict[str, StereoResult] | None = None
    measurement: MeasurementResult | None = None
    models: dict[str, ModelResult] | None = None
    oracle: dict[str, float | None] | None = None
    acquisition: AcquisitionResult | None = None
    pose_accuracy: dict[str, dict[str, PoseAccuracyResult]] | None = None
    decoupling: dict[str, dict[str, DecouplingResult]] | None = None
    distance_accuracy: dict[str, dict[str, DistanceResult]] | None = None
    stabilisation: dict[str, dict[str, StabilisationResult]] | None = None
    drift: dict[str, dict[str, DriftResult]] | None = None
    closed_loop: dict[str, AnyJson] | None = None
    timing: dict[str, AnyJson] | None = None
    target: str | None = None  # what the cameras measured (evaluate): a board or a tool's tip
    unseen: list[dict[str, AnyJson]] | None = None  # measurements not made: d_um, reason


class MeetFigures(FileSchema):
    """``meet.MODE.vision`` or ``.truth``: the gap between the tips, µm."""

    mean_um: float | None = None
    max_um: float | None = None
    distances_um: list[float | None] = Field(default_factory=list)


class MeetResult(FileSchema):
    """``meet.MODE``: a station's meet test in one loop (``open``, ``closed``)."""

    mode: str | None = None
    offset_um: list[float] | None = None
    targets_um: list[list[float]] = Field(default_factory=list)
    vision: MeetFigures | None = None
    truth: MeetFigures | None = None


class Results(DeviceResults):
    """``results.json``: every section optional (``evaluate`` writes the parts it ran; a
    station demo its ``devices`` and ``meet``).

    Keys not named here (future sections) are kept. NaN is stored as null, so figures may be
    None.
    """

    format: Literal["microcal.results/1"] = RESULTS_FORMAT
    devices: dict[str, DeviceResults] | None = None
    meet: dict[str, MeetResult] | None = None
    provenance: dict[str, AnyJson] | None = None

    def to_json(self) -> dict[str, JsonValue]:
        """The object of results.json (the keys that were given)."""
        return {"format": self.format, **self.model_dump(exclude={"format"}, exclude_unset=True)}


# --- the calibration's history of checks ---------------------------------------------------
class CheckRecord(FileSchema):
    """One check of a calibration as its history (``CALIBRATION.checks.jsonl``) records it:
    the verdict and offset, where and when (the keys of check.json, docs/formats.md)."""

    verdict: str
    offset_um: list[float]
    offset_std_um: list[float]
    p_value: float | None = None
    against: str = ""
    flag: str = ""
    manipulator: str | None = None  # None: recorded before devices were
    created: str = ""
    during: str | None = None  # the run a check inside a run was made in
    after_poses: int | None = None
