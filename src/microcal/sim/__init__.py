"""The simulated microrobotic platform (devices layer): microcal's default rig and test bed."""

from .kinematics import TrueKinematics, thesis_kinematics

__all__ = ["TrueKinematics", "thesis_kinematics"]
