"""``microcal check``: check a calibration on its rig, keep its history, update its offset.

The files are :mod:`microcal.formats.check_file`'s (check.json and the history beside the
calibration). The update (``--update NEW``): for the verdict ``offset`` only, a new
calibration.json with the base offset moved by the measured offset, its provenance naming
the old file; then checked again. For another verdict nothing is written and check.json says
why. :class:`PeriodicCheck` makes the same check inside a long acquisition.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .._version import __version__
from ..errors import DetectionError, InputError
from ..formats.atomic import write_text_atomic
from ..formats.calibration_file import (
    CALIBRATION_FORMAT,
    Calibration,
    load_calibration,
    write_calibration,
)
from ..formats.check_file import (
    CHECK_FORMAT,
    append_history,
    history_path,
    of_device,
    read_history,
)
from ..formats.hashing import sha256_file
from ..formats.json_file import check_json_output
from ..formats.provenance import provenance
from ..json_value import JsonValue
from ..procedures.check import (
    CheckConfig,
    CheckResult,
    CheckUpdate,
    offset_updated,
    planned_check,
    run_check,
)
from ..report.text_tables import periodic_check_line
from ..vision.probe import VisionProbe
from ..vision.tip_target import TipTarget
from .calibration_update import camera_models
from .station import open_station

__all__ = [
    "CheckConfig",
    "CheckOutcome",
    "CheckUpdate",
    "PeriodicCheck",
    "check_calibration",
    "check_reference",
    "parse_every",
    "record_check",
]


def _reference(history: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray] | None:
    for entry in history:
        if entry.get("verdict") == "valid" and entry.get("against") == "calibration":
            poses = entry["poses"]
            return (np.array([p["residual_um"] for p in poses]),
                    np.array([p["cov_um2"] for p in poses]))  # fmt: skip
    return None


def _far_from_history(result: CheckResult, history: list[dict[str, Any]], sigma: float) -> str:
    offsets = np.array([h["offset_um"] for h in history])
    if len(offsets) < 3:
        return ""
    spread = offsets.std(axis=0, ddof=1)
    z = (result.offset_um - offsets.mean(axis=0)) / np.sqrt(spread**2 + result.offset_std_um**2)
    worst = int(np.argmax(np.abs(z)))
    if abs(z[worst]) <= sigma:
        return ""
    return (f"far from the {len(offsets)} earlier checks: offset {'xyz'[worst]} "
            f"{result.offset_um[worst]:+.2f} µm is {abs(z[worst]):.1f} sigma from their "
            f"{offsets[:, worst].mean():+.2f} ± {spread[worst]:.2f} µm")  # fmt: skip


@dataclasses.dataclass(frozen=True)
class CheckOutcome:
    """What ``microcal check`` found and wrote.

    Attributes
    ----------
    result : CheckResult
        The check: verdict, offset, tests, poses.
    flag : str
        Why its offset stands out from the calibration's history (empty when it does not).
    update : CheckUpdate or None
        What ``--update`` did (None when not asked).
    out : Path
        check.json.
    replayed : bool
        A simulated rig measured exactly what the reference check measured (opened with
        the same seed, it replays the same frames).
    """

    result: CheckResult
    flag: str
    update: CheckUpdate | None
    out: Path
    replayed: bool = False


def check_calibration(
    rig: str | os.PathLike[str],
    calibration: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    manipulator: str | None = None,
    seed: int | None = None,
    config: CheckConfig | None = None,
    history_sigma: float = 3.0,
    update: str | os.PathLike[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
    scope: str | os.PathLike[str] | None = None,
    objective: str | None = None,
) -> CheckOutcome:
    """Check a calibration on its rig, write check.json, add to the history, update if asked.

    A one-camera rig measures the tip through its scope calibration (``scope``, its set
    ``objective``; :mod:`~.one_camera_station`).

    Returns
    -------
    CheckOutcome
        The check, its flag against the history and the update (check.json holds them).
    """
    cfg = config or CheckConfig()
    out_path = _check_outputs(calibration, out, update)
    cal = load_calibration(calibration)
    name = cal.manipulator(manipulator).name  # each device of a calibration has its history
    history = of_device(read_history(calibration), name, len(cal.manipulators) == 1)
    reference = _reference(history)
    with open_station(rig, calibration, manipulator=manipulator, seed=seed, scope=scope,
                      objective=objective, settle_s=cfg.settle_s) as station:  # fmt: skip
        rig_ = station.rig
        m = station.calibration
        measure = station.probe.measure_with_covariance
        seen_as = "the tool's tip" if isinstance(rig_.board, TipTarget) else "the board"
        probe = station.probe
        why = lambda: str(getattr(probe, "last_reason", ""))  # noqa: E731
        result = run_check(rig_.manipulator, rig_.clock, measure, m, config=cfg,
                           reference=reference, progress=progress, seen_as=seen_as,
                           why_unseen=why)  # fmt: skip
        replayed = _replayed(result, reference, rig_.truth is not None)
        done = None
        if update is not None:
            done = _update(cal, m.name, result, calibration, update, rig_, measure, cfg)
        target = rig_.board.spec
    flag = record_check(calibration, out_path, name, result, history, history_sigma, done,
                        target=target)  # fmt: skip
    return CheckOutcome(result, flag, done, Path(out_path), replayed)


def _replayed(
    result: CheckResult, reference: tuple[np.ndarray, np.ndarray] | None, simulated: bool
) -> bool:
    """Whether a simulated rig's check measured exactly what its reference measured."""
    if not simulated or reference is None or reference[0].shape != result.residual_um.shape:
        return False
    return bool(np.allclose(result.residual_um, reference[0], rtol=0.0, atol=1e-9))


def check_reference(history: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray] | None:
    """The residuals and covariances of the history's first valid check against the
    calibration, the reference of the later checks (None before there is one)."""
    return _reference(history)


def record_check(
    calibration: str | os.PathLike[str],
    out: str | os.PathLike[str],
    name: str,
    result: CheckResult,
    history: list[dict[str, Any]],
    history_sigma: float = 3.0,
    update: CheckUpdate | None = None,
    *,
    target: str | None = None,
) -> str:
    """Write check.json and add the check to the calibration's history; returns its flag
    (why its offset stands out from the history's, empty when it does not). ``target``: the
    spec of what the cameras measured (a board or a tool's tip), recorded in both."""
    flag = _far_from_history(result, history, history_sigma)
    data: dict[str, JsonValue] = {"format": CHECK_FORMAT, **result.as_dict(), "flag": flag}
    if target is not None:
        data["target"] = target
    data["provenance"] = provenance({"calibration": calibration}, command="check")
    if update is not None:
        data["update"] = update.to_json()
    write_text_atomic(out, json.dumps(data, indent=1, allow_nan=False) + "\n")
    entry = {k: v for k, v in data.items() if k not in ("format", "provenance", "update")}
    entry |= {"manipulator": name, "calibration_sha256": sha256_file(calibration, link_ok=True),
              "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
              "software": f"microcal {__version__}"}  # fmt: skip
    append_history(history_path(calibration), entry)
    return flag


def _check_outputs(
    calibration: str | os.PathLike[str],
    out: str | os.PathLike[str],
    update: str | os.PathLike[str] | None,
) -> Path:
    """Refuse, before the check, outputs that are not ours to replace or that name one file
    twice (check.json, the updated calibration, the calibration and its history); check.json's
    path."""
    out_path = check_json_output(out, CHECK_FORMAT, "check.json")
    history = history_path(calibration).resolve()
    if out_path.resolve() == history:
        raise InputError(f"--out {out}: is the calibration's history; give check.json its own name")
    if update is not None:
        check_json_output(update, CALIBRATION_FORMAT, "calibration-updated.json", "--update")
        target = Path(update).resolve()
        if target == Path(calibration).resolve():
            raise InputError("--update: write the updated calibration to a new file")
        if target == out_path.resolve():
            raise InputError(
                f"--update {update}: is --out too; give the updated calibration its own name"
            )
        if target == history:
            raise InputError(
                f"--update {update}: is the calibration's history; give the updated "
                f"calibration its own name"
            )
    return out_path


def _update(
    cal: Calibration,
    name: str,
    result: CheckResult,
    old: str | os.PathLike[str],
    new: str | os.PathLike[str],
    rig: Any,
    measure: Any,
    cfg: CheckConfig,
) -> CheckUpdate:
    """Re-fit the base offset only, write the new calibration, check it again."""
    if result.verdict != "offset":
        why = ("nothing to update: the calibration is valid" if result.verdict == "valid" else
               "the model no longer fits: an update re-fits only the offset; calibrate again "
               "(acquire, measure, fit)")  # fmt: skip
        return CheckUpdate(None, refused=why)
    m = cal.manipulators[name]
    model = offset_updated(m.model, result.offset_um)
    updated = dataclasses.replace(m, model=model)
    manipulators = {**cal.manipulators, name: updated}
    prov = provenance({"calibration": old}, command="check --update",
                      offset_um=result.offset_um.tolist(),
                      offset_std_um=result.offset_std_um.tolist())  # fmt: skip
    write_calibration(new, Calibration(manipulators, cal.cameras, prov))
    again = run_check(rig.manipulator, rig.clock, measure, updated, config=cfg)
    return CheckUpdate(str(new), verdict_after=again.verdict,
                       offset_after_um=tuple(again.offset_um.tolist()),
                       offset_after_std_um=tuple(again.offset_std_um.tolist()))  # fmt: skip


def parse_every(text: str) -> tuple[int | None, float | None]:
    """``--check-every``: ``N`` poses, or ``Mmin`` minutes of the run's clock.

    Returns (poses, seconds), one of them None.

    Raises
    ------
    InputError
        Anything else, with an example.
    """
    value = text.strip()
    try:
        if value.endswith("min"):
            minutes = float(value[:-3])
            if minutes > 0 and np.isfinite(minutes):
                return None, minutes * 60.0
        elif int(value) >= 1:
            return int(value), None
    except ValueError:
        pass
    raise InputError(f"--check-every {text}: expected a number of poses (20) or of minutes (15min)")


class PeriodicCheck:
    """A quick check of an earlier calibration inside a long run, every N poses or minutes.

    Called by the acquisition after each stored pose (its ``between``): when due, the check
    poses are measured as ``microcal check`` measures them, the result joins the
    calibration's history (with the run and the poses stored so far), and a line says the
    verdict. A check that cannot be made (a pose out of view) is reported and the run goes on.

    Parameters
    ----------
    rig : Rig
        The opened rig, its ``manipulator`` the device the calibration is of.
    calibration : path
        calibration.json with the cameras; its entry of the rig's device (or its only one).
    every : str
        ``N`` poses or ``Mmin`` minutes (:func:`parse_every`).
    run_dir : path
        The run the checks are made in (recorded with each).
    say : callable (str) -> None
        Where the verdict lines go.
    """

    def __init__(
        self,
        rig: Any,
        calibration: str | os.PathLike[str],
        every: str,
        run_dir: str | os.PathLike[str],
        say: Callable[[str], None],
        config: CheckConfig | None = None,
    ) -> None:
        self.poses, self.every_s = parse_every(every)
        cal = load_calibration(calibration)
        name = rig.selected if rig.selected in cal.manipulators else None
        self.entry = cal.manipulator(name)
        self.entry.check_device(rig.manipulator.identity)
        d_all, approach = planned_check(self.entry, rig.manipulator)  # limits, before the run
        self.last_leg = (d_all[-1] - approach if approach.any() else d_all[-2], d_all[-1])
        self.single = len(cal.manipulators) == 1
        #: Poses the run had stored before this session (a resumed run counts on from them).
        self.stored_before = 0
        self.config = config or CheckConfig()
        self.rig, self.path, self.run_dir, self.say = rig, Path(calibration), str(run_dir), say
        probe = VisionProbe(rig.cameras, camera_models(cal), rig.board, self.config.frames)
        self.measure = probe.measure_with_covariance
        self.probe = probe
        self.last_s = rig.clock.now_s()
        self.results: list[CheckResult] = []

    def __call__(self, done_now: int) -> tuple[np.ndarray, np.ndarray] | None:
        done = self.stored_before + done_now
        due = (self.poses is not None and done % self.poses == 0) or (
            self.every_s is not None and self.rig.clock.now_s() - self.last_s >= self.every_s
        )
        if not due:
            return None
        history = of_device(read_history(self.path), self.entry.name, self.single)
        try:
            seen_as = "the tool's tip" if isinstance(self.rig.board, TipTarget) else "the board"
            result = run_check(self.rig.manipulator, self.rig.clock, self.measure, self.entry,
                               config=self.config, reference=_reference(history),
                               seen_as=seen_as,
                               why_unseen=lambda: self.probe.last_reason)  # fmt: skip
        except DetectionError as exc:
            self.say(f"check after {done} poses not made: {exc}")
            here = np.asarray(self.rig.manipulator.position_um(), dtype=np.float64)
            return here, here  # the directions of the joints that moved are not known
        finally:
            self.last_s = self.rig.clock.now_s()
        self.results.append(result)
        entry = result.as_dict()
        flag = _far_from_history(result, history, 3.0)
        entry |= {"flag": flag, "during": self.run_dir,
                  "after_poses": done, "manipulator": self.entry.name,
                  "calibration_sha256": sha256_file(self.path, link_ok=True),
                  "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
                  "software": f"microcal {__version__}"}  # fmt: skip
        append_history(history_path(self.path), entry)
        self.say(periodic_check_line(result, done, self.config.alpha, flag))
        return self.last_leg
