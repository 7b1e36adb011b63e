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
- A module's layer is that of its package (the first part of its dotted name): every
  package has one layer, so two packages never import each other.
- Within a package, modules import each other without cycles (``test_no_import_cycles``).
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

# package (or top-level module) -> layer number: every package has exactly one layer
LAYERS = {
    "errors": 0,
    "_validation": 0,
    "_parallel": 0,
    "_version": 0,
    "json_value": 0,
    "journal_record": 0,
    "geometry": 1,
    "kinematics": 1,
    "metrics": 1,
    "thesis": 1,
    "vision": 2,
    "devices": 3,
    "sim": 4,
    "formats": 5,
    "control": 6,
    "procedures": 7,
    "experiments": 8,
    "report": 9,
    "workflows": 10,
    "cli": 11,
    "ui": 11,
    "__main__": 11,
}
_NUMERIC = {"numpy", "scipy"}
_VISION = _NUMERIC | {"cv2"}
_FILES = _VISION | {"pydantic", "tifffile"}
# third-party packages each layer may use
ALLOWED_THIRD_PARTY = {
    0: {"numpy"},
    1: _NUMERIC,
    2: _VISION,
    3: _VISION,
    4: _VISION,
    5: _FILES,
    6: _VISION,
    7: _VISION,
    8: _VISION,
    9: _FILES | {"matplotlib", "jinja2", "rich"},
    10: _FILES | {"matplotlib", "jinja2", "rich"},
    11: _FILES | {"matplotlib", "jinja2", "rich", "typer"},
}
# the station page's server (microcal.ui, an edge beside the command line): its web libraries,
# an optional extra (microcal[ui]), in that package alone
PACKAGE_LIBRARIES = {"ui": {"starlette", "uvicorn"}}
STDLIB_OK = set(sys.stdlib_module_names)
# optional hardware libraries (extras), each only in its own driver module
DRIVER_LIBRARIES = {
    "devices.aravis_camera": {"gi", "aravis"},
    "devices.micromanager": {"pymmcore_plus"},
    "devices.twin_camera": {"pymmcore_plus"},
    "devices.twin_stages": {"pymmcore_plus"},
    "devices.mm_tip_stage": {"pymmcore_plus"},
}

# The command line (microcal.cli) parses, calls one workflow and prints: besides itself it
# imports only the workflows, the report's printing and the errors it turns into one line.
CLI = "cli"
CLI_MAY_IMPORT = ("cli", "workflows", "report", "errors", "_version", "ui")


class Import(NamedTuple):
    target: str  # internal: dotted name relative to the package ("" for the root); else absolute
    internal: bool
    line: int


def layer_of(rel: str) -> int:
    """The layer of a module's package (the first part of its dotted name)."""
    if rel == ROOT:
        return ROOT_LAYER
    top = rel.split(".")[0]
    if top not in LAYERS:
        raise AssertionError(f"module microcal.{rel} is not assigned to a layer in this test")
    return LAYERS[top]


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
                and top not in PACKAGE_LIBRARIES.get(rel.split(".")[0], set())
            ):
                problems.append(
                    f"microcal.{rel or '__init__'}:{line} (layer {own}) imports third-party {top}"
                )
    assert not problems, "\n".join(problems)


def test_the_cli_only_calls_workflows_and_prints():
    problems = []
    cli_modules = [
        (path, rel) for path, rel in modules() if rel == CLI or rel.startswith(CLI + ".")
    ]
    assert cli_modules, "no microcal.cli module found"
    for path, rel in cli_modules:
        for target, internal, line in imports(path, rel):
            if internal and target.split(".")[0] not in CLI_MAY_IMPORT:
                problems.append(f"  {path.relative_to(PACKAGE.parent)}:{line}: microcal.{target}")
    assert not problems, (
        "the command line parses, calls one workflow and prints; these imports belong in a "
        "workflow (microcal.workflows):\n" + "\n".join(problems)
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
    """At most 70 lines per module on average and 110 in any one (a command grows the budget,
    not a command's logic), and no function of it over 40 lines (decorators included)."""
    files = sorted((PACKAGE / "cli").glob("*.py"))
    sizes = {f.name: len(f.read_text(encoding="utf-8").splitlines()) for f in files}
    lines = sum(sizes.values())
    assert lines <= 70 * len(files), f"microcal.cli has {lines} lines; move logic to a workflow"
    big = {name: n for name, n in sizes.items() if n > 110}
    assert not big, f"command modules over 110 lines: {big}; move logic to a workflow"
    long = []
    for f in files:
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef):
                start = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                if node.end_lineno is not None and node.end_lineno - start + 1 > 40:
                    long.append(f"{f.name}:{node.name} ({node.end_lineno - start + 1} lines)")
    assert not long, "functions over 40 lines: " + ", ".join(long)


def _import_graph() -> dict[str, set[str]]:
    """Module -> the modules of microcal it imports (every import, lazy ones included)."""
    graph: dict[str, set[str]] = {}
    for path, rel in modules():
        graph[rel] = {t for t, internal, _ in imports(path, rel) if internal and t != rel}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_no_import_cycles():
    """No module reaches itself through imports, lazy imports inside functions included."""
    cycles = _cycles(_import_graph())
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_no_two_packages_import_each_other():
    """Packages (the first part of a module's name) form no cycle either."""
    packages: dict[str, set[str]] = {}
    for rel, targets in _import_graph().items():
        own = rel.split(".")[0]
        packages.setdefault(own, set()).update(
            t.split(".")[0] for t in targets if t and t.split(".")[0] != own
        )
    cycles = _cycles(packages)
    assert not cycles, "package cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_cycle_finder_finds_a_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_every_package_has_one_layer():
    assert all("." not in name for name in LAYERS), "a layer is assigned to a whole package"
    tops = {rel.split(".")[0] for _, rel in modules() if rel}
    assert tops <= set(LAYERS), f"packages without a layer: {sorted(tops - set(LAYERS))}"


FILES_ONLY = ("control", "procedures", "experiments", "workflows", "report", "cli")


def test_formats_reads_and_writes_files_only():
    """``formats`` imports no control, procedure, experiment, workflow, report or CLI module."""
    problems = [
        f"microcal.{rel}:{line} imports microcal.{target}"
        for path, rel in modules()
        if rel.split(".")[0] == "formats"
        for target, internal, line in imports(path, rel)
        if internal and target.split(".")[0] in FILES_ONLY
    ]
    assert not problems, "\n".join(problems)


def test_the_layer_check_sees_imports_inside_functions():
    source = "def f():\n    from ..workflows import demo\n"
    targets = _imports_of(source, "formats.thing", "formats/thing.py")
    assert targets == ["workflows.demo"]
    assert layer_of(targets[0]) > layer_of("formats.thing")
