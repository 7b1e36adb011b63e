"""Assemble the report: sections from the run's files, rendered with one jinja2 template."""

from __future__ import annotations

import datetime as _dt
import json
import os
from importlib import resources
from pathlib import Path
from typing import Any

import jinja2
import numpy as np

from .._version import __version__
from ..formats.atomic import write_text_atomic
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
from .data import RunData, load_run
from .text_tables import is_thesis_rig

__all__ = ["build_report", "compares_with_thesis", "write_report"]

THESIS_REPROJECTION_PX = {"top": REPROJECTION_ERROR_TOP_PX, "side": REPROJECTION_ERROR_SIDE_PX}
CONDITIONS = ("uncalibrated", "matrix", "optimal")


def compares_with_thesis(data: RunData) -> bool:
    """Whether the report sets the run's figures beside the thesis's.

    Only a run on the simulator's ``thesis`` preset reproduces the thesis's platform, so only
    its figures are comparable; a hardware rig, another preset or a run whose rig is not
    recorded (no run.json) is reported on its own.
    """
    return is_thesis_rig(data.rig)


def _rig_text(data: RunData) -> str:
    """One line naming the rig of a run, for a report without the thesis comparison."""
    rig = data.rig
    if rig is None:
        return "not recorded (no run.json)" if not data.manifest else "not recorded in run.json"
    driver = rig.get("driver")
    if driver == "sim":
        text = f"the simulator, preset {rig.get('preset', '?')}"
        if rig.get("seed") is not None:
            text += f", seed {rig['seed']}"
        if rig.get("overrides"):
            text += f", {len(rig['overrides'])} settings overridden"
        return text
    if driver == "hardware":
        parts = []
        manipulator = rig.get("manipulator")
        if isinstance(manipulator, dict) and manipulator.get("kind"):
            parts.append(f"manipulator {manipulator['kind']}")
        cameras = rig.get("cameras")
        if isinstance(cameras, dict) and cameras:
            parts.append(
                "cameras "
                + ", ".join(
                    f"{name} ({c['kind']})" if isinstance(c, dict) and c.get("kind") else name
                    for name, c in cameras.items()
                )
            )
        return "hardware" + (": " + "; ".join(parts) if parts else "")
    return f"driver {driver}"


def _stereo(data: RunData, thesis: bool) -> dict[str, Any] | None:
    if not data.cameras:
        return None
    cams = data.cameras.get("cameras", {})
    rows, per_view, residuals, sizes, maps = [], {}, {}, {}, {}
    for name, c in cams.items():
        K = np.asarray(c["K"], dtype=float)
        dist = list(c.get("dist", [0.0] * 5))
        rows.append(
            {
                "name": name,
                "rms_px": c.get("rms_px"),
                "thesis_px": THESIS_REPROJECTION_PX.get(name) if thesis else None,
                "views_used": c.get("views_used"),
                "rejected": c.get("views_rejected", []),
                "fx": K[0, 0],
                "fy": K[1, 1],
                "cx": K[0, 2],
                "cy": K[1, 2],
                "k1": dist[0] if dist else 0.0,
                "size": c.get("image_size_px"),
                "lens_model": c.get("lens_model"),
                "diagnostics": c.get("diagnostics"),
            }
        )
        umap = (c.get("diagnostics") or {}).get("uncertainty_map_px")
        if umap:
            maps[name] = np.asarray(umap, dtype=float)
        if c.get("per_view_rms_px"):
            per_view[name] = c["per_view_rms_px"]
        views = c.get("residuals_px") or {}
        if views:
            residuals[name] = np.vstack([np.asarray(v, dtype=float) for v in views.values()])
            sizes[name] = c["image_size_px"]
    stereo = data.cameras.get("stereo", {})
    return {
        "rows": rows,
        "method": stereo.get("method", ""),
        "baseline_um": stereo.get("baseline_um"),
        "per_view": figures.per_view_rms(per_view) if per_view else None,
        "residuals": figures.calibration_residuals(residuals) if residuals else None,
        "coverage": figures.calibration_coverage(residuals, sizes) if residuals else None,
        "field": figures.residual_field(residuals, sizes) if residuals else None,
        "uncertainty": figures.projection_uncertainty(
            maps, {n: cams[n]["image_size_px"] for n in maps}
        )
        if maps
        else None,
        "turned": stereo.get("turned_views", []),
        "pairs_rejected": stereo.get("views_rejected", []),
        "notes": stereo.get("notes", []),
        "angle_deg": stereo.get("angle_deg"),
    }


def _acquisition(data: RunData) -> dict[str, Any] | None:
    if data.commands_um is None and not data.journal:
        return None
    n_fit = None
    for entry in data.calibration.manipulators.values() if data.calibration else []:
        n_fit = entry.validation.get("n_fit")
    settle = np.array([float(r["settle_s"]) for r in data.journal if "settle_s" in r])
    failed = [
        {"pose": r.get("pose"), "stage": "acquisition", "reason": r.get("reason", "")}
        for r in data.journal
        if r.get("status") != "ok"
    ]
    if data.measurements is not None:
        failed += [
            {"pose": pose, "stage": "measurement", "reason": reason}
            for pose, reason in sorted(data.measurements.failed_reasons.items())
            if not reason.startswith("acquisition failed")
        ]
    design = data.manifest.get("design", {})
    return {
        "n_commands": None if data.commands_um is None else len(data.commands_um),
        "n_stored": sum(1 for r in data.journal if r.get("status") == "ok"),
        "design": design,
        "settle": data.manifest.get("settle"),
        "frames": data.manifest.get("frames_per_pose"),
        "mean_settle_s": float(settle.mean()) if settle.size else None,
        "max_settle_s": float(settle.max()) if settle.size else None,
        "design_figure": (
            figures.command_design(data.commands_um, n_fit)
            if data.commands_um is not None
            else None
        ),
        "settle_figure": figures.settle_times(settle) if settle.size else None,
        "failed": failed,
    }


def _measurement(data: RunData, thesis: bool) -> dict[str, Any] | None:
    m = data.measurements
    if m is None:
        return None
    out: dict[str, Any] = {
        "n_ok": len(m.pose),
        "n_failed": m.n_failed,
        "rms_error_um": data.results.get("measurement", {}).get("rms_error_um"),
        "claimed_um": CLAIMED_ACCURACY_UM if thesis else None,
    }
    if m.std_um is not None:
        out["median_std_um"] = np.median(m.std_um, axis=0).tolist()
        out["figure"] = figures.measurement_uncertainty(m.std_um)
    return out


def _models(data: RunData, thesis: bool) -> dict[str, Any] | None:
    if data.calibration is None:
        return None
    errors = data.model_errors()
    models = [
        {
            "kind": kind,
            "axes": [{"axis": a, "terms": model.axis_terms(i)} for i, a in enumerate("xyz")],
            "n_terms": int(np.sum(model.selected)),
            "held": ", ".join(f"{j} at {v:g} µm" for j, v in model.held_um.items()),
            "validation": validation,
            "thesis": VALIDATION_UM.get(kind) if thesis else None,
        }
        for kind, model, validation in data.models()
    ]
    figure = (
        figures.prediction_errors({e.kind: (e.poses, e.errors_um) for e in errors})
        if errors
        else None
    )
    return {"models": models, "figure": figure}


def _pose_accuracy(data: RunData, thesis: bool) -> dict[str, Any] | None:
    pa = data.results.get("pose_accuracy")
    if not pa:
        return None
    sources = [s for s in ("vision", "truth") if s in pa]
    tables = []
    for source in sources:
        for name in CONDITIONS:
            if name in pa[source]:
                tables.append({"source": source, "condition": name, **pa[source][name]})
    return {"sources": sources, "tables": tables, "thesis": POSE_ACCURACY_UM if thesis else {}}


def _decoupling(data: RunData, thesis: bool) -> dict[str, Any] | None:
    dc = data.results.get("decoupling")
    if not dc:
        return None
    sources = [s for s in ("vision", "truth") if s in dc]
    plots = []
    for name in CONDITIONS:
        runs = {
            source: (
                np.asarray(dc[source][name]["samples_um"], dtype=float),
                np.asarray(dc[source][name]["segment"], dtype=int),
            )
            for source in sources
            if dc[source].get(name, {}).get("samples_um")
        }
        if runs:
            plots.append({"condition": name, "figure": figures.decoupling(name, runs)})
    return {
        "sources": sources,
        "plots": plots,
        "thesis_ranges": DECOUPLING_UM if thesis else {},
        "thesis_omega": OMEGA_UM if thesis else {},
    }


def _iso(data: RunData) -> list[dict[str, Any]]:
    """ISO 9283's distance, stabilisation and drift rows, where evaluate ran them."""
    rows = []
    for source, per in data.results.get("distance_accuracy", {}).items():
        rows += [{"what": "distance AD_P / RD (7.4)", "source": source, "condition": c,
                  "value": f"{_fmt(d['ad_p_um'])} / {_fmt(d['rd_p_um'])} µm over "
                           f"{_fmt(d['commanded_um'], 0)} µm"} for c, d in per.items()]  # fmt: skip
    for source, per in data.results.get("stabilisation", {}).items():
        rows += [{"what": f"stabilisation mean / worst, ±{d['band_um']} µm (7.5)",
                  "source": source, "condition": c,
                  "value": f"{_fmt(d['mean_s'])} / {_fmt(d['max_s'])} s"}
                 for c, d in per.items()]  # fmt: skip
    for source, per in data.results.get("drift", {}).items():
        rows += [{"what": "drift dAP (7.7)", "source": source, "condition": c,
                  "value": f"{_fmt(d['drift_ap_um'])} µm over "
                           f"{_fmt((d['t_s'][-1] - d['t_s'][0]) / 3600 if d['t_s'] else None)} h"}
                 for c, d in per.items()]  # fmt: skip
    return rows


def _station(data: RunData, root: Path) -> dict[str, Any] | None:
    """The devices of a station demo's results.json and its meet test (None for a run)."""
    results = data.results or {}
    devices, meet = results.get("devices"), results.get("meet")
    if not isinstance(devices, dict):
        return None
    rows = []
    for name, r in devices.items():
        pa = r.get("pose_accuracy", {}) if isinstance(r, dict) else {}

        def ap(source: str, condition: str, pa: dict[str, Any] = pa) -> Any:
            return pa.get(source, {}).get(condition, {}).get("mean_ap_p_um")

        poly = (r.get("models", {}) if isinstance(r, dict) else {}).get("polynomial", {})
        link = f"{name}/report.html" if (root / name / "report.html").is_file() else ""
        rows.append({"name": name, "validation": poly.get("validation", {}).get("mean_um"),
                     "uncalibrated": ap("truth", "uncalibrated"),
                     "optimal_truth": ap("truth", "optimal"),
                     "optimal_vision": ap("vision", "optimal"), "link": link})  # fmt: skip
    meets = []
    for mode, m in (meet or {}).items() if isinstance(meet, dict) else ():
        vision, truth = m.get("vision") or {}, m.get("truth") or {}
        meets.append({"mode": mode, "targets": len(m.get("targets_um", [])),
                      "vision_mean": vision.get("mean_um"), "vision_max": vision.get("max_um"),
                      "truth_mean": truth.get("mean_um"),
                      "truth_max": truth.get("max_um")})  # fmt: skip
    return {"devices": rows, "meet": meets}


def _checks(data: RunData) -> dict[str, Any] | None:
    if not data.checks:
        return None
    offsets = np.array([c["offset_um"] for c in data.checks], dtype=float)
    std = np.array([c["offset_std_um"] for c in data.checks], dtype=float)
    verdicts = [str(c["verdict"]) for c in data.checks]
    devices = [str(c.get("manipulator") or "m1") for c in data.checks]
    return {"rows": data.checks, "figure": figures.check_history(offsets, std, verdicts, devices)}


def _provenance(data: RunData) -> list[tuple[str, Any]]:
    rows: list[tuple[str, Any]] = [("run directory", str(data.run_dir))]
    for label, prov in (
        ("run", data.manifest.get("provenance")),
        ("cameras", (data.cameras or {}).get("provenance")),
        ("calibration", data.calibration.provenance if data.calibration else None),
        ("results", data.results.get("provenance")),
    ):
        for key, value in (prov or {}).items():
            rows.append((f"{label}: {key}", _plain(value)))
    if data.manifest.get("rig"):
        rows.append(("rig", _plain(data.manifest["rig"])))
    return rows


def _plain(value: Any) -> str:
    return json.dumps(value, sort_keys=True) if isinstance(value, dict | list) else str(value)


def build_report(run_dir: str | os.PathLike[str]) -> str:
    """The report of a run directory as one self-contained HTML page.

    Sections whose files are missing say so instead of failing, so a report can be made at
    any stage of a calibration (after ``acquire``, after ``fit``, after ``evaluate``).
    The thesis's figures stand beside the run's only for a run on the simulator's thesis
    preset (`compares_with_thesis`); any other run is reported with its own figures alone.
    """
    data = load_run(run_dir)
    thesis = compares_with_thesis(data)
    context = {
        "title": f"microcal calibration report: {Path(run_dir).resolve().name}",
        "version": __version__,
        "generated": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "results": data.results,
        "stereo": _stereo(data, thesis),
        "acquisition": _acquisition(data),
        "measurement": _measurement(data, thesis),
        "models": _models(data, thesis),
        "pose_accuracy": _pose_accuracy(data, thesis),
        "decoupling": _decoupling(data, thesis),
        "iso": _iso(data),
        "checks": _checks(data),
        "station": _station(data, Path(run_dir)),
        "provenance": _provenance(data),
        "rig": _rig_text(data),
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
    env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined)
    env.filters["f"] = _fmt
    return env.from_string(text).render(**context)


def _fmt(value: Any, digits: int = 2) -> str:
    if value is None:
        return "-"
    try:
        x = float(value)
    except (TypeError, ValueError):
        return str(value)
    return "-" if not np.isfinite(x) else f"{x:.{digits}f}"


def write_report(
    run_dir: str | os.PathLike[str], out: str | os.PathLike[str] | None = None
) -> Path:
    """Build the report and write it atomically (default: ``RUN_DIR/report.html``)."""
    path = Path(out) if out is not None else Path(run_dir) / "report.html"
    return write_text_atomic(path, build_report(run_dir))
