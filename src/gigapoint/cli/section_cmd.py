"""`gigapoint section`: a cross-section along a line (gigapoint.section, survey/section.py)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from ..errors import GigapointError, counted, number_text
from ..render import RenderSettings
from ..render.image_files import warn_alpha_dropped
from .app import app
from .cloud_opts import ClassesOption, ClipPolygonOption, DropClassesOption, RecursiveOption, filter_options, subfolders_read
from .output import check_image_fits, check_output, check_outputs_apart, save_image
from .settings_opts import options_named, with_settings_options


def numbers(option: str, text: str, count: int, kind=float, separator: str = ",") -> list:
    """``text`` (``option``'s value) as ``count`` numbers, else a one-line error naming the option."""
    try:
        values = [kind(t) for t in text.split(separator)]
    except ValueError:
        values = []
    if len(values) != count:
        shape = {"--line": "X1,Y1,X2,Y2 (the line's two ends, in the files' coordinates)", "--size": "WIDTHxHEIGHT in pixels (1600x400)"}[option]
        raise GigapointError(f"section: {option} {text}: give {shape}")
    return values


#: a section's options of stereo pairs, refused: two eyes of an orthographic side view see the same
_NO_STEREO = {name: f"section: --{name}: a section is one orthographic view (no stereo)" for name in ("stereo", "ipd", "convergence")}


@app.command()
@with_settings_options(RenderSettings, refused=_NO_STEREO)
def section(
    inputs: Annotated[list[Path], typer.Argument(readable=False, help="Point cloud files or directories (merged). A quoted glob pattern ('tiles/*.laz') stands for what it matches.")],
    line: Annotated[str, typer.Option("--line", metavar="X1,Y1,X2,Y2", help="The section's line: its two ends, in the files' coordinates; the image shows its start on the left.")],
    width: Annotated[float, typer.Option("--width", metavar="W", help="The corridor's width: the points within W/2 of the line (square to it, any z) and between its ends are drawn.")],
    output: Annotated[Path, typer.Option("-o", "--output", readable=False, help="Image to write (.png, .jpg, .webp, .tif).")],
    settings: RenderSettings,  # one option per RenderSettings field (cli/settings_opts.py): --color-mode, --point-size, ...
    csv: Annotated[Path | None, typer.Option("--csv", readable=False, help="Also write the corridor's points as distance_along,offset,z[,classification] rows, by distance (offset: positive left of the line).")] = None,
    scale: Annotated[float | None, typer.Option("--scale", metavar="PIXELS_PER_UNIT", help="Pixels per unit of the files' coordinates (the image sized to fit).")] = None,
    size: Annotated[str | None, typer.Option("--size", metavar="WxH", help="Image size in pixels: the section as large as fits, centred. Default: 1920 wide, as tall as the section is.")] = None,
    vertical_exaggeration: Annotated[float, typer.Option("--vertical-exaggeration", metavar="K", help="Heights drawn K times their scale (default 1: heights and distances on one scale).")] = 1.0,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace existing output files.")] = False,
    recursive: RecursiveOption = False,
    classes: ClassesOption = None,
    drop_classes: DropClassesOption = None,
    clip_polygon: ClipPolygonOption = None,
) -> None:
    """Draw a cross-section: the points of a corridor along a line, seen from the side."""
    import gigapoint as gp

    from ..io.filters import corridor_of
    from ..survey.change import unit_symbols
    from ..survey.section import check_size

    check_output(output, overwrite)
    if csv is not None:
        check_output(csv, overwrite, suffixes={".csv"})
    check_outputs_apart([output, csv], inputs)
    warn_alpha_dropped(output, settings.background[3])
    lane = corridor_of(numbers("--line", line, 4), width, f"section: --line {line}", f"section: --width {number_text(width)}")
    if scale is not None and size is not None:
        raise GigapointError("section: --scale and --size: give one (a size sets the scale)")
    if scale is not None and not (math.isfinite(scale) and scale > 0):
        raise GigapointError(f"section: --scale must be a number > 0 (pixels per unit), got {number_text(scale)}")
    image_size = None if size is None else check_size(numbers("--size", size.lower(), 2, int, "x"))
    if not (math.isfinite(vertical_exaggeration) and vertical_exaggeration > 0):
        raise GigapointError(f"section: --vertical-exaggeration must be a number > 0, got {number_text(vertical_exaggeration)}")
    keep = filter_options(classes, drop_classes, None, "section", clip_polygon)  # (checked here: its errors name the options)
    chosen = {} if keep is None else {"classes": keep.classes or None, "drop_classes": keep.drop_classes or None, "clip_polygon": keep.polygon}
    cut = gp.section(subfolders_read(inputs, recursive), lane[:4], lane[4], **chosen)
    camera = cut.camera(scale, image_size, vertical_exaggeration)
    check_image_fits(output, camera.width, camera.height)
    with options_named():  # drawing's errors name the option (--color-attribute NAME that the files lack)
        frame = cut.render_frame(scale, image_size, vertical_exaggeration, settings)
    save_image(frame.image, output)
    pixel = camera.ortho_height / camera.height
    across, up = unit_symbols(cut.units)  # the CRS's units, as change and volume name them ('units' where it names none)
    across = across or "units"
    up = up or across
    side = f"{across} a side" if vertical_exaggeration == 1 and up == across else f"{across} across, {pixel / vertical_exaggeration:.6g} {up} up"
    typer.echo(f"wrote {output} ({camera.width}x{camera.height}, {counted(cut.cloud.n_points, 'point')} in the corridor, a pixel {pixel:.6g} {side})")
    if csv is not None:
        cut.write_csv(csv, overwrite)
        typer.echo(f"wrote {csv} ({counted(cut.cloud.n_points, 'row')})")
