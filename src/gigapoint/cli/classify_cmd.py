"""`gigapoint classify`: points classified and written to one point file (gigapoint.classify_ground, classify.py)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from ..errors import GigapointError, InputError
from .app import app
from .cloud_opts import RecursiveOption, subfolders_read

#: the lengths' help: in the cloud's units, the default converted from metres
_UNITS = "in the cloud's units (its CRS's: a cloud in feet takes the default in feet)"


@app.command()
def classify(
    inputs: Annotated[list[Path], typer.Argument(readable=False, help="Point cloud files or directories (classified as one). A quoted glob pattern ('tiles/*.laz') stands for what it matches.")],
    output: Annotated[Path, typer.Option("-o", "--output", readable=False, help="The .las, .laz or .ply file to write: every point, every attribute as read, its classification set.")],
    ground: Annotated[bool, typer.Option("--ground", help="Classify ground (2) and the rest (1) by SMRF, PDAL's filters.smrf; noise (7, 18) keeps its class.")] = False,
    cell: Annotated[float | None, typer.Option("--cell", help=f"The raster's cell, {_UNITS}. Default 1 m.")] = None,
    slope: Annotated[float | None, typer.Option("--slope", help="The steepest terrain slope kept as ground, rise over run. Default 0.15.")] = None,
    window: Annotated[float | None, typer.Option("--window", help=f"The largest object (building) removed: the opening's largest radius, {_UNITS}. Default 18 m.")] = None,
    threshold: Annotated[float | None, typer.Option("--threshold", help=f"How far a ground point may lie off the ground model, {_UNITS}. Default 0.5 m.")] = None,
    scalar: Annotated[float | None, typer.Option("--scalar", help=f"What the threshold grows by per unit of the model's slope, {_UNITS}. Default 1.25 m.")] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace an existing OUTPUT.")] = False,
    recursive: RecursiveOption = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Classify point clouds (--ground: ground by the Simple Morphological Filter, as PDAL's smrf and lasground), read twice a chunk at a time, into one point file."""
    from ..classify import classify_ground

    if not ground:
        raise GigapointError("classify: say what to classify: --ground")
    params = {"cell": cell, "slope": slope, "window": window, "threshold": threshold, "scalar": scalar}
    try:
        result = classify_ground(subfolders_read(inputs, recursive), output, **params, overwrite=overwrite, progress=not quiet and sys.stderr.isatty())
    except InputError as exc:  # classify_ground: cell must be ... said as the option
        message = str(exc)
        for name in params:
            message = message.replace(f"classify_ground: {name} ", f"classify: --{name} ")
        raise type(exc)(message.replace("overwrite=True", "--overwrite").replace("classify_ground: ", "classify: ")) from None
    p = result.params
    units = p["units"]
    skipped = f", {result.skipped:,} invalid points skipped" if result.skipped else ""
    noise = f", {result.noise:,} noise kept" if result.noise else ""
    print(
        f"{output}: {result.points:,} points, {result.ground:,} ground (2), {result.non_ground:,} not (1){noise}{skipped}; "
        f"cell {p['cell']:.4g} {units}, slope {p['slope']:g}, window {p['window']:.4g}, threshold {p['threshold']:.4g}, scalar {p['scalar']:.4g}; "
        f"{result.seconds:.1f} s, {result.points_per_second / 1e6:.2f} M points/s"
    )
