"""What a test session makes once and its pytest-xdist workers share: a directory made by the
first worker that asks for it, while the others wait on a file lock, then read by all.

The directory lives beside the workers' own temporary directories (the parent of
``tmp_path_factory.getbasetemp()`` under xdist, that directory itself without it), so it
lasts as long as the session's temporary files and no longer. Tests must not change what it
holds: a test that changes a shared run works on a copy (``shutil.copytree``).
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

try:
    import fcntl
except ImportError:  # pragma: no cover - no fcntl (Windows): no xdist workers to wait for
    fcntl = None  # type: ignore[assignment]


def session_directory(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The directory every worker of this test session sees (the session's own without xdist)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    with open(path, "a", encoding="ascii") as fh:
        if fcntl is not None:
            fcntl.flock(fh, fcntl.LOCK_EX)  # released when the file closes
        yield


def made_once(
    tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], None]
) -> Path:
    """The shared directory ``name``: made by ``make(directory)`` once per test session.

    The first worker to ask makes it while holding ``name.lock``; the others wait for the lock
    and find it made (``name.done``). A make that fails is reported by every worker that
    asks, the first with its traceback, the others with its one line, and is not tried again.
    """
    root = session_directory(tmp_path_factory) / "shared"
    root.mkdir(exist_ok=True)
    path, done, failed = root / name, root / f"{name}.done", root / f"{name}.failed"
    with _locked(root / f"{name}.lock"):
        if failed.exists():
            pytest.fail(f"{name}, shared by the session, failed in another worker: "
                        f"{failed.read_text(encoding='utf-8')}", pytrace=False)  # fmt: skip
        if not done.exists():
            shutil.rmtree(path, ignore_errors=True)
            path.mkdir()
            try:
                make(path)
            except BaseException as exc:
                failed.write_text(f"{type(exc).__name__}: {exc}"[:2000], encoding="utf-8")
                raise
            done.touch()
    return path
