"""The ``population`` preset: every seed draws another manipulator and camera set-up.

A lab's manipulator is one draw from a population of them, so a method is judged on many.
:func:`draw_population` turns a seed into one platform's true kinematics, temperature
profile and camera placement, each parameter drawn from the distribution that
``docs/simulator.md`` gives with its source. The errors reach outside the polynomial family
the thesis identifies: smooth random straightness and angular (Abbe) errors along each
joint, a periodic sensor error, reversal error that changes along the travel, logarithmic
creep and drift that follows a room's temperature cycle.

Distributions (``U(a, b)`` uniform, ``logU(a, b)`` log-uniform, each with a random sign where
it says ±):

- linear: scale error ±logU(1e-4, 1e-3) per axis; coupling ±logU(2e-4, 6e-3) per pair;
- quadratic: each axis's pure squares bow by ±logU(0.5, 20) µm over the travel, its cross
  terms by ±logU(0.2, 5) µm; base position P_B within ±200 µm of the thesis's;
- straightness of each joint in the two other axes: a Gaussian process (squared-exponential,
  length scale U(0.8, 2) mm), standard deviation U(0.5, 1.5) µm;
- angular errors of each joint about x, y, z: the same process, U(10, 50) µrad, seen through a
  tool offset of U(10, 40) mm in a random direction (Abbe);
- periodic sensor error: U(0.02, 0.1) µm, period U(2, 20) µm;
- reversal: half gap U(0.2, 0.8) µm per joint, changing by ±U(0, 50) % over half the travel;
- creep: logarithmic, U(2e-4, 1e-3) of the step, tau U(0.2, 1) s, over U(10, 60) s;
- thermal: ±U(0.3, 1.5) µm/°C per axis; the room swings by U(0.05, 0.3) °C with a period of
  U(0.5, 2) h and drifts by ±U(0, 0.3) °C/h;
- cameras: each turned about the travel's middle by up to 2 degrees about each axis, its
  magnification within ±10 % of the thesis camera's;
- motion (drawn last, so the draws above are those of a platform without it): per joint five
  play operators, the largest radius U(2, 8) µm, the others down to a sixteenth of it, their
  weights from a flat Dirichlet; positioning scatter U(0.01, 0.04) µm and stick-slip step
  U(0.01, 0.1) µm per joint (:mod:`~microcal.sim.motion`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..kinematics.models import KinematicModel
from ..kinematics.terms import JOINTS, polynomial_terms
from .kinematics import JointErrors, TrueKinematics
from .motion import MotionNoise, PlayHysteresis, play_radii_um

__all__ = ["PopulationDraw", "draw_population"]

#: The span the profiles are drawn over: the simulated travel, µm.
PROFILE_LOW_UM = np.array([-500.0, -500.0, -500.0])
PROFILE_HIGH_UM = np.array([8500.0, 8500.0, 5300.0])
#: The test travel (the thesis's), over which the polynomial terms are sized, µm.
TRAVEL_UM = np.array([8000.0, 8000.0, 4800.0])
#: Knots of each joint's profiles.
KNOTS = 61
#: The thesis preset's base position, µm.
THESIS_BASE_UM = np.array([1000.0, 800.0, 300.0])


@dataclass(frozen=True)
class PopulationDraw:
    """One seed's platform: its true kinematics, temperature profile and camera changes.

    Attributes
    ----------
    truth : TrueKinematics
    temperature_swing_c, temperature_period_h, temperature_phase, temperature_drift_c_per_h
        The room's temperature profile.
    camera_rotation_deg : (n_cameras, 3) float
        Turn of each camera about the travel's middle (about {G}'s x, y, z), degrees.
    camera_magnification : (n_cameras,) float
        Factor on each camera's focal length.
    profile_length_um, straightness_sd_um, angle_sd_urad : (3,) float
        The prior each joint's straightness and angular profiles were drawn from: the
        process's length scale and standard deviations (for
        :mod:`~microcal.sim.population_prior`).
    play : PlayHysteresis
        The reversal error's memory (``truth`` has it only where the platform's
        ``manipulator.real_motion`` is on).
    motion : MotionNoise
        The moves' scatter and step.
    """

    truth: TrueKinematics
    temperature_swing_c: float
    temperature_period_h: float
    temperature_phase: float
    temperature_drift_c_per_h: float
    camera_rotation_deg: FloatArray
    camera_magnification: FloatArray
    profile_length_um: FloatArray
    straightness_sd_um: FloatArray
    angle_sd_urad: FloatArray
    play: PlayHysteresis
    motion: MotionNoise


def _signed_log_uniform(rng: np.random.Generator, low: float, high: float, size: int) -> FloatArray:
    mag = np.exp(rng.uniform(np.log(low), np.log(high), size))
    out: FloatArray = mag * rng.choice([-1.0, 1.0], size)
    return out


def _gaussian_process(
    rng: np.random.Generator, x: FloatArray, length: float, sigma: float, count: int
) -> FloatArray:
    """``count`` draws of a zero-mean squared-exponential process at ``x``, (len(x), count)."""
    k = np.exp(-0.5 * ((x[:, None] - x[None, :]) / length) ** 2)
    chol = np.linalg.cholesky(k + 1e-8 * np.eye(x.size))
    out: FloatArray = sigma * chol @ rng.standard_normal((x.size, count))
    return out


def _static(rng: np.random.Generator) -> KinematicModel:
    terms = polynomial_terms(JOINTS, 2)
    names = [t.name for t in terms]
    coef = np.zeros((3, len(terms)))
    linear = np.diag(1.0 + _signed_log_uniform(rng, 1e-4, 1e-3, 3))
    off = ~np.eye(3, dtype=bool)
    linear[off] = _signed_log_uniform(rng, 2e-4, 6e-3, 6)
    for j, joint in enumerate(JOINTS):
        coef[:, names.index(joint)] = linear[:, j]
    half = TRAVEL_UM / 2
    for axis in range(3):
        for j, joint in enumerate(JOINTS):
            # a bow of b µm over the travel: coefficient b / (L/2)^2 on the square
            bow = _signed_log_uniform(rng, 0.5, 20.0, 1)[0]
            coef[axis, names.index(f"{joint}^2")] = bow / half[j] ** 2
        for a, b in ((0, 1), (1, 2), (0, 2)):
            bow = _signed_log_uniform(rng, 0.2, 5.0, 1)[0]
            coef[axis, names.index(f"{JOINTS[a]}*{JOINTS[b]}")] = bow / (half[a] * half[b])
    coef[:, names.index("1")] = THESIS_BASE_UM + rng.uniform(-200.0, 200.0, 3)
    return KinematicModel(
        kind="polynomial",
        inputs=JOINTS,
        joints=JOINTS,
        terms=terms,
        coefficients=coef,
        selected=coef != 0,
        covariance=np.zeros((3, len(terms), len(terms))),
        selection={"method": "truth"},
    )


def _joint_errors(rng: np.random.Generator) -> tuple[JointErrors, FloatArray]:
    """The joints' errors, and their prior: rows length scale (µm), straightness sd (µm)
    and angle sd (µrad), a column per joint, (3, 3)."""
    knots = np.linspace(PROFILE_LOW_UM, PROFILE_HIGH_UM, KNOTS).T  # (3, K)
    straight = np.zeros((3, KNOTS, 3))
    angles = np.zeros((3, KNOTS, 3))
    prior = np.zeros((3, 3))
    for j in range(3):
        length = rng.uniform(800.0, 2000.0)
        sigma = rng.uniform(0.5, 1.5)
        others = [a for a in range(3) if a != j]
        straight[j][:, others] = _gaussian_process(rng, knots[j], length, sigma, 2)
        angle_sd = rng.uniform(10.0, 50.0)
        angles[j] = _gaussian_process(rng, knots[j], length, angle_sd, 3)
        prior[:, j] = length, sigma, angle_sd
    direction = rng.standard_normal(3)
    offset = rng.uniform(10000.0, 40000.0) * direction / np.linalg.norm(direction)
    errors = JointErrors(
        knots_um=knots,
        straightness_um=straight,
        angles_urad=angles,
        tool_offset_um=offset,
        periodic_um=rng.uniform(0.02, 0.1, 3),
        periodic_period_um=rng.uniform(2.0, 20.0, 3),
        periodic_phase=rng.uniform(0.0, 2 * np.pi, 3),
    )
    return errors, prior


def draw_population(seed: int | np.random.SeedSequence, n_cameras: int = 2) -> PopulationDraw:
    """One platform of the population (see the module docstring for the distributions).

    Parameters
    ----------
    seed : int or SeedSequence
        The same seed gives the same platform.
    n_cameras : int
        Cameras whose placement is drawn.
    """
    rng = np.random.default_rng(seed)
    static = _static(rng)
    errors, prior = _joint_errors(rng)
    centre = (PROFILE_LOW_UM + PROFILE_HIGH_UM) / 2
    truth = TrueKinematics(
        static=static,
        hysteresis_um=rng.uniform(0.2, 0.8, 3),
        thermal_um_per_c=_signed_log_uniform(rng, 0.3, 1.5, 3),
        reference_temperature_c=22.0,
        creep_fraction=float(rng.uniform(2e-4, 1e-3)),
        creep_tau_s=float(rng.uniform(0.2, 1.0)),
        joint_errors=errors,
        hysteresis_slope=rng.uniform(-0.5, 0.5, 3),
        hysteresis_centre_um=centre,
        hysteresis_half_travel_um=TRAVEL_UM / 2,
        creep_law="log",
        creep_end_s=float(rng.uniform(10.0, 60.0)),
    )
    room = (float(rng.uniform(0.05, 0.3)), float(rng.uniform(0.5, 2.0)),
            float(rng.uniform(0.0, 2 * np.pi)), float(rng.uniform(-0.3, 0.3)))  # fmt: skip
    rotation = rng.uniform(-2.0, 2.0, (n_cameras, 3))
    magnification = rng.uniform(0.9, 1.1, n_cameras)
    radii = np.array([play_radii_um(r) for r in rng.uniform(2.0, 8.0, 3)])
    play = PlayHysteresis(radii, rng.dirichlet(np.ones(radii.shape[1]), 3))
    motion = MotionNoise(
        scatter_um=tuple(rng.uniform(0.01, 0.04, 3).tolist()),
        step_um=tuple(rng.uniform(0.01, 0.1, 3).tolist()),
    )
    return PopulationDraw(
        truth=truth,
        temperature_swing_c=room[0],
        temperature_period_h=room[1],
        temperature_phase=room[2],
        temperature_drift_c_per_h=room[3],
        camera_rotation_deg=rotation,
        camera_magnification=magnification,
        profile_length_um=prior[0],
        straightness_sd_um=prior[1],
        angle_sd_urad=prior[2],
        play=play,
        motion=motion,
    )
