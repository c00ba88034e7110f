"""`gigapoint render` and `gigapoint demo`."""

from __future__ import annotations

import inspect
import math
import re
import time
from pathlib import Path
from typing import Annotated

import typer

from ..core.coords import MAX_ABS_COORDINATE, MAX_SPAN
from ..errors import CameraError, GigapointError, counted, number_text
from ..io import crs_wkt, files_label
from ..render import VIEWS, Camera, RenderSettings
from ..render.camera import image_size
from ..render.contours import draw_contours
from ..render.georef import (
    check_plain_image,
    check_side_outputs,
    checked_side_writes,
    map_image,
    raster_writes,
    stale_notes,
    write_map_files,
)
from ..render.image_files import warn_alpha_dropped
from ..render.raster_fill import fill_map
from . import compiling
from .app import app
from .cloud_opts import (
    ChunkedOption,
    ClassesOption,
    ClipOption,
    ClipPolygonOption,
    ColorsOption,
    DropClassesOption,
    RecursiveOption,
    check_colors,
    cloud_options,
    filter_options,
    open_files,
    rate_note,
    subfolders_read,
)
from .contour_opts import (
    ContoursBaseOption,
    ContoursOnImageOption,
    ContoursOption,
    ContoursOutOption,
    check_contour_options,
    contour_write,
    traced_contours,
)
from .gsd_opts import check_fill_nodata, check_gsd_value
from .info_cmd import memory_line
from .output import check_image_fits, check_output, check_outputs_apart, save_array, save_image
from .progress import err_console, progress_bar, status
from .quality_opts import check_color_attribute, prepare_cloud
from .settings_opts import named_option, options_named, settings_from_options, with_settings_options

_CAMERA_KEYS = {"eye": 3, "target": 3, "up": 3, "yaw": 1, "pitch": 1, "distance": 1, "fov": 1}


def parse_camera(text: str) -> dict:
    """'eye=x,y,z target=x,y,z [up=...]' or 'yaw=.. pitch=.. distance=.. [target=..]' (';' or spaces)."""
    values: dict = {}
    for part in filter(None, re.split(r"[;\s]+", text.strip())):
        key, sep, raw = part.partition("=")
        key = key.strip().lower()
        if not sep or key not in _CAMERA_KEYS:
            raise GigapointError(f"--camera: cannot read {part!r}; expected key=value with keys {', '.join(_CAMERA_KEYS)}")
        try:
            nums = [float(v) for v in raw.split(",")]
        except ValueError:
            raise GigapointError(f"--camera: {key} needs numbers, got {raw!r}") from None
        if len(nums) != _CAMERA_KEYS[key] or not all(math.isfinite(v) for v in nums):
            raise GigapointError(f"--camera: {key} needs {_CAMERA_KEYS[key]} finite number(s), got {raw!r}")
        # (an eye at 1e300 overflowed the camera's sums: numpy's warnings and a blank image, exit 0)
        if key in ("eye", "target") and max(map(abs, nums)) > MAX_ABS_COORDINATE:
            raise GigapointError(f"--camera: {key} {raw} lies beyond ±{MAX_ABS_COORDINATE:g}, where no point can be")
        if key == "distance" and nums[0] > MAX_SPAN:
            raise GigapointError(f"--camera: distance must be at most {MAX_SPAN:g}, the span points can have, got {raw}")
        if key in values:  # 'yaw=10 yaw=20' kept the last one without a word
            raise GigapointError(f"--camera: {key} is given twice")
        values[key] = nums if len(nums) > 1 else nums[0]
    look_at = "eye" in values
    orbit = any(k in values for k in ("yaw", "pitch", "distance"))
    if look_at and orbit:
        raise GigapointError("--camera: give either eye/target/up or yaw/pitch/distance, not both")
    if look_at and "target" not in values:
        raise GigapointError("--camera: eye needs a target (eye=x,y,z target=x,y,z)")
    if orbit and not {"yaw", "pitch"} <= set(values):
        raise GigapointError("--camera: orbit needs yaw and pitch (distance and target are optional)")
    if orbit and "up" in values:  # an orbit's up is the z axis: 'up' was ignored
        raise GigapointError("--camera: up goes with eye and target; an orbit (yaw, pitch) keeps z up")
    if not values:
        raise GigapointError("--camera: empty camera description")
    if not (look_at or orbit):  # 'target=...' or 'fov=...' alone was an internal KeyError
        raise GigapointError("--camera: give eye=x,y,z target=x,y,z or yaw=deg pitch=deg (fov, up, distance and target go with them)")
    return values


def check_image_size(width, height, fov=60.0) -> tuple[int, int]:
    """The image size (``image_size``: --width or --height alone, the other at 16:9) and field of
    view checked as a camera would; a bad one names its option."""
    try:
        width, height = image_size(width, height)
        Camera.look_at((0, 0, 1), (0, 0, 0), up=(0, 1, 0), width=width, height=height, fov=fov)
        return width, height
    except CameraError as exc:
        raise named_option(exc, {"image width": "--width", "image height": "--height", "camera fov": "--fov"}) from None


TURNTABLE_FPS = 30.0  # --fps's default
SIZE_HELP = "Image {} in pixels (default {}); given one side alone, the other follows 16:9."


def check_view(view: str) -> None:
    """A one-line error for a --view that is none of VIEWS, before anything is read or made."""
    if view not in VIEWS:
        raise GigapointError(f"--view: unknown view {view!r}; choose one of {', '.join(VIEWS)}")


def make_camera(cloud, width, height, view, camera_text, projection, fov) -> Camera:
    bounds = cloud.bounds
    if camera_text is None:  # 'auto' frames the cloud's points (the data fills the frame), the others its box
        return Camera.fit_cloud(cloud, view=view, width=width, height=height, fov=fov, projection=projection)
    return described_camera(camera_text, width, height, projection, fov, bounds)


def described_camera(camera_text, width, height, projection, fov, bounds=None) -> Camera | None:
    """The camera ``--camera`` describes; without ``bounds`` (before the inputs are read: a bad
    one was told once a large file was), what it can check without them: the text, and an
    eye/target camera whole (an orbit's distance and target default from the bounds: None)."""
    try:
        c = parse_camera(camera_text)
        if bounds is None and "eye" not in c:  # its angles, distance and fov checked by an orbit about the origin
            Camera.orbit((0, 0, 0), c["yaw"], c["pitch"], c.get("distance", 1.0), fov=c.get("fov", fov), width=width, height=height)
            return None
        return _described_camera(bounds, c, width, height, projection, fov)
    except CameraError as exc:  # 'camera eye and target are the same point' named no option
        raise CameraError(f"--camera: {exc}") from None


def _described_camera(bounds, c: dict, width, height, projection, fov) -> Camera:
    """The camera of a parsed ``--camera`` description."""
    import numpy as np

    fov = c.get("fov", fov)
    if "eye" in c:
        extra = {}
        if projection == "orthographic":  # (was dropped: a perspective image) as tall as the perspective view at the target
            distance = float(np.linalg.norm(np.subtract(c["eye"], c["target"])))
            extra = {"projection": projection, "ortho_height": 2 * distance * math.tan(math.radians(fov) / 2)}
        return Camera.look_at(c["eye"], c["target"], up=c.get("up", (0, 0, 1)), fov=fov, width=width, height=height, **extra)
    # a given distance is from the box's centre (recenter=False): the framing's target, moved to
    # centre the box's image, lay 150 m under autzen at pitch 45, and 'distance=100' showed nothing
    fitted = Camera.fit(bounds, view=(c["yaw"], c["pitch"]), width=width, height=height, fov=fov, projection=projection, recenter="distance" not in c)
    target = c.get("target", fitted.target)
    distance = c.get("distance", float(np.linalg.norm(np.subtract(fitted.eye, fitted.target))))
    extra = {"projection": projection, "ortho_height": fitted.ortho_height} if projection == "orthographic" else {}
    return Camera.orbit(target, c["yaw"], c["pitch"], distance, fov=fov, width=width, height=height, **extra)


def check_gsd(gsd, view, camera_text, width, height, projection, settings) -> None:
    """One-line errors, before anything is read, for a --gsd that is no size or for options that
    contradict it: it draws straight down, orthographic, one image whose size it sets."""
    check_gsd_value(gsd)
    contradicting = [name for name, given in (
        ("--view", view not in ("auto", "top")), ("--camera", camera_text is not None), ("--width", width is not None),
        ("--height", height is not None), ("--projection", projection == "perspective"), ("--stereo", settings.stereo != "none"),
    ) if given]  # fmt: skip
    if contradicting:
        raise GigapointError(
            f"{', '.join(contradicting)} and --gsd: give one (--gsd draws one image straight down, orthographic, north up, sized to cover the cloud)"
        )


def top_down_camera(cloud, gsd: float, output: Path, inputs) -> Camera:
    """The --gsd camera over ``cloud``'s bounds (Camera.top_down), its image checked against
    ``output``'s format; a gsd too fine for the largest image a one-line error naming the
    ``inputs`` (whose extent it is) and --gsd."""
    try:
        cam = Camera.top_down(cloud.bounds, gsd)
    except CameraError as exc:  # (its message begins 'gsd N makes ...': said as the option)
        raise CameraError(f"{files_label(inputs)}: --{exc}") from None
    check_image_fits(output, cam.width, cam.height)
    return cam


def open_inputs(inputs, point_budget: int, progressive: bool | None = None, options: dict | None = None, point_filter=None):
    """The command's inputs (lod/progressive.open_sized: inputs above the point budget build an
    LOD octree as they load, and the render waits for it; ``options``: ``--colors``/``--chunked``,
    ``point_filter``: ``--classes``/``--drop-classes``/``--clip``, cloud_opts.open_files); files
    show a bar while they are read (on a terminal). A load that stops (a corrupt file, the memory
    limit) raises its error."""
    from ..lod.progressive import ProgressiveOctree

    cloud = open_files(inputs, point_budget, progressive, options or {}, progress=err_console().is_terminal, point_filter=point_filter)
    if isinstance(cloud, ProgressiveOctree):
        total = cloud.loader.total
        with progress_bar(f"reading {cloud.name} into an LOD octree", total) as advance:
            while cloud.loading:  # (not `until wait()`: a load closed part-way never says it finished)
                cloud.wait(timeout=0.1)
                advance(cloud.loader.read)
        if not cloud.wait():  # closed part-way: its points freed, not drawn as though the whole input
            raise GigapointError(f"{cloud.name}: loading was stopped before every point was read (the octree was closed)")
    return cloud


def print_stats(stats, console=None, compiled_s: float = 0.0) -> None:
    """The render statistics line; ``compiled_s``: seconds of it numba spent compiling (a first run)."""
    console = console or err_console()
    h = stats.precision_histogram
    rate = rate_note(stats.points_processed / max(stats.time_ms, 1e-9) * 1e3)  # ("0.0 M points/s" for a small render)
    if compiled_s >= 0.5:
        rate = f"compiling kernels included: {compiled_s:.0f} s, once per install"
    console.print(
        f"{stats.points_processed:,} of {stats.points_total:,} points, "
        f"{stats.batches_rendered:,} batches drawn, {stats.batches_culled:,} culled, "
        f"precision 10/20/30 bit: {h[10]:,}/{h[20]:,}/{h[30]:,} points, "
        f"{stats.visible_pixels:,} pixels covered, {stats.time_ms:.1f} ms ({rate}) on {stats.backend}",
        highlight=False,
    )


@app.command()
@with_settings_options(RenderSettings)
def render(
    inputs: Annotated[list[Path], typer.Argument(readable=False, help="Point cloud files, directories or converted octrees (merged into one scene). A quoted glob pattern ('tiles/*.laz', 'city/**/*.laz') stands for what it matches.")],
    output: Annotated[Path, typer.Option("-o", "--output", readable=False, help="Image to write (.png, .jpg, .webp, .tif).")],
    settings: RenderSettings,  # one option per RenderSettings field (cli/settings_opts.py)
    width: Annotated[int | None, typer.Option("--width", "-W", help=SIZE_HELP.format("width", 1920))] = None,
    height: Annotated[int | None, typer.Option("--height", "-H", help=SIZE_HELP.format("height", 1080))] = None,
    view: Annotated[str, typer.Option(help=f"Named view: {', '.join(VIEWS)} (auto: iso, or turned so a long cloud fills the frame).")] = "auto",
    camera: Annotated[
        str | None, typer.Option(help=r"'eye=x,y,z target=x,y,z \[up=x,y,z]' or 'yaw=deg pitch=deg \[distance=m] \[target=x,y,z]' (distance from the target, by default the cloud's centre; without it the cloud fills the frame).")
    ] = None,
    projection: Annotated[str | None, typer.Option(help=r"perspective or orthographic. \[default: perspective]")] = None,
    fov: Annotated[float, typer.Option(help="Vertical field of view in degrees.")] = 60.0,
    depth_out: Annotated[
        Path | None, typer.Option(readable=False, help="Also write the depth buffer (.npy, float32, inf = empty); with --gsd the surface heights instead (a DSM: a float32 GeoTIFF, NaN = empty, with its world file and .prj).")
    ] = None,
    index_out: Annotated[Path | None, typer.Option(readable=False, help="Also write the point index buffer (.npy, int64, -1 = empty): each pixel's point as gigapoint holds the cloud (a file read into memory: gp.open(FILE).point_info(i); with --hidden-classes, of the points drawn: gp.open(FILE).without_classes(CLASSES)), not the file's row.")] = None,
    gsd: Annotated[
        float | None,
        typer.Option(help="Ground sample distance (cloud units per pixel): an orthophoto straight down, north up, covering the cloud, with a world file (.pgw, .jgw, .tfw, .wld) and a .prj of the cloud's CRS beside it; a .tif is a GeoTIFF (its grid and CRS in its tags)."),
    ] = None,
    fill_nodata: Annotated[
        str | None,
        typer.Option(help="With --gsd: fill the surface model's NaN pixels by linear interpolation (a TIN), never outside the data's footprint: 'all' every hole inside it, N only pixels within N of data (speckle), which also gives the orthophoto's empty pixels there the nearest colour. Needs scipy."),
    ] = None,
    stats: Annotated[bool, typer.Option("--stats", help="Print render statistics.")] = False,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace existing output files.")] = False,
    turntable: Annotated[
        int | None, typer.Option(help="Write a video of N frames orbiting the cloud instead of an image (-o out.mp4).")
    ] = None,
    fps: Annotated[float | None, typer.Option(help=r"Frames per second of --turntable videos, 0.01 to 1000. \[default: 30]")] = None,
    progressive: Annotated[
        bool | None,
        typer.Option(
            "--progressive/--no-progressive",
            help="Build an LOD octree while reading and render from it (default: for inputs above --point-budget points).",
        ),
    ] = None,
    colors: ColorsOption = "auto",
    chunked: ChunkedOption = None,
    recursive: RecursiveOption = False,
    classes: ClassesOption = None,
    drop_classes: DropClassesOption = None,
    clip: ClipOption = None,
    clip_polygon: ClipPolygonOption = None,
    contours: ContoursOption = None,
    contours_base: ContoursBaseOption = None,
    contours_out: ContoursOutOption = None,
    contours_on_image: ContoursOnImageOption = False,
) -> None:
    """Render point clouds to an image (or a turntable video)."""
    import gigapoint as gp

    from ..render.video import VIDEO_SUFFIXES, check_video_path

    if turntable is not None:
        check_video_path(output, overwrite)  # (in the library's words: 'not a video file', 'unsupported video type')
        ignored = [name for name, given in (("--depth-out", depth_out is not None), ("--index-out", index_out is not None),
                   ("--camera", camera is not None), ("--view", view != "auto"), ("--projection", projection not in (None, "perspective")),
                   ("--gsd", gsd is not None), ("--stats", stats)) if given]  # fmt: skip
        if ignored:  # each was dropped without a word: no depth file, the turntable's own orbit
            raise GigapointError(f"{', '.join(ignored)}: options of a still image, not of --turntable (it orbits the cloud at its own distance)")
    else:
        if fps is not None:
            raise GigapointError("--fps: an option of --turntable videos")
        if output.suffix.lower() in VIDEO_SUFFIXES:  # 'unsupported output type' left the video option to be found
            raise GigapointError(f"{output}: a video needs --turntable N (its number of frames); a still image is .png, .jpg, .webp or .tif")
        check_output(output, overwrite)
    for extra, suffixes in ((depth_out, {".tif", ".tiff"} if gsd is not None else {".npy"}), (index_out, {".npy"})):
        if extra is not None:
            check_output(extra, overwrite, suffixes=suffixes)
    georef = check_side_outputs([output, depth_out], overwrite) if gsd is not None else []
    # an earlier map's world file and .prj would place a plain image on its grid (a plain --depth-out is a .npy, which no GIS places)
    stale = check_plain_image(output, overwrite) if gsd is None and turntable is None else []
    warn_alpha_dropped(output, settings.background[3], VIDEO_SUFFIXES)
    contours_drawn = check_contour_options(contours, contours_base, contours_out, contours_on_image, gsd, overwrite)
    check_outputs_apart([output, depth_out, index_out, *georef, contours_out], inputs)
    if projection not in (None, "perspective", "orthographic"):
        raise GigapointError(f"--projection must be perspective or orthographic, got {projection!r}")
    check_view(view)
    if gsd is not None:
        check_gsd(gsd, view, camera, width, height, projection, settings)
    fill_distance = check_fill_nodata(fill_nodata, gsd, depth_out or contours)  # (contours are traced on the filled heights too)
    projection = projection or "perspective"
    width, height = check_image_size(width, height, fov)  # before reading anything
    point_filter = filter_options(classes, drop_classes, clip, "render", clip_polygon)
    inputs = subfolders_read(inputs, recursive)
    with options_named():  # (--color-attribute: the files' headers lack it)
        check_color_attribute(inputs, settings)
    if camera is not None:
        if view != "auto":  # the view was dropped without a word: --camera places the eye itself
            raise GigapointError(f"--view {view} and --camera: give one (--camera 'yaw=.. pitch=..' is a view of any angle)")
        if fov != 60.0 and "fov" in parse_camera(camera):  # --fov was dropped without a word
            raise GigapointError("--fov and --camera fov=: give one")
        described_camera(camera, width, height, projection, fov)
    if turntable is not None:
        from ..render.video import check_turntable

        fps = TURNTABLE_FPS if fps is None else fps
        try:
            check_turntable(output, turntable, width, height, fps, overwrite)
        except GigapointError as exc:  # the library's words ('video fps must be ...') named no option
            raise named_option(exc, {"turntable": "--turntable", "video fps": "--fps"}) from None
    elif gsd is None:  # (side-by-side stereo writes both eyes: twice the width; --gsd's size is known once the cloud is read)
        check_image_fits(output, width * (2 if settings.stereo == "side-by-side" else 1), height)
    cloud = open_inputs(inputs, settings.point_budget, progressive, cloud_options(colors, chunked), point_filter)
    with options_named():  # drawing's errors name the option (--color-attribute NAME that the file lacks)
        prepare_cloud(cloud, settings)
    from ..core.cloud import PointCloud  # (not at import: numba's kernels, which --help needs none of)

    if settings.max_points and not isinstance(cloud, PointCloud):
        # an octree (a converted folder, or inputs above the point budget read progressively, as
        # `render huge.laz --max-points N` is) draws at most that many too, as the viewer's cap
        # does: the option was dropped without a word
        settings = settings.replace(point_budget=min(settings.point_budget, settings.max_points))
    if turntable is not None:
        from ..render.video import render_turntable

        with progress_bar(f"turntable {output.name}", turntable) as advance, options_named():
            render_turntable(
                cloud, turntable, output, settings, width=width, height=height, fov=fov, fps=fps, overwrite=overwrite,
                progress=lambda done, total: advance(done),
            )  # fmt: skip
        typer.echo(f"wrote {output} ({counted(turntable, 'frame')}, {width}x{height}, {counted(cloud.n_points, 'point')})")
        return
    if gsd is not None:
        cam = top_down_camera(cloud, gsd, output, inputs)
        settings = settings.replace(adaptive_precision=False)  # 30-bit positions: exact pixels and heights, whatever a batch's size
        from ..lod.reader import cloud_crs_units

        crs, units = cloud_crs_units(cloud)
        wkt = crs_wkt(crs)
        side_writes, notes, stale = checked_side_writes(cam, (output, depth_out), crs, wkt, units, overwrite)  # (x.webp, then x.jpg: x.prj kept)
    else:
        cam = make_camera(cloud, width, height, view, camera, projection, fov)
        side_writes, notes = [], stale_notes(stale, map_drawn=False)
    compiled = compiling.compiled_seconds()
    with options_named():
        frame = gp.render_frame(cloud, cam, settings)
    compiled = compiling.compiled_seconds() - compiled
    surface = gsd is not None and (depth_out is not None or contours is not None)
    from ..render.surface import surface_heights  # (not at import: the renderer's numba kernels)

    with options_named():  # (the highest point's z in each pixel: drawn again where the image's points are splats)
        heights = surface_heights(cloud, cam, settings, frame) if surface else None
    image = frame.image
    if gsd is not None:  # a map: no data is no colour (--fill-nodata's filled pixels take their neighbour's alpha)
        image = map_image(image, frame.index < 0)
    if fill_nodata is not None:
        image, heights = fill_map(image, frame.index < 0, heights, fill_distance)
    lines = traced_contours(heights, cam, contours, contours_base, units) if contours is not None else []
    if contours_drawn:
        image = draw_contours(image, lines, cam.world_file())
    if gsd is not None:  # a map: a .tif is a GeoTIFF, --depth-out the heights (a surface model), as gigapoint.orthophoto writes them
        writes = raster_writes(cam, crs, wkt, units, [(output, image), (depth_out, heights)])
    else:
        writes = [(output, lambda p: save_image(image, p))]
        if depth_out is not None:
            writes.append((depth_out, lambda p: save_array(frame.depth, p)))
    if index_out is not None:
        writes.append((index_out, lambda p: save_array(frame.index, p)))
    if contours_out is not None:
        writes.append(contour_write(lines, cam, contours_out, crs, wkt))
    written = write_map_files(writes + side_writes, stale)
    if stats:
        print_stats(frame.stats, compiled_s=compiled)
        err_console().print(memory_line(cloud), highlight=False)
    drawn = frame.stats.points_processed  # (a budget, --max-points, culling: fewer than the cloud's; '110,000 points' said the cloud's)
    points = counted(cloud.n_points, "point") if drawn >= cloud.n_points else f"{drawn:,} of {cloud.n_points:,} points drawn"
    typer.echo(f"wrote {output} ({frame.image.shape[1]}x{frame.image.shape[0]}, {points})")  # (side-by-side stereo: both eyes)
    if len(written) > 1:
        typer.echo(f"wrote {', '.join(str(p) for p in written[1:])}")
    for note in notes:
        typer.echo(note)


@app.command()
def demo(
    points: Annotated[int, typer.Option("--points", "-n", help="Points in the procedural demo scene.")] = 20_000_000,
    output: Annotated[Path, typer.Option("-o", "--output", readable=False, help="Image to write.")] = Path("demo.png"),
    width: Annotated[int | None, typer.Option("--width", "-W", help=SIZE_HELP.format("width", 1920))] = None,
    height: Annotated[int | None, typer.Option("--height", "-H", help=SIZE_HELP.format("height", 1080))] = None,
    view: Annotated[str, typer.Option(help=f"Named view: {', '.join(VIEWS)}.")] = "auto",
    threads: Annotated[int | None, typer.Option(help="CPU threads (default: all cores).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the procedural scene.")] = 0,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace an existing output file.")] = False,
    live: Annotated[bool, typer.Option("--live", help="Instead: a synthetic depth sensor flying through the demo town, in the viewer.")] = False,
    colors: ColorsOption = "auto",
    scale: Annotated[
        float, typer.Option(help="Grid step of the positions in metres, as a LAS export of the scene holds them (the compact layout); 0: float positions, three 32-bit words a point.")
    ] = 0.01,
) -> None:
    """Generate the procedural demo scene, render it and report how fast each step was."""
    if live:
        from .live_cmd import view_live

        given = locals()  # (the options' values: every one but --live is the image's)
        dropped = [f"--{name}" for name, p in inspect.signature(demo).parameters.items() if name != "live" and given[name] != p.default]
        if dropped:  # they were dropped without a word (the image is not written; the live demo has its own scene)
            raise GigapointError(f"{' and '.join(dropped)}: options of the demo image, not of --live")
        from .view_cmd import _open_browser

        view_live("demo", open_browser=_open_browser)
        return
    from rich.console import Console

    from ..core import build_cloud
    from ..core.chunk import PointChunk
    from ..core.chunked import IN_MEMORY_BYTES_MIN, check_room
    from ..io.demo import MAX_DEMO_POINTS, check_seed, demo_arrays, round_to_grid
    from ..render import render_frame

    console = Console()
    if not 1 <= points <= MAX_DEMO_POINTS:
        raise GigapointError(f"--points must be between 1 and {MAX_DEMO_POINTS:,}, got {points}")
    check_seed("--seed", seed)  # 2**64 was an internal error in the generator
    check_room(f"demo({points:,})", points, IN_MEMORY_BYTES_MIN, instead=": take fewer --points")
    check_output(output, overwrite)
    width, height = check_image_size(width, height)
    check_image_fits(output, width, height)
    check_view(view)  # (told only once the scene was generated and sorted, without naming --view)
    settings = settings_from_options(RenderSettings, {"threads": threads})  # a bad --threads is named
    check_colors(colors)
    if not (scale == 0 or 1e-6 <= scale <= 1000):  # NaN fails both
        raise GigapointError(f"--scale must be 0 (float positions) or a grid step between 1e-6 and 1000 metres, got {number_text(scale)}")
    compiled_before = compiling.compiled_seconds()
    t0 = time.perf_counter()
    with status(f"generating the demo scene ({points:,} points)"):
        xyz, rgba, attrs = demo_arrays(points, seed)
        if scale:
            round_to_grid(xyz, scale)
    t1 = time.perf_counter()
    with status("Morton sort and batching"):
        cloud = build_cloud([PointChunk(xyz, rgba, attrs, scale=(scale,) * 3 if scale else None)], name=f"demo({points:,})", colors=colors)
    del xyz, rgba, attrs
    t2 = time.perf_counter()
    cam = make_camera(cloud, width, height, view, None, "perspective", 60.0)
    with progress_bar("rendering", 8) as advance:
        first = render_frame(cloud, cam, settings)
        advance()
        times = []
        for _ in range(7):  # the median of 7: this kind of shared host swings 1.5x within seconds
            frame = render_frame(cloud, cam, settings)
            times.append(frame.stats.time_ms)
            advance()
    median = sorted(times)[3]
    save_image(frame.image, output)
    compiled = compiling.compiled_seconds() - compiled_before  # numba compiled kernels: a first run
    if compiled >= 0.5:
        console.print(f"compiling the kernels took {compiled:.0f} s of the times below (once per install)", style="dim", highlight=False)
    console.print(f"demo scene: {points:,} points generated in {t1 - t0:.2f} s ({points / (t1 - t0) / 1e6:.1f} M points/s)", highlight=False)
    console.print(f"Morton sort + batching: {t2 - t1:.2f} s ({points / (t2 - t1) / 1e6:.1f} M points/s), {len(cloud.batches):,} batches", highlight=False)
    console.print(f"first render: {first.stats.time_ms:.0f} ms{' (compiling included)' if compiled >= 0.5 else ''}", highlight=False)
    console.print(
        f"render {width}x{height} '{view}': {median:.1f} ms per frame (median of 7) = {cloud.n_points / median / 1e3:,.0f} M points/s "
        f"({frame.stats.visible_pixels:,} pixels covered)",
        highlight=False,
    )
    console.print(memory_line(cloud), highlight=False)
    console.print(f"wrote {output}", highlight=False)
