"""The tip in 3D from one camera on the ``patch`` preset: the focus sweep, the tool's
reference stack and the peers' best-plane baseline, over seeds with ground truth.

Per seed: the rig of that seed (:func:`microcal.sim.patch.patch_rig`); a calibration step
with the tip at {G}'s origin (a fine sweep of 15 frames finds its focus and image, then the
reference stack is grabbed at whole-micron offsets from it); then ``--tips`` tip positions
drawn in a working volume (x, y within 100 µm, z within 15 µm of the calibration's), each
measured from a focus prior off by up to ``--prior-um`` and a pixel prior off by up to 3 px:

- the sweep (13 frames, 0.5 µm apart, centred on the prior);
- the stack method and the baseline on the same single frame at the prior's focus.

Errors are in the measurement's own coordinates: pixels of the frame (x, y, as µm at the
preset's pixel size) and the focus drive's reading at which the tip is in focus (z; the
truth divided by the drive's scale, so that what the calibration of the drive's scale
would correct is not counted here).

Run: ``PYTHONPATH=src python scripts/patch_depth_figures.py --seeds 10 --tips 10``
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from microcal.errors import MicrocalError
from microcal.sim.patch import PatchRig, patch_rig
from microcal.vision.focus_depth import (
    ANCHOR_SIGMA_PX,
    DepthEstimate,
    Frame,
    ReferenceStack,
    axis_cov_px,
    depth_by_best_plane,
    depth_by_stack,
    depth_by_sweep,
    grab_stack,
)

HALF_PX = 40  # the tip's region: 81 x 81 px
#: The stack methods' frame is taken this far above the prior: the tool's shank, rising
#: through the focal plane, shows sharp there.
ABOVE_UM = 1.0


def image_axis(rig: PatchRig) -> np.ndarray:
    """The tool's direction in the image, tip to shank (the rig knows its approach axis)."""
    cam = rig.camera()
    tip = rig.manipulator.true_position_um()
    q = cam.project(np.array([tip, tip + rig.config.tool_axis * 10.0]))
    d = np.asarray(q[1] - q[0], dtype=np.float64)
    out: np.ndarray = d / np.linalg.norm(d)
    return out


def end_offset_px(rig: PatchRig) -> float:
    """A pipette's opening seen at its approach angle: its radius times the sine, px."""
    cfg = rig.config
    return cfg.tool.end_radius_um * math.sin(math.radians(cfg.approach_deg)) / cfg.um_per_px


def box_at(c: np.ndarray) -> tuple[int, int, int, int]:
    x, y = round(float(c[0])), round(float(c[1]))
    return x - HALF_PX, y - HALF_PX, x + HALF_PX + 1, y + HALF_PX + 1


def linear(frame: Frame, focus_um: float, stack: ReferenceStack, near: np.ndarray) -> DepthEstimate:
    """The stack method with the linear interpolation between two planes (the former default)."""
    return depth_by_stack(frame, focus_um, stack, near, interpolation="linear")


def run_seed(seed: int, tips: int, prior_um: float, sweep: bool = True) -> list[dict[str, float]]:
    rig = patch_rig(seed)
    rng = np.random.default_rng([seed, 9283])
    axis = image_axis(rig)
    offset = end_offset_px(rig)
    # calibration: the tip at the origin, a fine sweep, then the stack around its focus
    z0, px0 = rig.in_focus()
    near0 = px0 + rng.uniform(-3, 3, 2)
    t0 = rig.clock.now_s()
    fine = depth_by_sweep(rig.grab_at_focus, box_at(near0), axis, 0.0, frames=15,
                          step_um=0.4, end_offset_px=offset, clock=rig.clock.now_s)  # fmt: skip
    stacks = {step: grab_stack(rig.grab_at_focus, fine.z_um, fine.apex_px, reach_um=4.0,
                               step_um=step, tip_focus_var_um2=fine.var_um2,
                               tip_cov_px=axis_cov_px(axis, *ANCHOR_SIGMA_PX), axis_px=axis)
              for step in (0.5, 1.0)}  # fmt: skip
    calib_s = rig.clock.now_s() - t0
    shared = (fine.apex_px - px0, fine.z_um - z0)  # the stacks' own errors, alike for every tip
    rows = []
    for _ in range(tips):
        joints = 10000.0 + np.array([rng.uniform(-100, 100), rng.uniform(-100, 100),
                                     rng.uniform(-15, 15)])  # fmt: skip
        rig.manipulator.move_to_um(joints)
        rig.clock.sleep(2.0)
        z_true, px_true = rig.in_focus()
        prior = z_true + rng.uniform(-prior_um, prior_um)
        near = px_true + rng.uniform(-3, 3, 2)
        row: dict[str, float] = {"seed": seed, "calib_s": calib_s}
        wall = time.perf_counter()
        try:
            if sweep:
                est = depth_by_sweep(rig.grab_at_focus, box_at(near), axis, prior,
                                     end_offset_px=offset, clock=rig.clock.now_s)  # fmt: skip
                _, px_at = rig.in_focus()
                record(row, "sweep", est, z_true, px_at, rig, time.perf_counter() - wall)
        except MicrocalError as exc:
            row["sweep_fail"] = 1.0
            print(f"seed {seed}: sweep: {exc}")
        above = prior + ABOVE_UM
        t_grab = rig.clock.now_s()
        frame = rig.grab_at_focus(above)
        row["grab_s"] = rig.clock.now_s() - t_grab
        for name, fn, step in (("stack", depth_by_stack, 0.5), ("stack1", depth_by_stack, 1.0),
                               ("stack1lin", linear, 1.0),
                               ("best", depth_by_best_plane, 1.0)):  # fmt: skip
            wall = time.perf_counter()
            try:
                est = fn(frame, above, stacks[step], near)
                record(row, name, est, z_true, frame.truth.tip_px, rig, time.perf_counter() - wall,
                       shared)  # fmt: skip
            except MicrocalError as exc:
                row[f"{name}_fail"] = 1.0
                print(f"seed {seed}: {name}: {exc}")
        rows.append(row)
    return rows


def record(row: dict[str, float], name: str, est: DepthEstimate, z_true: float,
           px_true: np.ndarray, rig: PatchRig, wall_s: float,
           shared: tuple[np.ndarray, float] | None = None) -> None:  # fmt: skip
    """One estimate's errors; with ``shared`` (the reference's own errors, px and µm, known
    from the truth) also the errors less them against the covariance less the shared part."""
    pitch = rig.config.um_per_px
    row[f"{name}_dz"] = est.z_um - z_true
    row[f"{name}_sz"] = est.sigma_um
    d = (est.apex_px - px_true) * pitch
    row[f"{name}_dx"], row[f"{name}_dy"] = float(d[0]), float(d[1])
    cov = est.cov_px * pitch**2
    row[f"{name}_chi2xy"] = float(d @ np.linalg.solve(cov, d))
    if shared is not None and np.any(est.shared_cov_px):
        own = d - shared[0] * pitch
        own_cov = (est.cov_px - est.shared_cov_px) * pitch**2
        row[f"{name}_chi2own"] = float(own @ np.linalg.solve(own_cov, own))
        own_z = row[f"{name}_dz"] - shared[1]
        row[f"{name}_zown"] = float(abs(own_z) / math.sqrt(est.var_um2 - est.shared_var_um2))
    row[f"{name}_frames"] = est.frames
    row[f"{name}_s"] = est.seconds
    row[f"{name}_wall"] = wall_s


def table(rows: list[dict[str, float]]) -> str:
    out = ["| method | measured | x, y RMS (µm) | z RMS (µm) | z mean (µm) | z 95 % covered "
           "| z error / sigma (RMS) | x, y 95 % covered | x, y mean chi2 (2 expected) | frames "
           "| rig time (s) | compute (s) | own part: x, y / z 95 % covered |",
           "|" + " --- |" * 13]  # fmt: skip
    for name, label in (("sweep", "focus sweep (13 frames)"),
                        ("stack", "reference stack 0.5 µm, interpolated"),
                        ("stack1", "reference stack 1 µm, interpolated"),
                        ("stack1lin", "reference stack 1 µm, linear (the former default)"),
                        ("best", "baseline: best plane of the 1 µm stack")):  # fmt: skip
        ok = [r for r in rows if f"{name}_dz" in r]
        if not ok:
            out.append(f"| {label} | 0 of {len(rows)} | | | | | | | | | | | |")
            continue
        dz = np.array([r[f"{name}_dz"] for r in ok])
        sz = np.array([r[f"{name}_sz"] for r in ok])
        dxy = np.array([[r[f"{name}_dx"], r[f"{name}_dy"]] for r in ok])
        chi = np.array([r[f"{name}_chi2xy"] for r in ok])
        xy = math.sqrt(float(np.mean(np.sum(dxy**2, axis=1))))
        zr = math.sqrt(float(np.mean(dz**2)))
        cz = float(np.mean(np.abs(dz) <= 1.96 * sz)) * 100
        cxy = float(np.mean(chi <= 5.991)) * 100
        nz = math.sqrt(float(np.mean((dz / sz) ** 2)))
        frames = np.mean([r[f"{name}_frames"] for r in ok])
        secs = np.mean([r["sweep_s" if name == "sweep" else "grab_s"] for r in ok])
        wall = np.mean([r[f"{name}_wall"] for r in ok])
        own = "n/a"
        if f"{name}_chi2own" in ok[0]:
            co = float(np.mean([r[f"{name}_chi2own"] <= 5.991 for r in ok])) * 100
            cz_own = float(np.mean([r[f"{name}_zown"] <= 1.96 for r in ok])) * 100
            own = f"{co:.0f} % / {cz_own:.0f} %"
        out.append(f"| {label} | {len(ok)} of {len(rows)} | {xy:.3f} | {zr:.3f} | "
                   f"{float(dz.mean()):+.3f} | {cz:.0f} % | {nz:.2f} | {cxy:.0f} % | "
                   f"{chi.mean():.2f} | {frames:.0f} | "
                   f"{secs:.2f} | {wall:.2f} | {own} |")  # fmt: skip
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--tips", type=int, default=10)
    parser.add_argument("--prior-um", type=float, default=1.0)
    parser.add_argument("--skip-sweep", action="store_true", help="the stack methods only")
    args = parser.parse_args()
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        rows += run_seed(seed, args.tips, args.prior_um, not args.skip_sweep)
    print(table(rows))
    calib = np.mean([r["calib_s"] for r in rows])
    print(f"\ncalibration per seed (fine sweep of 15 frames, stacks of 17 and 9): {calib:.2f} s")


if __name__ == "__main__":
    main()
