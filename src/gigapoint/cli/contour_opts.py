"""`render --gsd --contours INTERVAL [--contours-base B] [--contours-out lines.geojson]
[--contours-on-image]`: contour lines of the surface model's heights (render/contours.py), drawn
onto the orthophoto and/or written as GeoJSON beside it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..errors import GigapointError
from ..render.contours import check_base, check_interval, contour_lines, require_contourpy, write_contours
from .output import check_output

CONTOUR_SUFFIXES = {".geojson", ".json"}

ContoursOption = Annotated[
    float | None,
    typer.Option(
        "--contours",
        metavar="INTERVAL",
        help="With --gsd: contour lines of the surface model's heights (after --fill-nodata) every INTERVAL (cloud units) from --contours-base, every 5th an index contour; drawn onto the image, or with --contours-out written as GeoJSON instead. Needs contourpy.",
    ),
]
ContoursBaseOption = Annotated[
    float | None,
    typer.Option(metavar="BASE", help=r"The level --contours counts from: lines at BASE + k * INTERVAL, index contours at BASE + 5k * INTERVAL. \[default: 0]"),
]
ContoursOutOption = Annotated[
    Path | None,
    typer.Option(readable=False, help="The --contours lines as GeoJSON (LineStrings with 'elevation' and 'index' properties, in the cloud's CRS, named in its 'crs' member); the image is then left without them unless --contours-on-image."),
]
ContoursOnImageOption = Annotated[
    bool,
    typer.Option("--contours-on-image", help="Draw the --contours lines onto the image as well as writing --contours-out (without --contours-out they are drawn anyway): thin dark lines, index contours twice as wide."),
]


def check_contour_options(interval: float | None, base: float | None, out: Path | None, on_image: bool, gsd: float | None, overwrite: bool) -> bool:
    """One-line errors, before anything is read, for the --contours options: a bad interval or
    base, the others without --contours, --contours without --gsd, an output that exists.
    Returns whether the lines are drawn onto the image: without --contours-out, or asked."""
    if interval is None:
        given = [name for name, used in (("--contours-base", base is not None), ("--contours-out", out is not None), ("--contours-on-image", on_image)) if used]
        if given:  # each was dropped without a word
            raise GigapointError(f"{' and '.join(given)}: {'an option' if len(given) == 1 else 'options'} of --contours INTERVAL")
        return False
    if gsd is None:
        raise GigapointError("--contours: an option of --gsd (contour lines of a top-down render's surface model)")
    check_interval("--contours", interval)
    if base is not None:
        check_base("--contours-base", base)
    require_contourpy("--contours")
    if out is not None:
        check_output(out, overwrite, suffixes=CONTOUR_SUFFIXES)
    return on_image or out is None


def traced_contours(heights, camera, interval: float, base: float | None, units: dict):
    """The contour lines of ``heights`` (render's surface model) on ``camera``'s grid, traced before
    any file is written, so that too many levels for the heights' range is told first."""
    # heights are in the vertical unit, else (vertical_assumed: LAS files') the horizontal length unit
    unit = units.get("vertical") or (units.get("horizontal") if units.get("vertical_assumed") else None)
    unit = f" {unit['symbol']}" if unit else ""
    return contour_lines(heights, camera.world_file(), interval, base or 0.0, where="--contours", unit=unit)


def contour_write(lines, camera, out: Path, crs: str | None, wkt: str | None):
    """(``out``, its writer) for render's writes: ``lines`` as GeoJSON."""
    size = camera.world_file()[0]
    return out, lambda p: write_contours(p, lines, crs, wkt, pixel_size=size)
