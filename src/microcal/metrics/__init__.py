"""Performance metrics (pure math layer): ISO 9283 pose characteristics, decoupling."""

from .decoupling import DecouplingResult, decoupling_metrics, integration_index
from .iso9283 import (
    DistanceStatistics,
    PoseStatistics,
    distance_statistics,
    drift,
    multi_directional_variation,
    pose_accuracy,
    pose_repeatability,
    pose_statistics,
    stabilisation_time_s,
)

__all__ = [
    "DecouplingResult",
    "DistanceStatistics",
    "PoseStatistics",
    "decoupling_metrics",
    "distance_statistics",
    "drift",
    "integration_index",
    "multi_directional_variation",
    "pose_accuracy",
    "pose_repeatability",
    "pose_statistics",
    "stabilisation_time_s",
]
