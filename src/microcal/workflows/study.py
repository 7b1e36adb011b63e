"""``microcal study``: calibrate and evaluate on many seeded simulated platforms."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from ..experiments.study import StudyConfig, run_study
from ..experiments.study_figures import SeedRun, Study
from ..formats.study_file import check_study_folder, study_platform, write_study
from ..report.study_page import study_page

__all__ = ["SeedRun", "Study", "StudyConfig", "study"]


def study(
    out: Path,
    preset: str,
    rig: Path | None,
    seeds: range,
    config: StudyConfig,
    workers: int | None = None,
    tick: Callable[[int, int, SeedRun], None] | None = None,
) -> tuple[Path, Study]:
    """Run the study and write study.json and study.html into ``out``.

    ``preset`` or ``rig`` (a simulated rig file: its preset and settings) names the
    platform (its settings replace ``config.overrides``); ``tick(done, total, run)`` is
    called as each seed ends. Returns study.json's path and the study.
    """
    name, overrides = study_platform(preset, rig)
    check_study_folder(out)
    result = run_study(name, seeds, dataclasses.replace(config, overrides=overrides), workers, tick)
    return write_study(out, result, study_page(result)), result
