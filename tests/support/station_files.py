"""A calibration of the simulated thesis preset made in an instant: the simulator's true
cameras and its manipulator's true static model, as calibration.json (for tests of what
uses a calibration, not of how one is made)."""

from __future__ import annotations

from pathlib import Path

from microcal import sim
from microcal.formats.calibration_file import Calibration, write_calibration
from microcal.kinematics.manipulator_calibration import ManipulatorCalibration

#: validation figures of a model taken from the truth (none were measured)
NO_VALIDATION = {"n_fit": 0, "n_validate": 0, "mean_um": 0.0, "std_um": 0.0, "max_um": 0.0,
                 "rms_um": 0.0}  # fmt: skip


def write_truth_calibration(
    path: Path, seed: int = 0, preset: str = "thesis", cameras: tuple[str, ...] | None = None
) -> Path:
    """calibration.json at ``path`` with the preset's true cameras (``cameras`` only, when
    given: a station of those cameras) and static model."""
    plat = sim.platform(preset, seed=seed)
    cams = {n: {"image_size_px": list(m.image_size_px), "K": m.K.tolist(), "dist": m.dist.tolist(),
                "R": m.R.tolist(), "t_um": m.t_um.tolist()} for n, m in plat.camera_models.items()
            if cameras is None or n in cameras}  # fmt: skip
    entries = {name: ManipulatorCalibration(name, m.truth.static, NO_VALIDATION)
               for name, m in plat.manipulators.items()}  # fmt: skip
    return write_calibration(path, Calibration(entries, cams, {}))
