"""The study page (study.html): each figure's distribution over the seeds, per model."""

from __future__ import annotations

from html import escape
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from .figures import _uri

__all__ = ["study_page", "study_table"]

#: The figures drawn, their keys in a run and what they are.
FIGURES = (
    ("validation_mean_um", "validation error (mean, Eq 5.1), µm"),
    ("ap_truth_mean_um", "pose accuracy AP by truth (mean over the Table 5-2 poses), µm"),
    ("ap_vision_mean_um", "pose accuracy AP by the probe, µm"),
    ("vap_truth_mean_um", "multi-directional variation vAP by truth, µm"),
)


def _strip(runs: list[dict[str, Any]], key: str, title: str) -> str:
    names = list(runs[0][key])
    fig = Figure(figsize=(7, 2.6))
    ax = fig.add_subplot()
    rng = np.random.default_rng(0)  # horizontal jitter of the points only
    for i, name in enumerate(names):
        v = np.array([r[key][name] for r in runs], dtype=float)
        ax.plot(i + rng.uniform(-0.15, 0.15, v.size), v, "o", ms=3, alpha=0.7)
        ax.plot([i - 0.3, i + 0.3], [np.median(v)] * 2, "k-", lw=1.5)
    ax.set_xticks(range(len(names)), names)
    ax.set_yscale("log")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return _uri(fig)


def study_table(study: dict[str, Any]) -> list[tuple[str, float, float]]:
    """(figure, median, 90th percentile) of the summary's figures, in name order."""
    return [(k, v["median"], v["p90"]) for k, v in study["summary"].items()]


def study_page(study: dict[str, Any]) -> str:
    """The HTML of the study page (self-contained: figures inline)."""
    runs = study["runs"]
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>microcal study: {escape(study['preset'])}</title>",
        "<style>body{font-family:sans-serif;max-width:60em;margin:auto}"
        "td,th{padding:0 .6em;text-align:right}td:first-child{text-align:left}</style>",
        "</head><body>",
        f"<h1>Study of the {escape(study['preset'])} preset, {len(runs)} seeds</h1>",
        "<p>Each point is one seed's platform; the bar is the median. <em>oracle</em> is the "
        "true kinematics with its known parts re-estimated from the same measurements: the "
        "floor of every figure. <em>prior</em> (with <code>--prior</code>) is the Bayes "
        "estimator under the draw's own prior: what estimating the profiles from the same "
        "measurements costs any model, on average.</p>",
    ]
    for key, title in FIGURES:
        parts.append(f"<img alt='{escape(title)}' src='{_strip(runs, key, title)}'>")
    parts.append("<h2>Summary</h2><table><tr><th>figure</th><th>median</th><th>p90</th></tr>")
    for name, med, p90 in study_table(study):
        parts.append(f"<tr><td>{escape(name)}</td><td>{med:.3g}</td><td>{p90:.3g}</td></tr>")
    parts.append("</table></body></html>")
    return "\n".join(parts)
