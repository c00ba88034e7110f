"""`gigapoint change BEFORE AFTER --gsd G -o change.tif`: what moved between two surveys and how
much (gigapoint.change, survey/change.py), as a GeoTIFF of height differences, a colour
preview and cut/fill volumes."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated

import typer

from ..errors import GigapointError, counted, number_text
from ..render.georef import GEOTIFF_SUFFIXES, check_side_outputs, checked_side_writes, raster_writes, write_map_files
from .app import app
from .cloud_opts import ClassesOption, ClipOption, DropClassesOption, RecursiveOption, filter_options, subfolders_read
from .gsd_opts import ALL_POINTS_HELP, check_fill_nodata, check_gsd_value
from .output import check_image_fits, check_output, check_outputs_apart

SURVEY_HELP = (
    "The {} survey: a point cloud file, a folder of tiles or a quoted glob pattern ('{}/*.laz'), its files merged; "
    "or an LOD octree (a converted folder, a COPC file, an EPT dataset), read node by node down to the levels the gsd needs (--all-points: every node)."
)


@app.command()
def change(
    before: Annotated[Path, typer.Argument(readable=False, help=SURVEY_HELP.format("earlier", "2024"))],
    after: Annotated[Path, typer.Argument(readable=False, help=SURVEY_HELP.format("later", "2025"))],
    gsd: Annotated[float, typer.Option(help="Ground sample distance (cloud units per pixel) of the grid both surfaces are drawn on, pixel edges on its multiples.")],
    output: Annotated[Path, typer.Option("-o", "--output", readable=False, help="The height differences AFTER - BEFORE: a float32 GeoTIFF (.tif), NaN where either survey has no point, with its world file and .prj.")],
    preview: Annotated[Path | None, typer.Option(readable=False, help="Also a colour image of the differences (.png, ...): red lower (cut), white unchanged, blue higher (fill); transparent where not compared.")] = None,
    value_range: Annotated[float | None, typer.Option("--range", metavar="DZ", help="The preview's colours span -DZ..+DZ (default: the 98th percentile of |dz|).")] = None,
    min_change: Annotated[float, typer.Option(metavar="DZ", help="Pixels that moved by DZ or less count in neither the volumes nor the changed area (a level of detection; default 0: every change the float32 heights tell from their rounding).")] = 0.0,
    fill_nodata: Annotated[
        str | None,
        typer.Option(help="Fill each survey's empty pixels by linear interpolation (a TIN) inside its footprint before comparing: 'all' every hole, N only those within N pixels of a point. Needs scipy."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the volumes and areas as one JSON object (and nothing else).")] = False,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace existing output files.")] = False,
    all_points: Annotated[bool, typer.Option("--all-points", help=ALL_POINTS_HELP)] = False,
    recursive: RecursiveOption = False,
    classes: ClassesOption = None,
    drop_classes: DropClassesOption = None,
    clip: ClipOption = None,
) -> None:
    """Compare two surveys: height differences, cut and fill volumes (in the clouds' units).

    Both must be in one CRS and unit: surveys in feet and in metres are refused (reproject one
    first, gigapoint convert --to-crs)."""
    import gigapoint as gp

    from ..io import crs_wkt

    check_output(output, overwrite, suffixes=GEOTIFF_SUFFIXES)
    if preview is not None:
        check_output(preview, overwrite)
    georef = check_side_outputs([output, preview], overwrite)
    check_outputs_apart([output, preview, *georef], [before, after])
    check_gsd_value(gsd)
    if not (math.isfinite(min_change) and min_change >= 0):
        raise GigapointError(f"--min-change must be a number >= 0 (a height difference), got {number_text(min_change)}")
    if value_range is not None and not (math.isfinite(value_range) and value_range > 0):
        raise GigapointError(f"--range must be a number > 0 (the preview spans -DZ..+DZ), got {number_text(value_range)}")
    if value_range is not None and preview is None:  # (it would be dropped without a word)
        raise GigapointError("--range: an option of --preview (the colours' span)")
    distance = check_fill_nodata(fill_nodata, gsd, output)
    keep = filter_options(classes, drop_classes, clip, "change")
    chosen = {} if keep is None else {"classes": keep.classes or None, "drop_classes": keep.drop_classes or None, "clip": keep.clip or None}
    surveys = [subfolders_read([path], recursive) for path in (before, after)]
    result = gp.change(*surveys, gsd, fill_nodata=None if fill_nodata is None else distance or "all", min_change=min_change, full=all_points, **chosen)
    cam, crs = result.camera, result.crs
    if preview is not None:
        check_image_fits(preview, cam.width, cam.height)
    wkt = crs_wkt(crs)
    writes = raster_writes(cam, crs, wkt, result.units, [(output, result.dz), (preview, None if preview is None else result.preview(value_range))])
    side_writes, notes, stale = checked_side_writes(cam, (output, preview), crs, wkt, result.units, overwrite)  # (d.tif, then d.png: d.prj kept)
    written = write_map_files(writes + side_writes, stale)
    summary = result.summary()
    if as_json:
        typer.echo(json.dumps({**summary, "outputs": [str(p) for p in written]}, indent=1))
        return
    unit = summary["units"]
    typer.echo(f"wrote {output} ({cam.width}x{cam.height}, after - before, NaN where either survey has no point)")
    typer.echo(f"wrote {', '.join(str(p) for p in written[1:])}")
    for note in notes:
        typer.echo(note)
    typer.echo(f"compared {result.area_compared:,.2f} {unit['area']} ({counted(summary['pixels_compared'], 'pixel')} of {gsd:g} {unit['length']})")
    typer.echo(f"changed by more than {min_change:g} {unit['length']}: {result.area_changed:,.2f} {unit['area']}")
    for name in ("cut", "fill", "net"):
        typer.echo(f"{name:<4} {summary[name]:{'+' if name == 'net' else ''},.3f} {unit['volume']}")
