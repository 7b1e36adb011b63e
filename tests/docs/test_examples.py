"""Every fenced code block of README.md and docs/*.md runs, so that a page that stops working
fails here.

Each block is classified by an HTML comment on the line(s) just before it,
``<!-- example: KIND -->``; a block without one fails :func:`test_every_block_is_classified`.

========================  =============================================================
KIND                      what the test does with the block
========================  =============================================================
``sim``                   runs it in a sandbox directory (``sh``: every ``microcal``
                          command in this process, exit code 0; ``python``: ``exec``;
                          ``toml``: a whole rig file, loaded and opened)
``twin``                  the same, with a digital twin running in the test's own network
                          namespace; a ``microcal twin`` line starts it (with its options)
                          and writes its rig file where ``--rig-out`` says, otherwise the
                          sandbox's setup names where the twin's rig file goes
``make``                  every line is ``make TARGET``: a target of the Makefile (CI runs
                          them)
``rig fragment``          ``toml`` tables of a rig file: loaded inside the few lines of a
                          whole rig the setup gives (:data:`FRAGMENTS`)
``file NAME``             the content of a file NAME, read by microcal's reader of it
``listing``, ``output``   a file listing or format sketch, what a command prints: not run
``not run: REASON``       cannot run here, for REASON (real hardware only); kept rare
========================  =============================================================

In ``sh`` blocks, ``\\`` continuations are joined and ``#`` comments dropped; a line is a
``microcal`` command, ``make TARGET``, a ``pip`` command or ``microcal ui`` (a server until
Ctrl-C, which tests/ui/test_serve.py starts; both checked, not run) or the start of
``for VAR in WORDS; do ... done`` (its body runs once per word, ``$VAR`` replaced); any other
line fails as unclassified. What a block reads that an earlier step of its page would have
made is put in its sandbox by :data:`SETUPS` (keyed by page and block number, from 0).

docs/guide.md's section 3 runs once per session, as written (170 poses), shared by its tests:
it is the proof that the guide works.
"""

from __future__ import annotations

import contextlib
import json
import re
import shlex
import shutil
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import typer.main

from support.cli import invoke_microcal

ROOT = Path(__file__).resolve().parents[2]
PAGES = ["README.md", *sorted(f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```([A-Za-z]*)[^\n]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)
MARKER = re.compile(r"<!--\s*example:\s*((?:(?!-->).)*?)\s*-->\s*\Z", re.DOTALL)
RUN_KINDS = ("sim", "twin")
NOT_RUN = ("listing", "output")
FOR_LOOP = re.compile(r"^for (\w+) in ([^;]+); do$")
#: The simulated seconds per wall second of a twin this test starts: at least this (a twin
#: line's --time-scale is raised to it), so that its moves and waits pass quickly.
TWIN_TIME_SCALE = 20.0


@dataclass(frozen=True)
class Block:
    """One fenced block: where it is, its language, its text and its marker's KIND."""

    page: str
    number: int
    line: int
    lang: str
    body: str
    kind: str | None

    @property
    def where(self) -> str:
        return f"{self.page} block {self.number} (line {self.line})"


def page_blocks(page: str, text: str) -> list[Block]:
    """The fenced blocks of one page, numbered from 0, with the KIND of the comment before."""
    blocks = []
    for number, m in enumerate(FENCE.finditer(text)):
        before = MARKER.search(text[: m.start()].rstrip())
        kind = before.group(1) if before else None
        line = text.count("\n", 0, m.start()) + 1
        blocks.append(Block(page, number, line, m.group(1), m.group(2), kind))
    return blocks


def all_blocks() -> list[Block]:
    return [b for p in PAGES for b in page_blocks(p, (ROOT / p).read_text(encoding="utf-8"))]


BLOCKS = all_blocks()


# --- the sandboxes ----------------------------------------------------------------------------

#: A simulated rig (the thesis platform, seed 0: the quick demo's), for blocks that name a rig
#: file of the simulator.
SIM_RIG = 'driver = "sim"\npreset = "thesis"\nseed = 0\n'
#: The simulated one-camera rig of docs/microscope.md (small frames).
PATCH_RIG = (
    'driver = "sim"\npreset = "patch"\nseed = 0\n[overrides]\nsize_px = [512, 512]\n'
    "supersample = 1\n"
)


@dataclass(frozen=True)
class Setup:
    """What a block's sandbox holds before it runs.

    files: path -> text; demo: path -> a file or folder of the quick demo's run (``.`` the run
    itself); synthetic_run: a folder given a measurements.csv of 170 synthetic poses; twin_rig:
    where the twin's rig file goes (a twin block without a ``microcal twin`` line); python_prelude:
    run before a Python block that continues an earlier one; serve_s: ``Twin.serve()`` returns
    after this long instead of at Ctrl-C.
    """

    files: dict[str, str] = field(default_factory=dict)
    demo: dict[str, str] = field(default_factory=dict)
    synthetic_run: str | None = None
    twin_rig: str | None = None
    python_prelude: str = ""
    serve_s: float | None = None


SETUPS: dict[tuple[str, int], Setup] = {
    # "Calibrate your rig" and "Check it" on a simulator rig file
    ("README.md", 1): Setup(files={"myrig.toml": SIM_RIG}),
    ("README.md", 2): Setup(
        files={"myrig.toml": SIM_RIG}, demo={"runs/a/calibration.json": "calibration.json"}
    ),
    # "After make demo"
    ("README.md", 3): Setup(demo={"demo-out": "."}),
    ("docs/acquisition.md", 0): Setup(files={"myrig.toml": SIM_RIG}),
    ("docs/compensation.md", 0): Setup(demo={"calibration.json": "calibration.json"}),
    ("docs/compensation.md", 1): Setup(demo={"runs/a": ".", "cameras.json": "cameras.json"}),
    ("docs/formats.md", 5): Setup(demo={"calibration.json": "calibration.json"}),
    ("docs/guide.md", 2): Setup(demo={"runs/a/calibration.json": "calibration.json"}),
    ("docs/guide.md", 3): Setup(
        files={"myrig.toml": SIM_RIG}, demo={"runs/a/calibration.json": "calibration.json"}
    ),
    ("docs/hardware.md", 0): Setup(twin_rig="myrig.toml"),
    ("docs/hardware.md", 1): Setup(twin_rig="myrig.toml"),
    # the station of the section: the simulator's platform of two manipulators and a positioner
    ("docs/hardware.md", 4): Setup(
        files={"station.toml": 'driver = "sim"\npreset = "thesis-platform"\nseed = 0\n'}
    ),
    ("docs/hardware.md", 7): Setup(twin_rig="myrig.toml"),
    ("docs/hardware.md", 10): Setup(serve_s=0.2),
    ("docs/identification.md", 0): Setup(synthetic_run="runs/a"),
    ("docs/simulator.md", 2): Setup(python_prelude="from microcal import sim\n"),
    # the commands on a one-camera rig: the patch demo's seed as a rig file
    ("docs/microscope.md", 6): Setup(
        files={"patch.toml": 'driver = "sim"\npreset = "patch"\nseed = 0\n'}
    ),
    # the one-camera rig of the block before
    ("docs/microscope.md", 8): Setup(files={"patch.toml": PATCH_RIG}),
}

#: docs/hardware.md's rig fragments: (lines before, lines after) that make each a whole rig.
_HEAD = 'driver = "hardware"\n'
_BOARD = 'board = "chessboard:4x3:400"\n'
_MCS2 = (
    'kind = "smaract-mcs2"\naddress = "192.168.1.200"\nchannels = { x = 0, y = 1, z = 2 }\n'
    "limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }\n"
)
_CAMERAS = (
    '[cameras.top]\nkind = "aravis"\naddress = "192.168.1.11"\n'
    '[cameras.side]\nkind = "aravis"\naddress = "192.168.1.12"\n'
)
FRAGMENTS: dict[tuple[str, int], tuple[str, str]] = {
    ("docs/hardware.md", 2): (_HEAD + _BOARD, _CAMERAS),
    ("docs/hardware.md", 3): (_HEAD + _BOARD + "[manipulator]\n" + _MCS2, _CAMERAS),
    # m2's board alone: its table goes on with the device's keys
    ("docs/hardware.md", 5): (_HEAD, _MCS2 + "[manipulator]\n" + _MCS2 + _CAMERAS),
    ("docs/hardware.md", 6): (_HEAD + _BOARD, "[manipulator]\n" + _MCS2 + _CAMERAS),
    # a one-camera microscope: its stage and focus
    ("docs/microscope.md", 4): (
        _HEAD + "[manipulator]\n" + _MCS2,
        '[cameras.scope]\nkind = "micromanager"\ndevice = "Camera"\n',
    ),
}

#: Blocks whose commands take more than a few seconds (whole acquisitions and evaluations).
COSTLY = {
    ("README.md", 1),
    ("docs/acquisition.md", 0),
    ("docs/compensation.md", 1),
    ("docs/guide.md", 1),
    ("docs/hardware.md", 4),
    ("docs/hardware.md", 8),
    ("docs/hardware.md", 9),
    ("docs/microscope.md", 0),
    ("docs/microscope.md", 5),
    ("docs/microscope.md", 6),
    ("docs/microscope.md", 8),
}


def prepare(sandbox: Path, setup: Setup, demo_run: Path | None) -> None:
    """Put the setup's files in the sandbox."""
    for name, text in setup.files.items():
        (sandbox / name).parent.mkdir(parents=True, exist_ok=True)
        (sandbox / name).write_text(text, encoding="utf-8")
    for name, source in setup.demo.items():
        assert demo_run is not None
        target, origin = sandbox / name, demo_run / source
        target.parent.mkdir(parents=True, exist_ok=True)
        if origin.is_dir():
            shutil.copytree(origin, target)
        else:
            shutil.copy2(origin, target)
    if setup.synthetic_run:
        from microcal.formats.measurements import write_measurements
        from microcal.sim.synthetic_run import synthetic_run

        run = synthetic_run(170, seed=21)
        folder = sandbox / setup.synthetic_run
        folder.mkdir(parents=True)
        write_measurements(folder / "measurements.csv", run.d_um, run.measured_um)


# --- running a block ---------------------------------------------------------------------------


def shell_commands(body: str) -> list[list[str]]:
    """The block's commands as words: continuations joined, comments dropped, loops unrolled."""
    lines = [line.strip() for line in body.replace("\\\n", " ").splitlines()]
    lines = [line for line in lines if line and not line.startswith("#")]
    commands: list[list[str]] = []
    i = 0
    while i < len(lines):
        loop = FOR_LOOP.match(lines[i])
        if loop is None:
            commands.append(shlex.split(lines[i], comments=True))
            i += 1
            continue
        end = lines.index("done", i)
        for word in loop.group(2).split():
            for line in lines[i + 1 : end]:
                commands.append(shlex.split(line.replace(f"${loop.group(1)}", word), comments=True))
        i = end + 1
    return [words for words in commands if words]


def makefile_targets() -> set[str]:
    text = (ROOT / "Makefile").read_text(encoding="utf-8")
    return set(re.findall(r"^([a-z]+):", text, re.MULTILINE))


def check_server_line(where: str, words: list[str]) -> None:
    """``microcal ui ...``: its options parse (it serves until Ctrl-C: not run here)."""
    import click

    from microcal.cli import app

    command = typer.main.get_command(app).commands[words[1]]  # type: ignore[attr-defined]
    try:
        command.make_context(words[1], list(words[2:]))
    except click.ClickException as exc:
        pytest.fail(f"{where}: `{' '.join(words)}`: {exc.format_message()}", pytrace=False)


def check_pip(where: str, words: list[str]) -> None:
    """A pip command names the project (``.``) or a wheel of it, and extras it has."""
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    extras = set(extras.get("optional-dependencies", {}))
    for word in words[words.index("pip") + 2 :]:
        if word.startswith("-"):
            continue
        named = re.fullmatch(r"(?:\.|microcal|dist/microcal-\*\.whl)(?:\[([\w,-]+)\])?", word)
        assert named, f"{where}: `{' '.join(words)}` names {word!r}, not the project"
        unknown = set((named.group(1) or "").split(",")) - extras - {""}
        assert not unknown, f"{where}: `{' '.join(words)}`: no extras {sorted(unknown)}"


class Twins:
    """The twins a block starts, each writing its rig file into the sandbox."""

    def __init__(self, stack: contextlib.ExitStack, sandbox: Path) -> None:
        self.stack, self.sandbox = stack, sandbox

    def start(self, preset="thesis", seed=0, host="127.0.0.1", port=0, frames_port=0,
              time_scale=1.0, rig_out=None, duration_s=None,
              sample="tissue") -> None:  # fmt: skip
        """As ``microcal twin`` with these options does, however faster (TWIN_TIME_SCALE)."""
        from microcal.formats.twin_rig_file import twin_rig_toml
        from microcal.sim.twin import Twin

        twin = Twin(preset, seed, host=host, mcs2_port=port, frames_port=frames_port,
                    time_scale=max(time_scale, TWIN_TIME_SCALE), sample=sample)  # fmt: skip
        self.stack.enter_context(twin)
        if rig_out is not None:
            path = self.sandbox / rig_out
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(twin_rig_toml(twin.rig_description(), str(rig_out)), encoding="utf-8")
            from microcal.formats.rig_file import load_rig

            load_rig(str(path))

    def start_from_line(self, where: str, words: list[str]) -> None:
        from microcal.cli import app

        command = typer.main.get_command(app).commands["twin"]  # type: ignore[attr-defined]
        try:
            params = command.make_context("twin", words[2:]).params
        except Exception as exc:
            pytest.fail(f"{where}: `{' '.join(words)}` does not parse: {exc}", pytrace=False)
        self.start(**params)


def run_shell(block: Block, sandbox: Path, twins: Twins | None) -> dict[str, str]:
    """Every command of an ``sh`` block, in order; the output of each ``microcal`` command."""
    outputs: dict[str, str] = {}
    for words in shell_commands(block.body):
        shown = " ".join(words)
        if words[-1] == "&":
            words = words[:-1]
            assert words[:2] == ["microcal", "twin"], f"{block.where}: `{shown}` in the background"
        if words[:2] == ["microcal", "twin"]:
            assert twins is not None, f"{block.where}: `{shown}` in a block not marked twin"
            twins.start_from_line(block.where, words)
        elif words[:2] == ["microcal", "ui"]:
            check_server_line(block.where, words)
        elif words[0] == "microcal":
            ran = invoke_microcal(*words[1:], cwd=sandbox)
            if ran.returncode != 0:
                said = (ran.stderr.strip() or ran.stdout.strip()).splitlines()[-5:]
                pytest.fail(f"{block.where}: `{shown}` exited {ran.returncode}:\n"
                            + "\n".join(said), pytrace=False)  # fmt: skip
            outputs[shown] = ran.stdout
        elif words[0] == "make":
            assert len(words) == 2, f"{block.where}: `{shown}`: one target"
            assert words[1] in makefile_targets(), f"{block.where}: no Makefile target {words[1]}"
        elif words[0] == "pip" or words[1:3] == ["-m", "pip"]:
            check_pip(block.where, words)
        else:
            pytest.fail(f"{block.where}: `{shown}` is not classified (microcal, make, pip "
                        "or a for loop); say here how to check it", pytrace=False)  # fmt: skip
    return outputs


def run_python(block: Block, sandbox: Path, setup: Setup) -> None:
    with contextlib.chdir(sandbox):
        namespace: dict[str, object] = {"__name__": "__main__"}
        exec(compile(setup.python_prelude, f"{block.where} prelude", "exec"), namespace)
        exec(compile(block.body, block.where, "exec"), namespace)


def run_toml(block: Block, sandbox: Path) -> None:
    """A whole rig file: loaded, and a simulator's opened (its overrides built)."""
    from microcal.devices.rig_spec import SimRigSpec
    from microcal.formats.rig_file import load_rig
    from microcal.workflows.rigs import open_rig

    path = sandbox / "rig.toml"
    path.write_text(block.body, encoding="utf-8")
    spec = load_rig(str(path))
    if isinstance(spec, SimRigSpec):
        with open_rig(spec):
            pass


@contextlib.contextmanager
def network_of_its_own() -> Iterator[None]:
    """The test's own network namespace (loopback only), or a skip saying why not."""
    from support.netns import own_network_namespace, unavailable_reason

    reason = unavailable_reason()
    if reason:
        pytest.skip(reason)
    pytest.importorskip("pymmcore_plus", reason="the twin's cameras need microcal[mm]")
    with own_network_namespace():
        yield


def run_block(block: Block, sandbox: Path, demo_run: Path | None, monkeypatch) -> dict[str, str]:
    """Run one block of kind sim or twin in its sandbox; the outputs of its commands."""
    setup = SETUPS.get((block.page, block.number), Setup())
    prepare(sandbox, setup, demo_run)
    with contextlib.ExitStack() as stack:
        twins = None
        if block.kind == "twin":
            stack.enter_context(network_of_its_own())
            twins = Twins(stack, sandbox)
            if setup.twin_rig is not None:
                twins.start(rig_out=setup.twin_rig)
            if setup.serve_s is not None:
                from microcal.sim.twin import Twin

                serve = Twin.serve
                monkeypatch.setattr(Twin, "serve", lambda self, duration_s=None, ready=None:
                                    serve(self, setup.serve_s, ready))  # fmt: skip
        if block.lang in ("sh", "bash"):
            return run_shell(block, sandbox, twins)
        if block.lang == "python":
            run_python(block, sandbox, setup)
        elif block.lang == "toml":
            run_toml(block, sandbox)
        else:
            pytest.fail(f"{block.where}: a {block.lang or 'plain'} block cannot be {block.kind}")
    return {}


# --- docs/guide.md, section 3: the whole calibration, once per session (first: the longest) ---

GUIDE = "docs/guide.md"


def _guide_block(number: int) -> Block:
    return next(b for b in BLOCKS if b.page == GUIDE and b.number == number)


def render_known_displacement_views(sandbox: Path, rig_file: str) -> None:
    """What the guide's first command reads: cal/top_NN.tiff, cal/side_NN.tiff (8 frames each)
    of the dot grid lifted 0 to 4 mm, and cal/steps.csv, rendered by the rig's simulator."""
    import tifffile

    from microcal.errors import FrameError
    from microcal.formats.rig_file import load_rig
    from microcal.sim import platform
    from microcal.sim.render import Placement
    from microcal.vision.targets import parse_target

    spec = load_rig(str(sandbox / rig_file))
    plat = platform(spec.preset, seed=spec.seed, overrides=dict(spec.overrides))  # type: ignore[union-attr]
    plat.scene.show_board = False
    steps_um = [0.0, 1000.0, 2000.0, 3000.0, 4000.0]
    (sandbox / "cal").mkdir()
    grid = parse_target("dotgrid:40x30:250")
    for k, z in enumerate(steps_um):
        plat.scene.fixed = Placement(grid, np.eye(3), np.array([0.0, 0.0, z]))
        for name, cam in plat.cameras.items():
            frames = []
            while len(frames) < 8:
                with contextlib.suppress(FrameError):  # the rig's frame drops: grab again
                    frames.append(cam.grab())
            tifffile.imwrite(sandbox / "cal" / f"{name}_{k:02d}.tiff", np.stack(frames))
    rows = "".join(f"0,0,{z}\n" for z in steps_um)
    (sandbox / "cal" / "steps.csv").write_text("dx_um,dy_um,dz_um\n" + rows, encoding="utf-8")


@pytest.fixture(scope="session")
def guide_run(tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """docs/guide.md's section 3 run as written, once per session, in a sandbox holding the
    rig file of section 1 (myrig.toml) and the calibration views of step 1: (sandbox, output
    of every command)."""
    from support.shared import made_once

    def make(root: Path) -> None:
        sandbox = root / "sandbox"
        sandbox.mkdir()
        (sandbox / "myrig.toml").write_text(_guide_block(0).body, encoding="utf-8")
        render_known_displacement_views(sandbox, "myrig.toml")
        outputs = run_shell(_guide_block(1), sandbox, None)
        (root / "outputs.json").write_text(json.dumps(outputs), encoding="utf-8")

    root = made_once(tmp_path_factory, "guide-section-3", make)
    return root / "sandbox", json.loads((root / "outputs.json").read_text(encoding="utf-8"))


@pytest.mark.slow
@pytest.mark.docs_long
def test_the_guide_calibrates_and_checks_the_simulated_rig(guide_run):
    sandbox, outputs = guide_run
    assert _guide_block(0).kind == "sim"
    assert _guide_block(1).kind == "sim"
    commands = list(outputs)
    acquire = next(c for c in commands if c.startswith("microcal acquire") and "--poses" in c)
    assert "--poses 170" in acquire
    for name in ("cameras.json", "measurements.csv", "calibration.json", "results.json",
                 "report.html", "check.json"):  # fmt: skip
        assert (sandbox / "runs" / "a" / name).is_file(), name
    report = re.sub(r"<[^>]+>", " ", (sandbox / "runs/a/report.html").read_text("utf-8"))
    report = re.sub(r"\s+", " ", report)
    assert "Stereo calibration Method: known displacements" in report, "no cameras found"
    assert "Method: -" not in report
    assert re.search(r"baseline \d+ µm", report), "the report shows no stereo baseline"
    first_check = next(c for c in commands if c.startswith("microcal check"))
    verdict = [
        line for line in outputs[first_check].splitlines() if not line.startswith("check poses")
    ]
    assert verdict[0].startswith("valid"), outputs[first_check]  # after the progress lines
    run_b = json.loads((sandbox / "runs/b/run.json").read_text("utf-8"))
    assert run_b["design"]["poses"] == 170


# --- the tests ---------------------------------------------------------------------------------


def test_every_block_is_classified():
    kinds = {"sim", "twin", "make", "rig fragment", "listing", "output"}
    wrong = []
    for b in BLOCKS:
        kind = b.kind or ""
        if not (kind in kinds or kind.startswith("file ") or re.fullmatch(r"not run: \S.*", kind)):
            wrong.append(f"{b.where}: no <!-- example: KIND --> before it" if b.kind is None
                         else f"{b.where}: unknown kind {kind!r}")  # fmt: skip
        elif kind in NOT_RUN and b.lang:
            wrong.append(f"{b.where}: a {b.lang} block is code, not a {kind}: run it")
        elif not b.lang and kind not in NOT_RUN and not kind.startswith("not run"):
            wrong.append(f"{b.where}: a block without a language is a listing or an output")
        elif kind == "rig fragment" and (b.page, b.number) not in FRAGMENTS:
            wrong.append(f"{b.where}: a rig fragment without its rig in FRAGMENTS")
    assert not wrong, "\n".join(wrong)
    assert len(BLOCKS) > 40, "fewer blocks than the pages hold: is FENCE right?"


def test_the_setups_name_blocks_that_run():
    run = {(b.page, b.number) for b in BLOCKS if b.kind in RUN_KINDS}
    assert set(SETUPS) <= run, sorted(set(SETUPS) - run)
    assert run >= COSTLY, sorted(COSTLY - run)


def test_not_run_stays_rare():
    not_run = [b.where for b in BLOCKS if (b.kind or "").startswith("not run")]
    assert len(not_run) <= 2, not_run


def _params(kinds: tuple[str, ...], costly: bool | None = None):
    chosen = [b for b in BLOCKS if b.kind in kinds]
    if costly is not None:
        chosen = [b for b in chosen if ((b.page, b.number) in COSTLY) is costly]
    return [pytest.param(b, id=f"{b.page}:{b.number}") for b in chosen]


def _uses_demo(block: Block) -> bool:
    return bool(SETUPS.get((block.page, block.number), Setup()).demo)


def _demo_run(block: Block, request) -> Path | None:
    """The quick demo's run (shared by the session: copied, never changed), if the block uses it."""
    return request.getfixturevalue("quick_demo")[0] if _uses_demo(block) else None


@pytest.mark.parametrize("block", _params(RUN_KINDS, costly=False))
def test_block_runs(block, request, tmp_path, monkeypatch):
    run_block(block, tmp_path, _demo_run(block, request), monkeypatch)


@pytest.mark.slow
@pytest.mark.docs_long
@pytest.mark.parametrize(
    "block", [p for p in _params(RUN_KINDS, costly=True) if p.id != "docs/guide.md:1"]
)
def test_costly_block_runs(block, request, tmp_path, monkeypatch):
    run_block(block, tmp_path, _demo_run(block, request), monkeypatch)


@pytest.mark.parametrize("block", _params(("make",)))
def test_make_block_names_targets(block):
    run_shell(block, Path("."), None)


@pytest.mark.parametrize("block", [b for b in BLOCKS if b.kind == "rig fragment"],
                         ids=lambda b: f"{b.page}:{b.number}")  # fmt: skip
def test_rig_fragment_loads_in_a_whole_rig(block, tmp_path):
    from microcal.formats.rig_file import load_rig

    before, after = FRAGMENTS[(block.page, block.number)]
    path = tmp_path / "rig.toml"
    path.write_text(before + block.body + after, encoding="utf-8")
    spec = load_rig(str(path))
    for name in re.findall(r"^\[manipulators\.(\w+)\]", block.body, re.MULTILINE):
        assert name in spec.manipulators, f"{block.where}: {name} not read"  # type: ignore[union-attr]


#: The readers of the files a ``file NAME`` block shows.
def _read_measurements(path: Path) -> None:
    from microcal.formats.measurements import read_measurements

    meas = read_measurements(path)
    assert meas.pose.size >= 1


FILE_READERS: dict[str, Callable[[Path], None]] = {"measurements.csv": _read_measurements}


@pytest.mark.parametrize("block", [b for b in BLOCKS if (b.kind or "").startswith("file ")],
                         ids=lambda b: f"{b.page}:{b.number}")  # fmt: skip
def test_file_block_is_read_by_its_reader(block, tmp_path):
    name = block.kind.removeprefix("file ")
    assert name in FILE_READERS, f"{block.where}: no reader for {name}"
    path = tmp_path / name
    path.write_text(block.body, encoding="utf-8")
    FILE_READERS[name](path)
