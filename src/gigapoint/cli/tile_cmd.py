"""`gigapoint tile`: point files split into square LAS/LAZ tiles (gigapoint.tile, lod/convert/tiles.py)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from ..errors import GigapointError, counted, number_text
from .app import app
from .cloud_opts import (
    ClassesOption,
    ClipOption,
    ClipPolygonOption,
    ColorizeBitsOption,
    ColorizeOption,
    DropClassesOption,
    ExactTransformOption,
    FromCrsOption,
    RecursiveOption,
    ToCrsOption,
    crs_options_named,
    filter_options,
    output_crs_keywords,
    skipped_note,
    uncolored_note,
)
from .settings_opts import named_option


@app.command()
def tile(
    inputs: Annotated[list[Path], typer.Argument(readable=False, help="Point cloud files or directories (read as one, e.g. overlapping flight strips). A quoted glob pattern ('strips/*.laz') stands for what it matches.")],
    size: Annotated[float, typer.Option("--size", metavar="S", help="The tiles' edge, in the files' units (with --to-crs: the output's): tile (i, j) holds x in [i S, (i+1) S), y in [j S, (j+1) S), any z; a point on an edge is in the tile starting there, decided on the files' LAS grid.")],
    output: Annotated[Path, typer.Option("-o", "--output", readable=False, help="Folder of the tiles (made if missing), named NAME_XMIN_YMIN.laz after their lower-left corners.")],
    format: Annotated[str, typer.Option("--format", help="laz (the default) or las.")] = "laz",
    buffer: Annotated[float, typer.Option("--buffer", metavar="B", help="Each tile also holds the points within B of its square (0 to S), flagged in the LAS 1.4 overlap bit.")] = 0.0,
    name: Annotated[str | None, typer.Option("--name", help="The tiles' names' start (default: the input file's stem; for several inputs, the output folder's name).")] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Write into a folder holding LAS/LAZ files: the tiles of this run's names are replaced, other files left.")] = False,
    recursive: RecursiveOption = False,
    classes: ClassesOption = None,
    drop_classes: DropClassesOption = None,
    clip: ClipOption = None,
    clip_polygon: ClipPolygonOption = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
    to_crs: ToCrsOption = None,
    from_crs: FromCrsOption = None,
    exact_transform: ExactTransformOption = False,
    colorize: ColorizeOption = None,
    colorize_bits: ColorizeBitsOption = None,
) -> None:
    """Split point clouds into square LAS/LAZ tiles (lastile), read once, a chunk at a time; only tiles holding points are written."""
    from ..lod.convert.tiles import tile as run

    output_crs = output_crs_keywords("tile", to_crs, from_crs, exact_transform, colorize, colorize_bits)
    point_filter = filter_options(classes, drop_classes, clip, "tile", clip_polygon)  # its errors name the options
    try:
        result = run(
            [str(p) for p in inputs],
            output,
            size,
            buffer=buffer,
            format=format,
            name=name,
            overwrite=overwrite,
            recursive=recursive,
            progress=not quiet and sys.stderr.isatty(),
            **output_crs,
            **(point_filter.as_spec() if point_filter is not None else {}),
        )
    except GigapointError as exc:  # tile: size=0.0 said as the option
        raise named_option(exc, {f"tile: size={size!r}": f"tile: --size {number_text(size)}", f"tile: buffer={buffer!r}": f"tile: --buffer {number_text(buffer)}",
                                 f"tile: format={format!r}": f"tile: --format {format}", f"tile: name={name!r}": f"tile: --name {name}",
                                 **crs_options_named("tile", to_crs, from_crs)}) from None  # fmt: skip
    counts = np.array(result.points_per_tile)
    median = float(np.median(counts))
    buffered = f" (+{counted(result.buffer_points, 'buffer point')})" if result.buffer_points else ""
    skipped = skipped_note(result.skipped)
    print(
        f"{output}: {counted(len(counts), 'tile')} of {size:g} x {size:g} ({format}), {counted(result.points, 'point')}{buffered}{uncolored_note(result.uncolored, colorize)}{skipped}; "
        f"points per tile: min {counts.min():,}, median {median:,.{0 if median.is_integer() else 1}f}, max {counts.max():,}; {result.seconds:.1f} s"
    )

