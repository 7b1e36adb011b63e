"""``microcal evaluate``: ISO 9283 pose accuracy and the decoupling test on any rig."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from ..formats.json_file import check_json_output
from ..formats.results_file import RESULTS_FORMAT, update_results
from ..procedures.evaluation import run_evaluation
from ..procedures.evaluation_figures import Evaluation
from .station import open_calibrated_rig

__all__ = ["EvaluateRequest", "EvaluateResult", "evaluate"]


@dataclass(frozen=True)
class EvaluateRequest:
    """What ``microcal evaluate`` is asked (see its ``--help`` for each option).

    Attributes
    ----------
    calibration : Path
        calibration.json with its cameras.
    rig : str
        ``sim`` or a rig file.
    tests : str
        ``all``, ``pose-accuracy``, ``decoupling``, ``distance`` or ``stabilisation``.
    poses : str
        ``table-5-2`` or ``iso-cube``.
    control : str
        ``open``, ``closed`` or ``all``.
    drift_h : float
        Hours over which the drift of AP is measured (0: none).
    out : Path
        results.json to write or update.
    scope, objective : optional
        A one-camera rig's scope calibration (scope.json) and its objective's set.
    """

    calibration: Path
    rig: str = "sim"
    tests: str = "all"
    manipulator: str | None = None
    cycles: int = 3
    poses: str = "table-5-2"
    frames: int = 5
    settle_s: float = 5.0
    seed: int | None = None
    out: Path = Path("results.json")
    control: str = "open"
    tolerance_um: float = 0.5
    drift_h: float = 0.0
    band_um: float = 2.0
    scope: Path | None = None
    objective: str | None = None


@dataclass(frozen=True)
class EvaluateResult:
    """What the evaluation found (written into results.json) and on which rig (its record)."""

    evaluation: Evaluation
    rig_record: Mapping[str, object]
    out: Path


def evaluate(
    request: EvaluateRequest, progress: Callable[[str, int, int], None] | None = None
) -> EvaluateResult:
    """Run the evaluation tests of a calibrated device and add them to results.json.

    ``progress(stage, done, total)`` is called as the tests go on.
    """
    r = request
    check_json_output(r.out, RESULTS_FORMAT, "results.json")
    c = open_calibrated_rig(r.rig, r.calibration, seed=r.seed, manipulator=r.manipulator,
                            scope=r.scope, objective=r.objective)  # fmt: skip
    with c.opened:
        d = c.device
        parts = run_evaluation(
            d.manipulator, d.clock, d.cameras, c.models, d.board, c.entry,
            tests=r.tests, poses=r.poses, cycles=r.cycles, frames=r.frames,
            settle_s=r.settle_s, truth=d.truth, sensors=d.sensors, progress=progress,
            control=r.control, tolerance_um=r.tolerance_um, drift_s=r.drift_h * 3600.0,
            band_um=r.band_um, probe=c.probe,
        )  # fmt: skip
    update_results(r.out, {**parts.to_json(), "target": d.board.spec})
    return EvaluateResult(parts, c.spec.to_dict(), r.out)
