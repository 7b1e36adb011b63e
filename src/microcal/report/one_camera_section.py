"""The report's sections of a one-camera run (a microscope camera on a focus drive): the
camera against its stage, the tip measured from the image and the focus, the open loop over
the working volume, and the rig's time per stage.

A run is one-camera when its results.json holds the scope calibration (``scope``, as
``microcal demo --preset patch`` writes it), its directory holds a scope file
(``scope.json``) or it is a one-camera acquisition's (``one_camera.json``: the scope set it
measured in, ``microcal acquire --scope``). The report shows these sections in place of the
stereo calibration's and the cameras' measurement; the models and ISO 9283 sections are the
same for every rig.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..errors import FormatError
from ..formats.records import PoseAccuracyResult, Results
from ..formats.scope_file import load_objective, objective_names
from . import figures
from .bounds import Shown, first
from .data import RunData

__all__ = ["OneCameraSection", "ScopeRow", "one_camera_section"]

#: The conditions of the open loop over the working volume, in the order shown.
VOLUME_CONDITIONS = ("uncalibrated", "matrix", "optimal")


@dataclass(frozen=True)
class ScopeRow:
    """One objective's calibration against the stage: its set's keys as read, and where
    results.json holds the same numbers (``key``, ``scope.``), for the number cells."""

    objective: str
    record: Mapping[str, object]
    key: str  # "scope." when the set is results.json's own, "" when from scope.json only

    def value(self, *path: str | int) -> float | None:
        """A number of the set by its path (``"focus", "angle_deg"``); None when absent."""
        node: object = self.record
        for part in path:
            if isinstance(part, int) and isinstance(node, list) and part < len(node):
                node = node[part]
            elif isinstance(part, str) and isinstance(node, Mapping):
                node = node.get(part)
            else:
                return None
        return float(node) if isinstance(node, int | float) and not isinstance(node, bool) else None

    @property
    def affine(self) -> list[tuple[float | None, float | None]]:
        """The pixel-size affine's six numbers with their standard deviations."""
        return [(self.value("pixel_size_affine", k), self.value("pixel_size_affine_sd", k))
                for k in range(6)]  # fmt: skip


@dataclass(frozen=True)
class TipMeasurement:
    """The tips measured by one camera and its focus, against the simulator's truth."""

    method: str | None
    poses: int
    frames: int | None
    frames_per_pose: float | None
    rms_um: float | None
    rms_axis_um: dict[str, float | None]
    mahalanobis_mean_sq: float | None
    in_95: float | None
    median_std_um: list[float] | None
    figure: str | None


@dataclass(frozen=True)
class RigStage:
    """One stage of the run: its simulated rig time and its wall time, s."""

    name: str
    rig_s: float | None
    wall_s: float | None


@dataclass(frozen=True)
class OneCameraSection:
    """What the report shows of a one-camera run (module docstring)."""

    scope: Shown[ScopeRow]
    errors: Mapping[str, float | None]
    tip: TipMeasurement
    volume: Shown[tuple[str, PoseAccuracyResult]]
    stages: Shown[RigStage]
    calibration_rig_s: float | None
    closed_loop: Mapping[str, object] | None


def _scope_rows(data: RunData, results: Results) -> list[ScopeRow]:
    """results.json's own set first (``objective`` as scope.json names it), then scope.json's
    other sets."""
    extra = dict(results.model_extra or {})
    own = extra.get("scope")
    path = data.run_dir / "scope.json"
    names = objective_names(path) if path.exists() else []
    rows = []
    if isinstance(own, Mapping):
        mine = next((n for n in names if _same(load_objective(path, n), own)), None)
        rows.append(ScopeRow(mine or "this run's", own, "scope."))
    for name in names:
        if not rows or rows[0].objective != name:
            rows.append(ScopeRow(name, load_objective(path, name), ""))
    used = _acquired_with(data)
    if not rows and used is not None:
        rows.append(ScopeRow(str(used.get("objective", "?")), used.get("set") or {}, ""))
    return rows


def _acquired_with(data: RunData) -> Mapping[str, Mapping[str, object]] | None:
    """A one-camera acquisition's scope entry (``file``, ``objective``, ``set``); None for
    another run."""
    from ..formats.one_camera_run import is_one_camera_run, read_one_camera_setup

    if not is_one_camera_run(data.run_dir):
        return None
    scope = read_one_camera_setup(data.run_dir).get("scope")
    return scope if isinstance(scope, Mapping) else None


def _same(a: Mapping[str, object], b: Mapping[str, object]) -> bool:
    return a.get("pixel_size_affine") == b.get("pixel_size_affine")


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def _tip(data: RunData, results: Results) -> TipMeasurement:
    m = results.measurement
    acq = results.acquisition
    extra = dict(acq.model_extra or {}) if acq is not None else {}
    journal = data.journal
    std: FloatArray = journal.tip_std_um
    if not len(std) and data.measurements is not None and data.measurements.std_um is not None:
        std = data.measurements.std_um  # a one-camera acquisition's measurements.csv
    frames = _number(extra.get("frames"))
    n = len(std) or (acq.stored if acq is not None else 0)
    method = extra.get("method")
    axis = (m.rms_error_axis_um or {}) if m is not None else {}
    in_95 = _number((m.model_extra or {}).get("in_95")) if m is not None else None
    per_pose = float(np.nanmean(journal.tip_frames)) if journal.tip_frames.size else None
    if per_pose is None and frames is not None and n:
        per_pose = frames / n
    return TipMeasurement(
        method=method if isinstance(method, str) else None,
        poses=n,
        frames=None if frames is None else int(frames),
        frames_per_pose=per_pose,
        rms_um=m.rms_error_um if m is not None else None,
        rms_axis_um={a: axis.get(a) for a in "xyz"},
        mahalanobis_mean_sq=m.mahalanobis_mean_sq if m is not None else None,
        in_95=in_95,
        median_std_um=np.median(std, axis=0).tolist() if len(std) else None,
        figure=figures.measurement_uncertainty(std) if len(std) else None,
    )


def _stages(timing: Mapping[str, object]) -> list[RigStage]:
    rig, wall = timing.get("rig_s"), timing.get("stages_s")
    rig = rig if isinstance(rig, Mapping) else {}
    wall = wall if isinstance(wall, Mapping) else {}
    names = list(rig) + [n for n in wall if n not in rig]
    return [RigStage(str(n), _number(rig.get(n)), _number(wall.get(n))) for n in names]


def one_camera_section(data: RunData) -> OneCameraSection | None:
    """The section of a one-camera run; None for any other run.

    Raises
    ------
    FormatError
        The run's scope.json cannot be read (its message names the file).
    """
    results = data.results if data.results is not None else Results()
    extra = dict(results.model_extra or {})
    if (
        not isinstance(extra.get("scope"), Mapping)
        and not (data.run_dir / "scope.json").exists()
        and _acquired_with(data) is None
    ):
        return None
    scope = _scope_rows(data, results)
    own = extra.get("scope")
    errors = own.get("errors") if isinstance(own, Mapping) else None
    volume = extra.get("volume_accuracy")
    by_truth = volume.get("truth") if isinstance(volume, Mapping) else None
    rows: list[tuple[str, PoseAccuracyResult]] = []
    for name in VOLUME_CONDITIONS:
        found = by_truth.get(name) if isinstance(by_truth, Mapping) else None
        if isinstance(found, Mapping):
            try:
                rows.append((name, PoseAccuracyResult.model_validate(found)))
            except ValueError:
                raise FormatError(
                    f"{data.run_dir / 'results.json'}: volume_accuracy.truth.{name}: not a "
                    "pose-accuracy object"
                ) from None
    timing = results.timing or {}
    return OneCameraSection(
        scope=first(scope),
        errors=dict(errors) if isinstance(errors, Mapping) else {},
        tip=_tip(data, results),
        volume=first(rows),
        stages=first(_stages(timing)),
        calibration_rig_s=_number(timing.get("calibration_rig_s")),
        closed_loop=results.closed_loop,
    )
