"""study.json and study.html: a study's runs and their distributions (``microcal study``).

study.json (keys in ``docs/formats.md``): ``format`` ``microcal.study/1``, the preset, the
seeds, one entry per seed (its figures per model and the oracle's) and the summary (median
and 90th percentile of every figure). Both files are written atomically; an output folder
may be new or hold a study microcal wrote, nothing else of the same names.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from ..errors import InputError
from ..json_value import JsonRecord, JsonValue
from .atomic import write_text_atomic
from .json_file import check_json_output
from .outputs import check_output
from .safe_open import opened_regular

__all__ = ["FORMAT", "check_study_folder", "study_platform", "write_study"]

FORMAT = "microcal.study/1"
#: The first line of a study page microcal wrote (how it knows the page is its own).
PAGE_MARK = "<!-- microcal study page -->"


def _nulls(value: JsonValue) -> JsonValue:
    """NaN (a figure a failed condition has not) as JSON null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _nulls(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_nulls(v) for v in value]
    return value


def study_platform(
    preset: str, rig: str | os.PathLike[str] | None
) -> tuple[str, dict[str, object]]:
    """The preset and simulator settings a study runs: ``preset``, or a simulated rig file's
    preset and overrides (its seed is not used: a study's seeds are its own).

    Raises
    ------
    InputError
        Neither or both given, or a rig file of hardware.
    """
    if bool(preset) == (rig is not None):
        raise InputError("study: give --preset NAME or --rig FILE (a simulated rig), one of them")
    if rig is None:
        return preset, {}
    from ..devices.rig_spec import SimRigSpec
    from .rig_file import load_rig

    spec = load_rig(str(rig))
    if not isinstance(spec, SimRigSpec):
        raise InputError(
            f"--rig {rig}: a study runs on the simulator; give a rig with driver = sim"
        )
    return spec.preset, dict(spec.overrides)


def check_study_folder(out: str | os.PathLike[str]) -> Path:
    """Refuse, before any work, a folder whose study.json or study.html microcal did not
    write (or that cannot be written); returns the folder."""
    folder = Path(out)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"--out {folder}: is a file; give a folder such as study-population")
    check_json_output(folder / "study.json", FORMAT, "study-population/study.json")

    def foreign(p: Path) -> str | None:
        with opened_regular(p) as fh:
            first = fh.readline(4096).decode("utf-8", errors="replace").strip()
        return None if first == PAGE_MARK else "a page microcal did not write"

    check_output(folder / "study.html", kind="a study page", foreign=foreign,
                 example="study-population/study.html")  # fmt: skip
    return folder


def write_study(out: str | os.PathLike[str], study: JsonRecord, page: str) -> Path:
    """Write study.json (the study's ``to_json()``, a
    :class:`~microcal.experiments.study_figures.Study`) and study.html (``page``, the HTML of
    :func:`report.study_page`) into the folder ``out`` (made if missing); returns the path of
    study.json."""
    folder = check_study_folder(out)
    folder.mkdir(parents=True, exist_ok=True)
    text = json.dumps(_nulls({"format": FORMAT, **study.to_json()}), indent=1, allow_nan=False)
    path = write_text_atomic(folder / "study.json", text + "\n")
    write_text_atomic(folder / "study.html", PAGE_MARK + "\n" + page)
    return path
