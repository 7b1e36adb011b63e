"""The one-camera calibration through the digital twin's devices (the MCS2 driver, the
Micro-Manager camera, X-Y stage and focus) against the in-process simulator, same seed."""

from __future__ import annotations

import pytest

from microcal.experiments.patch_demo import run_patch_demo
from microcal.experiments.patch_twin import patch_figures, run_patch_demo_on_twin

BOUND = 0.15  # the twin's figures within 15 % of the in-process run's
FLOOR_UM = 0.01  # or within 10 nm: AP of a few nm (the optimal model's) is the noise's


@pytest.mark.slow
def test_the_patch_calibration_through_the_twin_gives_the_in_process_figures(netns):
    pytest.importorskip("pymmcore_plus")
    demo = {"cycles": 1, "volume_poses": 5}
    here = patch_figures(run_patch_demo(0, 30, **demo))
    twin = patch_figures(run_patch_demo_on_twin(0, 30, **demo))
    assert set(twin) == set(here)
    assert {"AP truth matrix", "AP truth optimal", "AP truth closed_loop", "AP volume optimal",
            "measurement RMS", "rig calibration s"} <= set(here)  # fmt: skip
    for key, value in here.items():
        floor = FLOOR_UM if key.startswith(("AP", "measurement")) else 0.0
        assert abs(twin[key] - value) <= max(BOUND * abs(value), floor), (key, value, twin[key])
    # the calibration fulfils the figures through the twin too
    assert twin["AP volume optimal"] <= 1.0
    assert twin["AP truth closed_loop"] <= 0.5
    assert twin["rig calibration s"] <= 600.0
