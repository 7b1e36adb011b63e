"""The public surface: ``import microcal`` is light, and every public name resolves."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

import microcal

# what a bare ``import microcal`` must not load (the edges' libraries and the numerical stack)
HEAVY = ("pydantic", "matplotlib", "typer", "jinja2", "cv2", "rich", "tifffile", "scipy")


def _modules_after(code: str, cwd: Path) -> list[str]:
    """The modules a fresh interpreter holds after running ``code``."""
    script = f"import sys, json\n{code}\nprint(json.dumps(sorted(sys.modules)))"
    result = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        check=True,
        cwd=cwd,
        stdin=subprocess.DEVNULL,
    )
    return list(json.loads(result.stdout))


def _heavy(modules: list[str]) -> list[str]:
    return sorted({m.split(".")[0] for m in modules} & set(HEAVY))


def test_import_microcal_loads_no_heavy_module(tmp_path):
    loaded = _modules_after("import microcal", tmp_path)
    assert "microcal" in loaded
    assert not _heavy(loaded), f"import microcal loads {_heavy(loaded)}"


def test_the_command_line_starts_without_the_report_and_file_readers(tmp_path):
    # `microcal --help` and every command's parsing: typer and rich, not what the work needs.
    loaded = _modules_after("import microcal.cli", tmp_path)
    slow = sorted({m.split(".")[0] for m in loaded} & {"pydantic", "matplotlib", "jinja2", "cv2",
                                                        "scipy", "tifffile"})  # fmt: skip
    assert not slow, f"import microcal.cli loads {slow}"


def test_a_lazy_name_loads_what_it_needs_on_first_use(tmp_path):
    loaded = _modules_after("import microcal\nmicrocal.load_calibration", tmp_path)
    assert "pydantic" in loaded
    assert "microcal.formats.calibration_file" in loaded


@pytest.mark.parametrize("name", microcal.__all__)
def test_every_public_name_resolves(name):
    value = getattr(microcal, name)
    assert value is not None
    if name != "__version__":
        assert value.__module__.startswith("microcal."), (name, value.__module__)


def test_star_import_gives_all_names():
    namespace: dict[str, object] = {}
    exec("from microcal import *", namespace)
    assert set(microcal.__all__) <= set(namespace)


def test_dir_lists_the_public_names_and_nothing_of_the_machinery():
    names = dir(microcal)
    assert set(microcal.__all__) <= set(names)
    assert "TYPE_CHECKING" not in names
    assert "_LAZY" not in names


def test_unknown_names_raise_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        _ = microcal.no_such_name  # type: ignore[attr-defined]
    assert not hasattr(microcal, "_private_probe")


def test_subpackages_load_on_attribute_access(tmp_path):
    loaded = _modules_after("import microcal\nmicrocal.geometry.CameraModel", tmp_path)
    assert "microcal.geometry" in loaded


def _root_imports() -> tuple[dict[str, str], set[str]]:
    """The root's type-checking imports (name -> module) and its eager imported names."""
    tree = ast.parse(Path(microcal.__file__).read_text(encoding="utf-8"))
    typed: dict[str, str] = {}
    eager: set[str] = set()
    for statement in tree.body:
        if isinstance(statement, ast.If) and getattr(statement.test, "id", "") == "TYPE_CHECKING":
            for node in statement.body:
                assert isinstance(node, ast.ImportFrom), ast.dump(node)
                assert node.level == 1, ast.dump(node)
                typed.update((alias.name, node.module or "") for alias in node.names)
        elif isinstance(statement, ast.ImportFrom) and statement.level == 1:
            eager.update(alias.name for alias in statement.names)
    return typed, eager


def test_the_lazy_table_matches_the_type_checking_imports_and_all():
    typed, eager = _root_imports()
    lazy = microcal._LAZY
    assert lazy == typed, "microcal._LAZY and the root's `if TYPE_CHECKING:` imports differ"
    assert set(microcal.__all__) == set(lazy) | eager
