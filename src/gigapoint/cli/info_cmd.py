"""`gigapoint info FILE...`: what point cloud files hold (format, points, bounds, attributes, CRS)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from .app import app


@app.command()
def info(
    files: list[Path] = typer.Argument(
        ..., help="Point cloud files (LAS/LAZ/PLY/XYZ/TXT/CSV/PTS/NPY/NPZ), directories, octrees, COPC/EPT files or URLs."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object per file instead of text."),
) -> None:
    """Show format, point count, bounds, attributes, LAS version/scale/offset and CRS of files."""
    from ..io import expand_paths, file_info, format_info
    from ..lod import is_lod_source, octree_info

    # an octree (folder, COPC file, EPT dataset, URL) is one dataset, not a folder of files
    paths: list[tuple[Path, bool]] = []
    for f in files:
        paths.extend([(f, True)] if is_lod_source(f) else [(p, False) for p in expand_paths([f])])
    for i, (path, octree) in enumerate(paths):
        data = octree_info(path) if octree else file_info(path)
        if as_json:
            typer.echo(json.dumps(data))
        else:
            if i:
                typer.echo("")
            typer.echo(format_info(data))
