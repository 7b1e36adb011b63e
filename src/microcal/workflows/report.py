"""``microcal report``: a run's calibration report, one self-contained HTML file."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..formats.outputs import check_output, foreign_report
from ..report import ReportInputs, write_report

__all__ = ["ReportInputs", "report"]


def report(run_dir: Path, out: Path | None = None, inputs: ReportInputs | None = None) -> Path:
    """Write the report of the run directory ``run_dir`` to ``out`` (default
    ``run_dir/report.html``); returns its path. ``inputs``: files kept outside the run
    directory (its own cameras.json, calibration.json and results.json otherwise).

    Raises
    ------
    InputError
        ``run_dir`` is not a directory, or ``out`` is a file microcal did not write.
    """
    if not run_dir.is_dir():
        raise InputError(f"{run_dir}: not a directory (expected a run directory)")
    target = out if out is not None else run_dir / "report.html"
    check_output(target, kind="a microcal report", foreign=foreign_report, example="report.html")
    return write_report(run_dir, target, inputs)
