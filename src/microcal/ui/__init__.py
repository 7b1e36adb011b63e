"""The station page: ``microcal ui`` serves a calibrated rig to a browser.

:mod:`.app` is the web application (Starlette, with the page's plain JavaScript in
``static/``), :mod:`.access` who may use it, :mod:`.serve` runs it; the work behind every
request is :class:`microcal.workflows.live.LiveStation`'s. Needs ``pip install
'microcal[ui]'``.
"""

from __future__ import annotations

__all__ = ["ui_available"]


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
