"""Run a test inside its own network namespace with only a loopback interface.

The calling thread leaves the machine's network for a fresh namespace (``unshare``), brings
``lo`` up, and returns to where it was afterwards (``setns``). Sockets, threads and processes
made meanwhile belong to the namespace, so nothing a test sends can leave loopback, and two
tests may both use a device's fixed port. Needs CAP_SYS_ADMIN (root) and ``ip``; without them
the tests that use it are skipped with the reason.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import shutil
import subprocess
from collections.abc import Iterator

CLONE_NEWNET = 0x40000000


def unavailable_reason() -> str | None:
    """Why a network namespace cannot be made here, or None."""
    if shutil.which("ip") is None:
        return "needs the 'ip' command (Debian package iproute2) to bring up loopback"
    if os.geteuid() != 0:
        return "needs root (CAP_SYS_ADMIN) to create a network namespace; CI runs as root"
    return None


@contextlib.contextmanager
def own_network_namespace() -> Iterator[None]:
    """The calling thread in a new network namespace, loopback up, for the block."""
    libc = ctypes.CDLL(None, use_errno=True)
    home = os.open("/proc/thread-self/ns/net", os.O_RDONLY)
    try:
        if libc.unshare(CLONE_NEWNET) != 0:
            raise OSError(ctypes.get_errno(), "unshare(CLONE_NEWNET) failed")
        try:
            subprocess.run(["ip", "link", "set", "lo", "up"], check=True, timeout=10)
            yield
        finally:
            if libc.setns(home, CLONE_NEWNET) != 0:
                raise OSError(ctypes.get_errno(), "setns back to the original namespace failed")
    finally:
        os.close(home)
