"""The calibration report: one self-contained HTML file built from a run directory.

``microcal report RUN_DIR`` and ``microcal demo`` write ``report.html``; figures are drawn
with matplotlib and embedded as PNG data, so the file reads offline and can be mailed.
"""

from .build import build_report, write_report
from .data import RunData, load_run

__all__ = ["RunData", "build_report", "load_run", "write_report"]
