"""Assemble the report: sections from the run's files, rendered with one jinja2 template."""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import stat
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import SupportsFloat
from urllib.parse import quote

import jinja2
import numpy as np

from .._parallel import Background
from .._validation import FloatArray
from .._version import __version__
from ..formats.atomic import write_text_atomic
from ..formats.cameras_file import (
    DiagnosticsRecord,
    LensModelRecord,
    RejectedPair,
    RejectedView,
    TurnedView,
)
from ..formats.outputs import foreign_report
from ..formats.records import (
    CheckRecord,
    DecouplingResult,
    DesignRecord,
    ModelResult,
    PoseAccuracyResult,
    Results,
    StereoResult,
    ValidationRecord,
)
from ..thesis.figures import (
    CLAIMED_ACCURACY_UM,
    DECOUPLING_UM,
    OMEGA_UM,
    POSE_ACCURACY_UM,
    REPROJECTION_ERROR_SIDE_PX,
    REPROJECTION_ERROR_TOP_PX,
    VALIDATION_UM,
)
from . import figures
from .bounds import MAX_PANELS, MAX_ROWS, Shown, clip, first, last
from .data import ReportInputs, RunData, load_run
from .glossary import GLOSSARY
from .one_camera_section import one_camera_section
from .text_tables import consistency_lines, is_thesis_rig

__all__ = ["build_report", "compares_with_thesis", "write_report"]

THESIS_REPROJECTION_PX = {"top": REPROJECTION_ERROR_TOP_PX, "side": REPROJECTION_ERROR_SIDE_PX}
CONDITIONS = ("uncalibrated", "matrix", "optimal")
#: The conditions of the pose-accuracy tables: the open loop's, then the closed loop where
#: the evaluation ran it.
POSE_CONDITIONS = (*CONDITIONS, "closed_loop")


def compares_with_thesis(data: RunData) -> bool:
    """Whether the report sets the run's figures beside the thesis's.

    Only a run on the simulator's ``thesis`` preset reproduces the thesis's platform, so only
    its figures are comparable; a hardware rig, another preset or a run whose rig is not
    recorded (no run.json) is reported on its own.
    """
    return is_thesis_rig(data.rig)


def _rig_text(data: RunData) -> str:
    """One line naming the rig of a run, for a report without the thesis comparison.

    The rig is run.json's record of it as written (a spec's ``to_dict()``), read key by key
    so that a rig of any version is named.
    """
    rig = data.rig
    preset = (data.results.model_extra or {}).get("preset") if data.results is not None else None
    if rig is None and isinstance(preset, str):  # a demo's run: results.json names its preset
        rig = {"driver": "sim", "preset": preset}
        seed = (data.results.provenance or {}).get("seed") if data.results is not None else None
        rig |= {"seed": seed} if isinstance(seed, int) else {}
    if rig is None:
        return "not recorded (no run.json)" if data.manifest is None else "not recorded in run.json"
    driver = rig.get("driver")
    if driver == "sim":
        text = f"the simulator, preset {rig.get('preset', '?')}"
        if rig.get("seed") is not None:
            text += f", seed {rig['seed']}"
        overrides = rig.get("overrides")
        if overrides and isinstance(overrides, Mapping | list | str):
            text += f", {len(overrides)} settings overridden"
        return text
    if driver == "hardware":
        parts = []
        manipulator = rig.get("manipulator")
        if isinstance(manipulator, Mapping) and manipulator.get("kind"):
            parts.append(f"manipulator {manipulator['kind']}")
        cameras = rig.get("cameras")
        if isinstance(cameras, Mapping) and cameras:
            parts.append(
                "cameras "
                + ", ".join(
                    f"{name} ({c['kind']})" if isinstance(c, Mapping) and c.get("kind") else name
                    for name, c in cameras.items()
                )
            )
        return "hardware" + (": " + "; ".join(parts) if parts else "")
    return f"driver {driver}"


# --- the sections: what the template shows, built from the run's records -------------------
@dataclass(frozen=True)
class CameraRow:
    """One camera of the stereo calibration's table."""

    name: str
    rms_px: float | None
    thesis_px: float | None
    views_used: int | None
    rejected: Shown[RejectedView]
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float
    size: tuple[int, int]
    lens_model: LensModelRecord | None
    diagnostics: DiagnosticsRecord | None


@dataclass(frozen=True)
class StereoSection:
    """The stereo calibration: a row per camera, the stereo figures, the figures drawn.

    The table shows the first :data:`~.bounds.MAX_ROWS` cameras, the figures the first
    ``drawn`` (at most :data:`~.bounds.MAX_PANELS`) of all ``n_cameras``.
    """

    rows: Shown[CameraRow]
    method: str
    baseline_um: float | None
    per_view: str | None
    residuals: str | None
    coverage: str | None
    field: str | None
    uncertainty: str | None
    turned: Shown[TurnedView]
    pairs_rejected: Shown[RejectedPair]
    notes: Shown[str]
    angle_deg: float | None
    n_cameras: int = 0
    drawn: int = 0
    consistency: tuple[str, ...] = ()
    """Sentences of the figures that need no reference (held-out views, pitch, closure)."""


def _stereo(data: RunData, thesis: bool) -> StereoSection | None:
    if data.cameras is None:
        return None
    cams = data.cameras.cameras
    rows = first(cams.items())
    per_view: dict[str, dict[str, float]] = {}
    residuals: dict[str, FloatArray] = {}
    sizes: dict[str, tuple[int, int]] = {}
    maps: dict[str, FloatArray] = {}
    table: list[CameraRow] = []
    for k, (name, c) in enumerate(rows):
        K = np.asarray(c.K, dtype=float)
        dist = list(c.dist)
        table.append(
            CameraRow(
                name=name,
                rms_px=c.rms_px,
                thesis_px=THESIS_REPROJECTION_PX.get(name) if thesis else None,
                views_used=c.views_used,
                rejected=first(c.views_rejected),
                fx=K[0, 0],
                fy=K[1, 1],
                cx=K[0, 2],
                cy=K[1, 2],
                k1=dist[0] if dist else 0.0,
                size=c.image_size_px,
                lens_model=c.lens_model,
                diagnostics=c.diagnostics,
            )
        )
        if k >= MAX_PANELS:
            continue  # in the table, not in the figures
        umap = c.diagnostics.uncertainty_map_px if c.diagnostics is not None else None
        if umap:
            maps[name] = np.asarray(umap, dtype=float)
        if c.per_view_rms_px:
            per_view[name] = c.per_view_rms_px
        if c.residuals_px:
            residuals[name] = np.vstack(
                [np.asarray(v, dtype=float) for v in c.residuals_px.values()]
            )
            sizes[name] = c.image_size_px
    stereo = data.cameras.stereo
    return StereoSection(
        rows=Shown(table, rows.more),
        method=stereo.method,
        baseline_um=stereo.baseline_um,
        per_view=figures.per_view_rms(per_view) if per_view else None,
        residuals=figures.calibration_residuals(residuals) if residuals else None,
        coverage=figures.calibration_coverage(residuals, sizes) if residuals else None,
        field=figures.residual_field(residuals, sizes) if residuals else None,
        uncertainty=figures.projection_uncertainty(maps, {n: cams[n].image_size_px for n in maps})
        if maps
        else None,
        turned=first(stereo.turned_views),
        pairs_rejected=first(stereo.views_rejected),
        notes=first(stereo.notes),
        angle_deg=stereo.angle_deg,
        n_cameras=len(cams),
        drawn=min(len(cams), MAX_PANELS),
        consistency=tuple(consistency_lines(stereo.consistency)),
    )


@dataclass(frozen=True)
class FailedRow:
    """A pose that failed, at which stage (acquisition or measurement) and why."""

    pose: int
    stage: str
    reason: str


@dataclass(frozen=True)
class AcquisitionSection:
    """The acquisition: how many poses, how they were designed and settled, what failed."""

    n_commands: int | None
    n_stored: int
    design: DesignRecord | None
    settle: str | None
    frames: int | None
    mean_settle_s: float | None
    max_settle_s: float | None
    rig_time_s: float | None
    rig_time_per_pose_s: float | None
    design_figure: str | None
    settle_figure: str | None
    failed: Shown[FailedRow]


def _acquisition(data: RunData) -> AcquisitionSection | None:
    journal = data.journal
    if data.commands_um is None and not journal.n_poses:
        return None
    models = data.models()  # the last device's own model last
    validation = models[-1].validation if models else None
    n_fit = validation.n_fit if validation is not None else None
    settle = journal.settle_s
    failed = [FailedRow(pose, "acquisition", reason) for pose, reason in journal.failed]
    n_failed = journal.n_failed
    if data.measurements is not None:
        measured = first(
            FailedRow(pose, "measurement", reason)
            for pose, reason in sorted(data.measurements.failed_reasons.items())
            if not reason.startswith("acquisition failed")
        )
        failed += measured.rows
        n_failed += len(measured.rows) + measured.more
    manifest = data.manifest
    planned = data.results.acquisition if data.results is not None else None  # a demo's
    return AcquisitionSection(
        n_commands=(
            len(data.commands_um)
            if data.commands_um is not None
            else (planned.poses if planned is not None else None)
        ),
        n_stored=journal.n_ok,
        design=manifest.design if manifest is not None else None,
        settle=manifest.settle if manifest is not None else None,
        frames=manifest.frames_per_pose if manifest is not None else None,
        mean_settle_s=float(settle.mean()) if settle.size else None,
        max_settle_s=float(settle.max()) if settle.size else None,
        rig_time_s=float(journal.rig_time_s.sum()) if journal.rig_time_s.size else None,
        rig_time_per_pose_s=float(journal.rig_time_s.mean()) if journal.rig_time_s.size else None,
        design_figure=(
            figures.command_design(data.commands_um, n_fit)
            if data.commands_um is not None
            else None
        ),
        settle_figure=figures.settle_times(settle) if settle.size else None,
        failed=Shown(failed[:MAX_ROWS], n_failed - min(len(failed), MAX_ROWS)),
    )


@dataclass(frozen=True)
class MeasurementSection:
    """The 3D measurement: poses measured and failed, its error against the truth (the
    simulator), the reported uncertainty."""

    n_ok: int
    n_failed: int
    rms_error_um: float | None
    claimed_um: float | None
    median_std_um: list[float] | None = None
    figure: str | None = None


def _measurement(data: RunData, thesis: bool) -> MeasurementSection | None:
    m = data.measurements
    if m is None:
        return None
    measured = data.results.measurement if data.results is not None else None
    std = m.std_um
    return MeasurementSection(
        n_ok=len(m.pose),
        n_failed=m.n_failed,
        rms_error_um=measured.rms_error_um if measured is not None else None,
        claimed_um=CLAIMED_ACCURACY_UM if thesis else None,
        median_std_um=None if std is None else np.median(std, axis=0).tolist(),
        figure=None if std is None else figures.measurement_uncertainty(std),
    )


@dataclass(frozen=True)
class AxisTerms:
    """The selected terms of one axis of {G}: (name, coefficient, standard error) each."""

    axis: str
    terms: Shown[tuple[str, float, float]]


@dataclass(frozen=True)
class ModelView:
    """An identified model: its terms per axis, validation, and the thesis's figures."""

    kind: str
    axes: list[AxisTerms]
    n_terms: int
    held: str
    validation: ValidationRecord | None
    thesis: dict[str, float] | None


@dataclass(frozen=True)
class ModelsSection:
    """The identified models and their prediction errors at the validation poses."""

    models: Shown[ModelView]
    figure: str | None


def _models(data: RunData, thesis: bool) -> ModelsSection | None:
    if data.calibration is None:
        return None
    errors = data.model_errors()
    shown = first(data.models())
    views = [
        ModelView(
            kind=found.kind,
            axes=[AxisTerms(a, first(found.model.axis_terms(i))) for i, a in enumerate("xyz")],
            n_terms=int(np.sum(found.model.selected)),
            held=", ".join(f"{j} at {v:g} µm" for j, v in found.model.held_um.items()),
            validation=found.validation,
            thesis=VALIDATION_UM.get(found.kind) if thesis else None,
        )
        for found in shown
    ]
    figure = (
        figures.prediction_errors({e.kind: (e.poses, e.errors_um) for e in errors})
        if errors
        else None
    )
    return ModelsSection(Shown(views, shown.more), figure)


@dataclass(frozen=True)
class PoseTable:
    """The pose accuracy of one condition by one source."""

    source: str
    condition: str
    figures: PoseAccuracyResult


@dataclass(frozen=True)
class PoseAccuracySection:
    """Pose accuracy: the sources measured, a table per source and condition, the thesis's
    figures (mean, worst) per condition where the run compares with it."""

    sources: list[str]
    tables: list[PoseTable]
    thesis: Mapping[str, tuple[float, float]]


def _pose_accuracy(data: RunData, thesis: bool) -> PoseAccuracySection | None:
    pa = data.results.pose_accuracy if data.results is not None else None
    if not pa:
        return None
    sources: list[str] = [s for s in ("vision", "truth") if s in pa]
    tables = [PoseTable(source, name, pa[source][name])
              for source in sources for name in POSE_CONDITIONS if name in pa[source]]  # fmt: skip
    return PoseAccuracySection(sources, tables, POSE_ACCURACY_UM if thesis else {})


@dataclass(frozen=True)
class DecouplingPlot:
    """The figure of one condition's decoupling run."""

    condition: str
    figure: str


@dataclass(frozen=True)
class DecouplingSection:
    """Decoupling: the figures per source and condition, their plots, the thesis's."""

    sources: list[str]
    by_source: dict[str, dict[str, DecouplingResult]]
    plots: list[DecouplingPlot]
    thesis_ranges: Mapping[str, Mapping[str, tuple[float, float]]]
    thesis_omega: Mapping[str, Mapping[str, float]]


def _decoupling(data: RunData, thesis: bool) -> DecouplingSection | None:
    dc = data.results.decoupling if data.results is not None else None
    if not dc:
        return None
    sources: list[str] = [s for s in ("vision", "truth") if s in dc]
    plots = []
    for name in CONDITIONS:
        runs: dict[str, tuple[FloatArray, np.ndarray]] = {}
        for source in sources:
            found = dc[source].get(name)
            if found is not None and found.samples_um:
                samples = np.asarray(found.samples_um, dtype=float)
                runs[source] = (samples, np.asarray(found.segment, dtype=int))
        if runs:
            plots.append(DecouplingPlot(name, figures.decoupling(name, runs)))
    return DecouplingSection(
        sources=sources,
        by_source=dc,
        plots=plots,
        thesis_ranges=DECOUPLING_UM if thesis else {},
        thesis_omega=OMEGA_UM if thesis else {},
    )


@dataclass(frozen=True)
class IsoRow:
    """One figure of ISO 9283's distance, stabilisation or drift tests."""

    what: str
    source: str
    condition: str
    value: str


def _iso(data: RunData) -> Shown[IsoRow]:
    """ISO 9283's distance, stabilisation and drift rows, where evaluate ran them."""
    results = data.results
    if results is None:
        return Shown([])
    rows = []
    for source, per in (results.distance_accuracy or {}).items():
        rows += [IsoRow("distance AD_P / RD (7.4)", source, c,
                        f"{_fmt(d.ad_p_um)} / {_fmt(d.rd_p_um)} µm over "
                        f"{_fmt(d.commanded_um, 0)} µm") for c, d in per.items()]  # fmt: skip
    for source, per_s in (results.stabilisation or {}).items():
        rows += [IsoRow(f"stabilisation mean / worst, ±{d.band_um} µm (7.5)", source, c,
                        f"{_fmt(d.mean_s)} / {_fmt(d.max_s)} s")
                 for c, d in per_s.items()]  # fmt: skip
    for source, per_d in (results.drift or {}).items():
        rows += [IsoRow("drift dAP (7.7)", source, c,
                        f"{_fmt(d.drift_ap_um)} µm over "
                        f"{_fmt((d.t_s[-1] - d.t_s[0]) / 3600 if d.t_s else None)} h")
                 for c, d in per_d.items()]  # fmt: skip
    return first(rows)


@dataclass(frozen=True)
class DeviceRow:
    """One device of a station: its validation error and mean AP_P (µm), its own report."""

    name: str
    validation: float | None
    uncalibrated: float | None
    optimal_truth: float | None
    optimal_vision: float | None
    link: str


@dataclass(frozen=True)
class MeetRow:
    """A station's meet test in one loop: the gap between the tips, µm."""

    mode: str
    targets: int
    vision_mean: float | None
    vision_max: float | None
    truth_mean: float | None
    truth_max: float | None


@dataclass(frozen=True)
class StationSection:
    """A station demo's devices side by side, and its meet tests."""

    devices: Shown[DeviceRow]
    meet: Shown[MeetRow] = field(default_factory=lambda: Shown([]))


def _station(data: RunData, root: Path) -> StationSection | None:
    """The devices of a station demo's results.json and its meet test (None for a run)."""
    results = data.results
    if results is None or results.devices is None:
        return None
    devices = first(results.devices.items())
    rows = []
    for name, r in devices:
        pa = r.pose_accuracy or {}

        def ap(source: str, condition: str, pa: Mapping[str, Mapping[str, PoseAccuracyResult]] = pa
               ) -> float | None:  # fmt: skip
            figures = pa.get(source, {}).get(condition)
            return figures.mean_ap_p_um if figures is not None else None

        poly = (r.models or {}).get("polynomial")
        link = device_report_link(root, name)
        rows.append(DeviceRow(name, poly.validation.mean_um if poly is not None else None,
                              ap("truth", "uncalibrated"), ap("truth", "optimal"),
                              ap("vision", "optimal"), link))  # fmt: skip
    meet = first((results.meet or {}).items())
    meets = []
    for mode, m in meet:
        vision, truth = m.vision, m.truth
        meets.append(MeetRow(mode, len(m.targets_um),
                             vision.mean_um if vision else None, vision.max_um if vision else None,
                             truth.mean_um if truth else None,
                             truth.max_um if truth else None))  # fmt: skip
    return StationSection(Shown(rows, devices.more), Shown(meets, meet.more))


#: A device's name that may become part of a link: letters, digits, ``_``, ``-`` and ``.``,
#: not first (no ``..``, no hidden folder, no scheme such as ``javascript:``, no slash).
_LINKABLE_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}")


def device_report_link(root: Path, name: str) -> str:
    """The relative link to a station device's own report, or "" for none.

    A link is made only to a report microcal wrote (its generator tag) as a regular file
    ``NAME/report.html`` in a folder (not a symbolic link) of the station's directory, and
    only for a plain name (:data:`_LINKABLE_NAME`): a name from results.json never becomes a
    link of its own choosing (another scheme, an absolute path, a folder outside).
    """
    if not _LINKABLE_NAME.fullmatch(name) or ".." in name:
        return ""
    folder, page = root / name, root / name / "report.html"
    try:
        if not stat.S_ISDIR(folder.lstat().st_mode) or not stat.S_ISREG(page.lstat().st_mode):
            return ""
    except OSError:
        return ""
    if foreign_report(page) is not None:
        return ""
    return f"{quote(name)}/report.html"


@dataclass(frozen=True)
class ChecksSection:
    """The history of checks of the calibration, and its figure."""

    rows: Shown[CheckRecord]  # the latest; ``more``: the earlier ones left out
    figure: str


def _checks(data: RunData) -> ChecksSection | None:
    if not data.checks:
        return None
    shown = last(data.checks)
    offsets = np.array([c.offset_um for c in shown], dtype=np.float64)
    std = np.array([c.offset_std_um for c in shown], dtype=np.float64)
    verdicts = [c.verdict for c in shown]
    devices = [str(c.manipulator or "m1") for c in shown]
    figure = figures.check_history(offsets, std, verdicts, devices, first_check=shown.more + 1)
    return ChecksSection(shown, figure)


def _provenance(data: RunData) -> Shown[tuple[str, str]]:
    rows: list[tuple[str, str]] = [("run directory", str(data.run_dir))]
    manifest, cameras, results = data.manifest, data.cameras, data.results
    sources: tuple[tuple[str, Mapping[str, object] | None], ...] = (
        ("run", manifest.provenance if manifest is not None else None),
        ("cameras", cameras.provenance if cameras is not None else None),
        ("calibration", data.calibration.provenance if data.calibration else None),
        ("results", results.provenance if results is not None else None),
    )
    for label, prov in sources:
        for key, value in (prov or {}).items():
            rows.append((f"{label}: {key}", _plain(value)))
    if manifest is not None and manifest.rig:
        rows.append(("rig", _plain(manifest.rig)))
    return first(rows)


def _plain(value: object) -> str:
    return json.dumps(value, sort_keys=True) if isinstance(value, dict | list) else str(value)


def build_report(
    run_dir: str | os.PathLike[str], inputs: ReportInputs | None = None, forked: bool = False
) -> str:
    """The report of a run directory as one self-contained HTML page.

    Sections whose files are missing say so instead of failing, so a report can be made at
    any stage of a calibration (after ``acquire``, after ``fit``, after ``evaluate``).
    The thesis's figures stand beside the run's only for a run on the simulator's thesis
    preset (`compares_with_thesis`); any other run is reported with its own figures alone.
    ``forked``: the two sections with the most figures (stereo, decoupling) are drawn in
    forked processes while the others are drawn here (the same page; for a command's own
    process, not for one serving other threads).
    """
    data = load_run(run_dir, inputs)
    thesis = compares_with_thesis(data)
    results = data.results if data.results is not None else Results()
    stereo: Background[StereoSection | None] | None = None
    decoupling: Background[DecouplingSection | None] | None = None
    if forked:
        stereo = Background(lambda: _stereo(data, thesis))
        decoupling = Background(lambda: _decoupling(data, thesis))
    drawn = {
        "acquisition": _acquisition(data),
        "measurement": _measurement(data, thesis),
        "models": _models(data, thesis),
        "pose_accuracy": _pose_accuracy(data, thesis),
    }
    context = {
        "title": f"microcal calibration report: {Path(run_dir).resolve().name}",
        "version": __version__,
        "generated": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "results": results,
        "summary": _summary(results),
        "stereo": _stereo(data, thesis) if stereo is None else stereo.result(),
        **drawn,
        "decoupling": _decoupling(data, thesis) if decoupling is None else decoupling.result(),
        "iso": _iso(data),
        "checks": _checks(data),
        "station": _station(data, Path(run_dir)),
        "one_camera": one_camera_section(data),
        "provenance": _provenance(data),
        "rig": _rig_text(data),
        "glossary": GLOSSARY,
        "thesis": (
            {
                "reprojection": THESIS_REPROJECTION_PX,
                "validation": VALIDATION_UM,
                "pose_accuracy": POSE_ACCURACY_UM,
                "claimed_um": CLAIMED_ACCURACY_UM,
            }
            if thesis
            else None
        ),
    }
    text = resources.files(__package__).joinpath("report.html.j2").read_text(encoding="utf-8")
    env = jinja2.Environment(
        autoescape=True, undefined=jinja2.StrictUndefined, finalize=_bounded_text
    )
    env.filters["f"] = _fmt
    env.globals["bounded"] = first
    return env.from_string(text).render(**context)


@dataclass(frozen=True)
class Summary:
    """The rows of the summary table that come from results.json's sections, bounded."""

    stereo: Shown[tuple[str, StereoResult]]
    models: Shown[tuple[str, ModelResult]]
    pose_accuracy: Shown[tuple[str, str, PoseAccuracyResult]]


def _summary(results: Results) -> Summary:
    return Summary(
        stereo=first((results.stereo or {}).items()),
        models=first((results.models or {}).items()),
        pose_accuracy=first((source, cond, r) for source, conds in
                            (results.pose_accuracy or {}).items() for cond, r in conds.items()),
    )  # fmt: skip


def _bounded_text(value: object) -> object:
    """What a template prints, a text from a file cut to MAX_TEXT_CHARS (figures whole; the
    output of the template's own macros was bounded where it was made)."""
    if isinstance(value, figures.FigureUri) or hasattr(value, "__html__"):  # markup: bounded
        return value
    return clip(value) if isinstance(value, str) else value


def _fmt(value: object, digits: int = 2) -> str:
    if value is None:
        return "-"
    if not isinstance(value, str | SupportsFloat):
        return str(value)
    try:
        x = float(value)
    except (TypeError, ValueError):
        return str(value)
    return "-" if not np.isfinite(x) else f"{x:.{digits}f}"


def write_report(
    run_dir: str | os.PathLike[str],
    out: str | os.PathLike[str] | None = None,
    inputs: ReportInputs | None = None,
    forked: bool = False,
) -> Path:
    """Build the report and write it atomically (default: ``RUN_DIR/report.html``);
    ``inputs`` names files kept outside the run directory; ``forked`` as for
    :func:`build_report`."""
    path = Path(out) if out is not None else Path(run_dir) / "report.html"
    return write_text_atomic(path, build_report(run_dir, inputs, forked))
