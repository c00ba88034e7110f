"""``--colors`` and ``--chunked/--no-chunked``: how the commands that open point files hold them
(``gp.open``'s ``colors`` and ``chunked``; core/cloud.py's colour formats, core/chunked.py).

Given explicitly, either one asks for *one point cloud built from the files*: an input that is
an octree (a converted folder, COPC, EPT) or ``--progressive`` does not hold points that way,
so they are refused with a line naming the option instead of being ignored silently.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..core.layout import COLOR_FORMATS
from ..errors import GigapointError, counted

ColorsOption = Annotated[
    str,
    typer.Option(
        "--colors",
        help="How the points' colours are held: auto (per-block palettes where they are as faithful as RGB565, "
        "else RGB565; 32 bits where the files have no scale), rgba (32 bits, exact), rgb565 (16 bits) or palette (8 bits).",
    ),
]
ChunkedOption = Annotated[
    bool | None,
    typer.Option(
        "--chunked/--no-chunked",
        help="Build the cloud in bounded memory (the files read three times, ~30 bytes a point of temporary disk; "
        "the same cloud). Default: when the headers count more than 50 M points.",
    ),
]

RecursiveOption = Annotated[
    bool,
    typer.Option(
        "--recursive",
        help="Read every point file below a folder, its subfolders' too (hidden ones and octrees left out); "
        "by default a folder's own files only (raw/ and classified/ copies of the same tiles would be read twice).",
    ),
]


ClassesOption = Annotated[
    str | None,
    typer.Option(
        "--classes",
        metavar="2,6",
        help="Read only the points of these LAS classes (2 ground, 6 building, ...); a file without classification is an error.",
    ),
]
DropClassesOption = Annotated[
    str | None,
    typer.Option("--drop-classes", metavar="7,18", help="Read all points but those of these LAS classes (7 low noise, 18 high noise, ...)."),
]
ClipOption = Annotated[
    str | None,
    typer.Option(
        "--clip",
        metavar="XMIN,YMIN,XMAX,YMAX",
        help="Read only the points inside this box, in the files' coordinates (with --to-crs: the output's), bounds included: "
        "xmin,ymin,xmax,ymax (any z) or xmin,ymin,zmin,xmax,ymax,zmax.",
    ),
]
ClipPolygonOption = Annotated[
    str | None,
    typer.Option(
        "--clip-polygon",
        metavar="AREA",
        help="Read only the points inside this polygon, in the files' coordinates (any z; holes left out, edges included): "
        "a GeoJSON file (Polygon, MultiPolygon, a Feature or FeatureCollection of them) or a WKT file or text ('POLYGON ((x y, ...))'). "
        "A GeoJSON naming another CRS (a crs member) is moved into the files' CRS first (pyproj); one in longitude/latitude naming none is refused.",
    ),
]


ToCrsOption = Annotated[
    str | None,
    typer.Option(
        "--to-crs",
        metavar="CRS",
        help="Reproject the points into this CRS (EPSG:32610, a WKT, a PROJ string) as they are read, from each file's own "
        "(its header's, or --from-crs); --clip, --thin and tile sizes are then in its units. z is transformed only between CRSs "
        "with a vertical part (compound ones, e.g. EPSG:2994+6360 to EPSG:32610+5703), else kept as it is (PROJ's rule). "
        "Needs pyproj: pip install 'gigapoint\\[gis]'.",  # \[: rich would take [gis] for markup and drop it
    ),
]
FromCrsOption = Annotated[
    str | None,
    typer.Option("--from-crs", metavar="CRS", help="With --to-crs: the CRS every input's coordinates are in, in place of what their headers name (for files naming none)."),
]
ExactTransformOption = Annotated[
    bool,
    typer.Option(
        "--exact-transform",
        help="With --to-crs: every point through PROJ's exact transform (slower), not the default interpolation from PROJ's "
        "transform of a grid of control points, checked to within a tenth of the output grid's step of it.",
    ),
]
ColorizeOption = Annotated[
    Path | None,
    typer.Option(
        "--colorize",
        metavar="RASTER",
        readable=False,
        help="Colour the points from an orthophoto (a GeoTIFF, any raster GDAL reads) in the output's CRS (after --to-crs): each point "
        "takes its pixel's bands 1-3 as red, green, blue; points outside it, or under its alpha 0 or nodata, keep their colour (0 "
        "where their file had none) and are counted. On a Dask cluster (convert --dask/--workers) its workers open it: put it on the file system "
        "they share, as the inputs. Needs rasterio: pip install 'gigapoint\\[gis]'.",
    ),
]

ColorizeBitsOption = Annotated[
    int | None,
    typer.Option(
        "--colorize-bits",
        metavar="N",
        help="With --colorize: how many bits its values hold (12 for a 16-bit raster of 0-4095 that names no NBITS: "
        "else read as 0-65535, its colours come out near black, with a warning), in place of its NBITS or type's.",
    ),
]


def check_from_crs(from_crs: str | None, to_crs: str | None, where: str) -> None:
    """A one-line error for --from-crs without --to-crs, in the options' words (the library's
    said "give to_crs too")."""
    if from_crs is not None and to_crs is None:
        raise GigapointError(f"{where}: --from-crs {from_crs}: the CRS the inputs are in, for --to-crs; give --to-crs too")


def output_crs_keywords(where: str, to_crs: str | None, from_crs: str | None, exact_transform: bool, colorize, colorize_bits: int | None) -> dict:
    """The library's keywords of --to-crs, --from-crs, --exact-transform, --colorize and
    --colorize-bits (``convert``'s and ``tile``'s), --from-crs without --to-crs refused first."""
    check_from_crs(from_crs, to_crs, where)
    return {"to_crs": to_crs, "from_crs": from_crs, "exact_transform": exact_transform, "colorize": colorize, "colorize_bits": colorize_bits}


def crs_options_named(where: str, to_crs: str | None, from_crs: str | None) -> dict[str, str]:
    """``named_option``'s blame for a bad CRS: the library's ``where: to_crs='...'``
    (io/reproject.py) said as the option typed, ``where: --to-crs ...``."""
    return {f"{where}: to_crs={to_crs!r}": f"{where}: --to-crs {to_crs}", f"{where}: from_crs={from_crs!r}": f"{where}: --from-crs {from_crs}"}


def skipped_note(skipped: int) -> str:
    """What a summary line says of the invalid points a command skipped (NaN, inf, beyond reach): nothing where none."""
    return f", {counted(skipped, 'invalid point')} skipped" if skipped else ""


def rate_note(points_per_second: float) -> str:
    """A summary line's speed: millions a second, or whole points a second below one million (a
    small or slow run printed "0.00 M points/s")."""
    if points_per_second >= 1e6:
        return f"{points_per_second / 1e6:.2f} M points/s"
    return f"{points_per_second:,.0f} points/s"


def uncolored_note(uncolored: int | None, raster) -> str:
    """What a summary line says of the points --colorize left uncoloured: nothing without it."""
    if uncolored is None:
        return ""
    return f", {uncolored:,} outside {raster} or under its mask (colour kept, 0 where none)" if uncolored else f", every point coloured from {raster}"


def filter_options(classes: str | None, drop_classes: str | None, clip: str | None, where: str, clip_polygon: str | None = None):
    """The PointFilter (io/filters.py) of ``--classes``, ``--drop-classes``, ``--clip`` and
    ``--clip-polygon``, None without them; a bad value a one-line error naming the option (a bad
    polygon file: the file), before anything is read."""
    from ..io.filters import cli_point_filter

    return cli_point_filter(classes, drop_classes, clip, where, clip_polygon)


def thin_option(text: str | None, where: str) -> float | None:
    """``--thin SPACING`` as a number (None without it); a bad one a one-line error naming the
    option as typed, before anything is read."""
    from ..io.thin import thin_spacing

    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        value = text  # (not a number: thin_spacing says what it takes)
    return thin_spacing(value, f"{where}: --thin {text}")


def subfolders_read(paths, recursive: bool) -> list:
    """The inputs as ``--recursive`` has them read: each folder by every point file below it."""
    from ..io import with_subfolders

    return with_subfolders(paths) if recursive else list(paths)


def check_colors(colors: str) -> str:
    """``colors`` if it names a colour format, else a one-line error naming ``--colors``."""
    if colors not in COLOR_FORMATS:
        raise GigapointError(f"--colors: unknown colour format {colors!r}; choose one of {', '.join(COLOR_FORMATS)}")
    return colors


def cloud_options(colors: str, chunked: bool | None) -> dict:
    """``gp.open`` keywords for the options given (none for the defaults)."""
    check_colors(colors)
    options: dict = {}
    if colors != "auto":
        options["colors"] = colors
    if chunked is not None:
        options["chunked"] = chunked
    return options


def option_names(options: dict) -> str:
    """'--colors', '--chunked' or both, for messages."""
    return " and ".join(f"--{k}" for k in options)


def open_files(inputs, point_budget: int, progressive: bool | None, options: dict, progress: bool, point_filter=None):
    """What ``render`` and ``view`` open: ``open_sized``'s choice (an octree as itself, big inputs
    progressively, else one PointCloud); with ``options`` (``cloud_options``) always one
    PointCloud built with them. ``point_filter`` (``filter_options``): only the points it keeps
    are read, whichever way (of one octree, drawn level of detail: its nodes filtered as frames
    load them, lod/reader.open_filtered)."""
    from ..io import open_cloud, shown_url
    from ..lod import is_lod_source
    from ..lod.kinds import refuse_unwritten_copc
    from ..lod.progressive import open_sized

    refuse_unwritten_copc(inputs)
    if not options:
        return open_sized(inputs, point_budget, progressive, progress=progress, point_filter=point_filter)
    if progressive:
        raise GigapointError(f"{option_names(options)}: options of a point cloud held in memory, not of --progressive")
    octrees = [shown_url(p) for p in inputs if is_lod_source(p)]
    if octrees:
        raise GigapointError(f"{option_names(options)}: {octrees[0]} is an octree, drawn as stored; the option applies to point files")
    return open_cloud(*inputs, progress=progress, point_filter=point_filter, **options)


__all__ = [
    "ChunkedOption",
    "ClassesOption",
    "ClipOption",
    "ClipPolygonOption",
    "ColorsOption",
    "DropClassesOption",
    "RecursiveOption",
    "check_colors",
    "cloud_options",
    "filter_options",
    "open_files",
    "subfolders_read",
]
