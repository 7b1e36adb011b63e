"""README.md: its first screen (what microcal does, two commands, a picture) and that every
command it names exists: `microcal` subcommands checked against the typer app, each command
line parsed with its options, `make` targets against the Makefile, links against the files;
its Python example runs."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import typer.main

from microcal.cli import app

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
FIRST_SCREEN = "\n".join(README.splitlines()[:40])
FENCE = re.compile(r"^```([a-z]*)\n(.*?)^```", re.MULTILINE | re.DOTALL)
SHELL = ("sh", "bash", "shell", "console", "")
# `microcal NAME` where NAME is a word: the command, not `microcal.triangulate` nor `--help`
MICROCAL_COMMAND = re.compile(r"(?<![\w.-])microcal[ \t]+([a-z][a-z0-9-]*)")
MAKE_TARGET = re.compile(r"(?<![\w.-])make[ \t]+([a-z]+)\b")


def _code() -> list[str]:
    """The README's shell blocks and its inline code spans (outside the blocks)."""
    blocks = [body for lang, body in FENCE.findall(README) if lang in SHELL]
    prose = FENCE.sub("", README)
    return blocks + re.findall(r"`([^`\n]+)`", prose)


def _command_lines() -> list[str]:
    """Every `microcal ...` line of the shell blocks, continuations joined, comments dropped."""
    lines = []
    for lang, body in FENCE.findall(README):
        if lang in SHELL:
            for line in body.replace("\\\n", " ").splitlines():
                line = line.split(" #")[0].strip()
                if line.startswith("microcal "):
                    lines.append(line)
    return lines


def _subcommands():
    """The app's commands by name, as the command line registers them."""
    return typer.main.get_command(app).commands


def test_first_code_block_is_exactly_make_demo_and_make_test():
    lang, body = FENCE.findall(README)[0]
    assert lang in SHELL
    commands = [line.split("#")[0].strip() for line in body.splitlines()]
    assert [c for c in commands if c] == ["make demo", "make test"]
    assert "```" + lang + "\n" + body in FIRST_SCREEN, "the two commands are on the first screen"


def test_first_screen_has_the_requirements_and_a_picture_that_exists():
    assert "Python 3.11" in FIRST_SCREEN
    assert "package index" in FIRST_SCREEN
    images = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", FIRST_SCREEN)
    assert images, "no picture on the first screen"
    for image in images:
        path = ROOT / image
        assert path.is_file(), image
        assert path.stat().st_size < 200_000, f"{image}: keep the picture small"


def test_every_microcal_command_named_is_a_subcommand():
    named = {name for code in _code() for name in MICROCAL_COMMAND.findall(code)}
    assert named, "the README names no microcal command"
    unknown = named - set(_subcommands())
    assert not unknown, f"not microcal subcommands: {sorted(unknown)}"


@pytest.mark.parametrize("line", _command_lines())
def test_every_command_line_parses(line):
    name, *args = shlex.split(line)[1:]
    command = _subcommands()[name]
    command.make_context(name, args)  # raises on an unknown option or a bad value


def test_every_make_target_named_exists():
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    targets = set(re.findall(r"^([a-z]+):", makefile, re.MULTILINE))
    named = {name for code in _code() for name in MAKE_TARGET.findall(code)}
    assert {"demo", "test", "docs"} <= named
    assert named <= targets, f"not Makefile targets: {sorted(named - targets)}"


def test_every_relative_link_exists():
    links = re.findall(r"\]\(([^)\s#]+)(?:#[^)]*)?\)", README)
    local = [link for link in links if "://" not in link]
    assert local
    missing = [link for link in local if not (ROOT / link).exists()]
    assert not missing


def test_the_python_example_runs(capsys):
    blocks = [body for lang, body in FENCE.findall(README) if lang == "python"]
    assert blocks
    for body in blocks:
        exec(compile(body, "README.md", "exec"), {})
    assert "4000." in capsys.readouterr().out
