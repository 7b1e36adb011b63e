"""The tables the commands print: plain titles, columns and rows of text, no terminal code.

Each builder takes what a procedure returned and gives a :class:`TextTable`; the command line
prints it. The thesis's columns appear only where the run is the thesis's experiment.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from ..control.visual_servo import smallest_confirmable_um
from ..thesis.figures import (
    CLAIMED_ACCURACY_UM,
    DECOUPLING_UM,
    POSE_ACCURACY_UM,
    REPROJECTION_ERROR_SIDE_PX,
    REPROJECTION_ERROR_TOP_PX,
    VALIDATION_UM,
)

if TYPE_CHECKING:
    from ..control.closed_loop import ClosedLoopSummary
    from ..control.visual_servo import ServoStep
    from ..experiments.demo import DemoResult
    from ..experiments.station_demo import StationDemoResult
    from ..formats.records import ValidationRecord
    from ..geometry import AnyCamera
    from ..kinematics.manipulator_calibration import ManipulatorCalibration
    from ..kinematics.models import KinematicModel
    from ..kinematics.validation import Validation
    from ..procedures.approach_axis import ApproachMove
    from ..procedures.check import CheckResult, CheckUpdate
    from ..procedures.compensation import Solution
    from ..procedures.evaluation_figures import (
        BySource,
        DecouplingFigures,
        Evaluation,
        PoseAccuracyFigures,
    )
    from ..procedures.identification import Identification
    from ..procedures.station import Arrival
    from ..vision.measurement import PoseMeasurement
    from ..vision.stereo_calibration import StereoCalibration

__all__ = [
    "TextTable",
    "decoupling_table",
    "demo_closing",
    "demo_intro",
    "demo_stereo_table",
    "demo_summary",
    "evaluation_tables",
    "fit_lines",
    "identification_table",
    "is_thesis_rig",
    "measurement_lines",
    "pose_accuracy_table",
    "solution_lines",
    "stereo_lines",
    "stereo_table",
    "terms_table",
    "validation_lines",
]


def is_thesis_rig(rig: Mapping[str, object] | None) -> bool:
    """Whether a rig's record (run.json's ``rig``, a spec's ``to_dict()``) is the thesis's.

    Only the simulator's ``thesis`` preset reproduces the thesis's platform, so only its
    figures are comparable with the thesis's; any other rig is reported on its own.
    """
    rig = rig or {}
    return rig.get("driver") == "sim" and rig.get("preset") == "thesis"


@dataclass
class TextTable:
    """A table to print: a title, column headings and rows (numbers right-aligned)."""

    title: str
    columns: list[str]
    rows: list[list[str]] = field(default_factory=list)
    first_left: bool = False  # the first column is text (term names), read left-aligned


SIGMA_CORNER = "σ corner px"  # noqa: RUF001


def _number(value: object) -> float | None:
    """A figure of a calibration's JSON-like record (a number, or None for any other)."""
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _objects(value: object) -> list[Mapping[str, object]]:
    """The objects of a JSON-like list (``candidates``); [] for anything else."""
    return [v for v in value if isinstance(v, Mapping)] if isinstance(value, list) else []


def stereo_table(calibration: StereoCalibration, digits: int = 4) -> TextTable:
    """Per camera: RMS, views used, focal lengths, the lens model with its held-out RMS and
    the projection uncertainty at the worst image corner (a ``StereoCalibration``)."""
    table = TextTable(
        f"Stereo calibration ({calibration.method})",
        [
            "camera",
            "model",
            "RMS px",
            "views",
            "scale x",
            "scale y",
            "lens model",
            "held-out px",
            SIGMA_CORNER,
        ],
    )
    for name, c in calibration.cameras.items():
        lens = str(c.lens_model.get("name", "")) if c.lens_model else ""
        chosen = [d for d in _objects(c.lens_model.get("candidates")) if d["name"] == lens]
        h = _number(chosen[0]["held_out_rms_px"]) if chosen else None
        sigma = f"{c.diagnostics.uncertainty_px['corners']:.3f}" if c.diagnostics else ""
        table.rows.append([name, c.model.kind, f"{c.rms_px:.{digits}f}", str(c.views_used),
                           *_scales(c.model), lens or "fixed",
                           "" if h is None else f"{h:.{digits}f}", sigma])  # fmt: skip
    return table


def demo_stereo_table(
    calibration: StereoCalibration, truth_px: Mapping[str, float], target: str
) -> TextTable:
    """The demo's stereo calibration next to the thesis's reprojection errors."""
    thesis = {"top": REPROJECTION_ERROR_TOP_PX, "side": REPROJECTION_ERROR_SIDE_PX}
    table = TextTable(
        f"1. Stereo calibration: {target} at 5 known heights ({calibration.method})",
        ["camera", "model", "RMS px", "thesis px", "vs true camera px", "scale x", "scale y"],
    )
    for name, c in calibration.cameras.items():
        table.rows.append([name, c.model.kind, f"{c.rms_px:.3f}",
                           f"{thesis.get(name, float('nan')):.3f}", f"{truth_px[name]:.3f}",
                           *_scales(c.model)])  # fmt: skip
    return table


def _scales(model: AnyCamera) -> list[str]:
    """A camera's scale per image axis with its unit: focal length (px) of a pinhole camera,
    magnification (px/µm) of an affine one."""
    if model.kind == "affine":
        return [f"{model.K[i, i]:.5f} px/µm" for i in (0, 1)]
    return [f"{model.K[i, i]:.1f} px" for i in (0, 1)]


def model_choice_lines(calibration: StereoCalibration) -> list[str]:
    """One line per camera whose model was chosen (``--camera-model auto``): the choice, its
    reason and every candidate's training and held-out RMS."""
    lines = []
    for name, c in calibration.cameras.items():
        choice = c.model_choice
        if not choice:
            continue
        figures = []
        for cand in _objects(choice.get("candidates")):
            if cand.get("failed"):
                figures.append(f"{cand['model']} failed ({cand['failed']})")
                continue
            train, held = _number(cand.get("train_rms_px")), _number(cand.get("held_out_rms_px"))
            ill = f", {cand['ill_conditioned']}" if cand.get("ill_conditioned") else ""
            figures.append(f"{cand['model']} held-out {_px(held)} (training {_px(train)}){ill}")
        lines.append(
            f"camera model of {name}: {choice['chosen']}, {choice['reason']}; " + "; ".join(figures)
        )
    return lines


def _px(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f} px"


def identification_table(
    validations: Mapping[str, Validation], oracle: Mapping[str, float]
) -> TextTable:
    """Validation errors per model next to the thesis's, and the oracle's (Eq 5.1, µm)."""
    n_fit = next(iter(validations.values())).n_fit
    table = TextTable(
        f"3. Identification: first {n_fit} poses fit, the rest validate (Eq 5.1, µm)",
        ["model", "mean", "std", "max", "thesis mean", "thesis std", "thesis max"],
    )
    keys = ("mean", "std", "max")
    for kind, v in validations.items():
        s = v.summary
        ours = [f"{float(x):.2f}" for x in (s.mean, s.std, s.max)]
        table.rows.append([kind, *ours, *(f"{VALIDATION_UM[kind][k]:.2f}" for k in keys)])
    table.rows.append(["oracle", *(f"{oracle[k]:.2f}" for k in keys), "-", "-", "-"])
    return table


def pose_accuracy_table(
    pose_accuracy: BySource[PoseAccuracyFigures],
    conditions: list[str],
    *,
    thesis: bool,
    title: str = "",
) -> TextTable:
    """Mean / worst AP_P per condition, by vision and ground truth; the thesis's if asked;
    and mean / worst vAP (ISO 9283 7.3) of each source that has it."""
    sources = [s for s in ("vision", "truth") if s in pose_accuracy]
    vap = [s for s in sources if all(pose_accuracy[s][n].vap_um is not None for n in conditions)]
    table = TextTable(
        title or "Pose accuracy AP_P (µm): mean / worst",
        ["condition", *(("ground truth" if s == "truth" else s) for s in sources)]
        + (["thesis"] if thesis else [])
        + [f"vAP {'truth' if s == 'truth' else s}" for s in vap],
    )
    for name in conditions:
        row = [name] + [
            f"{pose_accuracy[s][name].mean_ap_p_um:.2f} / {pose_accuracy[s][name].max_ap_p_um:.2f}"
            for s in sources
        ]
        if thesis:  # the thesis has no closed loop: nothing to set beside it
            published = POSE_ACCURACY_UM.get(name)
            row.append("-" if published is None else f"{published[0]:.2f} / {published[1]:.2f}")
        row += [f"{pose_accuracy[s][name].vap_um:.2f} / "
                f"{pose_accuracy[s][name].max_vap_um:.2f}" for s in vap]  # fmt: skip
        table.rows.append(row)
    return table


def decoupling_table(
    decoupling: BySource[DecouplingFigures], conditions: list[str], *, thesis: bool, title: str = ""
) -> TextTable:
    """Undesired displacement [min, max] per axis: by truth with the thesis's figures, or by
    vision | truth (by vision alone on a rig without ground truth)."""
    table = TextTable(
        title or "Decoupling: undesired displacement [min, max] (µm)",
        ["condition", "x", "y", "z"],
    )
    for name in conditions:
        cells = []
        for axis in "xyz":
            if thesis:
                lo, hi = decoupling["truth"][name].metrics.ranges_um[axis]
                published = DECOUPLING_UM.get(name)
                beside = "" if published is None else " ({:.1f}, {:.1f})".format(*published[axis])
                cells.append(f"[{lo:.1f}, {hi:.1f}]{beside}")
                continue
            parts = [decoupling[s][name].metrics.ranges_um[axis]
                     for s in ("vision", "truth") if s in decoupling]  # fmt: skip
            cells.append(" | ".join(f"[{v[0]:.1f}, {v[1]:.1f}]" for v in parts))
        table.rows.append([name, *cells])
    return table


def terms_table(model: KinematicModel) -> TextTable:
    """The selected terms of a model: coefficient ± standard error per axis."""
    table = TextTable(
        "Selected terms: coefficient ± standard error (µm per unit of the term)",
        ["term", "x (µm)", "y (µm)", "z (µm)"],
        first_left=True,
    )
    for a, t in enumerate(model.terms):
        if not model.selected[:, a].any():
            continue
        cells = []
        for axis in range(3):
            if model.selected[axis, a]:
                se = float(np.sqrt(model.covariance[axis, a, a]))
                cells.append(f"{model.coefficients[axis, a]:.6g} ± {se:.2g}")
            else:
                cells.append("-")
        table.rows.append([t.name, *cells])
    return table


def demo_summary(result: DemoResult, frames: int) -> list[TextTable | str]:
    """What ``microcal demo`` prints of a ``DemoResult``, step by step, next to the thesis."""
    from ..sim.platforms import CALIBRATION_TARGET

    out: list[TextTable | str] = [
        demo_stereo_table(result.calibration, result.calibration_truth_px, CALIBRATION_TARGET),
        *model_choice_lines(result.calibration),
    ]
    ok = result.measured_ok
    stds = np.array([m.std_um for m, good in zip(result.measurements, ok, strict=True) if good])
    out.append(
        f"2. Measured {int(ok.sum())} of {len(ok)} poses ({frames} frames each, "
        f"{result.sim_time_s / 60:.0f} min of simulated time): 3D error vs ground truth "
        f"{result.measurement_rms_um:.2f} µm RMS, x/y/z "
        + "/".join(f"{v:.2f}" for v in result.measurement_rms_axis_um)
        + f" (the thesis claimed ±{CLAIMED_ACCURACY_UM:g} µm without measuring); reported std "
        "x/y/z "
        + "/".join(f"{v:.2f}" for v in np.median(stds, axis=0))
        + f" µm; errors over the reported covariance: mean square {result.mahalanobis_mean_sq:.2f}"
        " (3 when it matches)."
    )
    validations = {k: _split(result.models[k]) for k in ("matrix", "polynomial")}
    out.append(identification_table(validations, result.oracle))
    evaluation = result.evaluation
    names = ["uncalibrated", "matrix", "optimal"]
    if evaluation.pose_accuracy is not None:
        title = "4. Pose accuracy at the Table 5-2 poses: mean / worst AP_P (µm)"
        out.append(pose_accuracy_table(evaluation.pose_accuracy, names, thesis=True, title=title))
    if evaluation.decoupling is not None:
        title = "5. Decoupling: undesired displacement [min, max] (µm), truth (thesis)"
        out.append(decoupling_table(evaluation.decoupling, names, thesis=True, title=title))
    return out


def _split(identification: Identification) -> Validation:
    """The validation of a model on the poses it was not fitted to (the thesis's split)."""
    if identification.split is None:
        raise ValueError("identification: no split validation to print")
    return identification.split


def validation_lines(v: ValidationRecord) -> list[str]:
    """What ``microcal fit`` prints of a calibration.json ``validation`` object."""
    lines = [
        f"validation ({v.method}): mean {v.mean_um:.2f} µm, std {v.std_um:.2f}, "
        f"max {v.max_um:.2f}, RMS {v.rms_um:.2f}, 95 % {v.p95_um:.2f}; RMS per axis "
        "x/y/z " + "/".join(f"{r:.2f}" for r in (v.rms_axis_um or {}).values()) + " µm"
    ]
    cv = v.cross_validation
    if cv is not None:
        lines.append(
            f"{cv.folds}-fold cross-validation (selection repeated per fold): mean "
            f"{cv.mean_um:.2f} µm, std {cv.std_um:.2f}, max {cv.max_um:.2f}"
        )
        unstable = [f"{axis}:{term} {share:.0%}" for axis, shares in cv.term_frequency.items()
                    for term, share in shares.items() if 0 < share < 1]  # fmt: skip
        if unstable:
            lines.append("terms not selected in every fold: " + ", ".join(unstable))
    return lines


def evaluation_tables(parts: Evaluation, poses: str, *, thesis: bool) -> list[TextTable | str]:
    """What ``microcal evaluate`` prints: pose accuracy over ``poses``, decoupling by vision
    and truth; the thesis's pose-accuracy figures where ``thesis`` (its poses, its preset);
    the closed loop's line where it ran."""
    out: list[TextTable | str] = []
    if parts.pose_accuracy is not None:
        pa = parts.pose_accuracy
        title = f"Pose accuracy AP_P (µm): mean / worst over the {poses} poses"
        out.append(pose_accuracy_table(pa, list(pa["vision"]), thesis=thesis, title=title))
    if parts.decoupling is not None:
        dc = parts.decoupling
        title = "Decoupling: undesired displacement [min, max] (µm), vision | truth"
        out.append(decoupling_table(dc, list(dc["vision"]), thesis=False, title=title))
    if parts.closed_loop is not None:
        out.append(closed_loop_line(parts.closed_loop))
    return out + iso_lines(parts)


def _s(value: float | None) -> str:
    return "not settled" if value is None else f"{value:.2f} s"


def iso_lines(parts: Evaluation) -> list[str]:
    """One line per source and condition for ISO 9283's distance, stabilisation and drift."""
    out: list[str] = []
    for source, per in (parts.distance_accuracy or {}).items():
        out += [f"distance {c} ({source}): AD_P {d.ad_p_um:+.3f} µm, RD {d.rd_p_um:.3f} µm "
                f"over {d.commanded_um:.0f} µm, {d.n} cycles (ISO 9283 7.4)"
                for c, d in per.items()]  # fmt: skip
    for source, per_s in (parts.stabilisation or {}).items():
        out += [f"stabilisation {c} ({source}): mean {_s(d.mean_s)}, worst {_s(d.max_s)} "
                f"within ±{d.band_um:g} µm (ISO 9283 7.5)" for c, d in per_s.items()]  # fmt: skip
    for source, per_d in (parts.drift or {}).items():
        for c, f in per_d.items():
            if f.drift_ap_um is not None:
                span = f.t_s[-1] - f.t_s[0]
                out.append(f"drift {c} ({source}): dAP {f.drift_ap_um:.3f} µm over "
                           f"{span / 3600:.2f} h, AP {f.ap_p_um[0]:.3f} -> "
                           f"{f.ap_p_um[-1]:.3f} µm (ISO 9283 7.7)")  # fmt: skip
    return out


def unseen_lines(unseen: Sequence[Mapping[str, Any]], shown: int = 3) -> list[str]:
    """What ``evaluate`` says of the measurements the cameras could not make: how many, and
    the first ``shown`` with their joints and reasons (results.json's ``unseen`` has all)."""
    if not unseen:
        return []
    out = [f"{len(unseen)} measurement(s) not made by the cameras; the figures by vision "
           f"leave them out (results.json: unseen):"]  # fmt: skip
    for u in unseen[:shown]:
        joints = ", ".join(f"{float(v):.1f}" for v in u["d_um"])
        out.append(f"  joints ({joints}) µm: {u['reason']}")
    if len(unseen) > shown:
        out.append(f"  and {len(unseen) - shown} more")
    return out


def approach_line(move: ApproachMove) -> str:
    """What ``goto --along-approach-um`` prints before the arrival: the axis and the move."""
    axis = ", ".join(f"{v:.4f}" for v in move.axis.tolist())
    return (
        f"along the approach axis ({axis}) of joint {move.joint}, {move.elevation_deg:.2f}° "
        f"from the x-y plane: {move.distance_um:g} µm in {len(move.targets_um)} step(s) by "
        f"that joint alone (the model bends its path {move.bend_um:.3f} µm off the line)"
    )


def arrival_line(a: Arrival, frame: str = "{G}") -> str:
    """What ``microcal goto`` prints: where the tip arrived, how sure, how it got there;
    ``frame``: ``{G}`` (the cameras') or ``{M}`` (a one-camera rig's scope calibration,
    whose frames are the focus sweep's)."""
    fmt = ", ".join
    how = (
        "open loop"
        if a.mode == "open"
        else f"closed loop, {a.iterations} correction(s), {_ended(a)}"
    )
    frames = f"{a.frames} frames per camera" if frame == "{G}" else f"{a.frames} frames"
    return (
        f"arrived at ({fmt(f'{v:.3f}' for v in a.measured_um.tolist())}) µm in {frame}, "
        f"std ({fmt(f'{v:.3f}' for v in a.std_um.tolist())}) µm, "
        f"{sum(v * v for v in a.error_um.tolist()) ** 0.5:.3f} µm from the target as measured "
        f"({how}, {frames}); "
        f"joints ({fmt(f'{v:.3f}' for v in a.d_um.tolist())}) µm"
    )


def correction_line(step: ServoStep) -> str:
    """One measurement of a closed loop, as ``goto`` shows it while the loop goes on."""
    e = float(np.linalg.norm(step.error_um))
    then = ("correcting" if np.any(step.correction_um != 0)
            else "done")  # fmt: skip
    sure = f"{100 * step.p_within:.0f} % sure of the tolerance"
    return (f"closed loop, measurement {step.iteration + 1}: {e:.3f} µm from the target "
            f"({step.frames} frames, {sure}); {then}")  # fmt: skip


def _ended(a: Arrival) -> str:
    """How a closed loop ended, in words (the cap, and why it was reached)."""
    if a.tolerance_um is None or a.confidence is None:
        return f"ended by {a.status}"
    sure = f"{100 * a.confidence:.0f} % sure of {a.tolerance_um:g} µm"
    if a.status == "tolerance":
        return f"ended {sure}"
    if a.status == "resolution":
        return "ended as the next correction was below the positioner's resolution"
    floor = smallest_confirmable_um(a.cov_um2, a.confidence)
    ask = math.ceil(11 * floor) / 10  # 10 % above it, rounded up to 0.1 µm
    cap = f"stopped at its cap of {a.max_iterations} corrections, not {sure}"
    if floor >= a.tolerance_um:
        return (f"{cap}: the measurement alone (std up to {float(a.std_um.max()):.2f} µm) "
                f"confirms no less than {floor:.2f} µm; --tolerance-um {ask:g} "
                "would end on the tolerance")  # fmt: skip
    return f"{cap}; the error was still shrinking"


def ended_words(status: Mapping[str, int]) -> str:
    """How the targets of a closed loop ended, in words (``{"tolerance": 6, ...}``: "6 sure
    of the tolerance")."""
    words = {"tolerance": "sure of the tolerance", "resolution": "below the resolution",
             "iterations": "at the cap of corrections, not sure of the tolerance"}  # fmt: skip
    return ", ".join(f"{n} {words.get(k, k)}" for k, n in status.items() if n)


def closed_loop_line(s: ClosedLoopSummary) -> str:
    """One line on the closed loop: iterations, frames, how it ended, how sure it was."""
    status = ended_words(s.status)
    line = (
        f"closed loop to {s.tolerance_um:g} µm at {100 * s.confidence:.0f} %: "
        f"{s.targets} targets, {s.iterations_mean:.1f} iterations (at most "
        f"{s.iterations_max}), {s.frames_mean:.0f} frames per camera (at most "
        f"{s.frames_max}); ended: {status}"
    )
    if s.truth_within_tolerance is not None and s.truth_in_measured_95 is not None:
        line += (
            f"; by ground truth within the tolerance at {100 * s.truth_within_tolerance:.0f} "
            f"% of targets, inside the last measurement's 95 % region at "
            f"{100 * s.truth_in_measured_95:.0f} %"
        )
    return line


def demo_intro(out: Path, poses: int) -> str:
    """The line ``microcal demo`` starts with."""
    return (
        f"microcal demo on the simulated thesis platform, writing {out}/: stereo "
        f"calibration from rendered images, {poses} poses acquired with vision settling and "
        "measured in 3D, kinematic identification, compensation, and the ISO 9283 and "
        "decoupling tests."
    )


def demo_closing(result: DemoResult, out: Path, wall_s: float) -> list[TextTable | str]:
    """The lines ``microcal demo`` ends with: what it wrote, the terms selected."""
    model = result.models["polynomial"].model
    terms = "; ".join(
        f"{axis}: {', '.join(name for name, _, _ in model.axis_terms(i))}"
        for i, axis in enumerate("xyz")
    )
    return [
        *([stage_time_table(result.stages_s, wall_s)] if result.stages_s else []),
        f"polynomial terms selected stepwise: {terms}",
        f"wrote {out}/: the run (run.json, commands.csv, journal.jsonl, images/), "
        f"measurements.csv, cameras.json, calibration.json, results.json and report.html "
        f"({wall_s:.0f} s); open {out / 'report.html'} in a browser",
    ]


def stage_time_table(stages_s: Mapping[str, float], wall_s: float) -> TextTable:
    """The demo's wall time per stage (results.json ``timing.stages_s``), with what the
    stages leave of the whole (start-up, imports, printing) and the total."""
    rows = [[name, f"{t:.1f}", f"{100 * t / wall_s:.0f}" if wall_s > 0 else "-"]
            for name, t in stages_s.items()]  # fmt: skip
    rest = max(0.0, wall_s - sum(stages_s.values()))
    rows.append(["other (start-up, imports)", f"{rest:.1f}",
                 f"{100 * rest / wall_s:.0f}" if wall_s > 0 else "-"])  # fmt: skip
    rows.append(["total", f"{wall_s:.1f}", "100"])
    return TextTable("wall time per stage", ["stage", "s", "%"], rows, first_left=True)


def measurement_lines(results: Sequence[PoseMeasurement], path: Path) -> list[TextTable | str]:
    """What ``microcal measure`` prints of its pose measurements."""
    ok = [r for r in results if r.status == "ok"]
    lines: list[TextTable | str] = [f"measured {len(ok)} of {len(results)} poses; wrote {path}"]
    if ok:
        med = np.median([r.std_um for r in ok], axis=0)
        lines.append(
            "median standard deviation x/y/z: " + "/".join(f"{v:.2f}" for v in med) + " µm"
        )
    lines += [f"pose {r.pose} failed: {r.reason}" for r in results if r.status != "ok"]
    return lines


def _figure(value: object) -> float:
    return float(value) if isinstance(value, int | float) else float("nan")


def consistency_lines(figures: Mapping[str, object]) -> list[str]:
    """Sentences of a calibration's consistency figures (cameras.json's
    ``stereo.consistency``, :mod:`~microcal.vision.calibration_consistency`)."""
    lines: list[str] = []
    held = figures.get("held_out")
    if isinstance(held, Mapping):
        parts = []
        groups = dict(held.get("cameras") or {})
        if isinstance(held.get("joint"), Mapping):
            groups["all cameras together"] = held["joint"]
        for name, f in groups.items():
            if not isinstance(f, Mapping):
                continue
            tr, he = _figure(f.get("training_rms_px")), _figure(f.get("held_out_rms_px"))
            if np.isfinite(tr) and np.isfinite(he):
                parts.append(f"{name} {he:.3f} px against {tr:.3f} px (x{he / tr:.2f})")
        if parts:
            lines.append("held-out views (each fold of the views predicted by the others) against "
                         "the views fitted: " + "; ".join(parts))  # fmt: skip
    pitch = figures.get("pitch")
    if isinstance(pitch, Mapping):
        for axis, f in pitch.items():
            if not isinstance(f, Mapping):
                continue
            worst = _figure(f.get("worst_cell_error"))
            lines.append(
                f"target pitch triangulated along {axis}: {_figure(f.get('mean_um')):.2f} µm "
                f"against {_figure(f.get('nominal_um')):g} µm "
                f"({100 * _figure(f.get('error')):+.3f} %"
                + (f"; worst ninth of the field {100 * worst:+.3f} %" if np.isfinite(worst) else "")
                + ")"
            )
    closure = figures.get("closure")
    if isinstance(closure, list):
        for f in closure:
            if not isinstance(f, Mapping):
                continue
            a, b, c = f.get("cameras", ["?", "?", "?"])
            lines.append(
                f"{a} to {c} calibrated directly against composed through {b}: translations "
                f"differ by {100 * _figure(f.get('translation_gap')):.3f} % of "
                f"{_figure(f.get('baseline_um')):.0f} µm, rotations by "
                f"{_figure(f.get('rotation_gap_deg')):.3f} deg"
            )
    return lines


def stereo_lines(calibration: StereoCalibration, out: Path) -> list[TextTable | str]:
    """What ``microcal stereo-calibrate`` prints: the table, rejected views, the baseline."""
    lines: list[TextTable | str] = [stereo_table(calibration)]
    for name, c in calibration.cameras.items():
        lines += [f"rejected {name} {r['image']}: {r['reason']}" for r in c.views_rejected]
        if c.lens_model:
            lines.append(f"lens model of {name}: {c.lens_model['reason']}")
        if c.diagnostics:
            lines += [f"{name} is limited by: {v}" for v in c.diagnostics.verdict]
    for cam in dict.fromkeys(t["camera"] for t in calibration.turned_views):
        turned = [f"{t['image']} ({t['turn_deg']} deg)" for t in calibration.turned_views
                  if t["camera"] == cam]  # fmt: skip
        whom = "the other cameras'" if calibration.method.startswith("unknown") else "its views'"
        lines.append(
            f"turned the corner numbering of camera {cam} in {', '.join(turned)} to agree with "
            f"{whom} (the board looks the same turned)"
        )
    lines += [f"left out of the cameras' joint refinement {r['view']}: {r['reason']}"
              for r in calibration.views_rejected]  # fmt: skip
    lines += model_choice_lines(calibration)
    lines += [f"warning: {n}" for n in calibration.notes]
    lines += consistency_lines(calibration.consistency)
    if len(calibration.cameras) == 1:
        lines.append(f"one camera, RMS {calibration.rms_px:.4f} px; wrote {out}")
        return lines
    baseline = calibration.baseline_um
    lines.append(
        (f"baseline {baseline:.0f} µm; " if np.isfinite(baseline) else "")
        + f"angle between the first two cameras {calibration.angle_deg:.2f} deg; stereo RMS "
        f"{calibration.rms_px:.4f} px; wrote {out}"
    )
    return lines


def fit_lines(
    model: KinematicModel, validation: Mapping[str, object], header: str, wrote: str
) -> list[TextTable | str]:
    """What ``microcal fit`` prints: what was fitted, its terms, validation (calibration.json's
    object, read as a :class:`~microcal.formats.records.ValidationRecord`), what it wrote."""
    from ..formats.json_file import parse_schema
    from ..formats.records import ValidationRecord

    figures = parse_schema(ValidationRecord, validation, "validation")
    return [header, terms_table(model), *validation_lines(figures), wrote]


def outlier_lines(result: Identification, poses: ArrayLike) -> list[str]:
    """The warnings of ``microcal fit`` about poses the model misses far more than the rest."""
    left_out = set(result.excluded)
    pose = np.asarray(poses)
    return [
        f"warning: pose {int(pose[row])} is {dist:.2f} µm from the model, {z:.0f} robust standard "
        f"deviations: " + ("left out of the fit" if row in left_out else
                           "check it (--exclude-outliers leaves such poses out)")
        for row, dist, z in result.outliers
    ]  # fmt: skip


def range_note(range_um: ArrayLike, what: str = "these joints") -> str:
    """The note that joints lie outside the (3, 2) range the model was identified on."""
    ranges = ",".join(f"{lo:.0f}:{hi:.0f}" for lo, hi in np.asarray(range_um))
    return (f"note: {what} lie outside the range the model was identified on {ranges} µm; "
            "the model extrapolates there")  # fmt: skip


def solution_lines(solution: Solution, calibration: ManipulatorCalibration) -> list[str]:
    """The notes ``microcal solve`` prints on stderr about a compensator's solution."""
    lines = []
    if solution.outside_range is not None:
        lines.append(range_note(solution.outside_range))
    if solution.approach_from_below:
        from ..control.feedforward import APPROACH_UM

        lines.append(
            "note: the model holds the reversal error: bring each joint to these values moving "
            f"up (e.g. from {APPROACH_UM:g} µm below), or the tip lands off by that error"
        )
    residual = ", ".join(f"{v:.2e}" for v in solution.residual_um)
    kind, name = calibration.model.kind, calibration.name
    held, off_um = calibration.model.held_um, float(np.linalg.norm(solution.residual_um))
    if held and off_um > 1e-3:
        lines.append(
            f"note: {name!r} holds {', '.join(held)} still, so it reaches a surface of {{G}}; "
            f"this target is {off_um:.3f} µm off it, and the joints give its nearest point"
        )
    lines.append(f"{kind} model of {name!r}: model(d) - target = {residual} µm")
    return lines


def _offset_text(result: CheckResult) -> tuple[str, str]:
    """A check's offset and its standard deviation, each as ``x, y, z`` (µm)."""
    off = ", ".join(f"{v:+.2f}" for v in result.offset_um.tolist())
    std = ", ".join(f"{v:.2f}" for v in result.offset_std_um.tolist())
    return off, std


def periodic_check_line(result: CheckResult, after_poses: int, alpha: float, flag: str) -> str:
    """The line a check made during a run (``acquire --check-calibration``) prints: its
    verdict in words, and for a verdict that is not ``valid`` how often that is chance."""
    off, std = _offset_text(result)
    chance = f"about one check in {1 / alpha:.0f} says so by chance"
    says = {"valid": f"valid (offset ({off}) ± ({std}) µm)",
            "offset": f"offset moved by ({off}) ± ({std}) µm (p {result.offset_p_value:.3f}; "
                      f"{chance}: if the next says it too, 'microcal check ... --update FILE' "
                      "corrects it)",
            "refit": f"the model no longer fits (p {result.p_value:.3f}; {chance}; offset "
                     f"({off}) ± ({std}) µm): if it repeats, calibrate again"}  # fmt: skip
    line = f"check after {after_poses} poses: {says[result.verdict]}"
    return line + (f"; {flag}" if flag else "")


#: What a check on the simulator that repeated its reference's frames says.
REPLAYED_NOTE = ("note: these measurements equal the reference check's exactly: the simulated "
                 "rig, opened with the same seed, replays the same frames (a real rig's noise "
                 "differs from check to check)")  # fmt: skip


def check_lines(
    result: CheckResult,
    flag: str = "",
    update: CheckUpdate | None = None,
    replayed: bool = False,
) -> list[str]:
    """What ``microcal check`` prints: the verdict, the offset, the tests, a flag, the update,
    and whether a simulated rig replayed the reference check's frames."""
    off, std = _offset_text(result)
    says = {"valid": "the calibration is still valid",
            "offset": f"the offset moved by ({off}) ± ({std}) µm; the model still fits "
                      "(--update writes a calibration with the new offset)",
            "refit": "the model no longer fits these poses: calibrate again (acquire, measure, "
                     "fit)"}[result.verdict]  # fmt: skip
    against = "reference check" if result.reference else "calibration"
    out = [f"{result.verdict}: {says}",
           f"{result.n_poses} poses against the {against}: fit chi2 "
           f"{result.chi2:.1f} (p {result.p_value:.3f}), offset ({off}) ± ({std}) µm "
           f"(p {result.offset_p_value:.3f})"]  # fmt: skip
    if flag:
        out.append(f"flag: {flag}")
    if update is not None and update.calibration is None:
        out.append(f"no update written: {update.refused}")
    elif update is not None:
        out.append(f"wrote {update.calibration} (offset re-fitted); checked again: "
                   f"{update.verdict_after}")  # fmt: skip
    if replayed:
        out.append(REPLAYED_NOTE)
    return out


def station_summary(result: StationDemoResult) -> list[TextTable | str]:
    """What ``microcal demo --preset thesis-platform`` prints: each device's figures in the
    one {G}, and the meet test of the two manipulators (a ``StationDemoResult``)."""
    devices = TextTable(
        "Devices calibrated in one {G} (AP: ISO 9283 mean, µm)",
        ["device", "validation µm", "AP uncal. truth", "AP optimal truth", "AP optimal vision"],
        first_left=True,
    )
    for name, r in result.devices.items():
        pa = r.evaluation.pose_accuracy or {}

        def ap(source: str, condition: str, pa: BySource[PoseAccuracyFigures] = pa) -> str:
            figures = pa.get(source, {}).get(condition)
            return "-" if figures is None else f"{figures.mean_ap_p_um:.2f}"

        split = r.models["polynomial"].split
        val = None if split is None else split.summary.mean
        devices.rows.append([name, "-" if val is None else f"{val:.2f}",
                             ap("truth", "uncalibrated"), ap("truth", "optimal"),
                             ap("vision", "optimal")])  # fmt: skip
    meet = TextTable(
        "Meet test: m2's tip sent to m1's (|p2 - p1|, µm)",
        ["loop", "targets", "vision mean", "vision max", "truth mean", "truth max"],
        first_left=True,
    )
    for mode, m in result.meet.items():
        cells = []
        for source in ("vision", "truth"):
            s = m.gap_summary(source)
            cells += ["-", "-"] if s is None else [f"{s.mean:.2f}", f"{s.max:.2f}"]
        meet.rows.append([mode, str(len(m.targets_um)), *cells])
    return [devices, meet]
