"""Evaluation runs (thesis 5.3, ISO 9283): pose accuracy and repeatability, decoupling.

Each run drives a manipulator without compensation, with the matrix compensator and with the
optimal compensator, and measures where the end-effector went with the vision system (and,
on the simulator, with ground truth, so the measurement's own error shows separately).

Positions are taken relative to a home pose measured first in each condition, as the thesis
did: a desired pose such as [2000, 0, 0] is a displacement from home, the command is the
displacement itself without compensation, and the compensator's joints for
``home + displacement`` with it (home being the model's position at zero joints).
ISO 9283 cycles visit the poses in the same order every cycle, so each pose is approached
from the same side.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypedDict

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, check_limits
from ..control.conditions import closed_loop_condition, open_loop_conditions
from ..control.feedforward import FeedForward, extra_inputs_reader
from ..control.visual_servo import ServoConfig
from ..devices.base import Camera, Clock, Manipulator
from ..errors import InputError
from ..geometry import AnyCamera
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..metrics import decoupling_metrics, multi_directional_variation, pose_statistics
from ..thesis.experiment import DECOUPLING_PATH_UM, TABLE_5_2_POSES_UM
from ..vision.probe import VisionProbe
from ..vision.targets import Target
from ..vision.tip_target import TipTarget
from . import trials
from .evaluation_figures import (
    BySource,
    DecouplingFigures,
    DirectionalPose,
    Evaluation,
    MultiDirectionalFigures,
    PoseAccuracyFigures,
)
from .trials import PositionProbe, aimed_poses_um

__all__ = [
    "APPROACH_SIDES",
    "DETOUR_UM",
    "TESTS",
    "Evaluation",
    "PositionProbe",
    "RunOptions",
    "aimed_poses_um",
    "approach_detours_um",
    "decoupling_path",
    "iso_cube_poses",
    "run_decoupling",
    "run_evaluation",
    "run_multi_directional",
    "run_pose_accuracy",
]


def iso_cube_poses(low_um: ArrayLike, high_um: ArrayLike) -> FloatArray:
    """The five test poses of ISO 9283's cube in the box [low, high], (5, 3) µm.

    The cube is the largest one with edges along the axes, centred in the box [low, high].
    P1 is its centre; P2 to P5 lie on the diagonals of the plane through two opposite edges
    (C1-C2-C7-C8 in the standard), 10 % of the diagonal's length from the corners.
    """
    low = np.asarray(low_um, dtype=np.float64)
    high = np.asarray(high_um, dtype=np.float64)
    moving = high > low  # a held axis (low == high): the cube is a square in the others
    side = float(np.min((high - low)[moving]))
    c0 = (low + high) / 2 - np.where(moving, side / 2, 0.0)
    x0, y0, z0 = c0
    x1, y1, z1 = c0 + np.where(moving, side, 0.0)
    corners = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z1], [x0, y1, z1]])
    centre = corners.mean(axis=0)
    pts = [centre] + [c + 0.1 * (centre - c) * 2 for c in corners]
    return np.array(pts)


def decoupling_path(
    samples_per_axis: int = 17, lengths_um: Sequence[float] = DECOUPLING_PATH_UM
) -> tuple[FloatArray, np.ndarray]:
    """The path of Fig 5.5 as displacements (N, 3) and the moving axis of each sample (N,)."""
    points, segment = [], []
    current = np.zeros(3)
    for axis, length in enumerate(lengths_um):
        for k in range(samples_per_axis):
            current[axis] = length * k / (samples_per_axis - 1)
            points.append(current.copy())
            segment.append(axis)
    return np.array(points), np.array(segment)


def run_pose_accuracy(
    manipulator: Manipulator,
    clock: Clock,
    probe: PositionProbe | None,
    conditions: dict[str, FeedForward | None],
    *,
    poses_um: FloatArray = TABLE_5_2_POSES_UM,
    cycles: int = 3,
    settle_s: float = 5.0,
    truth: Callable[[], FloatArray] | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> BySource[PoseAccuracyFigures]:
    """ISO 9283 pose accuracy (AP, clause 7.2.1) and repeatability (RP, 7.2.2) per condition.

    Returns
    -------
    dict
        ``{"vision" | "truth": {condition: PoseAccuracyFigures}}`` (the ``pose_accuracy``
        object of results.json).
    """
    out: BySource[PoseAccuracyFigures] = {s: {} for s in trials.sources(probe, truth)}
    for name, command in trials.commanders(manipulator, conditions).items():
        visit = functools.partial(trials.visit, command, manipulator=manipulator, clock=clock,
                                  settle_s=settle_s, probe=probe, truth=truth)  # fmt: skip
        home = visit(np.zeros(3))
        desired = aimed_poses_um(conditions[name], poses_um)
        arrivals: dict[str, list[list[FloatArray]]] = {k: [[] for _ in poses_um] for k in home}
        total = cycles * len(poses_um)
        for c in range(cycles):
            for i, pose in enumerate(poses_um):
                for source, p in visit(pose).items():
                    arrivals[source][i].append(p - home[source])
                if progress:
                    progress(f"pose accuracy, {name}", c * len(poses_um) + i + 1, total)
        for source, per_pose in arrivals.items():
            stats = []
            for pose, arr in zip(desired, per_pose, strict=True):
                a = np.array(arr)
                a = a[np.all(np.isfinite(a), axis=1)]
                if len(a):
                    stats.append(pose_statistics(pose, a))
            ap = [s.ap_p_um for s in stats]
            out[source][name] = PoseAccuracyFigures(
                mean_ap_p_um=float(np.mean(ap)) if ap else float("nan"),
                max_ap_p_um=float(np.max(ap)) if ap else float("nan"),
                poses=stats,
            )
    return out


#: The detour before each approach of the multi-directional test, µm along each axis.
DETOUR_UM = 300.0
#: The sides each approach of the multi-directional test comes from, per axis (-1: below).
#: ISO 9283 approaches along three directions parallel to the base axes; on a Cartesian
#: stage a move along one axis leaves the other joints' reversal state as the move before
#: left it, so microcal approaches along three diagonals instead: from below on every
#: axis, from above on every axis, and mixed, so that every joint reverses between them.
APPROACH_SIDES = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [1.0, -1.0, 1.0]])


def approach_detours_um(pose_um: FloatArray, low_um: FloatArray, high_um: FloatArray) -> FloatArray:
    """The three points a pose is approached from in the multi-directional test, (3, 3) µm:
    :data:`DETOUR_UM` to each side of :data:`APPROACH_SIDES`, displacements from home; a
    side that would leave ``[low_um, high_um]`` is the other one. An axis whose travel is one
    value (held) takes no detour."""
    sides = np.where(np.asarray(high_um) > np.asarray(low_um), APPROACH_SIDES, 0.0)
    out = pose_um[None, :] + DETOUR_UM * sides
    flipped = pose_um[None, :] - DETOUR_UM * sides
    outside = (out < low_um) | (out > high_um)
    out = np.where(outside, flipped, out)
    if np.any((out < low_um) | (out > high_um)):
        raise InputError(
            f"multi-directional test: pose {pose_um.tolist()} µm leaves no room for a "
            f"{DETOUR_UM:g} µm detour within {low_um.tolist()}..{high_um.tolist()} µm"
        )
    return out


def run_multi_directional(
    manipulator: Manipulator,
    clock: Clock,
    probe: PositionProbe | None,
    conditions: dict[str, FeedForward | None],
    *,
    poses_um: FloatArray = TABLE_5_2_POSES_UM,
    travel_um: tuple[FloatArray, FloatArray] | None = None,
    cycles: int = 3,
    settle_s: float = 5.0,
    truth: Callable[[], FloatArray] | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> BySource[MultiDirectionalFigures]:
    """ISO 9283 multi-directional pose accuracy variation (vAP, clause 7.3) per condition.

    Each pose is approached, every cycle, from three directions: from a point
    :data:`DETOUR_UM` away on every axis, to the sides of :data:`APPROACH_SIDES`
    (:func:`approach_detours_um`, within ``travel_um`` = (low, high) displacements from home;
    by default the soft limits less 50 µm). A compensator whose model has approach-direction
    terms makes its own fixed last approach
    (:class:`~microcal.control.feedforward.FeedForward`), which is what it is measured with.

    Returns
    -------
    dict
        ``{"vision" | "truth": {condition: MultiDirectionalFigures}}`` (vAP mean over the
        poses, the worst, and each pose's).
    """
    if travel_um is None:
        margin = np.where(manipulator.held, 0.0, 50.0)
        travel_um = (manipulator.limits_um[:, 0] + margin, manipulator.limits_um[:, 1] - margin)
    low, high = travel_um
    detours = [approach_detours_um(p, np.asarray(low), np.asarray(high)) for p in poses_um]
    out: BySource[MultiDirectionalFigures] = {s: {} for s in trials.sources(probe, truth)}
    for name, command in trials.commanders(manipulator, conditions).items():
        visit = functools.partial(trials.visit, command, manipulator=manipulator, clock=clock,
                                  settle_s=settle_s, probe=probe, truth=truth)  # fmt: skip
        home = visit(np.zeros(3))
        arrived: dict[str, list[list[list[FloatArray]]]] = {
            s: [[[] for _ in range(3)] for _ in poses_um] for s in home
        }
        total, done = cycles * len(poses_um) * 3, 0
        for _ in range(cycles):
            for i, pose in enumerate(poses_um):
                for k in range(3):
                    command(detours[i][k])
                    manipulator.wait_until_stopped(clock)
                    for source, p in visit(pose).items():
                        arrived[source][i][k].append(p - home[source])
                    done += 1
                    if progress:
                        progress(f"multi-directional, {name}", done, total)
        for source, per_pose in arrived.items():
            rows = []
            for pose, by_dir in zip(poses_um, per_pose, strict=True):
                dirs = [np.array(a)[np.all(np.isfinite(a), axis=1)] for a in by_dir]
                if all(len(a) for a in dirs):
                    rows.append(DirectionalPose(pose, multi_directional_variation(dirs)))
            vap = [r.vap_um for r in rows]
            out[source][name] = MultiDirectionalFigures(
                vap_um=float(np.mean(vap)) if vap else float("nan"),
                max_vap_um=float(np.max(vap)) if vap else float("nan"),
                poses=rows,
            )
    return out


def run_decoupling(
    manipulator: Manipulator,
    clock: Clock,
    probe: PositionProbe | None,
    conditions: dict[str, FeedForward | None],
    *,
    samples_per_axis: int = 17,
    settle_s: float = 5.0,
    truth: Callable[[], FloatArray] | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> BySource[DecouplingFigures]:
    """The decoupling test of Fig 5.5: undesired displacement ranges (Table 5-5) and Ω (5-6).

    Returns
    -------
    dict
        ``{"vision" | "truth": {condition: DecouplingFigures}}`` (the ``decoupling`` object
        of results.json, with the samples).
    """
    path, segment = decoupling_path(samples_per_axis)
    out: BySource[DecouplingFigures] = {s: {} for s in trials.sources(probe, truth)}
    for name, command in trials.commanders(manipulator, conditions).items():
        samples: dict[str, list[FloatArray]] = {k: [] for k in out}
        for k, rel in enumerate(path):
            for source, p in trials.visit(
                command, rel, manipulator, clock, settle_s, probe, truth
            ).items():
                samples[source].append(p)
            if progress:
                progress(f"decoupling, {name}", k + 1, len(path))
        for source, pts in samples.items():
            p = np.array(pts)
            good = np.all(np.isfinite(p), axis=1)
            out[source][name] = DecouplingFigures(
                decoupling_metrics(p[good], segment[good]), p, segment
            )
    return out


#: The tests of :func:`run_evaluation`.
TESTS = ("all", "pose-accuracy", "decoupling", "distance", "stabilisation")


class RunOptions(TypedDict):
    """The keywords every test of an evaluation takes (:func:`run_pose_accuracy` ...)."""

    settle_s: float
    truth: Callable[[], FloatArray] | None
    progress: Callable[[str, int, int], None] | None


def _iso_tests(
    manipulator: Manipulator,
    clock: Clock,
    probe: PositionProbe,
    conditions: dict[str, FeedForward | None],
    poses_um: FloatArray,
    tests: str,
    cycles: int,
    options: RunOptions,
    drift_s: float,
    drift_interval_s: float,
    band_um: float,
    into: Evaluation,
) -> None:
    """Distance, stabilisation and drift (``procedures.iso_tests``) as asked, ``into`` the
    evaluation."""
    from .iso_tests import run_distance, run_drift, run_stabilisation

    p1, p2, p4 = poses_um[0], poses_um[1], poses_um[min(3, len(poses_um) - 1)]
    if tests in ("all", "distance"):
        into.distance_accuracy = run_distance(manipulator, clock, probe, conditions, p2, p4,
                                              cycles=max(cycles, 2), **options)  # fmt: skip
    if tests in ("all", "stabilisation"):
        into.stabilisation = run_stabilisation(
            manipulator, clock, probe, conditions, p1, p2, cycles=cycles, band_um=band_um,
            truth=options["truth"], progress=options["progress"],
        )  # fmt: skip
    if drift_s > 0:
        into.drift = run_drift(manipulator, clock, probe, conditions, p1, duration_s=drift_s,
                               interval_s=min(drift_interval_s, drift_s), **options)  # fmt: skip


def run_evaluation(
    manipulator: Manipulator,
    clock: Clock,
    cameras: Mapping[str, Camera],
    models: dict[str, AnyCamera],
    board: Target | TipTarget,
    calibration: ManipulatorCalibration,
    *,
    tests: str = "all",
    poses: str = "table-5-2",
    cycles: int = 3,
    frames: int = 5,
    settle_s: float = 5.0,
    truth: Callable[[], FloatArray] | None = None,
    sensors: Mapping[str, Callable[[], float]] | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    control: str = "open",
    tolerance_um: float = 0.5,
    drift_s: float = 0.0,
    drift_interval_s: float = 600.0,
    band_um: float = 2.0,
    probe: Any = None,
) -> Evaluation:
    """The evaluation tests of a calibrated manipulator on any rig (thesis 5.3, ISO 9283).

    Each test runs without compensation, with the matrix compensator and (for a polynomial
    model) with the optimal one, measured by the calibrated cameras and, where ``truth``
    is given (the simulator), by ground truth.

    Parameters
    ----------
    cameras : mapping of name -> Camera
        The rig's cameras; each needs a model in ``models``.
    models : dict of name -> camera model
        The calibrated cameras.
    calibration : ManipulatorCalibration
        The manipulator's calibration.
    tests : {"all", "pose-accuracy", "decoupling", "distance", "stabilisation"}
        ``all`` runs the four: pose accuracy and repeatability (AP, RP), decoupling, distance
        accuracy and repeatability (AD, RD, between the second and fourth pose) and the
        stabilisation time (at the first pose, coming from the second; ``band_um``).
    poses : {"table-5-2", "iso-cube"}
        The pose-accuracy test's poses: Table 5-2's, or ISO 9283's cube P1-P5 spanning the
        joint range the model was identified on (the soft limits when not recorded).
    sensors : mapping of name -> callable () -> float, optional
        The rig's sensors of extra inputs by registry name, for models that have some.
    control : {"open", "closed", "all"}
        The open-loop conditions (uncalibrated, matrix, optimal), the closed loop
        (``closed_loop``: the optimal move, then visual servoing to ``tolerance_um`` at 90 %
        confidence), or both.
    drift_s : float
        Above 0: also the drift of AP at the first pose over this long, measured every
        ``drift_interval_s`` (ISO 9283 clause 7.7; on hardware it takes that long).
    probe : object, optional
        What measures the tip instead of the cameras' probe: a one-camera rig's
        (:class:`~microcal.procedures.one_camera_probe.OneCameraTipProbe`, ``cameras`` and
        ``models`` then unused). Its rig sees only its working volume: the tests are
        ISO 9283's at the cube (``poses="iso-cube"``: inside the calibration's
        ``working_volume_um`` where it records one); Table 5-2's poses and the decoupling
        path, which span the whole travel, are refused.

    Returns
    -------
    Evaluation
        The tests that ran (``pose_accuracy`` and/or ``decoupling``, the ISO 9283 tests
        asked), and with the closed loop its ``closed_loop`` summary (iterations, frames,
        how the loops ended); its ``to_json()`` is what results.json stores of them.
    """
    calibration.check_device(manipulator.identity)
    if tests not in TESTS:
        raise InputError(f"tests: expected one of {', '.join(TESTS)}, got {tests!r}")
    if control not in ("open", "closed", "all"):
        raise InputError(f"control: expected open, closed or all, got {control!r}")
    missing = sorted(set(cameras) - set(models))
    if missing and probe is None:
        raise InputError(f"evaluate: no camera calibration for the rig's camera(s) {missing}")
    if probe is not None and (poses != "iso-cube" or tests in ("all", "decoupling")):
        raise InputError(
            "evaluate on a one-camera rig: the camera sees only the working volume, and Table "
            "5-2's poses and the decoupling path span the whole travel; use --poses iso-cube "
            "--test pose-accuracy (or distance, stabilisation)"
        )
    if not np.isfinite(settle_s) or settle_s < 0:
        raise InputError(f"settle: expected a finite wait >= 0 s, got {settle_s}")
    try:
        read_extra = extra_inputs_reader(calibration.model, sensors)
    except InputError as exc:
        raise InputError(f"evaluate: {exc}") from None
    conditions: dict[str, FeedForward | None] = {}
    if control in ("open", "all"):
        conditions |= open_loop_conditions(manipulator, calibration, extra=read_extra, clock=clock)
    if probe is None:
        used = {n: models[n] for n in cameras}  # a calibrated camera the rig lacks is not used
        probe = VisionProbe({n: cameras[n] for n in used}, used, board, frames)
    loop = None
    if control in ("closed", "all"):
        loop = closed_loop_condition(manipulator, calibration, probe.measure_with_covariance,
                                     clock, read_extra, ServoConfig(tolerance_um=tolerance_um),
                                     truth=truth)  # fmt: skip
        conditions["closed_loop"] = loop
    options = RunOptions(settle_s=settle_s, truth=truth, progress=progress)
    parts = Evaluation()
    rng = calibration.joint_range_um
    lim = manipulator.limits_um if rng is None else rng
    volume = calibration.extra.get("working_volume_um")
    if volume is not None:  # a one-camera calibration's volume in {M}: low and high corners
        lim = np.asarray(volume, dtype=np.float64).reshape(2, 3).T
    poses_um = TABLE_5_2_POSES_UM if poses == "table-5-2" else iso_cube_poses(*lim.T)
    held = manipulator.held
    if held.any() and (poses == "table-5-2" or tests in ("all", "decoupling")):
        raise InputError(
            f"evaluate on {manipulator.name}: it holds {', '.join(np.array(list('xyz'))[held])} "
            f"still (an X-Y positioner), but the Table 5-2 poses and the decoupling path move "
            f"every axis; use --poses iso-cube --test pose-accuracy (or another single test)"
        )
    # Home is the zero joints; the uncompensated commands are the displacements themselves:
    # all must lie within the soft limits, checked before anything moves.
    planned = [np.zeros((1, 3))]
    planned += [poses_um] if tests in ("all", "pose-accuracy") else []
    planned += [decoupling_path()[0]] if tests in ("all", "decoupling") else []
    check_limits(np.vstack(planned), manipulator.limits_um, row="test command",
                 owner=f"evaluate on {manipulator.name}")  # fmt: skip
    if tests in ("all", "pose-accuracy"):
        parts.pose_accuracy = run_pose_accuracy(
            manipulator, clock, probe, conditions, cycles=cycles, poses_um=poses_um, **options
        )
    if tests in ("all", "decoupling"):
        parts.decoupling = run_decoupling(manipulator, clock, probe, conditions, **options)
    _iso_tests(manipulator, clock, probe, conditions, poses_um, tests, cycles, options, drift_s,
               drift_interval_s, band_um, parts)  # fmt: skip
    if loop is not None:
        parts.closed_loop = loop.summary()
    failures = getattr(probe, "failures", [])
    parts.unseen = [{"d_um": d.tolist(), "reason": why} for d, why in failures]
    return parts
