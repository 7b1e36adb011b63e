"""The simulated microrobotic platform (devices layer): microcal's default rig and test bed.

``microcal.sim.platform(preset="thesis", seed=0)`` returns the whole platform.
"""

from .kinematics import TrueKinematics
from .platforms import PlatformConfig, SimPlatform, platform

__all__ = [
    "PlatformConfig",
    "SimPlatform",
    "TrueKinematics",
    "platform",
]
