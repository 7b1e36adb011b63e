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

__all__ = ["study_page", "study_table"]

#: A run's figures per model or condition.
Figures = Callable[["SeedRun"], dict[str, float]]

#: The figures drawn: what they are, and how a run gives them.
FIGURES: tuple[tuple[str, Figures], ...] = (
    ("validation error (mean, Eq 5.1), µm", lambda r: r.validation_mean_um),
    ("pose accuracy AP by truth (mean over the Table 5-2 poses), µm", lambda r: r.ap_truth_mean_um),
    ("pose accuracy AP by the probe, µm", lambda r: r.ap_vision_mean_um),
    ("multi-directional variation vAP by truth, µm", lambda r: r.vap_truth_mean_um),
)


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
        parts.append(f"<img alt='{escape(title)}' src='{_strip(runs, of, title)}'>")
    parts.append("<h2>Summary</h2><table><tr><th>figure</th><th>median</th><th>p90</th></tr>")
    for name, med, p90 in study_table(study):
        parts.append(f"<tr><td>{escape(name)}</td><td>{med:.3g}</td><td>{p90:.3g}</td></tr>")
    parts.append("</table></body></html>")
    return "\n".join(parts)
