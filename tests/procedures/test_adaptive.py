"""The adaptive loop: it stops on its tolerance, and a run stopped mid-batch and resumed
chooses the same poses and keeps every pose (procedures.adaptive)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from microcal.errors import DegenerateDataError
from microcal.kinematics.adaptive_design import AdaptiveSettings
from microcal.procedures.acquisition import AcquisitionConfig
from microcal.procedures.adaptive import AdaptiveDesign, Measured, run_adaptive
from microcal.sim.thesis_kinematics import thesis_kinematics

LOW, HIGH = np.zeros(3), np.array([8000.0, 8000.0, 4800.0])
LIMITS = np.array([[-500.0, 8500.0], [-500.0, 8500.0], [-500.0, 5300.0]])
APPROACH = AcquisitionConfig(approach_um=300.0, approach_seed=5)
SETTINGS = AdaptiveSettings(until_um=1.2, max_poses=70, candidates=512, grid_per_axis=5)


def _design(settings: AdaptiveSettings = SETTINGS) -> AdaptiveDesign:
    return AdaptiveDesign(settings, LOW, HIGH, LIMITS, APPROACH)


def _measure(d: np.ndarray, poses: list[int], directions: np.ndarray | None = None) -> Measured:
    """A world whose measurement of a pose depends on its command, number and chosen
    approach directions alone."""
    truth = thesis_kinematics()
    chosen = np.full((len(d), 3), np.nan) if directions is None else directions
    signs = np.array([_design().signs_for(row[None, :], k, w)[0] for row, k, w in
                      zip(d, poses, chosen, strict=True)])  # fmt: skip
    noise = np.array([np.random.default_rng([k, 11]).normal(0.0, 0.25, 3) for k in poses])
    p = np.vstack([truth.position_um(row[None, :], s[None, :]) for row, s in zip(d, signs,
                                                                              strict=True)])  # fmt: skip
    p = p + noise
    return Measured(np.array(d), p, signs, np.full(len(d), 22.0), np.array(d))


class CrashError(Exception):
    pass


def test_it_stops_on_its_tolerance_or_its_most_poses() -> None:
    result = run_adaptive(_design(), _measure)
    final = result.final
    assert final.stop
    assert final.model is not None
    assert final.predicted_um <= SETTINGS.until_um or len(result.measured) == SETTINGS.max_poses
    assert len(result.measured) >= SETTINGS.start_poses
    # every pose after the start is a distinct candidate of the design
    later = result.measured.d_um[SETTINGS.start_poses :]
    assert len(np.unique(later, axis=0)) == len(later)


@pytest.mark.parametrize("choose_directions", [False, True])
def test_a_crash_mid_batch_then_resume_chooses_the_same_poses_and_loses_nothing(
    choose_directions: bool,
) -> None:
    settings = dataclasses.replace(SETTINGS, choose_directions=choose_directions,
                                   candidates=256 if choose_directions else SETTINGS.candidates)  # fmt: skip
    plain = run_adaptive(_design(settings), _measure)
    assert len(plain.measured) > SETTINGS.start_poses + SETTINGS.batch  # there is a batch to cut
    crash_at = SETTINGS.start_poses + SETTINGS.batch // 2  # in the middle of the first batch
    stored: list[Measured] = []
    planned: list[np.ndarray] = []

    def acquire(d: np.ndarray, poses: list[int], directions: np.ndarray) -> Measured:
        for row, pose, w in zip(d, poses, directions, strict=True):  # as a run stores them
            if pose > crash_at and not stored_after_crash:
                raise CrashError(f"the rig stopped before pose {pose}")
            stored.append(_measure(row[None, :], [pose], w[None, :]))
        got = Measured.empty()
        for m in stored[-len(poses) :]:
            got = got + m
        return got

    stored_after_crash: list[bool] = []
    with pytest.raises(CrashError):
        run_adaptive(_design(settings), acquire, on_plan=planned.append)
    assert sum(len(m) for m in stored) == crash_at  # what was stored before the crash
    # resume: from what the run directory holds, the poses stored and the commands planned
    stored_after_crash.append(True)
    have = Measured.empty()
    for m in stored:
        have = have + m
    resumed = run_adaptive(_design(settings), acquire, measured=have,
                           planned_um=np.vstack(planned), on_plan=planned.append)  # fmt: skip
    np.testing.assert_array_equal(resumed.measured.d_um, plain.measured.d_um)
    np.testing.assert_array_equal(resumed.measured.p_um, plain.measured.p_um)
    np.testing.assert_array_equal(resumed.measured.signs, plain.measured.signs)
    np.testing.assert_array_equal(np.vstack(planned), plain.measured.d_um)
    assert resumed.final.predicted_um == plain.final.predicted_um


def test_no_approach_no_adaptive_design() -> None:
    with pytest.raises(DegenerateDataError, match="approach"):
        AdaptiveDesign(SETTINGS, LOW, HIGH, LIMITS, AcquisitionConfig())
