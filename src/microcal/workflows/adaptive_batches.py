"""The batches of an adaptive run (``microcal acquire --design adaptive``): its options
file, and the design whose batches are run directories of their own."""

from __future__ import annotations

from typing import Any

import numpy as np

from .._validation import FloatArray
from ..kinematics.adaptive_design import AdaptiveSettings
from ..procedures.acquisition import AcquisitionConfig
from ..procedures.adaptive import AdaptiveDesign

__all__ = ["ADAPTIVE_FILE", "ADAPTIVE_FORMAT", "APPROACH_UM", "BatchedDesign"]

#: The adaptive run's options, in the run directory.
ADAPTIVE_FILE = "adaptive.json"
ADAPTIVE_FORMAT = "microcal.adaptive/1"
#: Each pose of an adaptive run is approached from this far past it, on a side drawn from
#: the pose (the approach directions vary apart from the positions), µm.
APPROACH_UM = 300.0


class BatchedDesign(AdaptiveDesign):
    """The adaptive design whose batches are runs of their own: each batch's poses are
    numbered from 1 and approached with that batch's seed, or in the directions the design
    chose for them (``AdaptiveSettings.choose_directions``, off in a run's design)."""

    def __init__(self, options: dict[str, Any], limits_um: FloatArray) -> None:
        self.options = options
        lim = np.asarray(limits_um, dtype=np.float64)
        settings = AdaptiveSettings(until_um=float(options["until_um"]),
                                    max_poses=int(options["max_poses"]),
                                    seed=int(options["seed"]))  # fmt: skip
        super().__init__(settings, lim[:, 0], lim[:, 1], lim, self.batch_config(0))

    def batch_config(self, index: int, directions: FloatArray | None = None) -> AcquisitionConfig:
        """How batch ``index`` (0-based) is acquired; ``directions`` (b, 3): the approach
        directions chosen for its poses (NaN or none: drawn)."""
        o = self.options
        fixed = str(o["settle"]).startswith("fixed")
        chosen = (
            ()
            if directions is None
            else tuple((float(a), float(b), float(c)) for a, b, c in np.asarray(directions))
        )
        return AcquisitionConfig(
            settle="fixed" if fixed else "vision",
            fixed_s=float(str(o["settle"]).partition(":")[2] or 30.0) if fixed else 30.0,
            frames_per_pose=int(o["frames"]), store_roi=o["store"] == "roi",
            approach_um=APPROACH_UM, approach_seed=int(o["seed"]) * 1000 + index,
            approach_directions=chosen,
        )  # fmt: skip

    def where(self, pose: int) -> tuple[int, int]:
        """(batch index, pose within it) of a pose of the whole run (both from 1 / 0)."""
        first, size = self.settings.start_poses, self.settings.batch
        if pose <= first:
            return 0, pose
        return 1 + (pose - first - 1) // size, (pose - first - 1) % size + 1

    def signs_for(
        self, d_um: FloatArray, pose: int, direction: FloatArray | None = None
    ) -> FloatArray:
        index, local = self.where(pose)
        config = self.batch_config(index)
        from ..procedures.acquisition import approach_start_um

        start = approach_start_um(d_um, local, config, self.limits_um, direction)
        out: FloatArray = np.where(d_um > start, 1.0, np.where(d_um < start, -1.0, 1.0))
        return out
