"""Performance metrics (pure math layer): ISO 9283 pose characteristics, decoupling."""

from .decoupling import DecouplingResult, decoupling_metrics, integration_index
from .iso9283 import (
    PoseStatistics,
    multi_directional_variation,
    pose_accuracy,
    pose_repeatability,
    pose_statistics,
)

__all__ = [
    "DecouplingResult",
    "PoseStatistics",
    "decoupling_metrics",
    "integration_index",
    "multi_directional_variation",
    "pose_accuracy",
    "pose_repeatability",
    "pose_statistics",
]
