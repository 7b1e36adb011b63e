"""The layers of docs/architecture.md: lower layers never import higher ones.

How imports are counted:

- Every ``import`` statement of a module counts, at module level or inside a function (a
  lazy import is still a dependency), with one exception, in the package root only.
- The package root (``microcal/__init__.py``) is layer 0 for its eager imports. It re-exports
  the public surface lazily (PEP 562): imports inside its module-level ``def __getattr__`` and
  under its module-level ``if TYPE_CHECKING:`` never run on ``import microcal`` and are not
  counted. ``tests/test_public_surface.py`` checks what ``import microcal`` loads at run time.
- ``from X import a`` counts as an import of the module ``X.a`` when that is a module, and
  ``from microcal import name`` as an import of the module that the root's lazy table
  (``microcal._LAZY``) takes ``name`` from.
- A module's layer is that of the longest dotted prefix of its name in ``LAYERS``.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import microcal

PACKAGE = Path(microcal.__file__).parent
ROOT = ""  # the package root's name relative to the package
ROOT_LAYER = 0
# the root's lazy table: public name -> the module (relative to the package) that defines it
ROOT_LAZY: dict[str, str] = getattr(microcal, "_LAZY", {})

# module (or package) prefix -> layer number
LAYERS = {
    "errors": 0,
    "_validation": 0,
    "_parallel": 0,
    "_version": 0,
    "json_value": 0,
    "journal_record": 0,
    "thesis": 0,
    "thesis.figures": 0,
    "thesis.experiment": 0,
    "geometry": 1,
    "kinematics": 1,
    "metrics": 1,
    "thesis.cameras": 1,
    "vision": 2,
    "devices": 3,
    "sim": 3,
    "thesis.kinematics": 3,
    "control": 4,
    "procedures": 5,
    "formats": 6,
    "cli": 6,
    "report": 6,
    "__main__": 6,
}
# third-party packages each layer may use
ALLOWED_THIRD_PARTY = {
    0: {"numpy"},
    1: {"numpy", "scipy"},
    2: {"numpy", "scipy", "cv2"},
    3: {"numpy", "scipy", "cv2"},
    4: {"numpy", "scipy", "cv2"},
    5: {"numpy", "scipy", "cv2"},
    6: {"numpy", "scipy", "cv2", "typer", "rich", "pydantic", "tifffile", "matplotlib", "jinja2"},
}
STDLIB_OK = set(sys.stdlib_module_names)
# optional hardware libraries (extras), each only in its own driver module
DRIVER_LIBRARIES = {
    "devices.aravis_camera": {"gi", "aravis"},
    "devices.micromanager": {"pymmcore_plus"},
    "devices.twin_camera": {"pymmcore_plus"},
}

# The command line (microcal.cli, a module or a package) parses, calls procedures or formats
# functions, and prints: it does not import the math layer, nor the synthetic geometry or the
# command designs, directly (a procedure does that for it).
CLI = "cli"
CLI_FORBIDDEN = (
    "geometry",
    "kinematics",
    "metrics",
    "thesis.cameras",
    "sim.synthetic_geometry",
    "procedures.designs",
)


class Import(NamedTuple):
    target: str  # internal: dotted name relative to the package ("" for the root); else absolute
    internal: bool
    line: int


def layer_of(rel: str) -> int:
    """The layer of the longest assigned prefix of a module's dotted name."""
    if rel == ROOT:
        return ROOT_LAYER
    parts = rel.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in LAYERS:
            return LAYERS[".".join(parts[:n])]
    raise AssertionError(f"module microcal.{rel} is not assigned to a layer in this test")


def is_module(rel: str) -> bool:
    """Whether ``microcal.<rel>`` is a module or package in the source tree."""
    path = PACKAGE.joinpath(*rel.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def modules() -> Iterator[tuple[Path, str]]:
    """Every module of the package with its dotted name relative to the package."""
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield path, ".".join(parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _counted_statements(tree: ast.Module, rel: str) -> Iterator[ast.AST]:
    """The nodes whose imports count: all of them, less the root's lazy parts."""
    for statement in tree.body:
        if rel == ROOT and (
            (isinstance(statement, ast.FunctionDef) and statement.name == "__getattr__")
            or (isinstance(statement, ast.If) and _is_type_checking(statement.test))
        ):
            continue  # the root's lazy imports: they run on first use of a name, not on import
        yield from ast.walk(statement)


def _internal(base: str, name: str | None) -> str:
    """The module that ``from microcal.<base> import <name>`` takes from."""
    if name is not None:
        candidate = f"{base}.{name}" if base else name
        if is_module(candidate):
            return candidate
        if base == ROOT and name in ROOT_LAZY:
            return ROOT_LAZY[name]
    return base


def imports(path: Path, rel: str, source: str | None = None) -> Iterator[Import]:
    """The imports of module ``microcal.<rel>`` (``source``: its text, if not read from path)."""
    tree = ast.parse(source if source is not None else path.read_text(encoding="utf-8"))
    package = rel.split(".") if path.name == "__init__.py" else rel.split(".")[:-1]
    package = [p for p in package if p]
    for node in _counted_statements(tree, rel):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "microcal" or alias.name.startswith("microcal."):
                    yield Import(alias.name.removeprefix("microcal").lstrip("."), True, node.lineno)
                else:
                    yield Import(alias.name, False, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:
                up = package[: len(package) - (node.level - 1)]
                base = ".".join([*up, module] if module else up)
            elif module == "microcal" or module.startswith("microcal."):
                base = module.removeprefix("microcal").lstrip(".")
            else:
                yield Import(module, False, node.lineno)
                continue
            for target in dict.fromkeys(_internal(base, alias.name) for alias in node.names):
                yield Import(target, True, node.lineno)


def test_every_module_respects_its_layer():
    problems = []
    for path, rel in modules():
        own = layer_of(rel)
        for target, internal, line in imports(path, rel):
            top = target.split(".")[0]
            if internal:
                if layer_of(target) > own:
                    problems.append(
                        f"microcal.{rel or '__init__'}:{line} (layer {own}) imports "
                        f"microcal.{target} (layer {layer_of(target)})"
                    )
            elif (
                top not in STDLIB_OK
                and top not in ALLOWED_THIRD_PARTY[own]
                and top not in DRIVER_LIBRARIES.get(rel, set())
            ):
                problems.append(
                    f"microcal.{rel or '__init__'}:{line} (layer {own}) imports third-party {top}"
                )
    assert not problems, "\n".join(problems)


def test_the_cli_does_not_import_the_math_layer():
    problems = []
    cli_modules = [
        (path, rel) for path, rel in modules() if rel == CLI or rel.startswith(CLI + ".")
    ]
    assert cli_modules, "no microcal.cli module found"
    for path, rel in cli_modules:
        for target, internal, line in imports(path, rel):
            if internal and any(target == f or target.startswith(f + ".") for f in CLI_FORBIDDEN):
                problems.append(f"  {path.relative_to(PACKAGE.parent)}:{line}: microcal.{target}")
    assert not problems, (
        "the command line parses, calls procedures or formats functions and prints; these "
        "imports of the math layer, the synthetic geometry or the designs belong in a "
        "procedure:\n" + "\n".join(problems)
    )


def _imports_of(source: str, rel: str, filename: str = "__init__.py") -> list[str]:
    return [target for target, _, _ in imports(PACKAGE / filename, rel, source)]


def test_only_the_roots_getattr_and_type_checking_imports_are_exempt():
    source = (
        "from typing import TYPE_CHECKING\n"
        "from .errors import InputError\n"
        "if TYPE_CHECKING:\n"
        "    from .formats.calibration_file import Calibration\n"
        "def __getattr__(name):\n"
        "    from .geometry import triangulate\n"
        "    return triangulate\n"
        "def helper():\n"
        "    from .kinematics import KinematicModel\n"
    )
    assert _imports_of(source, ROOT) == ["typing", "errors", "kinematics"]
    # anywhere else, lazy and type-only imports count like the others
    assert _imports_of(source, "vision") == [
        "typing",
        "vision.errors",
        "vision.formats.calibration_file",
        "vision.geometry",
        "vision.kinematics",
    ]


def test_from_imports_resolve_submodules_and_the_roots_lazy_names():
    source = (
        "from . import figures\n"
        "from ..sim import synthetic_geometry, platform\n"
        "from microcal import triangulate, InputError\n"
        "import microcal.thesis.cameras\n"
    )
    assert _imports_of(source, "report.build", "report/build.py") == [
        "report.figures",
        "sim.synthetic_geometry",
        "sim",
        "geometry",
        "",
        "thesis.cameras",
    ]


def test_the_command_line_stays_a_thin_shell():
    """At most 780 lines in all, and no function of it over 40 lines (decorators included)."""
    files = sorted((PACKAGE / "cli").glob("*.py"))
    lines = sum(len(f.read_text(encoding="utf-8").splitlines()) for f in files)
    assert lines <= 780, f"microcal.cli has {lines} lines; move logic to procedures or formats"
    long = []
    for f in files:
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef):
                start = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                if node.end_lineno is not None and node.end_lineno - start + 1 > 40:
                    long.append(f"{f.name}:{node.name} ({node.end_lineno - start + 1} lines)")
    assert not long, "functions over 40 lines: " + ", ".join(long)
