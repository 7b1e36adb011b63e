"""Vision (layer 2): targets, their detection, the virtual point, stereo calibration."""

from .targets import Target, parse_target

__all__ = ["Target", "parse_target"]
