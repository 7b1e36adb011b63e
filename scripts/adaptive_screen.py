"""Screen a setting of the adaptive design on the population at equal frames, in seconds.

    python scripts/adaptive_screen.py --seeds 0-9 [--set batch=2 --set boundary_grid=0]
        [--frames 20] [--curve] [--cache DIR]

Per seed it runs what ``microcal study --design adaptive --until-um 1.0`` runs for the adaptive
design (the same platform, probe, approach directions and settings, so the same poses and the
same ``tip_error_p95_um``) and nothing else: no ISO tests, no other model. The random design
grown on the same seed at ``--frames`` per pose (as ``scripts/adaptive_equal_frames.py`` grows
it) is cached per seed in ``--cache``, since no setting of the adaptive design changes it. It
prints per seed the poses, the true p95 tip error, the random poses needed for it and their
ratio, the rig time and the share of test poses inside the predicted 95 % region, then the
medians (the issue's figures) over the seeds.

``--curve`` adds a steadier figure for telling settings apart: the ratio at every step of the
run from 40 to 80 poses (each step's model against the random design's poses for its error),
averaged per seed; run it with ``--set until_um=0.01 --set max_poses=80`` so every seed goes
to 80 poses. The stop's own ratio moves by 0.1 between settings on ten seeds from the random
design's steps of 10 poses alone.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from microcal.control.feedforward import extra_inputs_reader
from microcal.experiments.adaptive_run import (
    TIP_TEST_POSES,
    PoseTimes,
    adaptive_curve,
    coverage_of,
    p95_um,
    random_curve,
    run_adaptive_fast,
    static_tip_errors_um,
    tip_test_joints_um,
)
from microcal.experiments.demo import demo_design_seed
from microcal.experiments.study import StudyConfig, adaptive_settings
from microcal.kinematics.compensators import Compensator
from microcal.procedures.acquisition import AcquisitionConfig
from microcal.procedures.adaptive import AdaptiveDesign
from microcal.sim import platform
from microcal.sim.synthetic_run import ProjectedProbe
from microcal.thesis.experiment import WORKSPACE_MAX_UM, WORKSPACE_MIN_UM

PRESET = "population"


def random_points(seed: int, frames: int, cache: Path) -> list[tuple[int, float]]:
    """The random design's (poses, true p95 µm) on the seed, grown in steps of 10 to 300."""
    path = cache / f"random-{seed}-{frames}.json"
    if path.exists():
        return [(int(n), float(e)) for n, e in json.loads(path.read_text(encoding="utf-8"))]
    config = StudyConfig(design="adaptive", until_um=1.0)
    acq = AcquisitionConfig(approach_um=config.approach_um, approach_seed=demo_design_seed(seed))
    curve = random_curve(platform(PRESET, seed=seed), seed, list(range(20, 301, 10)), acq,
                         config.settle_s, frames, adaptive_settings(config, seed))  # fmt: skip
    points = [(c.n_poses, c.tip_error_p95_um) for c in curve]
    path.write_text(json.dumps(points), encoding="utf-8")
    return points


def needed(points: list[tuple[int, float]], error_um: float) -> int | None:
    """The fewest random poses whose true p95 is at most ``error_um`` (None: never), as the
    study's :func:`~microcal.experiments.adaptive_run.poses_to_match` finds them."""
    return next((n for n, e in points if e <= error_um), None)


def run_seed(seed: int, overrides: dict[str, object], curve: bool) -> dict[str, object]:
    """One seed's adaptive run as the study makes it, and its figures."""
    config = StudyConfig(design="adaptive", until_um=1.0)
    plat = platform(PRESET, seed=seed)
    probe = ProjectedProbe.on_platform(plat, np.random.default_rng([seed, 7]))
    acq = AcquisitionConfig(approach_um=config.approach_um, approach_seed=demo_design_seed(seed))
    settings = dataclasses.replace(adaptive_settings(config, seed), **overrides)  # type: ignore[arg-type]
    times = PoseTimes.empty()
    result = run_adaptive_fast(plat, settings, acq, config.settle_s, probe, times,
                               config.adaptive_frames)  # fmt: skip
    sim = plat.manipulator
    t_cal = sim.temperature_at(plat.clock.now_s())
    model = result.final.model
    assert model is not None
    targets = sim.truth.position_um(tip_test_joints_um(), np.ones((TIP_TEST_POSES, 3)), t_cal)
    errors = static_tip_errors_um(model, sim, targets, t_cal)
    read = extra_inputs_reader(model, {"temperature": lambda: t_cal})
    d = Compensator(model, sim.limits_um).solve(targets, extra=None if read is None else
                                                read()).d_um  # fmt: skip
    design = AdaptiveDesign(settings, WORKSPACE_MIN_UM, WORKSPACE_MAX_UM, sim.limits_um, acq)
    extra = design.scatter_var_um2(result.measured)
    inside = coverage_of(model, errors, np.asarray(d), t_cal, extra,
                         inflation=result.final.inflation)  # fmt: skip
    steps = []
    if curve:
        steps = [(c.n_poses, c.tip_error_p95_um) for c in adaptive_curve(result, times, sim)]
    return {"seed": seed, "n_poses": len(result.measured), "tip_error_p95_um": p95_um(errors),
            "rig_time_s": times.total_s + result.fit_s, "inside": int(inside.sum()),
            "curve": steps}  # fmt: skip


def _seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def _value(text: str) -> object:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", default="0-9", help="a range, e.g. 0-9 (both included)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="an AdaptiveSettings field, e.g. batch=2 (repeatable)")  # fmt: skip
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--curve", action="store_true")
    parser.add_argument("--cache", type=Path, default=Path(".adaptive-screen"))
    args = parser.parse_args()
    overrides = {k: _value(v) for k, _, v in (s.partition("=") for s in args.set)}
    args.cache.mkdir(parents=True, exist_ok=True)
    ratios, poses, errors, rig, inside, steady = [], [], [], [], 0, []
    for seed in _seeds(args.seeds):
        run = run_seed(seed, overrides, args.curve)
        points = random_points(seed, args.frames, args.cache)
        n, e = int(run["n_poses"]), float(run["tip_error_p95_um"])  # type: ignore[arg-type]
        need = needed(points, e)
        ratio = n / need if need else float("nan")
        ratios.append(ratio)
        poses.append(n)
        errors.append(e)
        rig.append(float(run["rig_time_s"]) / 60)  # type: ignore[arg-type]
        inside += int(run["inside"])  # type: ignore[call-overload]
        at = [k / m for k, err in run["curve"] if 40 <= k <= 80  # type: ignore[attr-defined]
              if (m := needed(points, err))]  # fmt: skip
        steady.append(float(np.mean(at)) if at else float("nan"))
        print(f"seed {seed}: {n} poses, tip p95 {e:.3f} µm, random needs {need}, ratio "
              f"{ratio:.3f}, rig {rig[-1]:.1f} min, inside {run['inside']}/{TIP_TEST_POSES}"
              + (f", ratio over 40-80 poses {steady[-1]:.3f}" if args.curve else ""),
              flush=True)  # fmt: skip
    k = len(ratios)
    print(f"{k} seeds: median ratio {np.nanmedian(ratios):.3f}; true p95 <= 1.0 µm on "
          f"{sum(e <= 1.0 for e in errors)}/{k}; median poses {np.median(poses):g}; median rig "
          f"{np.median(rig):.1f} min; 95 % region holds {inside / (k * TIP_TEST_POSES):.1%}"
          + (f"; ratio over 40-80 poses: median {np.nanmedian(steady):.3f}" if args.curve
             else ""))  # fmt: skip


if __name__ == "__main__":
    main()
