"""Optimal compensator speed on a model with the approach-direction terms (sx, sy, sz, as the
demo fits), batched and one target at a time, against the thesis's way
(``scipy.optimize.fsolve`` on the polynomial model, one target at a time) and against the
previous code (``benchmarks/previous.py``), in the same run.
"""

from __future__ import annotations

import numpy as np
import scipy.optimize

from microcal.kinematics import fit_polynomial_model
from microcal.kinematics.compensators import Compensator
from microcal.sim.kinematics import approach_signs
from microcal.sim.synthetic_run import synthetic_run

from .harness import Case, best_time_s
from .previous import measure_previous, previous_ref

N_BATCH = 1_000_000
N_FSOLVE = 300
N_SINGLE = 300


def _problem() -> tuple[Compensator, np.ndarray]:
    """The compensator of a model with direction terms and N_BATCH targets it reaches."""
    data = synthetic_run(170, seed=12)
    u = np.hstack([data.d_um, approach_signs(data.d_um)])
    model = fit_polynomial_model(u, data.measured_um, extra={"sx": 1, "sy": 1, "sz": 1})
    rng = np.random.default_rng(4)
    d = rng.uniform([0, 0, 0], [8000, 8000, 4800], (N_BATCH, 3))
    p = model.predict_um(np.hstack([d, np.ones_like(d)]))  # approached from below
    return Compensator(model), p


def measure() -> dict[str, float]:
    """Timings with whichever microcal is importable (this one or the previous)."""
    comp, p = _problem()
    t_batch = best_time_s(lambda: comp.solve(p), 3)
    singles = p[:N_SINGLE]

    def one_by_one() -> None:
        for target in singles:
            comp.solve(target)

    t_single = best_time_s(one_by_one, 3) / N_SINGLE
    return {"batch_per_s": N_BATCH / t_batch, "single_s": t_single}


def run() -> list[Case]:
    rounds = [(measure(), measure_previous("bench_compensation")) for _ in range(2)]
    new = {"batch_per_s": max(r[0]["batch_per_s"] for r in rounds),
           "single_s": min(r[0]["single_s"] for r in rounds)}  # fmt: skip
    olds = [r[1] for r in rounds if r[1] is not None]
    nan = float("nan")
    old_batch = max((o["batch_per_s"] for o in olds), default=nan)
    old_single = min((o["single_s"] for o in olds), default=nan)
    comp, p = _problem()
    model = comp.model

    def fsolve_each() -> None:
        for target in p[:N_FSOLVE]:
            scipy.optimize.fsolve(
                lambda x, t=target: model.predict_um(np.r_[x, 1.0, 1.0, 1.0])[0] - t,
                comp.linear(target)[0],
                xtol=1e-12,
            )

    t_fsolve = best_time_s(fsolve_each, 1) / N_FSOLVE
    ref = f"previous code {previous_ref()[:10]}"
    rate, single = new["batch_per_s"], new["single_s"]
    return [
        Case(
            name="optimal compensator (direction terms), 1e6 targets batched",
            unit="targets/s",
            value=rate,
            baseline_name="fsolve one at a time",
            baseline=1.0 / t_fsolve,
            goal=">= 2e6 targets/s",
            meets_goal=rate >= 2e6,
            details={"time_s": N_BATCH / rate, "previous_code_targets_per_s": old_batch},
        ),
        Case(
            name="optimal compensator (direction terms), batched, against the previous code",
            unit="targets/s",
            value=rate,
            baseline_name=ref,
            baseline=old_batch,
            goal="faster than the previous code",
            meets_goal=None if olds == [] else rate > old_batch,
        ),
        Case(
            name="optimal compensator (direction terms), one target per call",
            unit="targets/s",
            value=1.0 / single,
            baseline_name="fsolve one at a time",
            baseline=1.0 / t_fsolve,
            goal="<= 50 µs per target",
            meets_goal=single <= 50e-6,
            details={
                "time_per_target_us": single * 1e6,
                "fsolve_us": t_fsolve * 1e6,
                "previous_code_us": old_single * 1e6,
            },
        ),
        Case(
            name="optimal compensator (direction terms), one target, against the previous code",
            unit="targets/s",
            value=1.0 / single,
            baseline_name=ref,
            baseline=1.0 / old_single,
            goal="faster than the previous code",
            meets_goal=None if olds == [] else single < old_single,
        ),
    ]
