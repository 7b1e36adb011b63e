"""Power and false alarms of ``microcal check`` over seeded trials (simulator, fast path).

Each trial checks a calibration on a simulated platform, first as it is (the reference
check), then after a change: none, a 1 µm offset in a random direction, or a 0.2 % scale
change of a random joint. The positions are measured by projecting the true end-effector
through the true cameras with the rendered pipeline's pixel noise and triangulating with the
calibrated cameras (``ProjectedProbe``).

Two ways to get the calibrations:

- one calibration.json for every trial (the platform of trial k has seed FIRST + k)::

    python scripts/check_power.py demo-out/calibration.json --trials 100 --frames 20

- ``--config quick | full | station``: one calibration per seed, checked on the platform of
  the same seed (the rig unchanged since its calibration). ``--demos 'DIR/q{seed}'`` reads
  each seed's calibration.json from a demo's directory (``microcal demo --quick --seed S
  --out DIR/qS``); otherwise it is made on the fast path: the demo's design (its seed, poses
  and workspace per device), the directions each joint last moved in, the true positions
  projected with the rendered pipeline's pixel noise for the demo's frames per pose
  (quick: 40 poses, 2 frames; full and station: 170 poses, 5 frames) and triangulated
  with the calibrated cameras of ``--cameras 'DIR/q{seed}'`` (a demo's cameras.json) or the
  true ones, then fitted as the demo fits (quadratic polynomial, stepwise, with direction
  terms, the thesis's split). ``station`` does it for each device of ``thesis-platform``::

    python scripts/check_power.py --config full --seeds 20 --cameras 'quick/q{seed}' \\
        --against calibration --repeats 5

The summary counts false alarms per test (the offset test and the fit test each at
``alpha``, on the unchanged rig) besides the verdicts.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from microcal.experiments.demo import demo_design, device_workspace
from microcal.formats.calibration_file import load_calibration
from microcal.geometry import AnyCamera
from microcal.kinematics.extra_inputs import APPROACH_INPUTS
from microcal.kinematics.manipulator_calibration import ManipulatorCalibration
from microcal.kinematics.models import held_from_limits
from microcal.procedures.check import CheckConfig, CheckResult, run_check
from microcal.procedures.identification import calibrate_manipulator, default_train
from microcal.sim import platform
from microcal.sim.kinematics import approach_signs
from microcal.sim.synthetic_run import (
    RENDERED_VIRTUAL_POINT_STD_PX,
    ProjectedProbe,
    measure_positions,
)
from microcal.workflows.calibration_update import camera_models

#: (preset, devices, poses, frames per pose) of each configuration.
CONFIGS = {
    "quick": ("thesis", ("m1",), 40, 2),
    "full": ("thesis", ("m1",), 170, 5),
    "station": ("thesis-platform", ("m1", "m2", "p1"), 170, 5),
}


def _pair(plat, calibrated: Mapping[str, AnyCamera] | None):
    a, b = list(plat.camera_models)[:2]
    true = (plat.camera_models[a], plat.camera_models[b])
    return true, (true if calibrated is None else (calibrated[a], calibrated[b]))


def fast_calibration(
    preset: str, device: str, seed: int, poses: int, frames: int,
    calibrated: Mapping[str, AnyCamera] | None,
) -> ManipulatorCalibration:  # fmt: skip
    """A demo's calibration of ``device`` made on the fast path (module docstring)."""
    plat = platform(preset, seed=seed)
    m = plat.manipulators[device]
    d = demo_design(seed, poses, device_workspace(m.limits_um))
    signs = approach_signs(d, m.joints_um(plat.clock.now_s()))
    truth = m.truth.position_um(d, signs, m.temperature_at(plat.clock.now_s()))
    std = tuple(s * np.sqrt(5.0 / frames) for s in RENDERED_VIRTUAL_POINT_STD_PX)
    true, seen = _pair(plat, calibrated)
    rng = np.random.default_rng([seed, 7])
    p, _ = measure_positions(truth, true, rng, std, seen)
    extra = {name: signs[:, k] for k, name in enumerate(APPROACH_INPUTS)}
    cal, _ = calibrate_manipulator(device, d, p, "polynomial", train=default_train(poses),
                                   extra_inputs=extra, family="quadratic", seed=seed,
                                   held_um=held_from_limits(m.limits_um))  # fmt: skip
    return cal


def check_once(
    cal: ManipulatorCalibration, models: Mapping[str, AnyCamera] | None, preset: str, seed: int,
    rng: np.random.Generator, change: str, frames: int, against: str,
) -> CheckResult:  # fmt: skip
    """One check of ``cal`` on the platform of ``seed`` after ``change``."""
    plat = platform(preset, seed=seed)
    m = plat.manipulators.get(cal.name, plat.manipulator)
    plat.scene.show(m.name, plat.clock.now_s())
    true, seen = _pair(plat, models)
    probe = ProjectedProbe(m.true_position_um, true, rng, RENDERED_VIRTUAL_POINT_STD_PX,
                           triangulate_with=seen)  # fmt: skip
    cfg = CheckConfig(frames=frames)
    reference = None
    if against == "reference":
        first = run_check(m, plat.clock, probe.measure_with_covariance, cal, config=cfg)
        reference = (first.residual_um, first.covariance_um2)
    if change == "offset":
        v = rng.normal(size=3)
        if cal.model.held_um:  # a positioner: an offset in the plane it moves in
            v[2] = 0.0
        m.mount_offset_um = v / np.linalg.norm(v) * 1.0
    elif change == "scale":
        moving = [k for k, j in enumerate(cal.model.joints) if j not in cal.model.held_um]
        m.joint_scale[moving[rng.integers(len(moving))]] = 1.0 + rng.choice([-1, 1]) * 0.002
    return run_check(m, plat.clock, probe.measure_with_covariance, cal, config=cfg,
                     reference=reference)  # fmt: skip


def trial(cal, models, seed: int, change: str, frames: int, against: str) -> str:
    """The verdict of one trial with a fixed calibration (platform ``thesis`` of ``seed``)."""
    rng = np.random.default_rng(seed)
    entry = cal.manipulator()
    return check_once(entry, models, "thesis", seed, rng, change, frames, against).verdict


def _summary(results: list[CheckResult], alpha: float) -> dict[str, float]:
    n = len(results)
    out = {v: sum(r.verdict == v for r in results) / n for v in ("valid", "offset", "refit")}
    out["offset_test_alarm"] = sum(r.offset_p_value < alpha for r in results) / n
    out["fit_test_alarm"] = sum(r.p_value < alpha for r in results) / n
    return out


def per_seed(args: argparse.Namespace) -> dict[str, object]:
    """The ``--config`` mode: one calibration per seed and device, checked on its platform."""
    preset, devices, poses, frames = CONFIGS[args.config]
    cals: list[tuple[int, ManipulatorCalibration, Mapping[str, AnyCamera] | None]] = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        if args.demos:
            c = load_calibration(Path(args.demos.format(seed=seed)) / "calibration.json")
            cals += [(seed, c.manipulator(n), camera_models(c)) for n in devices]
            continue
        models = None
        if args.cameras:
            models = camera_models(
                load_calibration(Path(args.cameras.format(seed=seed)) / "calibration.json")
            )
        for n in devices:
            cals.append((seed, fast_calibration(preset, n, seed, poses, frames, models), models))
    table: dict[str, object] = {}
    for change in args.changes.split(","):
        results, by_device = [], {}
        for seed, cal, models in cals:
            for k in range(args.repeats):
                rng = np.random.default_rng([seed, k, 11])
                r = check_once(cal, models, preset, seed, rng, change, args.frames, args.against)
                results.append(r)
                by_device.setdefault(cal.name, []).append(r)
        table[change] = _summary(results, args.alpha)
        if len(by_device) > 1:
            table[change] = {"all": table[change]} | {
                n: _summary(rs, args.alpha) for n, rs in by_device.items()
            }
        print(change, table[change], flush=True)
    return {"config": args.config, "seeds": args.seeds, "first_seed": args.first_seed,
            "repeats": args.repeats, "frames": args.frames, "against": args.against,
            "calibrations": "demos" if args.demos else "fast path", "table": table}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("calibration", nargs="?")
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=None)
    ap.add_argument("--against", choices=["reference", "calibration"], default="reference")
    ap.add_argument("--config", choices=sorted(CONFIGS))
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=1, help="checks per calibration and change")
    ap.add_argument("--demos", help="each seed's demo directory, e.g. 'quick/q{seed}'")
    ap.add_argument("--cameras", help="each seed's cameras from a demo directory")
    ap.add_argument("--changes", default="none,offset,scale")
    ap.add_argument("--alpha", type=float, default=0.05)
    args = ap.parse_args()
    if args.config is not None:
        args.first_seed = 0 if args.first_seed is None else args.first_seed
        print(json.dumps(per_seed(args)))
        return
    if args.calibration is None:
        ap.error("give a calibration.json or --config")
    first = 5000 if args.first_seed is None else args.first_seed
    cal = load_calibration(args.calibration)
    models = camera_models(cal)
    table = {}
    for change in args.changes.split(","):
        verdicts = [trial(cal, models, first + k, change, args.frames, args.against)
                    for k in range(args.trials)]  # fmt: skip
        table[change] = {v: verdicts.count(v) / len(verdicts) for v in ("valid", "offset", "refit")}
        print(change, table[change], flush=True)
    print(json.dumps({"frames": args.frames, "against": args.against, "trials": args.trials,
                      "table": table}))  # fmt: skip


if __name__ == "__main__":
    main()
