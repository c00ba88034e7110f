"""`gigapoint view`: the browser viewer."""

from __future__ import annotations

import sys
import threading
import time
import webbrowser
from pathlib import Path

import typer

from ..errors import GigapointError, SettingsError
from .app import app, prefer_passive_wait
from .cloud_opts import (
    ChunkedOption,
    ClassesOption,
    ClipOption,
    ClipPolygonOption,
    ColorsOption,
    DropClassesOption,
    RecursiveOption,
    cloud_options,
    filter_options,
    open_files,
    option_names,
    subfolders_read,
)
from .settings_opts import options_named


def _open_browser(url: str) -> None:
    try:
        webbrowser.get()  # raises when no browser is available (headless machines)
    except webbrowser.Error:
        return
    threading.Timer(0.3, webbrowser.open, args=(url,)).start()


def _report_load_error(cloud) -> None:
    """The error that stops a progressive load, on the terminal as in the viewer's HUD (the
    terminal said nothing; the viewer goes on showing the points loaded before it); ``wait``
    issues the load's warnings, which the CLI prints (they are kept until then: Loader)."""
    try:
        cloud.wait()
    except GigapointError as exc:
        print(f"warning: loading stopped: {exc}; showing the {cloud.n_points:,} points loaded", file=sys.stderr, flush=True)


def _report_load(cloud) -> None:
    from ..lod.progressive import ProgressiveOctree

    if isinstance(cloud, ProgressiveOctree):  # (the window's, too: its load's warnings were said by no one)
        threading.Thread(target=_report_load_error, args=(cloud,), name="gigapoint-load-report", daemon=True).start()


def _open_cloud(paths, demo, options, progressive, recursive, point_filter, settings):
    """The cloud viewed: --demo's or the files' (a progressive octree once its first points are in)."""
    import gigapoint

    from ..lod.progressive import ProgressiveOctree
    from ..render.settings import RenderSettings
    from ..viewer.classes import refusal

    budget = RenderSettings().point_budget
    if demo is not None:
        cloud = gigapoint.demo(demo, progressive=progressive if progressive is not None else demo > budget and not options, **options)
    else:
        from ..lod import OctreeDir
        from ..lod.preview import wait_for_preview

        if len(paths) == 1 and OctreeDir(paths[0]).awaiting_preview:  # `convert` was started a moment ago
            print(f"gigapoint viewer: waiting for the first preview of the conversion into {paths[0]} ...", file=sys.stderr)
            wait_for_preview(paths[0])
        cloud = open_files(subfolders_read(paths, recursive), budget, progressive, options, progress=False, point_filter=point_filter)  # big: shown while it loads
    if isinstance(cloud, ProgressiveOctree):  # a first slice of points, so that the first view frames them
        if settings.hidden_classes:  # (and its attributes, none before its first points, say whether classes can hide)
            cloud.wait_first_points()
        deadline = time.monotonic() + 5.0
        while cloud.n_points == 0 and cloud.loading and time.monotonic() < deadline:
            time.sleep(0.02)
        if cloud.n_points == 0 and not cloud.loading:  # a file cut off before its first point: its error, not a server showing nothing
            cloud.wait()
    refused = refusal(cloud) if settings.hidden_classes else ""
    if refused:  # (a progressive load, a cloud without classification): said once, not by every frame
        with options_named():
            raise SettingsError(refused)
    return cloud


def _points_said(cloud) -> str:
    """The start-up line's count: while a progressive load goes on, the points loaded so far and
    of how many (they were said as though the file's size: "250,000 points" of 3.3 M)."""
    from ..lod.progressive import ProgressiveOctree

    if not isinstance(cloud, ProgressiveOctree) or not cloud.loading:
        return f"{cloud.n_points:,} points"
    total = cloud.loader.total  # (the files' headers' or the demo's count; with a filter, of the points read)
    of = "" if not total else f" of at most {total:,}" if cloud.loader.point_filter is not None else f" of {total:,}"
    return f"{cloud.n_points:,}{of} points loaded so far (loading)"


@app.command("view")
def view(
    paths: list[Path] | None = typer.Argument(None, readable=False, help="Point cloud files or directories (several tiles make one scene). A quoted glob pattern ('tiles/*.laz', 'city/**/*.laz') stands for what it matches."),
    demo: int | None = typer.Option(None, "--demo", help="View the procedural demo scene with this many points instead."),
    port: int = typer.Option(0, "--port", help="Port to listen on (0: a free one)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on; anything but loopback requires a token in the URL."),
    browser: bool = typer.Option(True, "--browser/--no-browser", help="Open the page in a browser when one is available."),
    window: bool = typer.Option(False, "--window", help="Show a native window instead (needs the window extra and a display)."),
    progressive: bool | None = typer.Option(
        None, "--progressive/--no-progressive",
        help="Show the cloud while it loads, building its LOD octree as points arrive (default: for inputs above the point budget).",
    ),
    live: str | None = typer.Option(
        None, "--live", help="Show a live stream: 'demo' (a synthetic depth sensor), a TUM RGB-D folder, a ROS bag, a folder of frames.",
    ),
    replay: Path | None = typer.Option(None, "--replay", readable=False, help="Play back a stream recorded with --record (or LiveCloud.record) at its rate."),
    keep: int | None = typer.Option(None, "--keep", help=r"Live: frames drawn (the oldest leaves as a new one arrives). \[default: 100]"),
    decay: float | None = typer.Option(None, "--decay", help="Live: seconds after which a frame leaves (default: never)."),
    record: Path | None = typer.Option(None, "--record", readable=False, help="Live: also record the stream into this folder."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Live: replace a recording already in the --record folder."),
    colors: ColorsOption = "auto",
    chunked: ChunkedOption = None,
    recursive: RecursiveOption = False,
    classes: ClassesOption = None,
    drop_classes: DropClassesOption = None,
    clip: ClipOption = None,
    clip_polygon: ClipPolygonOption = None,
    hidden_classes: str | None = typer.Option(
        None, "--hidden-classes", help="LAS classes hidden from the start, e.g. '7,18' (unticked in the Classes panel); changing them re-reads nothing."
    ),
) -> None:
    """Serve an interactive viewer of PATH... in the browser (Ctrl+C stops it)."""
    prefer_passive_wait()
    options = cloud_options(colors, chunked)
    if recursive and not paths:  # (dropped without a word by --demo, --live and --replay)
        raise GigapointError("--recursive: reads the subfolders of the folders given as PATH...; none is given")
    point_filter = filter_options(classes, drop_classes, clip, "view", clip_polygon)
    if point_filter is not None and not paths:  # (as --recursive: --demo, --live and --replay read no file)
        raise GigapointError("--classes, --drop-classes, --clip and --clip-polygon: filter the points of the files given as PATH...; none is given")
    from ..render.settings import RenderSettings

    with options_named():  # a bad class said as --hidden-classes's, before anything is read
        settings = RenderSettings(hidden_classes=hidden_classes or ())
    if live is not None or replay is not None:
        from .live_cmd import check_live_options, view_live

        if paths or demo is not None or (live is not None and replay is not None):
            raise GigapointError("view: give one of PATH..., --demo N, --live SOURCE or --replay DIR")
        if options or settings.hidden_classes:
            said = option_names(options) if options else "--hidden-classes"
            raise GigapointError(f"{said}: options of a point cloud held in memory, not of a live stream")
        if window:
            raise GigapointError("view: --window does not show live streams yet; use the browser viewer (without --window)")
        if progressive is not None:
            raise GigapointError("--progressive: an option of files and --demo, not of a live stream")
        if overwrite and record is None:
            raise GigapointError("--overwrite: replaces a recording in --record DIR; give --record too")
        keep = 100 if keep is None else keep
        check_live_options(keep, decay, 1.0)
        view_live(str(replay) if replay is not None else live, replay=replay is not None, keep=keep, decay=decay, record=record,
                  overwrite=overwrite, host=host, port=port, browser=browser, open_browser=_open_browser)  # fmt: skip
        return
    from .live_cmd import listen_at, serve_at

    if demo is not None and paths:
        raise GigapointError("view: give either PATH... or --demo N, not both")
    served = [name for name, given in (("--host", host != "127.0.0.1"), ("--port", port != 0)) if given]
    if window and served:  # a native window listens on nothing: they were dropped without a word
        raise GigapointError(f"{' and '.join(served)}: options of the browser viewer, not of --window")
    live_only = [name for name, value in (("--keep", keep), ("--decay", decay), ("--record", record), ("--overwrite", overwrite or None)) if value is not None]
    if live_only:  # `view a.laz --record rec` recorded nothing, without a word
        raise GigapointError(f"{' and '.join(live_only)}: options of a live stream (--live SOURCE or --replay DIR)")
    if window:  # before loading: no display is said alone, not after minutes of reading
        from ..viewer.window import check_display

        check_display()
    if demo is not None:
        if not 1 <= demo <= 2_000_000_000:
            raise GigapointError(f"--demo: point count must be in 1..2e9, got {demo}")
        if options and progressive:
            raise GigapointError(f"{option_names(options)}: options of a point cloud held in memory, not of --progressive")
    elif not paths:
        raise GigapointError("view: name at least one file or directory (or --demo N)")
    if window:  # native window (rendercanvas + glfw), no server
        from ..viewer.window import open_window, run_loop

        cloud = _open_cloud(paths, demo, options, progressive, recursive, point_filter, settings)
        open_window(cloud, settings=settings)  # first: a window that cannot open is said alone, not after the title line
        print(f"gigapoint window: {cloud.name}, {_points_said(cloud)} (drag: orbit, right drag: pan, wheel: zoom)", file=sys.stderr)
        _report_load(cloud)
        run_loop()
        return
    sock = listen_at(host, port)  # before the points are read: a port in use was said after the whole file was
    try:
        cloud = _open_cloud(paths, demo, options, progressive, recursive, point_filter, settings)
        server = serve_at(cloud, host, port, sock=sock, settings=settings)
    except BaseException:
        sock.close()
        raise
    print(f"gigapoint viewer: {cloud.name}, {_points_said(cloud)}", file=sys.stderr)
    _report_load(cloud)
    if not server.loopback:
        print(f"warning: listening on {host}, reachable from the network; the URL's token is the only key", file=sys.stderr)
    print(server.url, flush=True)
    if browser:
        _open_browser(server.url)
    server.serve_forever()
