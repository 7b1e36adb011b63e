"""The study page (study.html): each figure's distribution over the seeds, per model."""

from __future__ import annotations

from collections.abc import Callable
from html import escape
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from .figures import _uri

if TYPE_CHECKING:
    from ..experiments.study_figures import SeedRun, Study

__all__ = ["rig_time_lines", "rig_time_table", "study_page", "study_table"]

#: Rig minutes the curves of an adaptive study are read at.
RIG_MINUTES: tuple[float, ...] = (2, 4, 6, 8, 10, 12, 15, 20, 25, 30, 40)

#: A run's figures per model or condition.
Figures = Callable[["SeedRun"], dict[str, float]]

#: The figures drawn: what they are, and how a run gives them.
FIGURES: tuple[tuple[str, Figures], ...] = (
    ("validation error (mean, Eq 5.1), µm", lambda r: r.validation_mean_um),
    ("pose accuracy AP by truth (mean over the Table 5-2 poses), µm", lambda r: r.ap_truth_mean_um),
    ("pose accuracy AP by the probe, µm", lambda r: r.ap_vision_mean_um),
    ("multi-directional variation vAP by truth, µm", lambda r: r.vap_truth_mean_um),
    ("compensated tip's true error, 95th percentile over the workspace, µm",
     lambda r: r.tip_error_p95_um),
)  # fmt: skip


def _strip(runs: list[SeedRun], of: Figures, title: str) -> str:
    names = list(of(runs[0]))
    fig = Figure(figsize=(7, 2.6))
    ax = fig.add_subplot()
    rng = np.random.default_rng(0)  # horizontal jitter of the points only
    for i, name in enumerate(names):
        v = np.array([of(r)[name] for r in runs], dtype=float)
        ax.plot(i + rng.uniform(-0.15, 0.15, v.size), v, "o", ms=3, alpha=0.7)
        ax.plot([i - 0.3, i + 0.3], [np.median(v)] * 2, "k-", lw=1.5)
    ax.set_xticks(range(len(names)), names)
    ax.set_yscale("log")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return _uri(fig)


def _at_minutes(curve: list[dict[str, float]], key: str, minutes: float) -> float:
    """A curve's figure at a rig time: that of its last point by then (NaN before its first)."""
    got = [c[key] for c in curve if c["rig_time_s"] <= 60.0 * minutes]
    return float(got[-1]) if got else float("nan")


def _curves(run: SeedRun) -> dict[str, list[dict[str, float]]]:
    if run.adaptive is None:
        return {}
    return {
        "adaptive": [c.to_json() for c in run.adaptive.curve],
        "random": [c.to_json() for c in run.adaptive.random_curve],
    }


def rig_time_table(study: Study) -> list[tuple[float, dict[str, tuple[float, float]]]]:
    """True error against rig time per design, the median over the seeds: for each of
    :data:`RIG_MINUTES`, per design, (AP by truth at the Table 5-2 poses, 95th percentile of
    the tip's error over the workspace), µm, of the model each run had by then. Empty for a
    study without the adaptive design (which grows the random design beside it)."""
    curves = [_curves(r) for r in study.runs]
    if not any(curves):
        return []
    out = []
    for minutes in RIG_MINUTES:
        row: dict[str, tuple[float, float]] = {}
        for design in ("adaptive", "random"):
            ap = [_at_minutes(c[design], "ap_truth_mean_um", minutes) for c in curves if c]
            tip = [_at_minutes(c[design], "tip_error_p95_um", minutes) for c in curves if c]
            row[design] = (_median(ap), _median(tip))
        out.append((minutes, row))
    return out


def rig_time_lines(study: Study) -> list[str]:
    """:func:`rig_time_table` as the lines ``microcal study`` prints (none without it)."""
    table = rig_time_table(study)
    if not table:
        return []
    out = ["true error against rig time (median over seeds; AP by truth / tip error p95, µm):"]
    for minutes, row in table:
        cells = "  ".join(f"{d} {ap:6.3g} / {tip:6.3g}" for d, (ap, tip) in row.items())
        out.append(f"  {minutes:4g} min  {cells}")
    return out


def _median(values: list[float]) -> float:
    """The median over the seeds, a seed without a figure counting as worse than any."""
    v = np.array(values, dtype=float)
    if not v.size or np.isnan(v).sum() * 2 >= v.size:
        return float("nan")
    return float(np.median(np.where(np.isnan(v), np.inf, v)))


def _curve_plot(study: Study) -> str:
    table = rig_time_table(study)
    fig = Figure(figsize=(7, 3))
    ax = fig.add_subplot()
    minutes = [m for m, _ in table]
    for design, style in (("adaptive", "o-"), ("random", "s--")):
        ax.plot(minutes, [row[design][0] for _, row in table], style, ms=4,
                label=f"{design}: AP by truth")  # fmt: skip
        ax.plot(minutes, [row[design][1] for _, row in table], style, ms=4, alpha=0.5,
                label=f"{design}: tip error p95")  # fmt: skip
    ax.set_xlabel("rig time, minutes")
    ax.set_ylabel("true error, µm (median over seeds)")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return _uri(fig)


def study_table(study: Study) -> list[tuple[str, float, float]]:
    """(figure, median, 90th percentile) of the summary's figures, in name order."""
    return [(k, v.median, v.p90) for k, v in study.summary.items()]


def study_page(study: Study) -> str:
    """The HTML of the study page (self-contained: figures inline)."""
    runs = study.runs
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>microcal study: {escape(study.preset)}</title>",
        "<style>body{font-family:sans-serif;max-width:60em;margin:auto}"
        "td,th{padding:0 .6em;text-align:right}td:first-child{text-align:left}</style>",
        "</head><body>",
        f"<h1>Study of the {escape(study.preset)} preset, {len(runs)} seeds</h1>",
        "<p>Each point is one seed's platform; the bar is the median. <em>oracle</em> is the "
        "true kinematics with its known parts re-estimated from the same measurements: the "
        "floor of every figure. <em>prior</em> (with <code>--prior</code>) is the Bayes "
        "estimator under the draw's own prior: what estimating the profiles from the same "
        "measurements costs any model, on average.</p>",
    ]
    for title, of in FIGURES:
        if of(runs[0]):
            parts.append(f"<img alt='{escape(title)}' src='{_strip(runs, of, title)}'>")
    if rig_time_table(study):
        parts.append(
            "<h2>True error against rig time</h2><p>The adaptive design and the "
            "random design grown on the same seeds: the error of the model each had "
            "after so many minutes of moves, settling, frames and fits.</p>"
        )
        parts.append(f"<img alt='true error against rig time' src='{_curve_plot(study)}'>")
    parts.append("<h2>Summary</h2><table><tr><th>figure</th><th>median</th><th>p90</th></tr>")
    for name, med, p90 in study_table(study):
        parts.append(f"<tr><td>{escape(name)}</td><td>{med:.3g}</td><td>{p90:.3g}</td></tr>")
    parts.append("</table></body></html>")
    return "\n".join(parts)
