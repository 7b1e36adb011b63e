"""The work behind ``microcal scope-calibrate`` and ``microcal scope-show``.

``scope-calibrate`` calibrates a one-camera microscope's camera against its X-Y stage and
focus drive for one objective (:func:`~microcal.procedures.scope_calibration.calibrate_scope`)
and adds the objective's set to a scope file (:mod:`microcal.formats.scope_file`), leaving the
file's other objectives as they were. ``--rig sim`` is the simulated microscope
(:mod:`microcal.sim.stage_slide`; its objectives are ``SIM_OBJECTIVES``); a rig file names the
camera and the ``[microscope]`` (Micro-Manager's XY stage and focus devices), or the simulated
one-camera rig (``preset = "patch"``: a slide on its stage, seen by its camera's truth).
``scope-show`` reads one objective's set by name.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..formats.json_file import check_json_output
from ..formats.provenance import provenance
from ..formats.scope_file import (
    SCOPE_FORMAT,
    check_objective_name,
    load_objective,
    objective_names,
    write_objective,
)
from ..json_value import JsonValue
from ..procedures.scope_calibration import ScopeRun, calibrate_scope, depth_for, scope_plan
from ..vision.stage_affine import ScopeCalibration
from ..vision.targets import parse_target

__all__ = ["ScopeRequest", "ScopeResult", "scope_calibrate", "scope_show"]


@dataclass(frozen=True)
class ScopeRequest:
    """What ``scope-calibrate`` is asked.

    Attributes
    ----------
    rig : str
        ``"sim"`` (the simulated microscope) or a rig file with a ``[microscope]``.
    objective : str
        The set's name in the file (``40x``); on ``sim`` one of ``SIM_OBJECTIVES``.
    out : Path
        The scope file (made, or its set of this objective added or replaced).
    target : str or None
        The slide's spec (a dot grid with markers); the simulator's own slide by default.
    um_per_px : float or None
        The nominal pixel size in the object, for the plan's steps; by default the camera's
        pixel over the objective's magnification (``40x`` -> 40).
    numerical_aperture : float
        The objective's NA, for the focus steps (the simulator's objective's by default).
    camera : str or None
        The camera (a rig of several); the only one by default.
    seed : int
        Seed of the simulated microscope.
    image_px : int
        The simulated camera's width and height.
    field_curvature : bool
        Also sweep the focus through ±3 λ/NA² in 15 steps and fit the focal surface.
    """

    rig: str
    objective: str
    out: Path
    target: str | None = None
    um_per_px: float | None = None
    numerical_aperture: float | None = None
    camera: str | None = None
    seed: int = 0
    image_px: int = 512
    field_curvature: bool = False


@dataclass(frozen=True)
class ScopeResult:
    """What ``scope-calibrate`` did: the calibration, the set written (``record``), the file
    and the objectives it holds."""

    path: Path
    objective: str
    calibration: ScopeCalibration
    missed: list[str] = field(default_factory=list)
    frames: int = 0
    objectives: list[str] = field(default_factory=list)
    record: dict[str, JsonValue] = field(default_factory=dict)


def _magnification(objective: str) -> float | None:
    m = re.match(r"^(\d+(?:\.\d+)?)[xX]", objective)
    return float(m.group(1)) if m else None


def _sweep(req: ScopeRequest, na: float) -> np.ndarray | None:
    """The focus sweep's offsets for the field curvature (None when not asked for)."""
    if not req.field_curvature:
        return None
    d = depth_for(na)
    return np.linspace(-3 * d, 3 * d, 15)


def _run_sim(req: ScopeRequest) -> tuple[ScopeRun, dict[str, JsonValue]]:
    from ..sim.stage_slide import SIM_OBJECTIVES, StageSlideScope, random_truth

    if req.objective not in SIM_OBJECTIVES:
        raise InputError(
            f"--objective {req.objective}: the simulated microscope has {', '.join(SIM_OBJECTIVES)}"
        )
    obj = SIM_OBJECTIVES[req.objective]
    scope = StageSlideScope(random_truth(req.seed, req.objective), slide=req.target or "",
                            image_size_px=(req.image_px, req.image_px), seed=req.seed)  # fmt: skip
    na = req.numerical_aperture or obj.numerical_aperture
    plan = scope_plan(req.image_px * (req.um_per_px or obj.um_per_px), depth_for(na))
    run = calibrate_scope(scope.move_stage, scope.move_focus, scope.grab, scope.target, plan,
                          sweep_um=_sweep(req, na))  # fmt: skip
    return run, {"rig": f"simulated microscope, seed {req.seed}", "slide": scope.slide}


def _run_rig(req: ScopeRequest) -> tuple[ScopeRun, dict[str, JsonValue]]:
    from ..devices.microscope_drive import MicroscopeDrive
    from ..devices.rig_spec import HardwareRigSpec, SimRigSpec
    from ..formats.rig_file import load_rig
    from ..sim.platforms import ONE_CAMERA_PRESET
    from .rigs import open_rig

    spec = load_rig(req.rig)
    if isinstance(spec, SimRigSpec) and spec.preset == ONE_CAMERA_PRESET:
        return _run_patch(req, spec)
    if not isinstance(spec, HardwareRigSpec) or spec.microscope is None:
        raise InputError(
            f"--rig {req.rig}: names no [microscope] (the X-Y stage and focus that move the "
            "slide); add one, or use --rig sim"
        )
    if req.target is None:
        raise InputError(
            "--target: name the slide (e.g. dotgrid:41x41:10:5:markers=20,20/22,20/20,19)"
        )
    cams = list(spec.cameras)
    name = req.camera or cams[0]
    if name not in spec.cameras or (req.camera is None and len(cams) > 1):
        raise InputError(f"--camera: name one of the rig's cameras: {', '.join(cams)}")
    nominal = req.um_per_px
    if nominal is None:
        mag = _magnification(req.objective)
        if mag is None:
            raise InputError(
                f"--objective {req.objective}: give --um-per-px (the nominal pixel size), or "
                "name the objective by its magnification (40x)"
            )
        nominal = spec.cameras[name].pixel_size_um / mag
    target = parse_target(req.target)
    rig = open_rig(spec)
    try:
        scope, camera = rig.microscope, rig.cameras[name]
        assert scope is not None  # opened from the spec's [microscope]
        # each move commands the other axes at their last command, not at their readout
        # (re-commanding a stage to its noisy readout would move it between focus steps)
        drive = MicroscopeDrive(scope, camera, rig.clock)
        w = int(np.asarray(camera.grab()).shape[1])
        na = req.numerical_aperture or 0.5
        plan = scope_plan(w * nominal, depth_for(na))
        run = calibrate_scope(drive.move_stage, drive.move_focus, camera.grab, target, plan,
                              start_stage_um=drive.stage_um, start_focus_um=drive.focus_um,
                              sweep_um=_sweep(req, na))  # fmt: skip
    finally:
        rig.close()
    return run, {"rig": str(req.rig), "camera": name, "slide": target.spec}


def _run_patch(req: ScopeRequest, spec: Any) -> tuple[ScopeRun, dict[str, JsonValue]]:
    """The slide on the simulated one-camera rig's stage, moved by its devices."""
    from ..devices.microscope_drive import MicroscopeDrive
    from ..sim.patch import PatchRig
    from ..sim.patch_devices import patch_as_rig, patch_config
    from ..sim.patch_scope import slide_scope

    if req.target is not None:
        raise InputError("--target: the simulated one-camera rig has its own slide; leave it out")
    patch = PatchRig(patch_config(spec.overrides), spec.seed)
    with patch_as_rig(patch) as rig:
        assert rig.microscope is not None  # the patch rig has one
        drive = MicroscopeDrive(rig.microscope, rig.cameras["scope"], rig.clock)
        slide = slide_scope(patch, req.image_px, spec.seed, drive)
        na = req.numerical_aperture or patch.config.numerical_aperture
        field_um = req.image_px * (req.um_per_px or patch.config.um_per_px)
        plan = scope_plan(field_um, depth_for(na))
        run = calibrate_scope(slide.move_stage, slide.move_focus, slide.grab, slide.target,
                              plan, sweep_um=_sweep(req, na))  # fmt: skip
    return run, {"rig": str(req.rig), "camera": "scope", "slide": slide.target.spec}


def scope_calibrate(req: ScopeRequest) -> ScopeResult:
    """Calibrate the camera for one objective and add its set to the scope file.

    Raises
    ------
    InputError
        A bad objective name, an output that is not a scope file, a rig without a microscope
        stage, a simulated objective that does not exist, or too few views (one line each;
        nothing is written).
    """
    check_objective_name(req.objective)
    out = check_json_output(req.out, SCOPE_FORMAT, "scope.json")
    if out.exists():
        objective_names(out)  # a file this microcal cannot read is refused before any work
    if req.target is not None:
        parse_target(req.target)
    run, where = (_run_sim if req.rig == "sim" else _run_rig)(req)
    cal = run.calibration
    record: dict[str, JsonValue] = {**cal.to_json(), **where}
    if run.curvature is not None:
        record["field_curvature"] = run.curvature.to_json()
    if run.missed:
        record["missed_views"] = list(run.missed)
    write_objective(out, req.objective, record, provenance(objective=req.objective))
    return ScopeResult(out, req.objective, cal, run.missed, run.frames, objective_names(out),
                       record)  # fmt: skip


def scope_show(path: Path, objective: str) -> dict[str, JsonValue]:
    """One objective's set of a scope file, by name.

    Raises
    ------
    InputError
        The file holds no set of that name (the ones it holds are named).
    """
    return load_objective(path, objective)
