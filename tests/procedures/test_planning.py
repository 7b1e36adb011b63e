"""Planning a run: the ISO 9283 cube lies in the box of the rig's limits, wherever it starts."""

from __future__ import annotations

import numpy as np


def test_the_iso_cube_design_lies_in_the_rigs_box():
    # ISO 9283's P1 is the centre of the box the limits span, wherever the box starts.
    from microcal.procedures.planning import plan_run

    limits = np.array([[-4000.0, 4000.0], [-500.0, 8500.0], [1000.0, 5800.0]])
    plan = plan_run("iso-cube", 5, 0, limits)
    np.testing.assert_allclose(plan.d_um[0], limits.mean(axis=1))
    assert np.all(plan.d_um >= limits[:, 0])
    assert np.all(plan.d_um <= limits[:, 1])
