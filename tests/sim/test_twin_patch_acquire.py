"""``microcal acquire`` on the one-camera twin: the dry run and a short run through its
Micro-Manager camera (frames read by region), stage and focus and its MCS2 manipulator, on
loopback in the test's own network namespace."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.formats.measurements import read_measurements
from microcal.formats.scope_file import write_objective
from microcal.sim.patch import PatchConfig
from microcal.sim.patch_scope import true_frame, truth_in_frame
from microcal.workflows.acquire import AcquireRequest
from microcal.workflows.adaptive_acquire import acquire_any


def _truth_scope(path) -> None:
    """A scope file whose 40x set is the rig's truth (a perfect scope calibration)."""
    frame = true_frame(PatchConfig())
    affine = np.column_stack([-np.linalg.inv(frame.px_per_um), np.zeros(2)])
    write_objective(path, "40x", {
        "pixel_size_affine": [float(v) for v in affine.ravel()],
        "pixel_size_um": PatchConfig().um_per_px, "rotation_deg": 0.0,
        "distortion": {"model": "radial2", "k": [0.0, 0.0]},
        "focus": {"drift_px_per_um": [float(v) for v in frame.drift_px_per_um]},
    })  # fmt: skip


@pytest.mark.slow
def test_the_dry_run_and_an_acquisition_through_the_twin(tmp_path) -> None:
    pytest.importorskip("pymmcore_plus")
    from support.twin_served import skip_without_namespace, twin_on_loopback

    skip_without_namespace()
    scope, rig = tmp_path / "scope.json", tmp_path / "patch-twin.toml"
    _truth_scope(scope)
    given = {"rig": str(rig), "scope": scope, "objective": "40x", "volume_um": "10,10,4"}
    with twin_on_loopback(rig, preset="patch", seed=0, time_scale=50) as twin:
        dry = list(acquire_any(AcquireRequest(tmp_path / "dry", dry_run=True, **given)))  # type: ignore[arg-type]
        assert "camera: 2048 x 2048 px, uint16" in "\n".join(dry)
        assert (
            dry[-1] == "design: 80 poses in 20 x 20 x 8 µm around the tip, within the soft limits"
        )
        assert not (tmp_path / "dry").exists()
        out = tmp_path / "run"
        lines = list(acquire_any(AcquireRequest(out, poses=12, settle="fixed:0.3", **given)))  # type: ignore[arg-type]
        assert lines[-1].startswith(f"stored 12 poses in {out} (12 tips measured")
        truth = truth_in_frame(twin.patch, true_frame(PatchConfig()))()
    last = read_measurements(out / "measurements.csv").p_um[-1]
    # the last pose's tip, measured through the twin, against where it truly is (the focus's
    # and the manipulator's errors, the truth scope set: a few tenths of a µm)
    assert float(np.linalg.norm(last - truth)) < 1.0
