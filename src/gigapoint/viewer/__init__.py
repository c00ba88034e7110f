"""The viewers: a browser viewer (a Starlette/uvicorn server streaming frames rendered on the
server to plain-JS pages) and a native window (window.py, rendercanvas).

``gigapoint view PATH`` from the shell, ``gigapoint.Viewer(cloud)`` from Jupyter. Starlette and
uvicorn come with the ``viewer`` extra and are imported only when a server starts.
"""

from __future__ import annotations

__all__ = ["Viewer", "ViewerServer", "create_app"]


def __getattr__(name):
    if name == "Viewer":
        from .jupyter import Viewer

        return Viewer
    if name in ("ViewerServer", "create_app"):
        from . import server

        return getattr(server, name)
    raise AttributeError(f"module 'gigapoint.viewer' has no attribute {name!r}")
