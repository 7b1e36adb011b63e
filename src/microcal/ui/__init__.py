"""The station page: ``microcal ui`` serves a calibrated rig to a browser.

:mod:`.app` is the web application (Starlette, with the page's plain JavaScript in
``static/``), :mod:`.access` who may use it, :mod:`.serve` runs it; the work behind every
request is :class:`microcal.workflows.live.LiveStation`'s. Needs ``pip install
'microcal[ui]'``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["serve_page", "ui_available"]


def ui_available() -> str | None:
    """None when the page's libraries (Starlette, uvicorn) can be imported, else the reason."""
    try:
        import starlette  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as exc:
        return (
            f"the station page needs Starlette and uvicorn ({exc}); "
            "install: pip install 'microcal[ui]'"
        )
    return None


def serve_page(rig: str, calibration: str, announce: Callable[[str], None], **options: Any) -> None:
    """:func:`microcal.ui.serve.serve` once its libraries are there (``microcal ui``).

    Raises
    ------
    InputError
        Starlette or uvicorn missing (how to install them), or as ``serve``.
    """
    from ..errors import InputError

    if reason := ui_available():
        raise InputError(reason)
    from .serve import serve

    serve(rig, calibration, announce=announce, **options)
