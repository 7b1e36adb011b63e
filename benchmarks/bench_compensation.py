"""Optimal compensator speed: batched and one target at a time, against the thesis's way
(``scipy.optimize.fsolve`` on the polynomial model, one target at a time), in the same run.
"""

from __future__ import annotations

import numpy as np
import scipy.optimize

from microcal.kinematics import fit_polynomial_model
from microcal.kinematics.compensators import Compensator
from microcal.sim.synthetic_run import synthetic_run

from .harness import Case, best_time_s

N_BATCH = 1_000_000
N_FSOLVE = 300
N_SINGLE = 300


def run() -> list[Case]:
    data = synthetic_run(170, seed=12)
    model = fit_polynomial_model(data.d_um, data.measured_um)
    comp = Compensator(model)
    rng = np.random.default_rng(4)
    d = rng.uniform([0, 0, 0], [8000, 8000, 4800], (N_BATCH, 3))
    p = model.predict_um(d)

    t_batch = best_time_s(lambda: comp.solve(p), 3)
    singles = p[:N_SINGLE]

    def one_by_one() -> None:
        for target in singles:
            comp.solve(target)

    t_single = best_time_s(one_by_one, 3) / N_SINGLE

    def fsolve_each() -> None:
        for target in p[:N_FSOLVE]:
            scipy.optimize.fsolve(
                lambda x, t=target: model.predict_um(x)[0] - t, comp.linear(target)[0], xtol=1e-12
            )

    t_fsolve = best_time_s(fsolve_each, 1) / N_FSOLVE
    rate = N_BATCH / t_batch
    return [
        Case(
            name="optimal compensator, 1e6 targets batched",
            unit="targets/s",
            value=rate,
            baseline_name="fsolve one at a time",
            baseline=1.0 / t_fsolve,
            goal=">= 1e6 targets/s",
            meets_goal=rate >= 1e6,
            details={"time_s": t_batch},
        ),
        Case(
            name="optimal compensator, one target per call",
            unit="targets/s",
            value=1.0 / t_single,
            baseline_name="fsolve one at a time",
            baseline=1.0 / t_fsolve,
            goal="<= 100 µs per target",
            meets_goal=t_single <= 100e-6,
            details={"time_per_target_us": t_single * 1e6, "fsolve_us": t_fsolve * 1e6},
        ),
    ]
