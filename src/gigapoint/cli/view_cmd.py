"""`gigapoint view`: the browser viewer."""

from __future__ import annotations

import sys
import threading
import webbrowser
from pathlib import Path

import typer

from ..errors import GigapointError
from .app import app


def _open_browser(url: str) -> None:
    try:
        webbrowser.get()  # raises when no browser is available (headless machines)
    except webbrowser.Error:
        return
    threading.Timer(0.3, webbrowser.open, args=(url,)).start()


@app.command("view")
def view(
    paths: list[Path] | None = typer.Argument(None, help="Point cloud files or directories (several tiles make one scene)."),
    demo: int | None = typer.Option(None, "--demo", help="View the procedural demo scene with this many points instead."),
    port: int = typer.Option(0, "--port", help="Port to listen on (0: a free one)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on; anything but loopback requires a token in the URL."),
    browser: bool = typer.Option(True, "--browser/--no-browser", help="Open the page in a browser when one is available."),
    window: bool = typer.Option(False, "--window", help="Show a native window instead (needs the window extra and a display)."),
) -> None:
    """Serve an interactive viewer of PATH... in the browser (Ctrl+C stops it)."""
    import gigapoint

    from ..viewer.server import ViewerServer

    if demo is not None and paths:
        raise GigapointError("view: give either PATH... or --demo N, not both")
    if demo is not None:
        if not 1 <= demo <= 2_000_000_000:
            raise GigapointError(f"--demo: point count must be in 1..2e9, got {demo}")
        cloud = gigapoint.demo(demo)
    elif paths:
        from ..lod import OctreeDir
        from ..lod.preview import wait_for_preview

        if len(paths) == 1 and OctreeDir(paths[0]).awaiting_preview:  # `convert` was started a moment ago
            print(f"gigapoint viewer: waiting for the first preview of the conversion into {paths[0]} ...", file=sys.stderr)
            wait_for_preview(paths[0])
        cloud = gigapoint.open(*paths)
    else:
        raise GigapointError("view: name at least one file or directory (or --demo N)")
    if window:  # native window (rendercanvas + glfw), no server
        from ..viewer.window import run_window

        print(f"gigapoint window: {cloud.name}, {cloud.n_points:,} points (drag: orbit, right drag: pan, wheel: zoom)", file=sys.stderr)
        run_window(cloud)
        return
    server = ViewerServer(cloud, host=host, port=port)
    print(f"gigapoint viewer: {cloud.name}, {cloud.n_points:,} points", file=sys.stderr)
    if not server.loopback:
        print(f"warning: listening on {host}, reachable from the network; the URL's token is the only key", file=sys.stderr)
    print(server.url, flush=True)
    if browser:
        _open_browser(server.url)
    server.serve_forever()
