"""`render --gsd --contours INTERVAL --contours-out lines.geojson`: contour lines of the surface
model's heights (render/contours.py), written as GeoJSON beside the orthophoto."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..errors import GigapointError
from ..render.contours import check_interval, contour_lines, require_contourpy, write_contours
from .output import check_output

CONTOUR_SUFFIXES = {".geojson", ".json"}

ContoursOption = Annotated[
    float | None,
    typer.Option(
        "--contours",
        metavar="INTERVAL",
        help="With --gsd: contour lines of the surface model's heights (after --fill-nodata) every INTERVAL (cloud units) from 0, every 5th an index contour; written to --contours-out. Needs contourpy.",
    ),
]
ContoursOutOption = Annotated[
    Path | None,
    typer.Option(readable=False, help="The --contours lines as GeoJSON (LineStrings with 'elevation' and 'index' properties, in the cloud's CRS, named in its 'crs' member)."),
]


def check_contour_options(interval: float | None, out: Path | None, gsd: float | None, overwrite: bool) -> None:
    """One-line errors, before anything is read, for --contours and --contours-out: a bad
    interval, one without the other, either without --gsd, an output that exists."""
    if interval is None and out is None:
        return
    if interval is None or out is None:
        raise GigapointError("--contours INTERVAL and --contours-out FILE.geojson go together: give both")
    if gsd is None:
        raise GigapointError("--contours: an option of --gsd (contour lines of a top-down render's surface model)")
    check_interval("--contours", interval)
    require_contourpy("--contours")
    check_output(out, overwrite, suffixes=CONTOUR_SUFFIXES)


def contour_write(heights, camera, interval: float, out: Path, crs: str | None, wkt: str | None, units: dict):
    """(``out``, its writer) for render's writes: the lines are traced now, so that too many
    levels for the heights' range is told before any file is written."""
    # heights are in the vertical unit, else (vertical_assumed: LAS files') the horizontal length unit
    unit = units.get("vertical") or (units.get("horizontal") if units.get("vertical_assumed") else None)
    unit = f" {unit['symbol']}" if unit else ""
    lines = contour_lines(heights, camera.world_file(), interval, where="--contours", unit=unit)
    size = camera.world_file()[0]
    return out, lambda p: write_contours(p, lines, crs, wkt, pixel_size=size)
