"""A digital twin served for a test: in the test's own network namespace (loopback only), on
free ports, ended with the block; the test is skipped with the reason where no namespace can
be made (:mod:`support.netns`)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from microcal.formats.twin_rig_file import twin_rig_toml
from microcal.sim.twin import Twin

from .netns import own_network_namespace, unavailable_reason


def skip_without_namespace() -> None:
    """Skip the test, with the reason, where it cannot have a network namespace of its own."""
    reason = unavailable_reason()
    if reason:
        pytest.skip(reason)


@contextlib.contextmanager
def twin_on_loopback(rig_file: Path | None = None, **twin: Any) -> Iterator[Twin]:
    """A :class:`Twin` made with ``twin``'s arguments on free ports, in its own network
    namespace; its rig file written to ``rig_file`` when given."""
    skip_without_namespace()
    with own_network_namespace(), Twin(mcs2_port=0, frames_port=0, **twin) as served:
        if rig_file is not None:
            rig_file.write_text(twin_rig_toml(served.rig_description(), str(rig_file)))
        yield served
