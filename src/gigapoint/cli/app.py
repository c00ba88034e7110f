"""The typer application every command module registers on."""

from __future__ import annotations

import typer

app = typer.Typer(
    name="gigapoint",
    help="Render massive point clouds fast: LAS/LAZ/PLY/XYZ/NPY to images, octrees and a browser viewer.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
