"""The optimal compensator's fast paths give the general path's solutions."""

from __future__ import annotations

import numpy as np

from microcal.kinematics import fit_polynomial_model
from microcal.kinematics.compensator_paths import CHUNK
from microcal.kinematics.compensators import Compensator
from microcal.sim.kinematics import approach_signs
from microcal.sim.synthetic_run import synthetic_run


def _with_direction_terms() -> Compensator:
    data = synthetic_run(170, seed=12)
    u = np.hstack([data.d_um, approach_signs(data.d_um)])
    model = fit_polynomial_model(u, data.measured_um, extra={"sx": 1, "sy": 1, "sz": 1})
    return Compensator(model)


def test_fast_paths_agree_with_the_general_path():
    fast = _with_direction_terms()
    general = _with_direction_terms()
    general._planar = general._scalar = None  # the general path alone
    rng = np.random.default_rng(7)
    d = rng.uniform([0, 0, 0], [8000, 8000, 4800], (CHUNK + 333, 3))  # two chunks
    e = rng.choice([-1.0, 1.0], (len(d), 3))
    p = fast.model.predict_um(np.hstack([d, e]))
    a, b = fast.solve(p, extra=e), general.solve(p, extra=e)
    assert a.converged.all()
    assert b.converged.all()
    # both converge to 1e-9 µm on the model: the joints agree far below a nanometre
    np.testing.assert_allclose(a.d_um, b.d_um, atol=1e-6)
    np.testing.assert_allclose(a.d_um, d, atol=1e-6)
    assert a.residual_um.max() <= 1e-9
    for k in (0, 5, CHUNK + 1):  # one target at a time (the scalar path)
        one = fast.solve(p[k], extra=e[k])
        assert one.converged.all()
        np.testing.assert_allclose(one.d_um[0], d[k], atol=1e-6)
        assert one.residual_um[0] <= 1e-9


def test_a_target_the_fast_path_gives_up_on_goes_to_the_general_path():
    comp = _with_direction_terms()
    p = comp.model.predict_um(np.array([[4000.0, 4000.0, 2400.0, 1.0, 1.0, 1.0]]))
    # no Newton step at all: the fast paths give up, the general path (with its
    # Levenberg-Marquardt fallback) still solves the target
    out = comp.solve(np.vstack([p, p]), max_iter=0)
    assert out.converged.all()
    assert out.n_fallback == 2
