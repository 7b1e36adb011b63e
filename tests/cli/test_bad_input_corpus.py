"""A corpus of bad inputs for every command, and the promise each refusal keeps.

Every case builds its inputs in a fresh directory (copies of good inputs, then mutated), runs
one command in-process through typer's CliRunner and checks that microcal treats it as a user
error:

- exit code 2;
- exactly one line on stderr, starting ``microcal: error: `` (and, where the case says so,
  naming the option, file or key at fault);
- no Python traceback anywhere in the output;
- every file that existed before the command still exists with the same SHA-256 (and every
  directory still exists);
- no temporary file left behind;
- an answer within a few seconds (a refusal comes before any long work).

The good inputs (a simulated run, cameras.json, calibration.json, measurements.csv,
results.json, rig files, rendered calibration images) are made once per module. Case ids
begin with the command (``acquire-poses-too-many``); :func:`cases_per_command` counts them.
"""

from __future__ import annotations

import csv
import hashlib
import importlib.util
import io
import json
import os
import re
import shutil
import signal
import stat
import traceback
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner, Result

from microcal import sim
from microcal.cli import WORKFLOW, app
from microcal.formats.measurements import write_measurements
from microcal.sim.calibration_views import (
    render_stereo_calibration_views,
    wide_angle_stereo_pair,
)
from microcal.sim.synthetic_run import synthetic_run
from microcal.vision.targets import parse_target

runner = CliRunner()

#: Longest a refusal may take, s (the slowest good command here takes about 3 s).
CASE_TIMEOUT_S = 10.0
#: Options that keep an acquisition short should a case be accepted by mistake.
ACQUIRE_QUICK = ["--poses", "12", "--frames", "1", "--settle", "fixed:0", "--store", "roi"]
#: The same for a design file (which has its own number of poses).
ACQUIRE_QUICK_FILE = ACQUIRE_QUICK[2:]
#: Options that keep an evaluation short should a case be accepted by mistake.
EVALUATE_QUICK = ["--test", "pose-accuracy", "--poses", "iso-cube", "--cycles", "1", "--frames", "1",
                  "--settle-s", "0"]  # fmt: skip
STEREO_TARGET = "chessboard:7x5:30000"
STEREO_VIEWS = 6
COMMANDS = ("cli", *WORKFLOW)
GARBAGE = bytes(range(256)) * 8 + b"\x00\xff\xfe" * 100
BOM = "\ufeff"
ERROR_PREFIX = "microcal: error: "


# --- the good inputs -----------------------------------------------------------------------
@dataclass(frozen=True)
class Good:
    """Good inputs, made once; a case copies what it needs (never uses these in place)."""

    root: Path

    def __truediv__(self, name: str) -> Path:
        return self.root / name


def _invoke_ok(argv: list[str]) -> Result:
    result = runner.invoke(app, argv)
    assert result.exit_code == 0, (argv, result.output, result.exception)
    return result


def _true_cameras() -> dict[str, Any]:
    plat = sim.platform("thesis", seed=0)
    cameras = {
        name: {
            "model": "pinhole",
            "image_size_px": list(m.image_size_px),
            "K": m.K.tolist(),
            "dist": m.dist.tolist(),
            "R": m.R.tolist(),
            "t_um": m.t_um.tolist(),
            "projection_sigma_px": 0.0,
            "rms_px": 0.1,
            "views_used": 8,
        }
        for name, m in plat.camera_models.items()
    }
    return {
        "format": "microcal.cameras/1",
        "cameras": cameras,
        "stereo": {"method": "known displacements", "rms_px": 0.1},
        "provenance": {},
    }


SIM_RIG = 'driver = "sim"\npreset = "thesis"\nseed = 0\n'
#: A hardware rig whose controller address refuses connections (nothing listens on port 9) and
#: whose cameras need Aravis: a rig file that is accepted is refused when it is opened.
HARDWARE_RIG = """driver = "hardware"
board = "chessboard:4x3:400"

[manipulator]
kind = "smaract-mcs2"
address = "127.0.0.1"
port = 9
timeout_s = 0.5
reconnects = 0
channels = { x = 0, y = 1, z = 2 }
limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }

[cameras.top]
kind = "aravis"
address = "127.0.0.2"
pixel_format = "Mono8"

[cameras.side]
kind = "aravis"
address = "127.0.0.3"
"""
RESULTS = {
    "format": "microcal.results/1",
    "pose_accuracy": {
        "vision": {
            "uncalibrated": {"mean_ap_p_um": 40.0, "max_ap_p_um": 90.0, "poses": []},
            "optimal": {"mean_ap_p_um": 4.0, "max_ap_p_um": 7.0, "poses": []},
        }
    },
}


# the module's tests share what a fixture makes once: one worker runs them all
pytestmark = pytest.mark.xdist_group("bad-input-corpus")


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> Good:
    """Every good input of the corpus, each checked to be accepted."""
    root = tmp_path_factory.mktemp("good")
    # a run of the simulated rig, measured
    run = root / "run"
    _invoke_ok(["acquire", "--rig", "sim", "--out", str(run), *ACQUIRE_QUICK])
    (root / "cameras.json").write_text(json.dumps(_true_cameras(), indent=1), encoding="utf-8")
    _invoke_ok(["measure", str(run), "--cameras", str(root / "cameras.json")])
    # measurements of a synthetic run, and calibrations fitted to them
    syn = synthetic_run(40, seed=5)
    write_measurements(root / "measurements.csv", syn.d_um, syn.measured_um,
                       temperature_c=np.linspace(21.0, 23.0, 40))  # fmt: skip
    write_measurements(root / "measurements-no-t.csv", syn.d_um, syn.measured_um)
    cal = root / "calibration.json"
    _invoke_ok(["fit", str(root / "measurements.csv"), "--out", str(cal),
                "--cameras", str(root / "cameras.json")])  # fmt: skip
    _invoke_ok(["fit", str(root / "measurements.csv"), "--out", str(root / "calibration-t.json"),
                "--temperature", "--select", "all"])  # fmt: skip
    _invoke_ok(["fit", str(root / "measurements-no-t.csv"),
                "--out", str(root / "calibration-no-cameras.json")])  # fmt: skip
    (root / "results.json").write_text(json.dumps(RESULTS, indent=1), encoding="utf-8")
    # a run directory holding everything a report reads
    full = root / "report-run"
    shutil.copytree(run, full)
    for name in ("cameras.json", "calibration.json", "results.json"):
        shutil.copy2(root / name, full / name)
    _invoke_ok(["report", str(full)])
    # rig files and a design
    (root / "rig.toml").write_text(SIM_RIG.replace("seed = 0", "seed = 3"), encoding="utf-8")
    (root / "hardware.toml").write_text(HARDWARE_RIG, encoding="utf-8")
    shutil.copy2(Path(__file__).parents[2] / "examples/rigs/micromanager.toml",
                 root / "micromanager.toml")  # fmt: skip
    rng = np.random.default_rng(7)
    d = rng.uniform([0.0, 0.0, 0.0], [8000.0, 8000.0, 4800.0], (12, 3))
    (root / "design.csv").write_text(
        "dx_um,dy_um,dz_um\n" + "".join(f"{a:.1f},{b:.1f},{c:.1f}\n" for a, b, c in d),
        encoding="utf-8",
    )
    _invoke_ok(["acquire", "--rig", str(root / "rig.toml"), "--design", str(root / "design.csv"),
                "--out", str(root / "dry"), "--dry-run", *ACQUIRE_QUICK_FILE])  # fmt: skip
    # calibration images of a wide-angle stereo pair, the cameras calibrated from them
    views = render_stereo_calibration_views(
        wide_angle_stereo_pair(), parse_target(STEREO_TARGET), STEREO_VIEWS, seed=1
    )
    (root / "cal").mkdir()
    for name, images in views.images.items():
        for k, image in enumerate(images):
            cv2.imwrite(str(root / "cal" / f"{name}_{k:02d}.png"), image)
    (root / "cal" / "steps.csv").write_text(
        "dx_um,dy_um,dz_um\n" + "".join(f"0,0,{1000 * k}\n" for k in range(STEREO_VIEWS)),
        encoding="utf-8",
    )
    cal_dir = root / "cal"
    _invoke_ok(["stereo-calibrate", "--target", STEREO_TARGET,
                "--images", f"left={cal_dir}/left_*.png", "--images", f"right={cal_dir}/right_*.png",
                "--out", str(root / "stereo.json")])  # fmt: skip
    _invoke_ok(["solve", str(cal), "3000", "2500", "1300"])
    (root / "notes.txt").write_text("lab notes: do not delete\n", encoding="utf-8")
    return Good(root)


# --- one case's directory ------------------------------------------------------------------
Edit = Callable[[Any], None]


def put(keys: tuple[str | int, ...], value: Any) -> Edit:
    """An edit of a JSON document: set the value at ``keys``."""

    def edit(doc: Any) -> None:
        for key in keys[:-1]:
            doc = doc[key]
        doc[keys[-1]] = value

    return edit


def drop(keys: tuple[str | int, ...]) -> Edit:
    """An edit of a JSON document: remove the key at ``keys``."""

    def edit(doc: Any) -> None:
        for key in keys[:-1]:
            doc = doc[key]
        del doc[keys[-1]]

    return edit


def cell(row: int, column: str, value: str) -> Callable[[str], str]:
    """An edit of a CSV text: one cell (``row`` counts data rows from 0)."""

    def edit(text: str) -> str:
        rows = list(csv.reader(io.StringIO(text)))
        rows[row + 1][rows[0].index(column)] = value
        return _csv(rows)

    return edit


def without_column(column: str) -> Callable[[str], str]:
    """An edit of a CSV text: drop a column."""

    def edit(text: str) -> str:
        rows = list(csv.reader(io.StringIO(text)))
        k = rows[0].index(column)
        return _csv([r[:k] + r[k + 1 :] for r in rows])

    return edit


def first_rows(n: int) -> Callable[[str], str]:
    """An edit of a CSV text: keep the header and the first ``n`` data rows."""
    return lambda text: "".join(text.splitlines(keepends=True)[: n + 1])


def _csv(rows: list[list[str]]) -> str:
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)
    return out.getvalue()


class Work:
    """The directory of one case: copies of the good inputs, mutated as the case says."""

    def __init__(self, root: Path, good: Good) -> None:
        self.root = root
        self.good = good
        self.held: list[int] = []  # descriptors of run locks the case holds

    def hold_lock(self, run: Path, pid: int = 4242) -> Path:
        """Hold a run directory's lock, as another microcal working in it would."""
        import fcntl

        fd = os.open(run / ".microcal.lock", os.O_RDWR | os.O_CREAT, 0o644)
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.ftruncate(fd, 0)
        os.write(fd, f"{pid}\n".encode("ascii"))
        self.held.append(fd)
        return run

    def release(self) -> None:
        """Let go of every lock the case holds."""
        while self.held:
            os.close(self.held.pop())

    def __truediv__(self, name: str) -> Path:
        return self.root / name

    def copy(self, name: str, dest: str | None = None) -> Path:
        """Copy a good input (file or directory) into the case's directory."""
        src, target = self.good / name, self.root / (dest or name)
        target.parent.mkdir(parents=True, exist_ok=True)
        if src.is_dir():
            shutil.copytree(src, target)
        else:
            shutil.copy2(src, target)
        return target

    def write(self, name: str, data: str | bytes) -> Path:
        """Write a file of the case (text as UTF-8)."""
        path = self.root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, bytes):
            path.write_bytes(data)
        else:
            path.write_text(data, encoding="utf-8")
        return path

    def mkdir(self, name: str, *files: str) -> Path:
        """A directory of the case, holding small user files."""
        path = self.root / name
        path.mkdir(parents=True, exist_ok=True)
        for f in files:
            (path / f).write_text(f"user file {f}\n", encoding="utf-8")
        return path

    def json(self, name: str, *edits: Edit, src: str | None = None) -> Path:
        """Copy a good JSON file (``src``, default ``name``) and edit it."""
        doc = json.loads((self.good / (src or name)).read_text(encoding="utf-8"))
        for edit in edits:
            edit(doc)
        return self.write(name, json.dumps(doc, indent=1))

    def text(self, name: str, edit: Callable[[str], str], src: str | None = None) -> Path:
        """Copy a good text file (``src``, default ``name``) and edit it."""
        return self.write(name, edit((self.good / (src or name)).read_text(encoding="utf-8")))

    def cut(self, name: str, fraction: float = 0.5, src: str | None = None) -> Path:
        """Copy a good file cut to its first ``fraction`` of bytes (truncated)."""
        data = (self.good / (src or name)).read_bytes()
        return self.write(name, data[: int(len(data) * fraction)])

    def read_only(self, name: str) -> Path:
        """A directory without write permission (a case that needs them: root ignores them)."""
        path = self.mkdir(name)
        path.chmod(stat.S_IRUSR | stat.S_IXUSR | stat.S_IRGRP | stat.S_IXGRP)
        return path


# --- the cases -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    """One bad input: its id (command first), what it runs, what the message must name.

    ``expect`` is a word the one line must hold (as a whole word, outside the case's own
    directory name): the option, file or key at fault.
    """

    id: str
    setup: Callable[[Work], list[str]]
    expect: str | None = None
    needs_permissions: bool = False  # relies on file permissions, which root ignores

    @property
    def command(self) -> str:
        """The command the case exercises (the longest command its id begins with)."""
        return max((c for c in COMMANDS if self.id.startswith(f"{c}-")), key=len)


def _demo(w: Work, *extra: str, out: Path | None = None) -> list[str]:
    return ["demo", "--out", str(out if out is not None else w / "demo"), *extra]


def _demo_dir(w: Work, *user_files: str) -> Path:
    """A run directory that says it is an earlier demo, with user files added."""
    run = w.copy("run")
    manifest = json.loads((run / "run.json").read_text(encoding="utf-8"))
    manifest["provenance"]["command"] = "demo"
    (run / "run.json").write_text(json.dumps(manifest, indent=1), encoding="utf-8")
    for name in user_files:
        w.write(f"run/{name}", b"user data\n")
    return run


def demo_cases() -> list[Case]:
    return [
        Case("demo-poses-too-few", lambda w: _demo(w, "--poses", "5"), "--poses"),
        Case("demo-poses-zero", lambda w: _demo(w, "--poses", "0"), "--poses"),
        Case("demo-poses-negative", lambda w: _demo(w, "--poses", "-40"), "--poses"),
        Case("demo-poses-not-a-number", lambda w: _demo(w, "--poses", "many"), "--poses"),
        Case("demo-poses-fraction", lambda w: _demo(w, "--poses", "40.5"), "--poses"),
        Case("demo-poses-too-many", lambda w: _demo(w, "--poses", "1000000"), "poses"),
        Case("demo-seed-negative", lambda w: _demo(w, "--quick", "--seed", "-1"), "--seed"),
        Case("demo-seed-not-a-number", lambda w: _demo(w, "--quick", "--seed", "abc"), "--seed"),
        Case("demo-quick-takes-no-value", lambda w: _demo(w, "--quick", "yes"), "yes"),
        Case("demo-unknown-option", lambda w: _demo(w, "--fast"), "--fast"),
        Case("demo-out-without-value", lambda w: ["demo", "--quick", "--out"], "--out"),
        Case("demo-out-is-a-file", lambda w: _demo(w, "--quick", out=w.copy("notes.txt")), "--out"),
        Case("demo-out-holds-user-files",
             lambda w: _demo(w, "--quick", out=w.mkdir("thesis", "chapter1.tex", "data.csv")), "--out"),
        Case("demo-out-holds-an-acquired-run", lambda w: _demo(w, "--quick", out=w.copy("run")), "--out"),
        Case("demo-out-demo-run-with-a-user-file",
             lambda w: _demo(w, "--quick", out=_demo_dir(w, "notes.txt")), "--out"),
        Case("demo-out-demo-run-with-a-user-image",
             lambda w: _demo(w, "--quick", out=_demo_dir(w, "images/holiday.jpg")), "--out"),
        Case("demo-out-demo-run-with-a-user-subdirectory",
             lambda w: _demo(w, "--quick", out=_demo_dir(w, "analysis/fit.py")), "--out"),
        Case("demo-out-empty-string-in-a-user-directory",
             lambda w: (w.copy("notes.txt"), ["demo", "--quick", "--out", ""])[1]),
        Case("demo-preset-unknown", lambda w: _demo(w, "--quick", "--preset", "telecentrc"), "telecentric"),
        Case("demo-preset-empty", lambda w: _demo(w, "--quick", "--preset", ""), "preset"),
        Case("demo-camera-model-unknown", lambda w: _demo(w, "--quick", "--camera-model", "fisheye"), "--camera-model"),
        Case("demo-camera-model-misspelt", lambda w: _demo(w, "--quick", "--camera-model", "afine"), "affine"),
        Case("demo-out-parent-is-a-file",
             lambda w: _demo(w, "--quick", out=w.copy("notes.txt") / "demo"), "notes.txt"),
        Case("demo-out-read-only-directory",
             lambda w: _demo(w, "--quick", out=w.read_only("locked") / "demo"), "locked",
             needs_permissions=True),
    ]  # fmt: skip


def _stereo(
    w: Work,
    *extra: str,
    target: str | None = STEREO_TARGET,
    left: str | None = None,
    right: str | None = None,
    out: Path | None = None,
) -> list[str]:
    cal = w / "cal"
    if not cal.exists():
        w.copy("cal")
    argv = ["stereo-calibrate"]
    if target is not None:
        argv += ["--target", target]
    argv += ["--images", left if left is not None else f"left={cal}/left_*.png"]
    argv += ["--images", right if right is not None else f"right={cal}/right_*.png"]
    out = out if out is not None else w.copy("stereo.json", "cameras.json")
    return [*argv, "--out", str(out), *extra]


def _fake_views(w: Work, data: bytes, suffix: str = "png") -> tuple[str, str]:
    """--images options of files that hold ``data`` (one per view and camera)."""
    for cam in ("left", "right"):
        for k in range(STEREO_VIEWS):
            w.write(f"fake/{cam}_{k:02d}.{suffix}", data)
    return f"left={w / 'fake'}/left_*.{suffix}", f"right={w / 'fake'}/right_*.{suffix}"


def _truncated_views(w: Work) -> tuple[str, str]:
    cal = w.copy("cal")
    for f in cal.glob("*.png"):
        data = f.read_bytes()
        f.write_bytes(data[: len(data) // 3])
    return f"left={cal}/left_*.png", f"right={cal}/right_*.png"


def _blank_views(w: Work) -> tuple[str, str]:
    blank = np.full((480, 640), 128, np.uint8)
    for cam in ("left", "right"):
        for k in range(STEREO_VIEWS):
            (w / "blank").mkdir(exist_ok=True)
            cv2.imwrite(str(w / "blank" / f"{cam}_{k:02d}.png"), blank)
    return f"left={w / 'blank'}/left_*.png", f"right={w / 'blank'}/right_*.png"


def _stereo_with(w: Work, views: tuple[str, str], *extra: str) -> list[str]:
    return _stereo(w, *extra, left=views[0], right=views[1])


def _steps(w: Work, text: str | bytes) -> list[str]:
    return _stereo(w, "--known-displacements", str(w.write("steps.csv", text)))


STEPS = "dx_um,dy_um,dz_um\n" + "".join(f"0,0,{1000 * k}\n" for k in range(STEREO_VIEWS))


def stereo_cases() -> list[Case]:
    s = "stereo-calibrate-"
    return [
        Case(s + "target-missing", lambda w: _stereo(w, target=None), "--target"),
        Case(s + "camera-model-unknown", lambda w: _stereo(w, "--camera-model", "orthographic"), "--camera-model"),
        Case(s + "affine-without-known-displacements", lambda w: _stereo(w, "--camera-model", "affine"), "--known-displacements"),
        Case(s + "target-unknown-kind", lambda w: _stereo(w, target="foo:7x5:30000"), "foo"),
        Case(s + "target-chessboard-1x1", lambda w: _stereo(w, target="chessboard:1x1:400"), "1x1"),
        Case(s + "target-dotgrid-0x3", lambda w: _stereo(w, target="dotgrid:0x3:10"), "0x3"),
        Case(s + "target-negative-pitch", lambda w: _stereo(w, target="chessboard:7x5:-30000"), "target"),
        Case(s + "target-zero-pitch", lambda w: _stereo(w, target="chessboard:7x5:0"), "pitch"),
        Case(s + "target-pitch-not-a-number", lambda w: _stereo(w, target="chessboard:7x5:1.2.3"), "target"),
        Case(s + "target-dots-larger-than-pitch", lambda w: _stereo(w, target="dotgrid:4x3:100:200"), "target"),
        Case(s + "target-chessboard-with-feature-size", lambda w: _stereo(w, target="chessboard:7x5:30000:5"), "target"),
        Case(s + "target-empty", lambda w: _stereo(w, target=""), "target"),
        Case(s + "target-absurdly-large-board", lambda w: _stereo(w, target="chessboard:100000x100000:1"), "target"),
        Case(s + "target-not-in-the-images",
             lambda w: _stereo(w, target="chessboard:9x6:30000", left=f"left={w.copy('cal')}/left_0[0-2].png",
                               right=f"right={w / 'cal'}/right_0[0-2].png")),
        Case(s + "images-missing", lambda w: ["stereo-calibrate", "--target", STEREO_TARGET], "--images"),
        Case("calibrate-cameras-images-missing", lambda w: ["calibrate-cameras", "--target", STEREO_TARGET], "--images"),
        Case("calibrate-cameras-target-unknown-kind",
             lambda w: ["calibrate-cameras", *_stereo(w, target="foo:7x5:30000")[1:]], "foo"),
        Case(s + "images-without-camera-name", lambda w: _stereo(w, left=f"{w / 'cal'}/left_*.png"), "CAMERA=GLOB"),
        Case(s + "images-empty-camera-name", lambda w: _stereo(w, left=f"={w / 'cal'}/left_*.png"), "CAMERA=GLOB"),
        Case(s + "images-empty-glob", lambda w: _stereo(w, left="left="), "CAMERA=GLOB"),
        Case(s + "images-camera-given-twice", lambda w: _stereo(w, right=f"left={w / 'cal'}/right_*.png"), "left"),
        Case(s + "images-three-cameras-one-short",
             lambda w: _stereo(w, "--images", f"third={w / 'cal'}/left_0[1-9].png"), "one image per view"),
        Case(s + "images-glob-matches-nothing", lambda w: _stereo(w, left=f"left={w.root}/nothing_*.png"), "nothing_"),
        Case(s + "images-count-mismatch",
             lambda w: (w.copy("cal"), (w / "cal/right_05.png").unlink(), _stereo(w))[2], "--images"),
        Case(s + "images-not-images", lambda w: _stereo_with(w, _fake_views(w, b"not an image\n"))),
        Case(s + "images-empty-files", lambda w: _stereo_with(w, _fake_views(w, b""))),
        Case(s + "images-binary-garbage-tiff", lambda w: _stereo_with(w, _fake_views(w, GARBAGE, "tiff"))),
        Case(s + "images-truncated-png", lambda w: _stereo_with(w, _truncated_views(w))),
        Case(s + "images-are-directories",
             lambda w: _stereo(w, left=f"left={w.mkdir('dirs/left_00.png').parent}/left_*.png",
                               right=f"right={w.mkdir('dirs/right_00.png').parent}/right_*.png")),
        Case(s + "images-without-a-board", lambda w: _stereo_with(w, _blank_views(w))),
        Case(s + "images-one-view",
             lambda w: _stereo(w, left=f"left={w.copy('cal')}/left_00.png", right=f"right={w / 'cal'}/right_00.png")),
        Case(s + "lens-model-unknown", lambda w: _stereo(w, "--lens-model", "fisheye99"), "fisheye99"),
        Case(s + "lens-model-with-known-displacements",
             lambda w: _stereo(w, "--lens-model", "radial2", "--known-displacements", str(w.write("steps.csv", STEPS))),
             "--lens-model"),
        Case(s + "reference-view-out-of-range", lambda w: _stereo(w, "--reference-view", "99"), "reference"),
        Case(s + "reference-view-negative", lambda w: _stereo(w, "--reference-view", "-1"), "reference"),
        Case(s + "reference-view-not-a-number", lambda w: _stereo(w, "--reference-view", "first"), "--reference-view"),
        Case(s + "known-displacements-missing-file",
             lambda w: _stereo(w, "--known-displacements", str(w / "nosteps.csv")), "nosteps.csv"),
        Case(s + "known-displacements-directory",
             lambda w: _stereo(w, "--known-displacements", str(w.mkdir("stepsdir"))), "stepsdir"),
        Case(s + "known-displacements-too-few-rows", lambda w: _steps(w, first_rows(5)(STEPS)), "--known-displacements"),
        Case(s + "known-displacements-too-many-rows", lambda w: _steps(w, STEPS + "0,0,9000\n"), "--known-displacements"),
        Case(s + "known-displacements-missing-column", lambda w: _steps(w, without_column("dz_um")(STEPS)), "dz_um"),
        Case(s + "known-displacements-text-cell", lambda w: _steps(w, cell(2, "dz_um", "two mm")(STEPS)), "dz_um"),
        Case(s + "known-displacements-nan-cell", lambda w: _steps(w, cell(2, "dz_um", "nan")(STEPS)), "dz_um"),
        Case(s + "known-displacements-empty-file", lambda w: _steps(w, ""), "--known-displacements"),
        Case(s + "known-displacements-binary-garbage", lambda w: _steps(w, GARBAGE), "--known-displacements"),
        Case(s + "known-displacements-bom-and-semicolons",
             lambda w: _steps(w, BOM + STEPS.replace(",", ";")), "--known-displacements"),
        Case(s + "known-displacements-all-zero",
             lambda w: _steps(w, "dx_um,dy_um,dz_um\n" + "0,0,0\n" * STEREO_VIEWS)),
        Case(s + "known-displacements-duplicate-pose",
             lambda w: _steps(w, "pose," + STEPS.replace("\n0,", "\n1,0,")), "pose"),
        Case(s + "out-is-a-directory", lambda w: _stereo(w, out=w.mkdir("outdir")), "--out"),
        Case(s + "out-is-a-calibration-json", lambda w: _stereo(w, out=w.copy("calibration.json")), "--out"),
        Case(s + "out-is-a-csv-file", lambda w: _stereo(w, out=w.copy("measurements.csv")), "--out"),
        Case(s + "out-is-a-garbage-file", lambda w: _stereo(w, out=w.write("cameras.json", GARBAGE)), "--out"),
        Case(s + "out-parent-is-a-file", lambda w: _stereo(w, out=w.copy("notes.txt") / "cameras.json"), "--out"),
        Case(s + "out-read-only-directory", lambda w: _stereo(w, out=w.read_only("locked") / "cameras.json"),
             "--out", needs_permissions=True),
        Case(s + "unknown-option", lambda w: _stereo(w, "--lens", "auto"), "--lens"),
    ]  # fmt: skip


def _acquire(
    w: Work, *extra: str, out: Path | None = None, quick: list[str] = ACQUIRE_QUICK
) -> list[str]:
    target = out if out is not None else w / "run"
    return ["acquire", "--out", str(target), *quick, *extra]


def _design_file(w: Work, path: Path) -> list[str]:
    return _acquire(w, "--design", str(path), quick=ACQUIRE_QUICK_FILE)


def _design(w: Work, data: str | bytes) -> list[str]:
    return _design_file(w, w.write("mydesign.csv", data))


def _design_edit(w: Work, edit: Callable[[str], str]) -> list[str]:
    return _design_file(w, w.text("mydesign.csv", edit, src="design.csv"))


def _resume(w: Work, *extra: str) -> list[str]:
    """``acquire --out RUN --resume`` alone, as a stopped run is continued."""
    return ["acquire", "--out", str(w / "run"), "--resume", *extra]


def _rig(w: Work, text: str | bytes, *extra: str) -> list[str]:
    """acquire --dry-run with a rig file (nothing moves or is written when it is accepted)."""
    return _acquire(w, "--rig", str(w.write("myrig.toml", text)), "--dry-run", *extra)


def _override(table: str, line: str) -> str:
    return SIM_RIG + f"\n[overrides{'.' + table if table else ''}]\n{line}\n"


def _hardware(old: str, new: str) -> str:
    assert old in HARDWARE_RIG, old
    return HARDWARE_RIG.replace(old, new)


def _edit_journal(w: Work, edit: Callable[[list[str]], list[str]]) -> None:
    path = w / "run" / "journal.jsonl"
    lines = path.read_text(encoding="utf-8").splitlines()
    path.write_text("\n".join(edit(lines)) + "\n", encoding="utf-8")


def _with_run(w: Work, change: Callable[[Path], object]) -> Path:
    run = w.copy("run")
    change(run)
    return run


def _replace_with_directory(path: Path) -> None:
    path.unlink()
    path.mkdir()
    (path / "keep.txt").write_text("user file\n", encoding="utf-8")


def acquire_cases() -> list[Case]:
    a = "acquire-"
    limits = "limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }"
    return [
        # options
        Case(a + "out-missing", lambda w: ["acquire", *ACQUIRE_QUICK], "--out"),
        Case(a + "poses-one", lambda w: _acquire(w, "--poses", "1"), "poses"),
        Case(a + "poses-zero", lambda w: _acquire(w, "--poses", "0"), "poses"),
        Case(a + "poses-negative", lambda w: _acquire(w, "--poses", "-5"), "poses"),
        Case(a + "poses-too-few", lambda w: _acquire(w, "--poses", "11"), "poses"),
        Case(a + "poses-too-many", lambda w: _acquire(w, "--poses", "10000000"), "poses"),
        Case(a + "poses-too-many-dry-run", lambda w: _acquire(w, "--poses", "10000000", "--dry-run"), "poses"),
        Case(a + "poses-not-a-number", lambda w: _acquire(w, "--poses", "ten"), "--poses"),
        Case(a + "seed-negative", lambda w: _acquire(w, "--seed", "-1"), "--seed"),
        Case(a + "seed-not-a-number", lambda w: _acquire(w, "--seed", "x"), "--seed"),
        Case(a + "frames-zero", lambda w: _acquire(w, "--frames", "0"), "--frames"),
        Case(a + "frames-negative", lambda w: _acquire(w, "--frames", "-2"), "--frames"),
        Case(a + "frames-not-a-number", lambda w: _acquire(w, "--frames", "two"), "--frames"),
        Case(a + "settle-fixed-inf", lambda w: _acquire(w, "--settle", "fixed:inf"), "--settle"),
        Case(a + "settle-fixed-negative", lambda w: _acquire(w, "--settle", "fixed:-1"), "--settle"),
        Case(a + "settle-fixed-nan", lambda w: _acquire(w, "--settle", "fixed:nan"), "--settle"),
        Case(a + "settle-fixed-overflow", lambda w: _acquire(w, "--settle", "fixed:1e999"), "--settle"),
        Case(a + "settle-fixed-without-seconds", lambda w: _acquire(w, "--settle", "fixed:"), "--settle"),
        Case(a + "settle-unknown", lambda w: _acquire(w, "--settle", "soon"), "--settle"),
        Case(a + "settle-vision-with-seconds", lambda w: _acquire(w, "--settle", "vision:3"), "--settle"),
        Case(a + "store-unknown", lambda w: _acquire(w, "--store", "bogus"), "--store"),
        Case(a + "store-empty", lambda w: _acquire(w, "--store", ""), "--store"),
        Case(a + "unknown-option", lambda w: _acquire(w, "--pose", "12"), "--pose"),
        # several devices
        Case(a + "manipulator-unknown", lambda w: _acquire(w, "--manipulator", "m7"), "--manipulator"),
        Case(a + "manipulator-unknown-on-a-platform",
             lambda w: _acquire(w, "--manipulator", "m3", "--rig",
                                str(w.write("platform.toml", 'driver = "sim"\npreset = "thesis-platform"\n'))),
             "--manipulator"),
        Case(a + "further-manipulator-named-m1",
             lambda w: _rig(w, HARDWARE_RIG + '\n[manipulators.m1]\nkind = "smaract-mcs2"\n'
                            'address = "127.0.0.4"\nchannels = { x = 0, y = 1, z = 2 }\n' + limits),
             "manipulators.m1"),
        Case(a + "further-manipulator-unknown-key",
             lambda w: _rig(w, HARDWARE_RIG + '\n[manipulators.m2]\nkind = "smaract-mcs2"\n'
                            'adress = "127.0.0.4"\n'),
             "manipulators.m2.adress"),
        Case(a + "check-every-not-a-count", lambda w: _acquire(w, "--check-calibration",
             str(w.good / "calibration.json"), "--check-every", "often"), "--check-every"),
        Case(a + "check-every-zero", lambda w: _acquire(w, "--check-calibration",
             str(w.good / "calibration.json"), "--check-every", "0"), "--check-every"),
        Case(a + "check-every-without-a-calibration", lambda w: _acquire(w, "--check-every", "20"),
             "--check-every"),
        Case(a + "check-calibration-missing", lambda w: _acquire(w, "--check-calibration",
             str(w / "nocal.json")), "nocal.json"),
        # --design
        Case(a + "design-unknown", lambda w: _acquire(w, "--design", "rnadom"), "--design"),
        Case(a + "design-missing-file", lambda w: _design_file(w, w / "nodesign.csv"), "nodesign.csv"),
        Case(a + "design-directory", lambda w: _design_file(w, w.mkdir("designs")), "designs"),
        Case(a + "design-empty-file", lambda w: _design(w, ""), "mydesign.csv"),
        Case(a + "design-header-only", lambda w: _design(w, "dx_um,dy_um,dz_um\n"), "mydesign.csv"),
        Case(a + "design-missing-column", lambda w: _design_edit(w, without_column("dy_um")), "dy_um"),
        Case(a + "design-text-cell", lambda w: _design_edit(w, cell(3, "dx_um", "left")), "dx_um"),
        Case(a + "design-nan-cell", lambda w: _design_edit(w, cell(3, "dz_um", "nan")), "dz_um"),
        Case(a + "design-inf-cell", lambda w: _design_edit(w, cell(3, "dz_um", "inf")), "dz_um"),
        Case(a + "design-short-row", lambda w: _design_edit(w, lambda t: t.replace("\n", "\n1000\n", 2)), "mydesign.csv"),
        Case(a + "design-duplicate-pose",
             lambda w: _design(w, "pose,dx_um,dy_um,dz_um\n1,100,100,100\n1,8000,8000,4800\n" +
                               "".join(f"{k},{k * 600},{(13 - k) * 600},{k * 350}\n" for k in range(2, 13))), "pose"),
        Case(a + "design-pose-zero",
             lambda w: _design(w, "pose,dx_um,dy_um,dz_um\n" +
                               "".join(f"{k},{k * 600 + 100},{(13 - k) * 600},{k * 350}\n" for k in range(12))), "pose"),
        Case(a + "design-outside-limits", lambda w: _design_edit(w, cell(4, "dx_um", "1000000")), "limits"),
        Case(a + "design-binary-garbage", lambda w: _design(w, GARBAGE), "mydesign.csv"),
        Case(a + "design-bom-and-tabs",
             lambda w: _design(w, BOM + (w.good / "design.csv").read_text(encoding="utf-8").replace(",", "\t")),
             "mydesign.csv"),
        Case(a + "design-utf16",
             lambda w: _design(w, (w.good / "design.csv").read_text(encoding="utf-8").encode("utf-16")), "mydesign.csv"),
        Case(a + "design-one-axis-still",
             lambda w: _design(w, "dx_um,dy_um,dz_um\n" +
                               "".join(f"{k * 600},{(k * 7919) % 8000},1000\n" for k in range(12))), "axis z"),
        Case(a + "design-two-rows", lambda w: _design_edit(w, first_rows(2))),
        # --out
        Case(a + "out-is-a-file", lambda w: _acquire(w, out=w.copy("notes.txt")), "--out"),
        Case(a + "out-holds-a-run", lambda w: _acquire(w, out=w.copy("run")), "--resume"),
        Case(a + "out-holds-user-files", lambda w: _acquire(w, out=w.mkdir("mydata", "notes.txt", "thesis.docx")), "--out"),
        Case(a + "out-holds-user-images",
             lambda w: _acquire(w, out=(w.copy("run/images/top_0001.tiff", "mine/images/top_0001.tiff"), w / "mine")[1]),
             "--out"),
        Case(a + "out-holds-a-measurements-file",
             lambda w: _acquire(w, out=w.copy("measurements.csv", "mine/measurements.csv").parent), "--out"),
        Case(a + "out-parent-is-a-file", lambda w: _acquire(w, out=w.copy("notes.txt") / "run"), "--out"),
        Case(a + "out-read-only-directory", lambda w: _acquire(w, out=w.read_only("locked") / "run"), "--out",
             needs_permissions=True),
        # --resume
        Case(a + "resume-without-a-run", lambda w: (w.mkdir("run"), _resume(w))[1], "--resume"),
        Case(a + "resume-nonexistent-directory", lambda w: _resume(w), "--resume"),
        Case(a + "resume-with-dry-run", lambda w: (w.copy("run"), _resume(w, "--dry-run"))[1], "--dry-run"),
        Case(a + "resume-another-rig",
             lambda w: (w.copy("run"), _resume(w, "--rig", str(w.copy("rig.toml"))))[1], "rig"),
        Case(a + "resume-edited-commands",
             lambda w: (_run_file(w, "commands.csv", cell(2, "dx_um", "1234.5")), _resume(w))[1], "commands.csv"),
        Case(a + "resume-changed-image",
             lambda w: (_with_run(w, lambda r: (r / "images/top_0002.tiff").write_bytes(GARBAGE)), _resume(w))[1],
             "top_0002"),
        Case(a + "resume-missing-image",
             lambda w: (_with_run(w, lambda r: (r / "images/side_0003.tiff").unlink()), _resume(w))[1], "side_0003"),
        Case(a + "resume-journal-is-a-directory",
             lambda w: (_with_run(w, lambda r: _replace_with_directory(r / "journal.jsonl")), _resume(w))[1], "journal"),
        Case(a + "resume-run-in-use", lambda w: (w.hold_lock(w.copy("run")), _resume(w))[1], "4242"),
        Case(a + "resume-run-json-garbage",
             lambda w: (_with_run(w, lambda r: (r / "run.json").write_bytes(GARBAGE)), _resume(w))[1], "run.json"),
        Case(a + "resume-run-json-future-version",
             lambda w: (w.copy("run"), w.json("run/run.json", put(("format",), "microcal.run/2")), _resume(w))[2],
             "version"),
        Case(a + "resume-run-json-is-a-directory",
             lambda w: (_with_run(w, lambda r: _replace_with_directory(r / "run.json")), _resume(w))[1], "run.json"),
        Case(a + "resume-commands-missing",
             lambda w: (_with_run(w, lambda r: (r / "commands.csv").unlink()), _resume(w))[1], "commands.csv"),
        # --rig: the file
        Case(a + "rig-missing-file", lambda w: _acquire(w, "--rig", str(w / "norig.toml"), "--dry-run"), "norig.toml"),
        Case(a + "rig-directory", lambda w: _acquire(w, "--rig", str(w.mkdir("rigs")), "--dry-run"), "rigs"),
        Case(a + "rig-empty-string", lambda w: _acquire(w, "--rig", "", "--dry-run"), "--rig"),
        Case(a + "rig-empty-file", lambda w: _rig(w, ""), "driver"),
        Case(a + "rig-binary-garbage", lambda w: _rig(w, GARBAGE), "myrig.toml"),
        Case(a + "rig-not-toml", lambda w: _rig(w, "driver = sim\n"), "myrig.toml"),
        Case(a + "rig-bom-and-unterminated-string", lambda w: _rig(w, BOM + 'driver = "sim\n'), "myrig.toml"),
        Case(a + "rig-utf16", lambda w: _rig(w, SIM_RIG.encode("utf-16")), "myrig.toml"),
        Case(a + "rig-unknown-driver", lambda w: _rig(w, SIM_RIG.replace('"sim"', '"simulator"')), "driver"),
        Case(a + "rig-driver-missing", lambda w: _rig(w, 'preset = "thesis"\n'), "driver"),
        Case(a + "rig-driver-not-a-string", lambda w: _rig(w, SIM_RIG.replace('"sim"', "3")), "driver"),
        Case(a + "rig-unknown-preset", lambda w: _rig(w, SIM_RIG.replace('"thesis"', '"nope"')), "preset"),
        Case(a + "rig-unknown-key-near-seed", lambda w: _rig(w, SIM_RIG + "seeed = 1\n"), "seed"),
        Case(a + "rig-unknown-key-near-preset", lambda w: _rig(w, 'driver = "sim"\nprest = "thesis"\n'), "preset"),
        Case(a + "rig-seed-not-an-integer", lambda w: _rig(w, SIM_RIG.replace("seed = 0", 'seed = "a"')), "seed"),
        Case(a + "rig-seed-negative", lambda w: _rig(w, SIM_RIG.replace("seed = 0", "seed = -1")), "seed"),
        Case(a + "rig-seed-fraction", lambda w: _rig(w, SIM_RIG.replace("seed = 0", "seed = 1.5")), "seed"),
        Case(a + "rig-overrides-not-a-table", lambda w: _rig(w, SIM_RIG + "overrides = 5\n"), "overrides"),
        # --rig: the simulator's settings
        Case(a + "rig-override-unknown-key-near-drop-rate",
             lambda w: _rig(w, _override("top.faults", "drop_rat = 0.1")), "drop_rate"),
        Case(a + "rig-override-unknown-camera-near-top",
             lambda w: _rig(w, _override("tpo.faults", "drop_rate = 0.1")), "top"),
        Case(a + "rig-override-unknown-key-near-read-noise",
             lambda w: _rig(w, _override("side.formation", "read_noise = 10.0")), "read_noise_e"),
        Case(a + "rig-override-drop-rate-above-one", lambda w: _rig(w, _override("top.faults", "drop_rate = 1.5")), "drop_rate"),
        Case(a + "rig-override-drop-rate-above-one-acquiring",
             lambda w: _acquire(w, "--rig", str(w.write("myrig.toml", _override("top.faults", "drop_rate = 1.5")))),
             "drop_rate"),
        Case(a + "rig-override-drop-rate-negative", lambda w: _rig(w, _override("top.faults", "drop_rate = -0.1")), "drop_rate"),
        Case(a + "rig-override-drop-rate-text", lambda w: _rig(w, _override("top.faults", 'drop_rate = "high"')), "drop_rate"),
        Case(a + "rig-override-drop-rate-inf", lambda w: _rig(w, _override("top.faults", "drop_rate = inf")), "drop_rate"),
        Case(a + "rig-override-drop-rate-nan", lambda w: _rig(w, _override("top.faults", "drop_rate = nan")), "drop_rate"),
        Case(a + "rig-override-occlusion-rate-above-one",
             lambda w: _rig(w, _override("side.faults", "occlusion_rate = 3.0")), "occlusion_rate"),
        Case(a + "rig-override-timeout-rate-above-one",
             lambda w: _rig(w, _override("manipulator.faults", "timeout_rate = 2.0")), "timeout_rate"),
        Case(a + "rig-override-read-noise-negative",
             lambda w: _rig(w, _override("top.formation", "read_noise_e = -5.0")), "read_noise_e"),
        Case(a + "rig-override-blur-negative",
             lambda w: _rig(w, _override("side.formation", "blur_sigma_px = -1.0")), "blur_sigma_px"),
        Case(a + "rig-override-full-well-zero",
             lambda w: _rig(w, _override("top.formation", "full_well_e = 0.0")), "full_well_e"),
        Case(a + "rig-override-supersample-zero",
             lambda w: _rig(w, _override("top.formation", "supersample = 0")), "supersample"),
        Case(a + "rig-override-jitter-wrong-length",
             lambda w: _rig(w, _override("top.formation", "jitter_px = [0.1]")), "jitter_px"),
        Case(a + "rig-override-bit-depth-zero", lambda w: _rig(w, _override("top", "bit_depth = 0")), "bit_depth"),
        Case(a + "rig-override-pixel-size-negative",
             lambda w: _rig(w, _override("side", "pixel_size_um = -6.9")), "pixel_size_um"),
        Case(a + "rig-override-dist-wrong-length", lambda w: _rig(w, _override("top", "dist = [0.5]")), "dist"),
        Case(a + "rig-override-speed-zero",
             lambda w: _rig(w, _override("manipulator", "speed_um_s = 0.0")), "speed_um_s"),
        Case(a + "rig-override-sensor-noise-negative",
             lambda w: _rig(w, _override("manipulator", "sensor_noise_um = -0.05")), "sensor_noise_um"),
        Case(a + "rig-override-limits-inverted",
             lambda w: _rig(w, _override("manipulator", "limits_um = [[8500.0, -500.0], [-500.0, 8500.0], [-500.0, 5300.0]]")),
             "limits_um"),
        Case(a + "rig-override-limits-one-axis",
             lambda w: _rig(w, _override("manipulator", "limits_um = [[0.0, 8000.0]]")), "limits_um"),
        Case(a + "rig-override-board-unknown-kind", lambda w: _rig(w, _override("", 'board = "foo:4x3:400"')), "board"),
        Case(a + "rig-override-board-1x1", lambda w: _rig(w, _override("", 'board = "chessboard:1x1:400"')), "board"),
        # --rig: hardware
        Case(a + "rig-hardware-without-manipulator",
             lambda w: _rig(w, HARDWARE_RIG.split("[manipulator]")[0] + "[cameras.top]" + HARDWARE_RIG.split("[cameras.top]")[1]),
             "manipulator"),
        Case(a + "rig-hardware-unknown-manipulator-kind",
             lambda w: _rig(w, _hardware('kind = "smaract-mcs2"', 'kind = "smaract"')), "smaract-mcs2"),
        Case(a + "rig-hardware-unknown-key-near-address",
             lambda w: _rig(w, _hardware('address = "127.0.0.1"', 'adress = "127.0.0.1"')), "address"),
        Case(a + "rig-hardware-port-out-of-range", lambda w: _rig(w, _hardware("port = 9", "port = 70000")), "port"),
        Case(a + "rig-hardware-timeout-negative",
             lambda w: _rig(w, _hardware("timeout_s = 0.5", "timeout_s = -1.0")), "timeout_s"),
        Case(a + "rig-hardware-channel-negative",
             lambda w: _rig(w, _hardware("x = 0, y = 1", "x = -1, y = 1")), "channels"),
        Case(a + "rig-hardware-limits-inverted",
             lambda w: _rig(w, _hardware(limits, limits.replace("x = [0, 8000]", "x = [8000, 0]"))), "limits_um"),
        Case(a + "rig-hardware-limits-missing-axis",
             lambda w: _rig(w, _hardware(limits, limits.replace(", z = [0, 4800]", ""))), "limits_um"),
        Case(a + "rig-hardware-one-camera",
             lambda w: _rig(w, HARDWARE_RIG.split("[cameras.side]")[0]), "cameras"),
        Case(a + "rig-hardware-unknown-camera-kind",
             lambda w: _rig(w, _hardware('kind = "aravis"\naddress = "127.0.0.2"', 'kind = "gige"\naddress = "127.0.0.2"')),
             "aravis"),
        Case(a + "rig-hardware-unknown-pixel-format",
             lambda w: _rig(w, _hardware('pixel_format = "Mono8"', 'pixel_format = "Mono9"')), "pixel_format"),
        Case(a + "rig-hardware-region-negative-size",
             lambda w: _rig(w, _hardware('pixel_format = "Mono8"', "region_px = [0, 0, -10, 100]")), "region_px"),
        Case(a + "rig-hardware-board-1x1",
             lambda w: _rig(w, _hardware('board = "chessboard:4x3:400"', 'board = "chessboard:1x1:400"')), "board"),
        Case(a + "rig-hardware-controller-unreachable", lambda w: _rig(w, HARDWARE_RIG), "127.0.0.1"),
        # without the extra: pymmcore-plus is named; with it: its configuration file is
        Case(a + "rig-micromanager-cannot-open",
             lambda w: _acquire(w, "--rig", str(w.copy("micromanager.toml")), "--dry-run"),
             "MMConfig_rig.cfg" if importlib.util.find_spec("pymmcore_plus") else "pymmcore"),
        Case(a + "rig-micromanager-config-and-python-devices",
             lambda w: _rig(w, (w.good / "micromanager.toml").read_text(encoding="utf-8").replace(
                 '# python_devices = "mydevices:load"', 'python_devices = "mydevices:load"')), "micromanager"),
    ]  # fmt: skip


def _measure(
    w: Work, *extra: str, run: Path | None = None, cameras: Path | None = None
) -> list[str]:
    cams = cameras if cameras is not None else w.copy("cameras.json")
    run_dir = run if run is not None else (w / "run" if (w / "run").exists() else w.copy("run"))
    return ["measure", str(run_dir), "--cameras", str(cams), *extra]


def _cameras(w: Work, *edits: Edit) -> list[str]:
    return _measure(w, cameras=w.json("cameras.json", *edits))


def _run_file(w: Work, name: str, edit: Callable[[str], str]) -> Path:
    w.copy("run")
    return w.text(f"run/{name}", edit, src=f"run/{name}")


def _consistent_commands(w: Work, edit: Callable[[str], str]) -> Path:
    """A run whose commands.csv is edited and whose run.json records the edited file's hash
    (a malformed file that is not caught as an edit)."""
    path = _run_file(w, "commands.csv", edit)
    manifest = json.loads((w / "run/run.json").read_text(encoding="utf-8"))
    manifest["commands_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    w.write("run/run.json", json.dumps(manifest, indent=1))
    return path


def _run_json(w: Work, *edits: Edit) -> Path:
    w.copy("run")
    return w.json("run/run.json", *edits, src="run/run.json")


def measure_cases() -> list[Case]:
    m = "measure-"
    top = ("cameras", "top")
    return [
        # the run directory
        Case(m + "run-missing", lambda w: _measure(w, run=w / "norun"), "norun"),
        Case(m + "run-is-a-file", lambda w: _measure(w, run=w.copy("notes.txt")), "notes.txt"),
        Case(m + "run-empty-directory", lambda w: _measure(w, run=w.mkdir("empty")), "commands.csv"),
        Case(m + "run-user-directory", lambda w: _measure(w, run=w.mkdir("mydata", "notes.txt")), "mydata"),
        Case(m + "run-argument-missing", lambda w: ["measure", "--cameras", str(w.copy("cameras.json"))], "run_dir"),
        Case(m + "commands-text-cell", lambda w: (_consistent_commands(w, cell(1, "dy_um", "up")), _measure(w))[1], "dy_um"),
        Case(m + "commands-nan-cell", lambda w: (_consistent_commands(w, cell(1, "dy_um", "nan")), _measure(w))[1], "dy_um"),
        Case(m + "commands-duplicate-pose",
             lambda w: (_consistent_commands(w, cell(3, "pose", "2")), _measure(w))[1], "pose"),
        Case(m + "commands-missing-column",
             lambda w: (_consistent_commands(w, without_column("dz_um")), _measure(w))[1], "dz_um"),
        Case(m + "commands-empty", lambda w: (_consistent_commands(w, lambda t: ""), _measure(w))[1], "commands.csv"),
        Case(m + "commands-binary-garbage",
             lambda w: (w.copy("run"), w.write("run/commands.csv", GARBAGE), _measure(w))[2], "commands.csv"),
        Case(m + "run-json-garbage",
             lambda w: (w.copy("run"), w.write("run/run.json", GARBAGE), _measure(w))[2], "run.json"),
        Case(m + "run-json-future-version", lambda w: (_run_json(w, put(("format",), "microcal.run/2")), _measure(w))[1],
             "version"),
        Case(m + "run-json-array", lambda w: (w.copy("run"), w.write("run/run.json", "[1, 2]"), _measure(w))[2], "run.json"),
        Case(m + "run-json-target-unknown-kind",
             lambda w: (_run_json(w, put(("target",), "foo:4x3:400")), _measure(w))[1], "run.json"),
        Case(m + "run-json-target-not-a-string", lambda w: (_run_json(w, put(("target",), 5)), _measure(w))[1], "target"),
        Case(m + "journal-is-a-directory",
             lambda w: (_with_run(w, lambda r: _replace_with_directory(r / "journal.jsonl")), _measure(w))[1], "journal"),
        Case(m + "journal-binary-garbage",
             lambda w: (w.copy("run"), w.write("run/journal.jsonl", GARBAGE), _measure(w))[2], "journal"),
        Case(m + "journal-empty", lambda w: (w.copy("run"), w.write("run/journal.jsonl", ""), _measure(w))[2], "journal"),
        Case(m + "journal-missing",
             lambda w: (_with_run(w, lambda r: (r / "journal.jsonl").unlink()), _measure(w))[1], "journal"),
        Case(m + "images-missing", lambda w: (_with_run(w, lambda r: shutil.rmtree(r / "images")), _measure(w))[1], "images"),
        Case(m + "measurements-is-a-directory",
             lambda w: (_with_run(w, lambda r: _replace_with_directory(r / "measurements.csv")), _measure(w))[1],
             "measurements.csv"),
        Case(m + "measurements-is-a-user-file",
             lambda w: (_with_run(w, lambda r: (r / "measurements.csv").write_text("my own table\n")), _measure(w))[1],
             "measurements.csv"),
        Case(m + "measurements-is-a-user-file-forced",
             lambda w: (_with_run(w, lambda r: (r / "measurements.csv").write_text("my own table\n")),
                        _measure(w, "--force"))[1], "measurements.csv"),
        Case(m + "run-in-use", lambda w: _measure(w, run=w.hold_lock(w.copy("run"))), "4242"),
        Case(m + "run-read-only-directory",
             lambda w: (_with_run(w, lambda r: (r / "measurements.csv").unlink()), (w / "run").chmod(0o555), _measure(w))[2],
             "run", needs_permissions=True),
        Case(m + "target-unknown-kind", lambda w: _measure(w, "--target", "foo:4x3:400"), "foo"),
        Case(m + "target-chessboard-1x1", lambda w: _measure(w, "--target", "chessboard:1x1:400"), "1x1"),
        Case(m + "target-not-in-the-images",
             lambda w: (_consistent_commands(w, first_rows(3)), _measure(w, "--target", "chessboard:9x6:400"))[1],
             "chessboard:9x6:400"),
        # --cameras
        Case(m + "cameras-option-missing", lambda w: ["measure", str(w.copy("run"))], "--cameras"),
        Case(m + "cameras-missing-file", lambda w: _measure(w, cameras=w / "nocams.json"), "nocams.json"),
        Case(m + "cameras-directory", lambda w: _measure(w, cameras=w.mkdir("camdir")), "camdir"),
        Case(m + "cameras-empty-file", lambda w: _measure(w, cameras=w.write("cameras.json", "")), "cameras.json"),
        Case(m + "cameras-binary-garbage", lambda w: _measure(w, cameras=w.write("cameras.json", GARBAGE)), "cameras.json"),
        Case(m + "cameras-truncated", lambda w: _measure(w, cameras=w.cut("cameras.json")), "cameras.json"),
        Case(m + "cameras-json-array", lambda w: _measure(w, cameras=w.write("cameras.json", "[]")), "cameras.json"),
        Case(m + "cameras-json-null", lambda w: _measure(w, cameras=w.write("cameras.json", "null")), "cameras.json"),
        Case(m + "cameras-bom-and-truncated",
             lambda w: _measure(w, cameras=w.write("cameras.json", BOM + (w.good / "cameras.json").read_text()[:300])),
             "cameras.json"),
        Case(m + "cameras-utf16",
             lambda w: _measure(w, cameras=w.write("cameras.json", (w.good / "cameras.json").read_text().encode("utf-16"))),
             "cameras.json"),
        Case(m + "cameras-is-a-calibration-without-cameras",
             lambda w: _measure(w, cameras=w.copy("calibration-no-cameras.json")), "cameras"),
        Case(m + "cameras-is-a-results-file", lambda w: _measure(w, cameras=w.copy("results.json")), "results.json"),
        Case(m + "cameras-is-a-run-json", lambda w: _measure(w, cameras=w.copy("run/run.json", "run.json")), "run.json"),
        Case(m + "cameras-is-a-csv-file", lambda w: _measure(w, cameras=w.copy("measurements.csv")), "measurements.csv"),
        Case(m + "cameras-future-version", lambda w: _cameras(w, put(("format",), "microcal.cameras/2")), "version"),
        Case(m + "cameras-format-missing", lambda w: _cameras(w, drop(("format",))), "format"),
        Case(m + "cameras-format-not-a-string", lambda w: _cameras(w, put(("format",), 1)), "format"),
        Case(m + "cameras-none", lambda w: _cameras(w, put(("cameras",), {})), "cameras"),
        Case(m + "cameras-a-list", lambda w: _cameras(w, put(("cameras",), [])), "cameras"),
        Case(m + "cameras-one-camera", lambda w: _cameras(w, drop(("cameras", "side"))), "cameras"),
        Case(m + "cameras-of-another-rig", lambda w: _measure(w, cameras=w.copy("stereo.json", "cameras.json")), "--cameras"),
        Case(m + "cameras-camera-not-an-object", lambda w: _cameras(w, put(("cameras", "top"), "pinhole")), "top"),
        Case(m + "cameras-K-missing", lambda w: _cameras(w, drop((*top, "K"))), "K"),
        Case(m + "cameras-K-wrong-shape", lambda w: _cameras(w, put((*top, "K"), [[1.0, 0.0], [0.0, 1.0]])), "K"),
        Case(m + "cameras-K-text", lambda w: _cameras(w, put((*top, "K"), "identity")), "K"),
        Case(m + "cameras-K-nan", lambda w: _cameras(w, put((*top, "K", 0, 0), float("nan"))), "K"),
        Case(m + "cameras-K-zero", lambda w: _cameras(w, put((*top, "K"), [[0.0] * 3] * 3)), "K"),
        Case(m + "cameras-focal-length-negative", lambda w: _cameras(w, put((*top, "K", 0, 0), -5000.0)), "K"),
        Case(m + "cameras-dist-wrong-length", lambda w: _cameras(w, put((*top, "dist"), [0.1, 0.0, 0.0])), "dist"),
        Case(m + "cameras-dist-inf", lambda w: _cameras(w, put((*top, "dist", 0), float("inf"))), "dist"),
        Case(m + "cameras-image-size-negative", lambda w: _cameras(w, put((*top, "image_size_px"), [-1600, 1200])),
             "image_size_px"),
        Case(m + "cameras-image-size-not-the-images", lambda w: _cameras(w, put((*top, "image_size_px"), [800, 600])),
             "--cameras"),
        Case(m + "cameras-R-not-a-rotation", lambda w: _cameras(w, put((*top, "R"), [[2.0, 0, 0], [0, 2.0, 0], [0, 0, 2.0]])), "R"),
        Case(m + "cameras-t-wrong-length", lambda w: _cameras(w, put((*top, "t_um"), [1.0, 2.0])), "t_um"),
        Case(m + "cameras-t-text", lambda w: _cameras(w, put((*top, "t_um"), ["a", "b", "c"])), "t_um"),
        Case(m + "cameras-model-unknown", lambda w: _cameras(w, put((*top, "model"), "fisheye")), "fisheye"),
        Case(m + "cameras-projection-sigma-negative", lambda w: _cameras(w, put((*top, "projection_sigma_px"), -1.0)),
             "projection_sigma_px"),
    ]  # fmt: skip


def _fit(w: Work, *extra: str, source: Path | None = None, out: Path | None = None) -> list[str]:
    src = source if source is not None else w.copy("measurements.csv")
    target = out if out is not None else w.copy("calibration.json")
    return ["fit", str(src), "--out", str(target), *extra]


def _meas(w: Work, edit: Callable[[str], str], src: str = "measurements.csv") -> list[str]:
    return _fit(w, source=w.text("measurements.csv", edit, src=src))


def _meas_data(w: Work, data: str | bytes) -> list[str]:
    return _fit(w, source=w.write("measurements.csv", data))


def _all_rows(edit: Callable[[list[str], list[str]], None]) -> Callable[[str], str]:
    """An edit of a CSV text: ``edit(header, row)`` on every data row."""

    def apply(text: str) -> str:
        rows = list(csv.reader(io.StringIO(text)))
        for row in rows[1:]:
            edit(rows[0], row)
        return _csv(rows)

    return apply


def _set_all(column: str, value: str) -> Callable[[list[str], list[str]], None]:
    def edit(header: list[str], row: list[str]) -> None:
        row[header.index(column)] = value

    return edit


def fit_cases() -> list[Case]:
    f = "fit-"
    return [
        # the measurements
        Case(f + "source-missing", lambda w: _fit(w, source=w / "nomeas.csv"), "nomeas.csv"),
        Case(f + "source-directory-without-measurements", lambda w: _fit(w, source=w.mkdir("empty")), "measurements.csv"),
        Case(f + "source-measurements-is-a-directory",
             lambda w: _fit(w, source=w.mkdir("run/measurements.csv").parent), "measurements.csv"),
        Case(f + "source-empty-file", lambda w: _meas_data(w, ""), "measurements.csv"),
        Case(f + "source-header-only", lambda w: _meas(w, first_rows(0)), "measurements.csv"),
        Case(f + "source-one-row", lambda w: _meas(w, first_rows(1)), "measurements.csv"),
        Case(f + "source-two-rows", lambda w: _meas(w, first_rows(2)), "measurements.csv"),
        Case(f + "source-missing-column", lambda w: _meas(w, without_column("z_um")), "z_um"),
        Case(f + "source-text-cell", lambda w: _meas(w, cell(4, "x_um", "12,5 mm")), "x_um"),
        Case(f + "source-nan-cell", lambda w: _meas(w, cell(4, "y_um", "nan")), "y_um"),
        Case(f + "source-inf-cell", lambda w: _meas(w, cell(4, "dz_um", "-inf")), "dz_um"),
        Case(f + "source-empty-cell", lambda w: _meas(w, cell(4, "dx_um", "")), "dx_um"),
        Case(f + "source-short-row", lambda w: _meas(w, lambda t: t.replace("\n", "\n41,ok,1.0\n", 1)), "measurements.csv"),
        Case(f + "source-duplicate-pose", lambda w: _meas(w, cell(5, "pose", "3")), "pose"),
        Case(f + "source-pose-not-a-whole-number", lambda w: _meas(w, cell(5, "pose", "5.5")), "pose"),
        Case(f + "source-every-pose-failed", lambda w: _meas(w, _all_rows(_set_all("status", "failed"))), "ok"),
        Case(f + "source-binary-garbage", lambda w: _meas_data(w, GARBAGE), "measurements.csv"),
        Case(f + "source-bom-and-semicolons",
             lambda w: _meas_data(w, BOM + (w.good / "measurements.csv").read_text().replace(",", ";")), "measurements.csv"),
        Case(f + "source-utf16",
             lambda w: _meas_data(w, (w.good / "measurements.csv").read_text().encode("utf-16")), "measurements.csv"),
        Case(f + "source-is-a-cameras-json", lambda w: _fit(w, source=w.copy("cameras.json")), "cameras.json"),
        Case(f + "source-one-axis-still", lambda w: _meas(w, _all_rows(_set_all("dy_um", "4000.0"))), "dy"),
        Case(f + "source-identical-rows",
             lambda w: _meas(w, lambda t: t.splitlines()[0] + "\n" + "".join(
                 f"{k}," + t.splitlines()[1].split(",", 1)[1] + "\n" for k in range(1, 41))), "'dx'"),
        # options
        Case(f + "train-zero", lambda w: _fit(w, "--train", "0"), "--train"),
        Case(f + "train-more-than-the-poses", lambda w: _fit(w, "--train", "1000"), "train"),
        Case(f + "train-every-pose", lambda w: _fit(w, "--train", "40"), "train"),
        Case(f + "folds-one", lambda w: _fit(w, "--folds", "1"), "--folds"),
        Case(f + "folds-more-than-the-poses", lambda w: _fit(w, "--folds", "1000"), "folds"),
        Case(f + "penter-above-one", lambda w: _fit(w, "--penter", "2"), "penter"),
        Case(f + "penter-negative", lambda w: _fit(w, "--penter", "-0.1"), "penter"),
        Case(f + "penter-nan", lambda w: _fit(w, "--penter", "nan"), "penter"),
        Case(f + "premove-below-penter", lambda w: _fit(w, "--penter", "0.2", "--premove", "0.1"), "premove"),
        Case(f + "premove-not-a-number", lambda w: _fit(w, "--premove", "ten percent"), "--premove"),
        Case(f + "extra-unknown", lambda w: _fit(w, "--extra", "pressure"), "pressure"),
        Case(f + "extra-temperature-without-its-column",
             lambda w: _fit(w, "--temperature", source=w.copy("measurements-no-t.csv", "measurements.csv")), "temperature"),
        Case(f + "temperature-blank-cells",
             lambda w: [*_meas(w, cell(6, "temperature_c", "")), "--temperature"], "temperature"),
        Case(f + "temperature-text-cell",
             lambda w: [*_meas(w, cell(6, "temperature_c", "warm")), "--temperature"], "temperature_c"),
        Case(f + "temperature-with-the-matrix-model", lambda w: _fit(w, "--temperature", "--model", "matrix"), "polynomial"),
        Case(f + "model-unknown", lambda w: _fit(w, "--model", "cubic"), "--model"),
        Case(f + "select-unknown", lambda w: _fit(w, "--select", "best"), "--select"),
        Case(f + "seed-not-a-number", lambda w: _fit(w, "--folds", "5", "--seed", "x"), "--seed"),
        Case(f + "manipulator-empty-name", lambda w: _fit(w, "--manipulator", ""), "manipulator"),
        # --out, --cameras, --mat
        Case(f + "out-is-a-directory", lambda w: _fit(w, out=w.mkdir("outdir", "keep.txt")), "--out"),
        Case(f + "out-is-a-cameras-json", lambda w: _fit(w, out=w.copy("cameras.json")), "cameras.json"),
        Case(f + "out-is-a-text-file", lambda w: _fit(w, out=w.copy("notes.txt")), "notes.txt"),
        Case(f + "out-is-a-garbage-file", lambda w: _fit(w, out=w.write("calibration.json", GARBAGE)), "calibration.json"),
        Case(f + "out-future-version",
             lambda w: _fit(w, out=w.json("calibration.json", put(("format",), "microcal.calibration/2"))), "version"),
        Case(f + "out-parent-is-a-file", lambda w: _fit(w, out=w.copy("notes.txt") / "calibration.json"), "--out"),
        Case(f + "out-read-only-directory", lambda w: _fit(w, out=w.read_only("locked") / "calibration.json"), "--out",
             needs_permissions=True),
        Case(f + "cameras-missing-file", lambda w: _fit(w, "--cameras", str(w / "nocams.json")), "nocams.json"),
        Case(f + "cameras-is-a-csv-file", lambda w: _fit(w, "--cameras", str(w.copy("measurements.csv", "m2.csv"))), "m2.csv"),
        Case(f + "cameras-is-a-results-file", lambda w: _fit(w, "--cameras", str(w.copy("results.json"))), "results.json"),
        Case(f + "cameras-garbage", lambda w: _fit(w, "--cameras", str(w.write("cameras.json", GARBAGE))), "cameras.json"),
        Case(f + "mat-parent-is-a-file", lambda w: _fit(w, "--mat", str(w.copy("notes.txt") / "calibration.mat")), "--mat"),
        Case(f + "mat-is-a-directory", lambda w: _fit(w, "--mat", str(w.mkdir("matdir", "keep.txt"))), "--mat"),
        Case(f + "mat-is-the-calibration-file", lambda w: [*_fit(w), "--mat", str(w / "calibration.json")], "--mat"),
        Case(f + "mat-read-only-directory", lambda w: _fit(w, "--mat", str(w.read_only("locked") / "c.mat")), "--mat",
             needs_permissions=True),
    ]  # fmt: skip


def _solve(
    w: Work, *position: str, calibration: Path | None = None, extra: tuple[str, ...] = ()
) -> list[str]:
    cal = calibration if calibration is not None else w.copy("calibration.json")
    return ["solve", str(cal), *extra, *(position or ("3000", "2500", "1300"))]


def _cal(w: Work, *edits: Edit, src: str = "calibration.json") -> Path:
    return w.json("calibration.json", *edits, src=src)


def _second_manipulator(doc: Any) -> None:
    doc["manipulators"]["m2"] = doc["manipulators"]["m1"]


def solve_cases() -> list[Case]:
    s = "solve-"
    model = ("manipulators", "m1", "model")
    return [
        Case(s + "calibration-missing", lambda w: _solve(w, calibration=w / "nocal.json"), "nocal.json"),
        Case(s + "calibration-directory", lambda w: _solve(w, calibration=w.mkdir("caldir")), "caldir"),
        Case(s + "calibration-empty-file", lambda w: _solve(w, calibration=w.write("calibration.json", "")), "calibration.json"),
        Case(s + "calibration-binary-garbage", lambda w: _solve(w, calibration=w.write("calibration.json", GARBAGE)),
             "calibration.json"),
        Case(s + "calibration-truncated", lambda w: _solve(w, calibration=w.cut("calibration.json")), "calibration.json"),
        Case(s + "calibration-is-a-cameras-json", lambda w: _solve(w, calibration=w.copy("cameras.json")), "cameras.json"),
        Case(s + "calibration-is-a-results-file", lambda w: _solve(w, calibration=w.copy("results.json")), "results.json"),
        Case(s + "calibration-future-version",
             lambda w: _solve(w, calibration=_cal(w, put(("format",), "microcal.calibration/2"))), "version"),
        Case(s + "calibration-without-manipulators", lambda w: _solve(w, calibration=_cal(w, drop(("manipulators",)))),
             "manipulators"),
        Case(s + "calibration-no-manipulator", lambda w: _solve(w, calibration=_cal(w, put(("manipulators",), {}))),
             "manipulator"),
        Case(s + "calibration-model-kind-unknown", lambda w: _solve(w, calibration=_cal(w, put((*model, "kind"), "cubic"))),
             "kind"),
        Case(s + "calibration-coefficients-wrong-shape",
             lambda w: _solve(w, calibration=_cal(w, put((*model, "coefficients"), [[1.0, 2.0]]))), "coefficients"),
        Case(s + "calibration-coefficients-nan",
             lambda w: _solve(w, calibration=_cal(w, put((*model, "coefficients", 0, 0), float("nan")))), "coefficients"),
        Case(s + "calibration-coefficients-text",
             lambda w: _solve(w, calibration=_cal(w, put((*model, "coefficients", 0, 0), "one"))), "coefficients"),
        Case(s + "calibration-term-unknown",
             lambda w: _solve(w, calibration=_cal(w, put((*model, "terms", 1), "dq^2"))), "dq^2"),
        Case(s + "calibration-selected-not-booleans",
             lambda w: _solve(w, calibration=_cal(w, put((*model, "selected", 0, 0), "maybe"))), "selected"),
        Case(s + "calibration-covariance-missing", lambda w: _solve(w, calibration=_cal(w, drop((*model, "covariance")))),
             "covariance"),
        Case(s + "calibration-joints-unknown",
             lambda w: _solve(w, calibration=_cal(w, put((*model, "joints"), ["a", "b", "c"]))), "joints"),
        Case(s + "calibration-inputs-too-few",
             lambda w: _solve(w, calibration=_cal(w, put((*model, "inputs"), ["dx", "dy"]))), "inputs"),
        Case(s + "calibration-singular-model",
             lambda w: _solve(w, calibration=_cal(w, lambda d: d["manipulators"]["m1"]["model"].update(
                 coefficients=[[0.0] * len(d["manipulators"]["m1"]["model"]["terms"])] * 3)))),
        Case(s + "position-two-numbers", lambda w: _solve(w, "1", "2"), "position"),
        Case(s + "position-four-numbers", lambda w: _solve(w, "1", "2", "3", "4"), "position"),
        Case(s + "position-nan", lambda w: _solve(w, "3000", "nan", "1300"), "position"),
        Case(s + "position-inf", lambda w: _solve(w, "3000", "2500", "inf"), "position"),
        Case(s + "position-text", lambda w: _solve(w, "3000", "north", "1300"), "position_um"),
        Case(s + "position-missing", lambda w: ["solve", str(w.copy("calibration.json"))], "position_um"),
        Case(s + "position-outside-the-limits",
             lambda w: _solve(w, "1000000", "2500", "1300", extra=("--limits", "0:8000,0:8000,0:4800")), "limits"),
        Case(s + "limits-one-pair", lambda w: _solve(w, extra=("--limits", "0:8000")), "--limits"),
        Case(s + "limits-text", lambda w: _solve(w, extra=("--limits", "a:b,c:d,e:f")), "--limits"),
        Case(s + "limits-inverted", lambda w: _solve(w, extra=("--limits", "8000:0,0:8000,0:4800")), "--limits"),
        Case(s + "limits-inf", lambda w: _solve(w, extra=("--limits", "0:inf,0:8000,0:4800")), "--limits"),
        Case(s + "limits-empty", lambda w: _solve(w, extra=("--limits", "")), "--limits"),
        Case(s + "manipulator-unknown", lambda w: _solve(w, extra=("--manipulator", "m9")), "m9"),
        Case(s + "two-manipulators-none-named", lambda w: _solve(w, calibration=_cal(w, _second_manipulator)), "manipulator"),
        Case(s + "temperature-for-a-model-without-T", lambda w: _solve(w, extra=("--temperature", "22")), "temperature"),
        Case(s + "temperature-missing-for-a-T-model",
             lambda w: _solve(w, calibration=w.copy("calibration-t.json", "calibration.json")), "temperature"),
        Case(s + "temperature-nan",
             lambda w: _solve(w, calibration=w.copy("calibration-t.json", "calibration.json"), extra=("--temperature", "nan")),
             "temperature"),
        Case(s + "temperature-not-a-number", lambda w: _solve(w, extra=("--temperature", "warm")), "--temperature"),
    ]  # fmt: skip


def _evaluate(
    w: Work, *extra: str, calibration: Path | None = None, out: Path | None = None
) -> list[str]:
    cal = calibration if calibration is not None else w.copy("calibration.json")
    target = out if out is not None else w.copy("results.json")
    return ["evaluate", "--calibration", str(cal), *EVALUATE_QUICK, "--out", str(target), *extra]


def evaluate_cases() -> list[Case]:
    e = "evaluate-"
    return [
        Case(e + "calibration-option-missing", lambda w: ["evaluate", *EVALUATE_QUICK], "--calibration"),
        Case(e + "calibration-missing-file", lambda w: _evaluate(w, calibration=w / "nocal.json"), "nocal.json"),
        Case(e + "calibration-directory", lambda w: _evaluate(w, calibration=w.mkdir("caldir")), "caldir"),
        Case(e + "calibration-binary-garbage", lambda w: _evaluate(w, calibration=w.write("calibration.json", GARBAGE)),
             "calibration.json"),
        Case(e + "calibration-is-a-cameras-json", lambda w: _evaluate(w, calibration=w.copy("cameras.json")), "cameras.json"),
        Case(e + "calibration-without-cameras",
             lambda w: _evaluate(w, calibration=w.copy("calibration-no-cameras.json")), "--cameras"),
        Case(e + "calibration-one-camera", lambda w: _evaluate(w, calibration=_cal(w, drop(("cameras", "side")))), "side"),
        Case(e + "calibration-cameras-of-another-rig",
             lambda w: _evaluate(w, calibration=_cal(w, put(("cameras",), json.loads((w.good / "stereo.json").read_text())["cameras"]))),
             "top"),
        Case(e + "calibration-camera-K-missing",
             lambda w: _evaluate(w, calibration=_cal(w, drop(("cameras", "top", "K")))), "K"),
        Case(e + "test-unknown", lambda w: _evaluate(w, "--test", "speed"), "--test"),
        Case(e + "poses-unknown", lambda w: _evaluate(w, "--poses", "everywhere"), "--poses"),
        Case(e + "cycles-zero", lambda w: _evaluate(w, "--cycles", "0"), "--cycles"),
        Case(e + "frames-zero", lambda w: _evaluate(w, "--frames", "0"), "--frames"),
        Case(e + "settle-negative", lambda w: _evaluate(w, "--settle-s", "-1"), "--settle-s"),
        Case(e + "settle-nan", lambda w: _evaluate(w, "--settle-s", "nan"), "settle"),
        Case(e + "settle-inf", lambda w: _evaluate(w, "--settle-s", "inf"), "settle"),
        Case(e + "seed-negative", lambda w: _evaluate(w, "--seed", "-1"), "--seed"),
        Case(e + "seed-with-a-hardware-rig", lambda w: _evaluate(w, "--rig", str(w.copy("hardware.toml")), "--seed", "1"),
             "--seed"),
        Case(e + "rig-missing-file", lambda w: _evaluate(w, "--rig", str(w / "norig.toml")), "norig.toml"),
        Case(e + "rig-binary-garbage", lambda w: _evaluate(w, "--rig", str(w.write("myrig.toml", GARBAGE))), "myrig.toml"),
        Case(e + "rig-unknown-key-near-seed", lambda w: _evaluate(w, "--rig", str(w.write("myrig.toml", SIM_RIG + "sede = 2\n"))),
             "seed"),
        Case(e + "rig-override-drop-rate-above-one",
             lambda w: _evaluate(w, "--rig", str(w.write("myrig.toml", _override("top.faults", "drop_rate = 1.5")))),
             "drop_rate"),
        Case(e + "manipulator-unknown", lambda w: _evaluate(w, "--manipulator", "m9"), "m9"),
        Case(e + "out-is-a-directory", lambda w: _evaluate(w, out=w.mkdir("outdir", "keep.txt")), "--out"),
        Case(e + "out-is-a-cameras-json", lambda w: _evaluate(w, out=w.copy("cameras.json")), "--out"),
        Case(e + "out-is-a-text-file", lambda w: _evaluate(w, out=w.copy("notes.txt")), "--out"),
        Case(e + "out-future-version",
             lambda w: _evaluate(w, out=w.json("results.json", put(("format",), "microcal.results/2"))), "version"),
        Case(e + "out-parent-is-a-file", lambda w: _evaluate(w, out=w.copy("notes.txt") / "results.json"), "--out"),
        Case(e + "out-read-only-directory", lambda w: _evaluate(w, out=w.read_only("locked") / "results.json"), "--out",
             needs_permissions=True),
    ]  # fmt: skip


def _check(
    w: Work, *extra: str, calibration: Path | None = None, out: Path | None = None
) -> list[str]:
    cal = calibration if calibration is not None else w.copy("calibration.json")
    target = out if out is not None else w / "check.json"
    return ["check", "--calibration", str(cal), "--frames", "1", "--settle-s", "0",
            "--out", str(target), *extra]  # fmt: skip


def check_cases() -> list[Case]:
    c = "check-"
    device = ("manipulators", "m1", "device")
    return [
        Case(c + "calibration-option-missing", lambda w: ["check"], "--calibration"),
        Case(c + "calibration-missing-file", lambda w: _check(w, calibration=w / "nocal.json"), "nocal.json"),
        Case(c + "calibration-binary-garbage", lambda w: _check(w, calibration=w.write("calibration.json", GARBAGE)),
             "calibration.json"),
        Case(c + "calibration-is-a-cameras-json", lambda w: _check(w, calibration=w.copy("cameras.json")), "cameras.json"),
        Case(c + "calibration-without-cameras",
             lambda w: _check(w, calibration=w.copy("calibration-no-cameras.json")), "--cameras"),
        Case(c + "calibration-of-another-device",
             lambda w: _check(w, calibration=_cal(w, put(device, "SmarAct MCS2 MCS2-0042 channels 0,1,2"))),
             "MCS2-0042"),
        Case(c + "history-not-json",
             lambda w: (w.write("calibration.checks.jsonl", "{not json\n"), _check(w))[1], "calibration.checks.jsonl"),
        Case(c + "frames-zero", lambda w: _check(w, "--frames", "0"), "--frames"),
        Case(c + "alpha-too-large", lambda w: _check(w, "--alpha", "0.9"), "--alpha"),
        Case(c + "settle-nan", lambda w: _check(w, "--settle-s", "nan"), "settle"),
        Case(c + "seed-with-a-hardware-rig", lambda w: _check(w, "--rig", str(w.copy("hardware.toml")), "--seed", "1"),
             "--seed"),
        Case(c + "rig-missing-file", lambda w: _check(w, "--rig", str(w / "norig.toml")), "norig.toml"),
        Case(c + "out-is-a-directory", lambda w: _check(w, out=w.mkdir("outdir", "keep.txt")), "--out"),
        Case(c + "out-is-a-cameras-json", lambda w: _check(w, out=w.copy("cameras.json")), "--out"),
        Case(c + "out-is-a-text-file", lambda w: _check(w, out=w.copy("notes.txt")), "--out"),
        Case(c + "update-is-the-calibration",
             lambda w: _check(w, "--update", str(w / "calibration.json")), "--update"),
        Case(c + "update-is-a-text-file", lambda w: _check(w, "--update", str(w.copy("notes.txt"))), "--update"),
    ]  # fmt: skip


def _report(w: Work, *extra: str, run: Path | None = None) -> list[str]:
    run_dir = (
        run
        if run is not None
        else (w / "run" if (w / "run").exists() else w.copy("report-run", "run"))
    )
    return ["report", str(run_dir), *extra]


def _report_json(w: Work, name: str, *edits: Edit) -> list[str]:
    w.copy("report-run", "run")
    w.json(f"run/{name}", *edits, src=f"report-run/{name}")
    return _report(w)


def _report_file(w: Work, name: str, data: str | bytes) -> list[str]:
    w.copy("report-run", "run")
    w.write(f"run/{name}", data)
    return _report(w)


def _report_text(w: Work, name: str, edit: Callable[[str], str]) -> list[str]:
    w.copy("report-run", "run")
    w.text(f"run/{name}", edit, src=f"report-run/{name}")
    return _report(w)


def report_cases() -> list[Case]:
    r = "report-"
    top = ("cameras", "top")
    return [
        Case(r + "run-argument-missing", lambda w: ["report"], "run_dir"),
        Case(r + "run-missing", lambda w: _report(w, run=w / "norun"), "norun"),
        Case(r + "run-is-a-file", lambda w: _report(w, run=w.copy("notes.txt")), "run directory"),
        Case(r + "run-empty-directory", lambda w: _report(w, run=w.mkdir("empty")), "empty"),
        Case(r + "run-user-directory", lambda w: _report(w, run=w.mkdir("mydata", "notes.txt", "photo.jpg")), "mydata"),
        Case(r + "out-is-a-directory", lambda w: _report(w, "--out", str(w.mkdir("outdir", "keep.txt"))), "--out"),
        Case(r + "out-is-the-runs-commands", lambda w: (_report(w), _report(w, "--out", str(w / "run/commands.csv")))[1],
             "--out"),
        Case(r + "out-is-a-cameras-json", lambda w: _report(w, "--out", str(w.copy("cameras.json"))), "--out"),
        Case(r + "out-parent-is-a-file", lambda w: _report(w, "--out", str(w.copy("notes.txt") / "report.html")), "--out"),
        Case(r + "out-read-only-directory", lambda w: _report(w, "--out", str(w.read_only("locked") / "report.html")),
             "--out", needs_permissions=True),
        Case(r + "default-out-is-a-directory",
             lambda w: (w.copy("report-run", "run"), _replace_with_directory(w / "run/report.html"), _report(w))[2],
             "report.html"),
        Case(r + "cameras-garbage", lambda w: _report_file(w, "cameras.json", GARBAGE), "cameras.json"),
        Case(r + "cameras-future-version", lambda w: _report_json(w, "cameras.json", put(("format",), "microcal.cameras/2")),
             "version"),
        Case(r + "cameras-K-missing", lambda w: _report_json(w, "cameras.json", drop((*top, "K"))), "K"),
        Case(r + "cameras-K-text", lambda w: _report_json(w, "cameras.json", put((*top, "K"), "identity")), "K"),
        Case(r + "cameras-not-objects", lambda w: _report_json(w, "cameras.json", put(("cameras",), [1, 2])), "cameras"),
        Case(r + "cameras-residuals-wrong-shape",
             lambda w: _report_json(w, "cameras.json", put((*top, "residuals_px"), {"v1.png": [[1.0, 2.0]]})), "residuals_px"),
        Case(r + "calibration-garbage", lambda w: _report_file(w, "calibration.json", GARBAGE), "calibration.json"),
        Case(r + "calibration-future-version",
             lambda w: _report_json(w, "calibration.json", put(("format",), "microcal.calibration/2")), "version"),
        Case(r + "calibration-validation-text",
             lambda w: _report_json(w, "calibration.json", put(("manipulators", "m1", "validation", "n_fit"), "many")), "n_fit"),
        Case(r + "results-garbage", lambda w: _report_file(w, "results.json", GARBAGE), "results.json"),
        Case(r + "results-future-version", lambda w: _report_json(w, "results.json", put(("format",), "microcal.results/2")),
             "version"),
        Case(r + "results-section-wrong-type", lambda w: _report_json(w, "results.json", put(("pose_accuracy",), 5)),
             "pose_accuracy"),
        Case(r + "results-figure-text",
             lambda w: _report_json(w, "results.json", put(("pose_accuracy", "vision", "optimal", "mean_ap_p_um"), "small")),
             "mean_ap_p_um"),
        Case(r + "measurements-text-cell", lambda w: _report_text(w, "measurements.csv", cell(2, "x_um", "far")), "x_um"),
        Case(r + "measurements-missing-column",
             lambda w: _report_text(w, "measurements.csv", without_column("status")), "status"),
        Case(r + "commands-binary-garbage", lambda w: _report_file(w, "commands.csv", GARBAGE), "commands.csv"),
        Case(r + "run-json-array", lambda w: _report_file(w, "run.json", "[]"), "run.json"),
        Case(r + "run-json-future-version", lambda w: _report_json(w, "run.json", put(("format",), "microcal.run/2")),
             "version"),
        Case(r + "run-json-rig-not-an-object", lambda w: _report_json(w, "run.json", put(("rig",), 5)), "rig"),
        Case(r + "journal-is-a-directory",
             lambda w: (w.copy("report-run", "run"), _replace_with_directory(w / "run/journal.jsonl"), _report(w))[2],
             "journal"),
    ]  # fmt: skip


ONE_CAMERA_RIG = """driver = "hardware"
[manipulator]
kind = "smaract-mcs2"
address = "192.168.1.200"
channels = { x = 0, y = 1, z = 2 }
limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }
[cameras.scope]
kind = "aravis"
address = "192.168.1.11"
"""


def _scope(w: Work, *extra: str, out: Path | None = None) -> list[str]:
    target = out if out is not None else w / "scope.json"
    return ["scope-calibrate", "--objective", "40x", "--out", str(target), *extra]


def scope_cases() -> list[Case]:
    s = "scope-calibrate-"
    return [
        Case(s + "objective-missing", lambda w: ["scope-calibrate"], "--objective"),
        Case(s + "objective-bad-name", lambda w: ["scope-calibrate", "--objective", "40x/oil"], "--objective"),
        Case(s + "objective-not-simulated", lambda w: ["scope-calibrate", "--objective", "63x"], "63x"),
        Case(s + "rig-missing-file", lambda w: _scope(w, "--rig", str(w / "norig.toml")), "norig.toml"),
        Case(s + "rig-one-camera-without-focus",
             lambda w: _scope(w, "--rig", str(w.write("scope.toml", ONE_CAMERA_RIG))), "focus"),
        Case(s + "rig-without-microscope",
             lambda w: _scope(w, "--rig", str(w.copy("hardware.toml")), "--target", "dotgrid:5x5:10:5"), "microscope"),
        Case(s + "target-garbage", lambda w: _scope(w, "--target", "dotgrid:many"), "target"),
        Case(s + "um-per-px-negative", lambda w: _scope(w, "--um-per-px", "-1"), "--um-per-px"),
        Case(s + "out-is-a-directory", lambda w: _scope(w, out=w.mkdir("outdir", "keep.txt")), "--out"),
        Case(s + "out-is-a-cameras-json", lambda w: _scope(w, out=w.copy("cameras.json")), "--out"),
        Case(s + "out-future-version",
             lambda w: _scope(w, out=w.write("scope.json", '{"format": "microcal.scope/2", "objectives": {}}')),
             "version"),
    ]  # fmt: skip


def cli_cases() -> list[Case]:
    return [
        Case("cli-unknown-command", lambda w: ["calibrate"], "calibrate"),
        Case("cli-command-typo", lambda w: ["mesure", str(w.root)], "mesure"),
        Case("cli-unknown-root-option", lambda w: ["--verbose", "demo"], "--verbose"),
    ]


CASES: list[Case] = [
    *cli_cases(),
    *demo_cases(),
    *stereo_cases(),
    *acquire_cases(),
    *measure_cases(),
    *fit_cases(),
    *solve_cases(),
    *evaluate_cases(),
    *report_cases(),
    *check_cases(),
    *scope_cases(),
]


def cases_per_command(cases: list[Case] = CASES) -> dict[str, int]:
    """How many cases exercise each command, in workflow order."""
    counts = Counter(case.command for case in cases)
    return {command: counts[command] for command in COMMANDS if counts[command]}


# --- running one case ----------------------------------------------------------------------
class CaseTimeout(BaseException):
    """A case ran longer than :data:`CASE_TIMEOUT_S` (a BaseException: nothing catches it)."""


@dataclass(frozen=True)
class Snapshot:
    """The files (by SHA-256) and directories under a directory."""

    files: dict[str, str]
    dirs: set[str]

    @classmethod
    def of(cls, root: Path) -> Snapshot:
        files: dict[str, str] = {}
        dirs: set[str] = set()
        for path in root.rglob("*"):
            rel = str(path.relative_to(root))
            if path.is_dir() and not path.is_symlink():
                dirs.add(rel)
            elif path.is_file():
                files[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
        return cls(files, dirs)


def _is_temporary(name: str) -> bool:
    lower = name.lower()
    return (
        ".tmp" in lower
        or lower.startswith(("tmp", ".~", "~$"))
        or lower.endswith(("~", ".part", ".partial", ".swp"))
    )


def _names(message: str, what: str) -> bool:
    """Whether the message holds ``what`` as a whole word (``board``, not ``chessboard``)."""
    return re.search(rf"(?<![A-Za-z0-9_]){re.escape(what)}(?![A-Za-z0-9_])", message) is not None


def _where_raised(exc: BaseException) -> str:
    """``Type: message`` and the innermost frame in microcal's source where it was raised."""
    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if f"{os.sep}microcal{os.sep}" in f.filename]
    place = ""
    if ours:
        f = ours[-1]
        rel = f.filename.split(f"{os.sep}src{os.sep}")[-1]
        place = f" at {rel}:{f.lineno} in {f.name}"
    text = str(exc).splitlines()[0][:200] if str(exc) else ""
    return f"{type(exc).__name__}: {text}{place}"


@pytest.fixture
def case_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A fresh directory with a neutral name (the message is searched, not the path)."""
    path = tmp_path_factory.mktemp("c", numbered=True)
    yield path
    for p in [path, *path.rglob("*")]:  # give back permissions a case took away
        if p.is_dir() and not p.is_symlink():
            p.chmod(0o755)


def _run_with_timeout(argv: list[str]) -> Result:
    def expire(signum: int, frame: FrameType | None) -> None:
        raise CaseTimeout(f"still running after {CASE_TIMEOUT_S:g} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, CASE_TIMEOUT_S)
    try:
        return runner.invoke(app, argv)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def check_refusal(case: Case, work: Work) -> list[str]:
    """Run a case; what it broke of the promise (empty: it kept it)."""
    argv = case.setup(work)
    before = Snapshot.of(work.root)
    try:
        result = _run_with_timeout(argv)
    except CaseTimeout as exc:
        after = Snapshot.of(work.root)
        return [f"timed out ({exc})", *_file_problems(before, after)]
    after = Snapshot.of(work.root)
    problems = []
    stderr, stdout = result.stderr, result.stdout
    if result.exit_code != 2:
        problems.append(f"exit code {result.exit_code}")
    exc = result.exception
    if exc is not None and not isinstance(exc, SystemExit):
        problems.append(f"raised {_where_raised(exc)}")
    lines = stderr.strip().splitlines()
    if len(lines) != 1:
        shown = " | ".join(line[:160] for line in lines[:3])
        problems.append(f"{len(lines)} lines on stderr: {shown!r}")
    if lines and not lines[0].startswith(ERROR_PREFIX):
        problems.append(f"stderr does not start with {ERROR_PREFIX!r}: {lines[0][:160]!r}")
    if "Traceback" in stdout + stderr + result.output:
        problems.append("a traceback in the output")
    if case.expect is not None and lines:
        message = lines[0].replace(str(work.root), "<dir>")
        if not _names(message, case.expect):
            problems.append(f"the message does not name {case.expect!r}: {lines[0][:240]!r}")
    if problems and result.exit_code == 2 and lines:
        problems.append(f"stderr: {lines[0][:240]!r}")
    if result.exit_code == 0:
        problems.append(
            f"stdout: {stdout.strip().splitlines()[-1][:160]!r}" if stdout.strip() else "no output"
        )
    return problems + _file_problems(before, after)


def _file_problems(before: Snapshot, after: Snapshot) -> list[str]:
    problems = []
    changed = sorted(f for f, h in before.files.items() if f in after.files and after.files[f] != h)
    deleted = sorted(f for f in before.files if f not in after.files)
    gone = sorted(d for d in before.dirs if d not in after.dirs)
    temporary = sorted(
        f for f in set(after.files) - set(before.files) if _is_temporary(Path(f).name)
    )
    for what, names in (("changed", changed), ("deleted", deleted), ("directory removed", gone),
                        ("temporary file left", temporary)):  # fmt: skip
        if names:
            problems.append(f"{what}: {', '.join(names[:5])}{' ...' if len(names) > 5 else ''}")
    return problems


# --- the tests -----------------------------------------------------------------------------
@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input_is_refused_in_one_line(
    case: Case, good: Good, case_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    if case.needs_permissions and os.geteuid() == 0:
        pytest.skip("root ignores file permissions")
    monkeypatch.chdir(case_dir)  # default outputs (calibration.json, results.json) land here
    work = Work(case_dir, good)
    try:
        problems = check_refusal(case, work)
    finally:
        work.release()
    assert not problems, f"{case.id}: " + "; ".join(problems)


def test_case_ids_are_unique_and_name_their_command() -> None:
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids)), [i for i, n in Counter(ids).items() if n > 1]
    for case in CASES:
        assert case.command in COMMANDS, case.id


def test_the_corpus_covers_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    counts = cases_per_command()
    with capsys.disabled():
        print("\nbad-input cases per command: " + ", ".join(f"{c} {n}" for c, n in counts.items())
              + f"; total {sum(counts.values())}")  # fmt: skip
    assert set(WORKFLOW) <= set(counts), sorted(set(WORKFLOW) - set(counts))
    assert sum(counts.values()) >= 170
