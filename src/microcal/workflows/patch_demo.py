"""``microcal demo --preset patch``: the one-camera ``patch`` rig's whole calibration and its
files.

Writes into ``--out`` (new, empty, or an earlier patch demo's): ``journal.jsonl`` (each pose
as it is measured: its record and its tip in {M}), ``scope.json`` (the camera against its
stage, objective ``40x``), ``calibration.json`` (the manipulator's models; its joints counted
from the start pose, ``results.json``'s ``joint_origin_um``) and ``results.json`` (the
thesis demo's sections where they apply: ``measurement``, ``models``, ``oracle``,
``acquisition``, ``pose_accuracy``, ``closed_loop``, ``timing``; and the rig's own:
``scope``, ``volume_accuracy``, ``rig_time_s``) and ``report.html`` (the report of those files,
its one-camera sections: :mod:`microcal.report.one_camera_section`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..formats.outputs import check_writable
from .demo_results import fit_sections

if TYPE_CHECKING:
    from ..experiments.patch_demo import PatchDemoResult
    from ..journal_record import JournalRecord
    from ..kinematics.manipulator_calibration import ManipulatorCalibration

__all__ = ["PATCH_FILES", "PatchDemoRun", "patch_demo"]

#: What the patch demo writes into its directory (and may replace on the next one).
PATCH_FILES = frozenset(
    {"journal.jsonl", "scope.json", "calibration.json", "results.json", "report.html"}
)


def _check_dir(out: Path) -> None:
    """``out`` new, empty, or holding only a patch demo's files (removed)."""
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; choose a directory")
    check_writable(out, f"--out {out}")
    if not out.exists():
        out.mkdir(parents=True)
        return
    foreign = sorted(p.name for p in out.iterdir() if p.name not in PATCH_FILES)
    if foreign:
        named = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
        raise InputError(
            f"--out {out}: holds files that an earlier patch demo did not write ({named}); "
            f"choose a new or empty directory"
        )
    for name in PATCH_FILES:
        (out / name).unlink(missing_ok=True)


class PatchDemoRun:
    """What :func:`patch_demo` returns: the result and the directory written."""

    def __init__(self, result: PatchDemoResult, out: Path, wall_s: float) -> None:
        self.result = result
        self.out = out
        self.wall_s = wall_s


def patch_demo(
    out: Path,
    seed: int = 0,
    poses: int = 80,
    quick: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
    started: Callable[[], None] | None = None,
    method: str = "sweep",
) -> PatchDemoRun:
    """Run the ``patch`` demo (:func:`~microcal.experiments.patch_demo.run_patch_demo`) and
    write its files; ``quick``: one ISO cycle, 5 points of the volume, the slide on 384 px;
    ``method``: the tips' depth by focus sweeps or by the tool's reference stack."""
    from ..experiments.patch_demo import MIN_POSES, run_patch_demo
    from ..experiments.stage_clock import StageClock
    from ..formats.calibration_file import Calibration, write_calibration
    from ..formats.pose_journal import PoseJournal
    from ..formats.provenance import provenance
    from ..formats.results_file import update_results
    from ..formats.scope_file import write_objective
    from ..report import write_report

    wall0 = time.monotonic()
    if poses < MIN_POSES:
        raise InputError(f"--poses: the patch demo needs {MIN_POSES} or more, got {poses}")
    _check_dir(out)
    if started is not None:
        started()
    journal = PoseJournal(out / "journal.jsonl")
    stages = StageClock()
    result = run_patch_demo(
        seed, poses, cycles=1 if quick else 3, volume_poses=5 if quick else 20,
        slide_roi_px=384 if quick else 512,
        progress=progress, stages=stages, method=method,
        store=lambda record, tip: journal.append(record.to_json() | tip.to_json()),
    )  # fmt: skip
    with stages.stage("files"):
        prov = provenance(command="demo", seed=seed)
        write_objective(out / "scope.json", "40x", result.scope.calibration.to_json(), prov)
        if result.manipulator is None:
            raise InputError("demo: nothing was identified; no calibration to write")
        entry = _with_frame_keys(result)
        write_calibration(out / "calibration.json", Calibration({entry.name: entry}, {}, prov))
        update_results(out / "results.json", _results(result, prov))
    result.stages_s = dict(stages.stages_s)
    wall = time.monotonic() - wall0
    update_results(out / "results.json", {"timing": {
        "simulated_s": result.sim_time_s, "wall_s": wall, "stages_s": result.stages_s,
        "rig_s": result.rig_s, "calibration_rig_s": result.calibration_rig_s,
    }})  # fmt: skip
    write_report(out)  # the report of the files (results.json's timing: without it)
    return PatchDemoRun(result, out, time.monotonic() - wall0)


def _with_frame_keys(result: PatchDemoResult) -> ManipulatorCalibration:
    """The manipulator's calibration with where its joints are counted from
    (``joint_origin_um``, the start pose's joints) and the working volume in {M} it was made
    for (``working_volume_um``: low and high corners), so that a command on the rig counts
    the joints as the model does and evaluates inside the volume."""
    from ..experiments.patch_demo import PATCH_VOLUME_HALF_UM

    entry = result.manipulator
    assert entry is not None
    half = np.asarray(PATCH_VOLUME_HALF_UM, dtype=np.float64)
    extra = {**entry.extra, "joint_origin_um": np.asarray(result.joint_origin_um).tolist(),
             "working_volume_um": [(-half).tolist(), half.tolist()]}  # fmt: skip
    return dataclasses.replace(entry, extra=extra)


def _measured(result: PatchDemoResult, records: list[JournalRecord]) -> dict[str, object]:
    """The demo's ``measurement``, ``models``, ``oracle`` and ``acquisition`` sections; the
    measurement's with the share of true tips inside their stated 95 % region (``in_95``),
    the acquisition's with its frames and how the tips' depth was found (``method``)."""
    from ..control.closed_loop import CHI2_3_95

    frames = int(sum(t.frames for t in result.run.tips))
    out = fit_sections(result, records, {"frames": frames, "method": result.method})
    ok = result.run.ok
    e = result.run.p_um[ok] - result.truth_um[ok]
    m2 = np.einsum("ni,nij,nj->n", e, np.linalg.inv(result.run.cov_um2[ok]), e)
    measurement = out["measurement"]
    assert isinstance(measurement, dict)
    measurement["in_95"] = float(np.mean(m2 <= CHI2_3_95)) if len(m2) else None
    return out


def _results(result: PatchDemoResult, prov: Mapping[str, object]) -> dict[str, object]:
    from ..procedures.evaluation_figures import Evaluation

    records = result.records
    volume = Evaluation(pose_accuracy=result.volume_accuracy).to_json()
    return {
        "preset": "patch",
        "scope": result.scope.calibration.to_json() | {"errors": result.scope_errors},
        **_measured(result, records),
        "joint_origin_um": np.asarray(result.joint_origin_um).tolist(),
        **result.evaluation.to_json(),
        "volume_accuracy": volume.get("pose_accuracy"),
        "provenance": prov,
    }  # fmt: skip
