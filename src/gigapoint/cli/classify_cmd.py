"""`gigapoint classify`: points classified and written to one point file (gigapoint.classify_ground, survey/ground.py, noise.py, heights.py)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from ..errors import GigapointError, InputError, counted
from .app import app
from .cloud_opts import RecursiveOption, rate_note, skipped_note, subfolders_read

#: the lengths' help: in the cloud's units, the default converted from metres
_UNITS = "in the cloud's units (its CRS's: a cloud in feet takes the default in feet)"
#: what each mode is called, and its option
_MODES = {"ground": ("the ground classification", "--ground"), "noise": ("the noise classification", "--noise"),
          "heights": ("the heights above ground", "--height-above-ground")}  # fmt: skip
#: the modes each parameter's option is for (--height-above-ground alone makes its ground model of class 2 in cells of --cell)
_OPTION_MODES = {"cell": ("ground", "heights"), "slope": ("ground",), "window": ("ground",), "threshold": ("ground",), "scalar": ("ground",),
                 "step": ("noise",), "step_z": ("noise",), "isolated": ("noise",)}  # fmt: skip


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
    noise: Annotated[bool, typer.Option("--noise", help="Classify isolated points (birds, multipath returns, spikes) as noise (7), as lasnoise does; with --ground, found first and kept out of the ground.")] = False,
    step: Annotated[float | None, typer.Option("--step", help=f"--noise's cells' width (x and y), {_UNITS}. Default 4 m.")] = None,
    step_z: Annotated[float | None, typer.Option("--step-z", help=f"--noise's cells' height, {_UNITS}. Default as long as --step.")] = None,
    isolated: Annotated[int | None, typer.Option("--isolated", help="--noise: a point with at most this many others in the 3 x 3 x 3 cells around it is noise. Default 5.")] = None,
    height_above_ground: Annotated[bool, typer.Option("--height-above-ground", help="Write each point's height above the ground as the float attribute HeightAboveGround (PDAL's hag_dem, lasheight): the ground model of the file's class 2 points, or with --ground of the ground just found.")] = False,
    normalize: Annotated[bool, typer.Option("--normalize", help="With --height-above-ground (implied): z replaced by the height above ground, for a canopy height model (render --gsd of the output).")] = False,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace an existing OUTPUT.")] = False,
    recursive: RecursiveOption = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Classify point clouds (--ground: ground by the Simple Morphological Filter, as PDAL's smrf and lasground; --noise: isolated points, as lasnoise; --height-above-ground: each point's height above the ground), read a chunk at a time, into one point file."""
    from ..survey.ground import classify_ground

    heights = height_above_ground or normalize
    if not (ground or noise or heights):
        raise GigapointError("classify: say what to classify: --ground, --noise, --height-above-ground, or several")
    if noise and heights and not ground:  # (heights alone are measured from the file's own class 2, which --noise does not make)
        raise GigapointError("classify: --noise and --height-above-ground go together only with --ground; or run them one after the other")
    noise_params = {"step": step, "step_z": step_z, "isolated": isolated}
    params = {"cell": cell, "slope": slope, "window": window, "threshold": threshold, "scalar": scalar}
    _refuse_unused_options({**params, **noise_params}, {mode for mode, chosen in (("ground", ground), ("noise", noise), ("heights", heights)) if chosen})
    if noise and not ground:
        _classify_noise(inputs, output, noise_params, overwrite, recursive, quiet)
        return
    shown = not quiet and sys.stderr.isatty()
    if not ground:
        _heights_only(subfolders_read(inputs, recursive), output, params, normalize, overwrite, shown)
        return
    try:
        result = classify_ground(subfolders_read(inputs, recursive), output, **params, overwrite=overwrite, progress=shown,
                                 noise=noise_params if noise else None, heights=heights, normalize=normalize)  # fmt: skip
    except InputError as exc:  # classify_ground: cell must be ... said as the option
        raise type(exc)(_as_command(str(exc))) from None
    p = result.params
    units = p["units"]
    skipped = skipped_note(result.skipped)
    noise = f", {result.noise:,} noise kept" if result.noise else ""
    if "isolated" in p:  # (--noise: the points found, and the noise the files held already)
        kept = f", {result.noise - result.isolated:,} noise kept" if result.noise > result.isolated else ""
        noise = f", {result.isolated:,} isolated found noise (7; step {_step_told(p)}, isolated {p['isolated']}){kept}"
    up = "" if p["height_units"] == units else f" {p['height_units']}"  # threshold and scalar are heights: in degrees, said in metres
    print(
        f"{output}: {counted(result.points, 'point')}, {result.ground:,} ground (2), {result.non_ground:,} not (1){noise}{_heights_told(result.heights, p['height_units'], normalize)}{skipped}; "
        f"cell {p['cell']:.4g} {units}, slope {p['slope']:g}, window {p['window']:.4g}, threshold {p['threshold']:.4g}{up}, scalar {p['scalar']:.4g}{up}; "
        f"{result.seconds:.1f} s, {rate_note(result.points_per_second)}"
    )


def _refuse_unused_options(given: dict, modes: set) -> None:
    """A one-line error where a parameter is given (not None) whose option none of the chosen
    ``modes`` uses ("classify: --step is for the noise classification: give --noise too"):
    --ground --step 1000 ran with the default step, silently."""
    unused: dict[tuple, list[str]] = {}
    for name, value in given.items():
        if value is not None and not modes & set(_OPTION_MODES[name]):
            unused.setdefault(_OPTION_MODES[name], []).append(f"--{name.replace('_', '-')}")
    said = []
    for owners, options in unused.items():
        what, flags = (" or ".join(_MODES[mode][i] for mode in owners) for i in (0, 1))
        said.append(f"{', '.join(options)} {'is' if len(options) == 1 else 'are'} for {what}: give {flags} too")
    if said:
        raise GigapointError(f"classify: {'; '.join(said)}")


def _as_command(message: str) -> str:
    """A classification's message said of the command: its parameters as the options
    ("classify: --step-z must be ...", whichever function said it: height_above_ground's cell was
    left "classify: cell"), the command for its function ("out.txt: classify writes a .las, ..."
    was "classify_noise writes"; main() says overwrite=True as the option)."""
    for function in ("classify_ground", "classify_noise", "height_above_ground"):
        message = message.replace(f": {function} writes ", ": classify writes ")
        for name in _OPTION_MODES:
            message = message.replace(f"{function}: {name} ", f"classify: --{name.replace('_', '-')} ")
        message = message.replace(f"{function}: ", "classify: ")
    return message.replace("(--ground, heights=True)", "(--ground)")


def _classify_noise(inputs, output: Path, params: dict, overwrite: bool, recursive: bool, quiet: bool) -> None:
    """``classify --noise`` alone: classify_noise, and its counts in one line."""
    from ..survey.noise import classify_noise

    try:
        result = classify_noise(subfolders_read(inputs, recursive), output, **params, overwrite=overwrite, progress=not quiet and sys.stderr.isatty())
    except InputError as exc:
        raise type(exc)(_as_command(str(exc))) from None
    p = result.params
    skipped = skipped_note(result.skipped)
    kept = f", {result.kept_noise:,} noise kept" if result.kept_noise else ""
    print(
        f"{output}: {counted(result.points, 'point')}, {result.noise:,} isolated found noise (7){kept}{skipped}; "
        f"step {_step_told(p)}, isolated {p['isolated']}; {result.cells:,} cells in {result.table_bytes / 2**20:.1f} MiB; "
        f"{result.seconds:.1f} s, {rate_note(result.points_per_second)}"
    )


def _step_told(p: dict) -> str:
    """--noise's cells' width and height, each in its unit (a cloud in degrees: 'step 4e-05 ° x 4 m')."""
    if p["units"] == p["height_units"]:
        return f"{p['step']:.4g} x {p['step_z']:.4g} {p['units']}"
    return f"{p['step']:.4g} {p['units']} x {p['step_z']:.4g} {p['height_units']}"


def _heights_told(heights, units: str, normalize: bool) -> str:
    """The output line's words for the heights above ground written (None: none), in ``units``, the vertical unit's."""
    if heights is None:
        return ""
    return f", heights above ground {heights[0]:.4g} to {heights[1]:.4g} {units} in HeightAboveGround{' and z' if normalize else ''}"


def _heights_only(sources, output: Path, params: dict, normalize: bool, overwrite: bool, progress: bool) -> None:
    """--height-above-ground without --ground: from the class-2 points the files have."""
    from ..survey.heights import height_above_ground

    try:
        result = height_above_ground(sources, output, cell=params["cell"], normalize=normalize, overwrite=overwrite, progress=progress)
    except InputError as exc:
        raise type(exc)(_as_command(str(exc))) from None
    p = result.params
    skipped = skipped_note(result.skipped)
    print(
        f"{output}: {counted(result.points, 'point')}{_heights_told(result.heights, p['height_units'], normalize)}; "
        f"ground model of {counted(result.ground, 'class-2 point')}, cell {p['cell']:.4g} {p['units']}{skipped}; "
        f"{result.seconds:.1f} s, {rate_note(result.points_per_second)}"
    )
