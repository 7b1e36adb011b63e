"""The calibration report: one self-contained HTML file built from a run directory.

``microcal report RUN_DIR`` and ``microcal demo`` write ``report.html``; figures are drawn
with matplotlib and embedded as PNG data, so the file reads offline and can be mailed.
The tables the commands print (:mod:`.text_tables`, :mod:`.console`) are light; the report's
names below load matplotlib and the file readers on first use, so the command line starts
without them.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .build import build_report, write_report
    from .data import ReportInputs, RunData, load_run

__all__ = ["ReportInputs", "RunData", "build_report", "load_run", "write_report"]
_WHERE = {
    "build_report": ".build",
    "write_report": ".build",
    "RunData": ".data",
    "ReportInputs": ".data",
    "load_run": ".data",
}


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
