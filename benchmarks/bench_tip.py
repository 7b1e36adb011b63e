"""A tool's tip in a 256 x 256 region: time per detection, and its accuracy.

microcal: the fast fit (:mod:`microcal.vision.tip_fast`: the coarse search on the halved
image, a closed-form image of the tool's end fitted on a patch; the default for a needle or
a jaw), on pipettes, needles and jaws in focus; the reference method,
:func:`microcal.vision.tip_reference.match_tip` (nine
templates of 41 x 41 px at focus offsets from -2 to +2 depths of field; every other one
correlated at half resolution, the best's neighbours at full resolution around it, the peak
refined by Gauss-Newton with its covariance), the model fit,
:func:`microcal.vision.tip.detect_tip` (the outline fitted to the image), and the image fit
(``method="image fit"``, the tool's image drawn and fitted near its end; the default for a
glass pipette), on needles and on pipettes.
Baseline in the same run: OpenCV's ``matchTemplate`` (``TM_CCOEFF_NORMED``) of the in-focus
template over the same region and its whole-pixel peak, as the peers match a tip.

Images: needles (and, for the image fit, pipettes) rendered in focus by
``sim.tool_population`` (10x objective, NA 0.3, 0.65 µm pixels, plain, tissue or debris
backgrounds), with each tip's truth; each reference from nine frames of the same needle
10 µm away. Goal: a detection in <= 5 ms.
"""

from __future__ import annotations

import cv2
import numpy as np

from microcal.sim.tool_population import (
    NUMERICAL_APERTURE,
    UM_PER_PX,
    draw_tool_image,
    population_camera,
)
from microcal.sim.tools import Optics, ToolPlacement, ToolScene, tool_image
from microcal.vision.tip import detect_tip
from microcal.vision.tip_reference import TipReference, build_reference, match_tip
from microcal.vision.tip_target import parse_tip

from .harness import Case, best_time_s

N_IMAGES = 8
REPEAT = 3
GOAL_MS = 5.0


def _scenes() -> list[tuple[np.ndarray, np.ndarray, TipReference, str]]:
    """(image, true tip, reference, spec) per image."""
    out = []
    dof = Optics(NUMERICAL_APERTURE).depth_of_field_um(UM_PER_PX)
    offsets = np.linspace(-2.0, 2.0, 9) * dof
    for seed in range(N_IMAGES):
        image = draw_tool_image(70_000 + seed, "needle", 0.0)
        placement = image.scene.placements[0]
        moved = ToolPlacement(placement.tool, placement.tip_um + [10.0, -6.0, 0.0],
                              placement.axis)  # fmt: skip
        rng = np.random.default_rng(seed)
        frames = [
            tool_image(population_camera(), ToolScene(
                [moved], Optics(NUMERICAL_APERTURE, focus_depth_um=1000.0 + f),
                image.scene.background), rng)[0]
            for f in offsets
        ]  # fmt: skip
        anchor = detect_tip(frames[4], parse_tip(image.spec))
        if not anchor.found:
            continue
        reference = build_reference(frames, offsets, anchor.apex_px)
        out.append((image.image, image.truths[0].tip_px, reference, image.spec))
    return out


def _tools(kind: str = "pipette") -> list[tuple[np.ndarray, np.ndarray, str]]:
    """(image, true tip, spec) of tools of one kind in focus."""
    first = {"pipette": 10_000, "needle": 20_000, "jaw": 30_000}[kind]
    out = []
    for seed in range(N_IMAGES):
        image = draw_tool_image(first + seed, kind, 0.0)
        out.append((image.image, image.truths[0].tip_px, image.spec))
    return out


def _fast(images: list[tuple[np.ndarray, np.ndarray, str]]) -> list[np.ndarray]:
    return [detect_tip(im, parse_tip(spec), method="fast fit").apex_px for im, _, spec in images]


def _baseline(image: np.ndarray, reference: TipReference) -> np.ndarray:
    template = reference.templates[len(reference.templates) // 2]
    res = cv2.matchTemplate(image.astype(np.float32), template, cv2.TM_CCOEFF_NORMED)
    iy, ix = np.unravel_index(int(np.argmax(res)), res.shape)
    return np.array([ix, iy], dtype=np.float64) + reference.anchor_px


def _error(found: list[np.ndarray], truth: list[np.ndarray]) -> float:
    e = np.array([f - t for f, t in zip(found, truth, strict=True)])
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) if len(e) else float("nan")


def run() -> list[Case]:
    scenes = _scenes()
    images = [s[0] for s in scenes]
    truths = [s[1] for s in scenes]

    def ours_reference() -> list[np.ndarray]:
        return [match_tip(im, ref).apex_px for im, _, ref, _ in scenes]

    def ours_model() -> list[np.ndarray]:
        return [detect_tip(im, parse_tip(spec), method="model fit").apex_px
                for im, _, _, spec in scenes]  # fmt: skip

    def baseline() -> list[np.ndarray]:
        return [_baseline(im, ref) for im, _, ref, _ in scenes]

    def ours_image_fit() -> list[np.ndarray]:
        return [detect_tip(im, parse_tip(spec), method="image fit").apex_px
                for im, _, _, spec in scenes]  # fmt: skip

    pipettes = _tools("pipette")
    kinds = {kind: _tools(kind) for kind in ("pipette", "needle", "jaw")}
    t_fast = {kind: best_time_s(lambda im=im: _fast(im), REPEAT) / max(len(im), 1)
              for kind, im in kinds.items()}  # fmt: skip

    def ours_image_fit_pipettes() -> list[np.ndarray]:
        return [detect_tip(im, parse_tip(spec), method="image fit").apex_px
                for im, _, spec in pipettes]  # fmt: skip

    def found(points: list[np.ndarray], truth: list[np.ndarray]) -> float:
        ok = [(p, t) for p, t in zip(points, truth, strict=True) if np.all(np.isfinite(p))]
        return _error([p for p, _ in ok], [t for _, t in ok])

    n = max(len(images), 1)
    t_ref = best_time_s(ours_reference, REPEAT) / n
    t_model = best_time_s(ours_model, 1) / n
    t_base = best_time_s(baseline, REPEAT) / n
    t_image = best_time_s(ours_image_fit, 1) / n
    t_pipette = best_time_s(ours_image_fit_pipettes, 1) / max(len(pipettes), 1)
    details = {
        "n_images": len(images),
        "region_px": [256, 256],
        "template_px": list(scenes[0][2].templates.shape) if scenes else [],
        "baseline_rms_px": _error(baseline(), truths),
    }

    def case(what: str, seconds: float, **more: object) -> Case:
        return Case(
            name=f"tip by {what}, 256 x 256 region",
            unit="ms/detection",
            value=seconds * 1e3,
            baseline_name="matchTemplate TM_CCOEFF_NORMED, one template, whole-pixel peak",
            baseline=t_base * 1e3,
            goal=f"<= {GOAL_MS:g} ms",
            meets_goal=seconds * 1e3 <= GOAL_MS,
            details={**details, **more},
        )

    cases = [
        case(
            f"the fast fit, {kind}" + (" (the default)" if kind != "pipette" else ""),
            t_fast[kind],
            n_images=len(images),
            rms_px=found(_fast(images), [t for _, t, _ in images]),
        )
        for kind, images in kinds.items()
    ]
    cases += [
        case("the tool's reference", t_ref, rms_px=_error(ours_reference(), truths)),
        case("the model fit", t_model, rms_px=_error(ours_model(), truths)),
        case("the image fit, needle", t_image, rms_px=found(ours_image_fit(), truths)),
        case(
            "the image fit, glass pipette (the default)",
            t_pipette,
            n_images=len(pipettes),
            rms_px=found(ours_image_fit_pipettes(), [t for _, t, _ in pipettes]),
        ),
    ]
    return cases
