"""A quick check of a calibration (and a quick update of its offset) from a few poses.

A device that was re-mounted, had its tool exchanged or drifted no longer sits where its
calibration says. :func:`run_check` drives the manipulator to ``check_poses_um`` (by default
ten poses of ISO 9283's cube, each approached as the calibration was made), measures each with
the cameras, and compares the measured position ``p_i`` with the calibration's prediction
``p̂_i``: residuals ``r_i = p_i - p̂_i`` with covariance ``S_i``.

- Against the calibration alone (no reference): ``S_i`` = the measurement's covariance +
  the model's validation error per axis (the misfit the model leaves, from
  calibration.json); and the model's prediction covariance (its coefficients), which is
  shared by the poses: one set of coefficients predicts all of them, so its error moves the
  ten predictions together and does not average down over them. The residuals' covariance
  ``V`` (3n x 3n) holds it between the poses. The misfit, too, need not average down: the
  check approaches every pose from the same side and its poses lie near the corners of the
  joints' range, where a model from few poses is off in the same way at all of them (an
  approach-direction term left out, a curvature it lacks). Its validation error per axis
  is therefore also counted as a bias common to the poses, in the offset's covariance.
- Against a reference check (the first check after the calibration, same poses): the
  differences ``r_i - r_ref_i``, whose covariance is the two measurements' alone; the
  model's error at each pose, common or not, cancels, so a smaller change is seen.

Two tests, each at level ``alpha``, from the generalised least-squares mean ``m`` of the
residuals (``C0 = (A^T V^-1 A)^-1``, ``m = C0 A^T V^-1 r``, ``A`` ten identities stacked;
with ``V`` block-diagonal, the weighted mean ``(Σ S_i^-1)^-1 Σ S_i^-1 r_i``): the offset,
``m^T C^-1 m`` with 3 degrees of freedom, ``C = C0`` + the common misfit; and the scatter
about it, ``r^T V^-1 r - m^T C0^-1 m`` (``Σ (r_i - m)^T S_i^-1 (r_i - m)`` for a block-diagonal
``V``) with ``3 (n - 1)``. The verdict: ``refit`` when the scatter is too
large (the model no longer fits: a scale, an axis, a new error), else ``offset`` when the
mean is (the device moved as a whole: :func:`offset_updated` re-fits the base offset and only
that), else ``valid``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import stats

from .._validation import FloatArray, as_array
from ..control.feedforward import APPROACH_UM, has_approach_terms
from ..devices.base import Clock, Manipulator
from ..errors import DetectionError, FormatError, InputError
from ..json_value import JsonValue
from ..kinematics.extra_inputs import by_symbol, fixed_approach_values
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..kinematics.models import KinematicModel

__all__ = [
    "CheckConfig",
    "CheckResult",
    "CheckUpdate",
    "check_poses_um",
    "compare",
    "offset_updated",
    "run_check",
]

Verdict = Literal["valid", "offset", "refit"]
#: ``measure(d_um, frames) -> (p_um (3,), cov_um2 (3, 3))``
#: (``VisionProbe.measure_with_covariance``).
Measure = Callable[[FloatArray, int], tuple[FloatArray, FloatArray]]


def check_poses_um(low_um: FloatArray, high_um: FloatArray) -> FloatArray:
    """Ten check poses in the joint box [low, high], (10, 3) µm.

    ISO 9283's cube (the largest with edges along the axes, centred in the box): its centre
    P1, the eight points 10 % of the diagonal in from its corners (P2-P5 of the standard and
    their mirror images), and P1 again, so that a drift during the check shows as a misfit.
    A held joint (low == high: an X-Y positioner's z) keeps its value; the cube is then a
    square whose four corner poses are each visited twice.
    """
    low, high = np.asarray(low_um, dtype=np.float64), np.asarray(high_um, dtype=np.float64)
    moving = high > low
    side = float(np.min((high - low)[moving]))
    centre = (low + high) / 2
    unit = np.array([[sx, sy, sz] for sz in (-1, 1) for sy in (-1, 1) for sx in (-1, 1)])
    corners = centre + unit * np.where(moving, side / 2, 0.0)
    inner = corners + 0.2 * (centre - corners)
    return np.vstack([centre, inner, centre])


@dataclass(frozen=True)
class CheckConfig:
    """How a check measures and decides.

    Attributes
    ----------
    frames : int
        Frames per camera and pose (20: a 1 µm offset found at 95 % power or more from ten
        poses on the thesis's platform; see docs/compensation.md).
    settle_s : float
        Wait after the device reports "stopped", s.
    alpha : float
        False-alarm rate of each test (0.05).
    """

    frames: int = 20
    settle_s: float = 5.0
    alpha: float = 0.05

    def __post_init__(self) -> None:
        if not 1 <= self.frames <= 1000:
            raise InputError(f"frames: expected 1 to 1000 per pose, got {self.frames}")
        if not 0 < self.alpha < 0.5:
            raise InputError(f"alpha: expected a false-alarm rate in (0, 0.5), got {self.alpha}")
        if not (np.isfinite(self.settle_s) and self.settle_s >= 0):
            raise InputError(f"settle_s: expected a finite wait >= 0 s, got {self.settle_s}")


@dataclass(frozen=True)
class CheckUpdate:
    """What ``check --update`` did: the calibration written with the re-fitted offset and the
    check made again with it, or why nothing was written.

    Attributes
    ----------
    calibration : str or None
        The updated calibration file, or None when nothing was written.
    refused : str
        Why nothing was written (empty when it was).
    verdict_after : str
        The verdict of the check made again with the updated calibration.
    offset_after_um, offset_after_std_um : (3,) float
        Its offset and standard deviation.
    """

    calibration: str | None
    refused: str = ""
    verdict_after: str = ""
    offset_after_um: tuple[float, ...] = ()
    offset_after_std_um: tuple[float, ...] = ()

    def to_json(self) -> dict[str, JsonValue]:
        """check.json's ``update`` object."""
        if self.calibration is None:
            return {"calibration": None, "refused": self.refused}
        return {"calibration": self.calibration, "verdict_after": self.verdict_after,
                "offset_after_um": list(self.offset_after_um),
                "offset_after_std_um": list(self.offset_after_std_um)}  # fmt: skip


@dataclass
class CheckResult:
    """A check's measurements and verdict (the ``check.json`` object).

    Attributes
    ----------
    verdict : {"valid", "offset", "refit"}
    offset_um, offset_std_um : (3,) float
        The weighted mean residual and its standard deviation, µm.
    chi2, p_value : float
        The scatter test (the model's fit): statistic and p-value.
    offset_chi2, offset_p_value : float
        The mean test (the offset).
    d_um, measured_um, predicted_um, residual_um : (n, 3) float
        Check poses (joints), where the cameras saw them, where the calibration puts them,
        and the difference, µm.
    covariance_um2 : (n, 3, 3) float
        Each measurement's covariance, µm².
    reference : bool
        Whether the residuals were compared with a reference check's.
    """

    verdict: Verdict
    offset_um: FloatArray
    offset_std_um: FloatArray
    chi2: float
    p_value: float
    offset_chi2: float
    offset_p_value: float
    d_um: FloatArray
    measured_um: FloatArray
    predicted_um: FloatArray
    residual_um: FloatArray
    covariance_um2: FloatArray
    reference: bool = False
    extra: dict[str, JsonValue] = field(default_factory=dict)

    @property
    def n_poses(self) -> int:
        return int(self.d_um.shape[0])

    def as_dict(self) -> dict[str, JsonValue]:
        """check.json's keys (``format`` is the writer's)."""
        return {
            "verdict": self.verdict,
            "offset_um": self.offset_um.tolist(),
            "offset_std_um": self.offset_std_um.tolist(),
            "chi2": self.chi2,
            "p_value": self.p_value,
            "offset_chi2": self.offset_chi2,
            "offset_p_value": self.offset_p_value,
            "n_poses": self.n_poses,
            "against": "reference check" if self.reference else "calibration",
            "poses": [
                {
                    "d_um": d.tolist(),
                    "measured_um": m.tolist(),
                    "predicted_um": p.tolist(),
                    "residual_um": r.tolist(),
                    "cov_um2": c.tolist(),
                }
                for d, m, p, r, c in zip(
                    self.d_um,
                    self.measured_um,
                    self.predicted_um,
                    self.residual_um,
                    self.covariance_um2,
                    strict=True,
                )
            ],
        } | self.extra


def _rms_um(rms_axis_um: object, axis: str) -> float:
    """The validation's RMS error along an axis (``validation.rms_axis_um``), µm; 0 when
    the validation records none."""
    value = rms_axis_um.get(axis, 0.0) if isinstance(rms_axis_um, Mapping) else 0.0
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise FormatError(f"validation.rms_axis_um.{axis}: expected a number, got {value!r}")
    return float(value)


def _inputs(model: KinematicModel, d_um: FloatArray) -> FloatArray:
    """The model's inputs at joints ``d_um`` (n, 3): approach terms at +1, others refused."""
    extras = model.extra_inputs
    fixed = fixed_approach_values(extras)
    names = {e: by_symbol(e).name for e in extras}
    unknown = [e for e in extras if names[e] not in fixed]
    if unknown:
        raise InputError(
            f"check: the model's extra inputs {unknown} are not supported by the check yet; "
            "check a model without them"
        )
    cols = [np.full(len(d_um), fixed[names[e]]) for e in extras]
    return np.column_stack([d_um, *cols]) if cols else d_um


def compare(
    model: KinematicModel,
    validation_rms_axis_um: FloatArray,
    d_um: FloatArray,
    measured_um: FloatArray,
    cov_um2: FloatArray,
    *,
    alpha: float = 0.05,
    reference: tuple[FloatArray, FloatArray] | None = None,
) -> CheckResult:
    """The tests of the module docstring on measured check poses.

    Parameters
    ----------
    model : KinematicModel
    validation_rms_axis_um : (3,) float
        The model's validation RMS error per axis (its misfit), µm.
    d_um, measured_um : (n, 3) float
    cov_um2 : (n, 3, 3) float
    reference : (residual_um (n, 3), cov_um2 (n, 3, 3)), optional
        A reference check at the same poses.
    """
    d = as_array(d_um, "d_um", (None, 3))
    n = d.shape[0]
    p = as_array(measured_um, "measured_um", (n, 3))
    cov = as_array(cov_um2, "cov_um2", (n, 3, 3))
    if n < 3:
        raise InputError(f"check: expected 3 poses or more, got {n}")
    u = _inputs(model, d)
    predicted = model.predict_um(u)
    r = p - predicted
    if reference is None:
        misfit = np.asarray(validation_rms_axis_um, dtype=np.float64) ** 2
        V = _pose_blocks(cov + np.einsum("a,ab->ab", misfit, np.eye(3)))
        V += _across_poses(model.prediction_covariance_um2(u))
        common = np.diag(misfit)
        x = r
    else:
        ref_r, ref_cov = reference
        V = _pose_blocks(cov + as_array(ref_cov, "reference cov_um2", (n, 3, 3)))
        common = np.zeros((3, 3))
        x = r - as_array(ref_r, "reference residual_um", (n, 3))
    m, C0, chi2 = _generalised_mean(V, x)
    C = C0 + common
    offset_chi2 = float(m @ np.linalg.solve(C, m))
    p_fit = float(stats.chi2.sf(chi2, 3 * (n - 1)))
    p_off = float(stats.chi2.sf(offset_chi2, 3))
    verdict: Verdict = "refit" if p_fit < alpha else "offset" if p_off < alpha else "valid"
    return CheckResult(verdict, m, np.sqrt(np.diag(C)), chi2, p_fit, offset_chi2, p_off, d, p,
                       predicted, r, cov, reference is not None)  # fmt: skip


def _pose_blocks(cov_um2: FloatArray) -> FloatArray:
    """(3n, 3n) block-diagonal matrix of the poses' own (n, 3, 3) covariances (pose-major:
    row ``3 i + axis``)."""
    n = cov_um2.shape[0]
    out: FloatArray = np.zeros((3 * n, 3 * n))
    for i in range(n):
        out[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = cov_um2[i]
    return out


def _across_poses(per_axis_um2: FloatArray) -> FloatArray:
    """(3n, 3n) pose-major matrix of per-axis (3, n, n) covariances between the poses (none
    between the axes)."""
    n = per_axis_um2.shape[1]
    out: FloatArray = np.einsum("aij,ab->iajb", per_axis_um2, np.eye(3)).reshape(3 * n, 3 * n)
    return out


def _generalised_mean(V: FloatArray, x: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """The generalised least-squares mean of residuals ``x`` (n, 3) with covariance ``V``
    (3n, 3n): the mean m (3,), its covariance C (3, 3), and the scatter about it
    ``x^T V^-1 x - m^T C^-1 m`` (chi² with 3 (n - 1) degrees of freedom). With ``V``
    block-diagonal, m is the weighted mean ``(Σ S_i^-1)^-1 Σ S_i^-1 x_i`` and the scatter
    ``Σ (x_i - m)^T S_i^-1 (x_i - m)``."""
    n = x.shape[0]
    A = np.tile(np.eye(3), (n, 1))
    L = np.linalg.cholesky(V)
    WA = np.linalg.solve(L.T, np.linalg.solve(L, A))  # V^-1 A
    C = np.linalg.inv(A.T @ WA)
    C = (C + C.T) / 2
    flat = x.reshape(-1)
    m = C @ (WA.T @ flat)
    z = np.linalg.solve(L, flat - A @ m)
    return m, C, float(z @ z)


def planned_check(
    calibration: ManipulatorCalibration,
    manipulator: Manipulator,
    poses_um: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The check poses (n, 3) µm and the approach below each ((3,) µm per joint, zeros:
    none; a held joint never takes one), each checked against the manipulator's soft limits.

    The poses are :func:`check_poses_um` in the joints' range of the calibration data (the
    soft limits when it records none), or ``poses_um``.

    Raises
    ------
    LimitError
        A pose, or the start of its approach, outside the soft limits.
    """
    rng = calibration.joint_range_um
    box = manipulator.limits_um if rng is None else rng
    d_all = (
        check_poses_um(*box.T) if poses_um is None else as_array(poses_um, "poses_um", (None, 3))
    )
    distance = APPROACH_UM if has_approach_terms(calibration.model) else 0.0
    approach = manipulator.below_um(np.zeros(3), -distance)  # +distance on each moving joint
    for d in d_all:
        manipulator.check_limits(d)
        manipulator.check_limits(d - approach)
    return d_all, approach


def run_check(
    manipulator: Manipulator,
    clock: Clock,
    measure: Measure,
    calibration: ManipulatorCalibration,
    *,
    poses_um: FloatArray | None = None,
    config: CheckConfig | None = None,
    reference: tuple[FloatArray, FloatArray] | None = None,
    progress: Callable[[int, int], None] | None = None,
    seen_as: str = "the board",
    why_unseen: Callable[[], str] | None = None,
) -> CheckResult:
    """Measure the check poses and test them against the calibration (module docstring).

    ``seen_as`` names the target in the refusal of a pose the cameras did not see (``the
    tool's tip``), ``why_unseen`` gives their reasons (the probe's, camera by camera).

    Each pose is approached as the calibration was made: from :data:`APPROACH_UM` below on
    every joint when the model has approach-direction terms. All poses are checked against
    the soft limits before anything moves.

    Raises
    ------
    LimitError
        A check pose outside the soft limits (nothing moved).
    DetectionError
        The cameras did not see the board at some pose.
    """
    cfg = config or CheckConfig()
    calibration.check_device(manipulator.identity)
    model = calibration.model
    d_all, approach = planned_check(calibration, manipulator, poses_um)
    measured, covs = [], []
    start_s = clock.now_s()
    for i, d in enumerate(d_all):
        if approach.any():
            manipulator.move_to_um(d - approach)
            manipulator.wait_until_stopped(clock)
        manipulator.move_to_um(d)
        manipulator.wait_until_stopped(clock)
        clock.sleep(cfg.settle_s)
        p, c = measure(d, cfg.frames)
        if not np.all(np.isfinite(p)):
            why = why_unseen() if why_unseen is not None else ""
            raise DetectionError(
                f"check: the cameras did not see {seen_as} at check pose {i + 1} "
                f"(joints {np.round(d, 1).tolist()} µm{f'; {why}' if why else ''}); is it in "
                f"view and lit?"
            )
        measured.append(p)
        covs.append(c)
        if progress:
            progress(i + 1, len(d_all))
    rms = calibration.validation.get("rms_axis_um")
    misfit = np.array([_rms_um(rms, a) for a in "xyz"])
    result = compare(model, misfit, d_all, np.array(measured), np.array(covs), alpha=cfg.alpha,
                     reference=reference)  # fmt: skip
    result.extra["duration_s"] = clock.now_s() - start_s
    result.extra["frames"] = cfg.frames
    return result


def offset_updated(model: KinematicModel, offset_um: FloatArray) -> KinematicModel:
    """The model with its base offset moved by ``offset_um`` (3,) µm, nothing else changed.

    Raises
    ------
    InputError
        The model has no constant term on some axis.
    """
    import dataclasses

    const = [a for a, t in enumerate(model.terms) if not t.inputs]
    if len(const) != 1 or not model.selected[:, const[0]].all():
        raise InputError("update: the model has no base offset (constant term) on every axis")
    coef = model.coefficients.copy()
    coef[:, const[0]] += as_array(offset_um, "offset_um", (3,))
    return dataclasses.replace(model, coefficients=coef)
