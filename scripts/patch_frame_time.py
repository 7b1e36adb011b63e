"""Time one whole frame of the ``patch`` camera (``PatchFrame.full()``), and optionally keep it.

python scripts/patch_frame_time.py --seed 0 [--save frame.npy] [--size 2048]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from microcal.sim.patch import patch_rig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--size", type=int, default=2048, help="frame side, px")
    parser.add_argument("--save", default=None, help="write the frame here (.npy)")
    args = parser.parse_args()
    rig = patch_rig(args.seed, size_px=(args.size, args.size))
    frame = rig.grab()
    t0, c0 = time.perf_counter(), time.process_time()
    full = frame.full()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(
        f"seed {args.seed}: {full.shape[1]} x {full.shape[0]} frame in {wall:.2f} s wall, "
        f"{cpu:.2f} s CPU; tip at {np.round(frame.truth.tip_px, 1).tolist()} px"
    )
    if args.save:
        np.save(args.save, full)


if __name__ == "__main__":
    main()
