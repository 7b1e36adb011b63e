"""The ``patch`` demo through the digital twin: the whole one-camera calibration driven through
the hardware drivers (the MCS2 driver, Micro-Manager's camera, X-Y stage and focus) against a
twin of the same seed, for comparison with the in-process run.

:func:`run_patch_demo_on_twin` starts a twin of preset ``patch`` in this process (on free
loopback ports), opens the rig file it writes through the hardware drivers, and runs
:func:`~microcal.experiments.patch_demo.run_patch_demo` on those devices; the ground truth and
the slide are the twin's own rig's. :func:`patch_figures` gives the figures the two runs are
compared by (``scripts/patch_twin_figures.py``).

The twin's clock is either

- a :class:`~microcal.sim.clock.SimClock` shared with the demo (``time_scale=None``): simulated
  time passes only by the devices' waits (moves, exposures) and the demo's, as in the
  in-process run, so the rig time compares; or
- its scaled clock (``time_scale=20``, say): simulated time follows the wall clock, so every
  second of computing (the demo's, the twin's rendering, the protocols') is ``time_scale``
  simulated seconds of rig time, as it would be on a rig.

Needs ``microcal[mm]`` (pymmcore-plus).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from ..devices.rig import open_hardware_rig
from ..devices.rig_spec import HardwareRigSpec
from ..errors import DeviceError
from ..formats.atomic import write_text_atomic
from ..formats.rig_file import load_rig
from ..formats.twin_rig_file import twin_rig_toml
from ..sim.clock import SimClock
from ..sim.twin import Twin
from .patch_demo import PatchDemoResult, run_patch_demo

__all__ = ["CONDITIONS", "patch_figures", "run_patch_demo_on_twin"]

#: The conditions whose ISO 9283 AP the figures give.
CONDITIONS = ("uncalibrated", "matrix", "optimal", "closed_loop")


def run_patch_demo_on_twin(
    seed: int = 0, poses: int = 80, *, time_scale: float | None = None, **demo: Any
) -> PatchDemoResult:
    """The ``patch`` demo of ``seed`` on the devices of a twin of the same seed.

    Parameters
    ----------
    seed, poses :
        As :func:`~microcal.experiments.patch_demo.run_patch_demo`'s.
    time_scale : float, optional
        The twin's scaled clock, simulated seconds per wall second; None: a simulated clock
        shared with the demo (module docstring).
    **demo :
        Further arguments of ``run_patch_demo`` (``cycles``, ``volume_poses`` ...).

    Raises
    ------
    DeviceError
        The twin's devices cannot be opened (pymmcore-plus missing, say).
    """
    clock = SimClock() if time_scale is None else None
    scale = 1.0 if time_scale is None else float(time_scale)
    with (
        Twin(preset="patch", seed=seed, time_scale=scale, mcs2_port=0, frames_port=0,
             clock=clock) as twin,
        tempfile.TemporaryDirectory(prefix="microcal-twin-") as folder,
    ):  # fmt: skip
        path = Path(folder) / "patch-twin.toml"
        write_text_atomic(path, twin_rig_toml(twin.rig_description(), str(path)))
        spec = load_rig(str(path))
        if not isinstance(spec, HardwareRigSpec) or twin.patch is None:
            raise DeviceError("twin: its rig file is not a hardware rig of the patch preset")
        with open_hardware_rig(spec) as rig:
            rig.clock = twin.clock  # the procedures wait in the twin's simulated seconds
            return run_patch_demo(seed, poses, patch=twin.patch, rig=rig, **demo)


def patch_figures(result: PatchDemoResult) -> dict[str, float]:
    """The figures a run of the ``patch`` demo is compared by: ISO 9283 AP (mean over P1-P5,
    µm) by ground truth per condition at the cube and at the random points of the working
    volume, the tips' RMS error against ground truth (µm), and the rig's simulated time,
    s (the calibration: slide, acquisition and measurement, fit; and the evaluation)."""
    pa = result.evaluation.pose_accuracy or {}
    cube = pa.get("truth", {})
    volume = (result.volume_accuracy or {}).get("truth", {})
    out = {f"AP truth {c}": float(cube[c].mean_ap_p_um) for c in CONDITIONS if c in cube}
    out |= {f"AP volume {c}": float(volume[c].mean_ap_p_um) for c in CONDITIONS if c in volume}
    out["measurement RMS"] = result.measurement_rms_um
    out["rig calibration s"] = result.calibration_rig_s
    out["rig evaluation s"] = float(result.rig_s.get("evaluation", 0.0))
    return out
