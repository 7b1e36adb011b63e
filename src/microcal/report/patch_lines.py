"""The lines ``microcal demo --preset patch`` prints: each stage's headline figures."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING

from .text_tables import ended_words

if TYPE_CHECKING:
    from ..experiments.patch_demo import PatchDemoResult

__all__ = ["patch_demo_lines"]

_CONDITIONS = ("uncalibrated", "matrix", "optimal", "closed_loop")


def _ap(by_condition: Mapping[str, object], name: str) -> str:
    fig = by_condition.get(name)
    if fig is None:
        return "-"
    mean, worst = getattr(fig, "mean_ap_p_um", math.nan), getattr(fig, "max_ap_p_um", math.nan)
    return f"{mean:.3f} / {worst:.3f}"


def patch_demo_lines(result: PatchDemoResult) -> list[str]:
    """What the demo measured, stage by stage, with the rig's time per stage."""
    r = result
    cal = r.scope.calibration
    rig = r.rig_s
    ok = r.run.ok
    frames = sum(t.frames for t in r.run.tips)
    axis = "/".join(f"{v:.3f}" for v in r.measurement_rms_axis_um)
    how = "focus sweeps" if r.method == "sweep" else "the reference stack"
    acq_min = rig.get("acquisition and measurement", 0.0) / 60
    out = [
        f"1. Slide: pixel size {cal.pixel_size_um:.6f} µm, focus axis {cal.focus_angle_deg:.3f}° "
        f"from the optical axis; against the truth: scale {r.scope_errors['scale_error_pct']:.4f} "
        f"%, rotation {r.scope_errors['rotation_error_deg']:.5f}° ({cal.views} views, "
        f"{rig.get('slide', 0.0):.0f} s of rig time)",
        f"2. Acquired and measured {int(ok.sum())} of {len(ok)} poses ({frames} frames, "
        f"{how}; {acq_min:.1f} min of rig time): "
        f"error vs ground truth {r.measurement_rms_um:.3f} µm RMS, x/y/z {axis}; errors over "
        f"the stated covariance: mean square {r.mahalanobis_mean_sq:.2f} (3 when it matches)",
    ]
    for name, ident in r.models.items():
        v = ident.validation
        out.append(f"3. {name} model: held-out error mean {v['mean_um']:.3f} µm, max "
                   f"{v['max_um']:.3f} µm ({v['method']})")  # fmt: skip
    out.append(f"   measurement's own error on those poses (oracle): mean "
               f"{r.oracle.get('mean', math.nan):.3f} µm")  # fmt: skip
    pa = r.evaluation.pose_accuracy or {}
    for source in ("truth", "vision"):
        if source in pa:
            row = ", ".join(f"{c} {_ap(pa[source], c)}" for c in _CONDITIONS if c in pa[source])
            out.append(f"4. ISO 9283 AP at the cube P1-P5 by {source} (mean / worst µm): {row}")
    if r.volume_accuracy and "truth" in r.volume_accuracy:
        by = r.volume_accuracy["truth"]
        row = ", ".join(f"{c} {_ap(by, c)}" for c in _CONDITIONS if c in by)
        out.append(f"   AP at random points filling the working volume, by truth: {row}")
    if r.evaluation.closed_loop is not None:
        cl = r.evaluation.closed_loop
        out.append(f"   closed loop: {cl.targets} targets, {cl.iterations_mean:.1f} corrections "
                   f"on average; ended: {ended_words(cl.status)}")  # fmt: skip
    out.append(f"Rig time: calibration (slide, acquisition and measurement, fit) "
               f"{r.calibration_rig_s / 60:.1f} min; evaluation "
               f"{rig.get('evaluation', 0.0) / 60:.1f} min")  # fmt: skip
    return out
