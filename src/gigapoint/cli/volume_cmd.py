"""`gigapoint volume FILES --clip-polygon toe.geojson --gsd G`: the volume of each stockpile a
polygon outlines, above and below a base (gigapoint.volume, survey/volume.py), with its footprint and
highest point; -o writes the height above the base the volumes sum (a GeoTIFF), --preview a colour
image of it with the toes drawn, --dsm-out the surface model measured."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from ..errors import CameraError, GigapointError, counted
from ..render.georef import GEOTIFF_SUFFIXES, check_side_outputs, write_map
from .app import app
from .cloud_opts import ClassesOption, DropClassesOption, RecursiveOption, filter_options, subfolders_read
from .gsd_opts import VOLUME_POINTS_HELP, check_fill_nodata, check_gsd_value
from .output import IMAGE_SUFFIXES, check_output, check_outputs_apart


def _base_of(text: str) -> str | float:
    if text in ("plane", "lowest"):
        return text
    try:
        return float(text)
    except ValueError:
        raise GigapointError(f"--base must be 'plane', 'lowest' or an elevation (a number), got {text!r}") from None


@app.command()
def volume(
    inputs: Annotated[list[Path], typer.Argument(readable=False, help="Point cloud files or directories of one survey (merged), or an LOD octree (a converted folder, a COPC file, an EPT dataset: every node near the piles read; --levels-only: only the levels the gsd needs). A quoted glob pattern ('tiles/*.laz') stands for what it matches.")],
    gsd: Annotated[float, typer.Option(help="Ground sample distance (cloud units per pixel) of the surface model the volumes are summed on.")],
    clip_polygon: Annotated[
        str | None,
        typer.Option(
            "--clip-polygon",
            metavar="AREA",
            help="The piles' boundaries (toes), in the files' coordinates: a GeoJSON file (Polygon, MultiPolygon, a Feature or FeatureCollection of them: one pile each Feature, named by its 'name', a MultiPolygon Feature one pile in parts; one each polygon outside a Feature) or a WKT file or text (one pile each polygon). A GeoJSON naming another CRS (a crs member) is moved into the survey's first (pyproj). A polygon crossing itself is refused.",
        ),
    ] = None,
    base: Annotated[str, typer.Option(metavar="plane|lowest|Z", help="What the volume stands on: 'plane' the least-squares plane through the surface along the toe, 'lowest' flat at the toe's lowest height, or an elevation Z.")] = "plane",
    fill_nodata: Annotated[str, typer.Option(help="Fill empty pixels inside the piles by linear interpolation (a TIN) first: 'all' every hole (default), N only those within N pixels of a point, 'none' leave them out of the volume. Needs scipy.")] = "all",
    output: Annotated[
        Path | None,
        typer.Option("-o", "--output", readable=False, help="Write the height above the base inside the piles (what the volumes sum) as a float32 GeoTIFF (.tif), NaN outside, with its world file and .prj."),
    ] = None,
    preview: Annotated[
        Path | None,
        typer.Option(readable=False, help="Write a colour image (.png, ...) of the height above the base: dark purple at the base to yellow at the highest pile's top, the toes drawn in red, transparent outside; with its world file."),
    ] = None,
    dsm_out: Annotated[Path | None, typer.Option(readable=False, help="Also write the surface model inside the piles (holes filled) as a float32 GeoTIFF (.tif), NaN outside, with its world file and .prj.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print each pile's figures and the total as one JSON object (and nothing else).")] = False,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace existing output files.")] = False,
    all_points: Annotated[bool, typer.Option("--all-points/--levels-only", help=VOLUME_POINTS_HELP)] = True,
    recursive: RecursiveOption = False,
    classes: ClassesOption = None,
    drop_classes: DropClassesOption = None,
) -> None:
    """Stockpile volumes of one survey: above (fill) and below (cut) a base inside each polygon."""
    import gigapoint as gp

    if clip_polygon is None:
        raise GigapointError("--clip-polygon is needed: the piles' boundaries (a GeoJSON or WKT polygon)")
    for path, suffixes in ((output, GEOTIFF_SUFFIXES), (preview, IMAGE_SUFFIXES), (dsm_out, GEOTIFF_SUFFIXES)):
        if path is not None:
            check_output(path, overwrite, suffixes=suffixes)
    # (an existing .prj: write_map judges it once the CRS is known; the rest it takes as checked here)
    georef = check_side_outputs([output, preview, dsm_out], overwrite)
    check_outputs_apart([output, preview, dsm_out, *georef], inputs)
    check_gsd_value(gsd)
    chosen_base = _base_of(base.strip().lower())
    # the heights are filled for the volumes whether or not the surface model is written
    distance = None if fill_nodata.strip().lower() == "none" else check_fill_nodata(fill_nodata, gsd, "the volume")
    keep = filter_options(classes, drop_classes, None, "volume", clip_polygon)
    filled = None if fill_nodata.strip().lower() == "none" else distance or "all"
    try:
        result = gp.volume(
            subfolders_read(inputs, recursive), keep.polygon, gsd, base=chosen_base, classes=keep.classes or None, drop_classes=keep.drop_classes or None, fill_nodata=filled, full=all_points
        )
    except CameraError as exc:  # the grid spans the polygons' box, not the data's: say whose (it named neither)
        raise CameraError(f"{keep.polygon.source}: --gsd over its box: {exc}") from None
    rasters = [(output, result.above_base), (preview, None if preview is None else result.preview()), (dsm_out, result.heights)]
    # all or none; nothing asked, nothing written (nor a word on the .prj none would have)
    written = write_map(result.camera, result.crs, result.units, rasters, overwrite) if any(path for path, _ in rasters) else []
    summary = result.summary()
    if as_json:
        typer.echo(json.dumps({**summary, "outputs": [str(p) for p in written]}, indent=1))
        return
    unit = summary["units"]
    for pile in result.piles:
        x, y, z = pile.highest
        typer.echo(f"{pile.name}: fill {pile.fill:,.3f} {unit['volume']}, cut {pile.cut:,.3f}, net {pile.net:+,.3f}")
        typer.echo(f"  footprint {pile.area:,.2f} {unit['area']} ({counted(pile.pixels, 'pixel')} of {gsd:g} {unit['length']}; polygon {pile.polygon_area:,.2f})")
        typer.echo(f"  highest {z:.3f} at {x:.3f}, {y:.3f}: {pile.height:.3f} {unit['length']} above {'an' if pile.base['type'] == 'elevation' else 'a'} {pile.base['type']} base (mean z {pile.base['z']:.3f})")
        if "parts" in pile.base:  # a Feature's MultiPolygon
            typer.echo(f"  in {len(pile.base['parts'])} parts, each on a base of its own toe")
        if pile.filled or pile.empty:
            typer.echo(f"  {pile.filled:.1%} of its pixels filled by interpolation, {pile.empty:.1%} left empty")
    if len(result.piles) > 1:
        typer.echo(f"total: fill {result.fill:,.3f} {unit['volume']}, cut {result.cut:,.3f}, net {result.net:+,.3f}, footprint {result.area:,.2f} {unit['area']}")
    if written:
        typer.echo(f"wrote {', '.join(map(str, written))}")
