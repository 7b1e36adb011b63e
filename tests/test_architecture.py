"""The layers of docs/architecture.md: lower layers never import higher ones."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import microcal

PACKAGE = Path(microcal.__file__).parent

# module (or package) prefix -> layer number
LAYERS = {
    "errors": 0,
    "_validation": 0,
    "_version": 0,
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
    "procedures": 4,
    "formats": 5,
    "cli": 5,
    "report": 5,
    "__main__": 5,
}
# third-party packages each layer may use
ALLOWED_THIRD_PARTY = {
    0: {"numpy"},
    1: {"numpy", "scipy"},
    2: {"numpy", "scipy", "cv2"},
    3: {"numpy", "scipy", "cv2"},
    4: {"numpy", "scipy", "cv2"},
    5: {"numpy", "scipy", "cv2", "typer", "rich", "pydantic", "tifffile", "matplotlib", "jinja2"},
}
STDLIB_OK = set(sys.stdlib_module_names)
# optional hardware libraries (extras), each only in its own driver module
DRIVER_LIBRARIES = {
    "devices.aravis_camera": {"gi", "aravis"},
    "devices.micromanager": {"pymmcore_plus"},
}


def layer_of(rel: str) -> int:
    """The layer of the longest assigned prefix of a module's dotted name."""
    parts = rel.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in LAYERS:
            return LAYERS[".".join(parts[:n])]
    raise AssertionError(f"module microcal.{rel} is not assigned to a layer in this test")


def imports(path: Path, rel: str):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package_parts = rel.split(".")[:-1] if path.name != "__init__.py" else rel.split(".")
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, False
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package_parts[: len(package_parts) - (node.level - 1)]
                target = ".".join([*base, node.module] if node.module else base)
                yield target, True
            else:
                yield node.module or "", False


def test_every_module_respects_its_layer():
    problems = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = ".".join(path.relative_to(PACKAGE).with_suffix("").parts)
        if rel == "__init__":
            continue  # the package root re-exports the public surface
        rel = rel.removesuffix(".__init__")
        own = layer_of(rel)
        for target, internal in imports(path, rel):
            top = target.split(".")[0]
            if internal or top == "microcal":
                name = target.removeprefix("microcal.") if not internal else target
                if name and layer_of(name) > own:
                    problems.append(f"microcal.{rel} (layer {own}) imports {target}")
            elif (
                top not in STDLIB_OK
                and top not in ALLOWED_THIRD_PARTY[own]
                and top not in DRIVER_LIBRARIES.get(rel, set())
            ):
                problems.append(f"microcal.{rel} (layer {own}) imports third-party {top}")
    assert not problems, "\n".join(problems)
