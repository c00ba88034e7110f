"""`gigapoint convert`: point cloud files -> an LOD octree (a gigapoint or Potree 2.0 directory, a COPC file),
or one plain point file (.las, .laz, .ply) of their points merged, filtered and thinned."""

from __future__ import annotations

import shlex
import sys
from contextlib import nullcontext
from pathlib import Path

import typer

from ..errors import InputError, counted
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
    rate_note,
    skipped_note,
    thin_option,
    uncolored_note,
)
from .settings_opts import named_option


@app.command()
def convert(
    inputs: list[Path] = typer.Argument(..., readable=False, help="Input files or directories (every supported point cloud file inside, as for render). A quoted glob pattern ('tiles/*.laz', 'city/**/*.laz') stands for what it matches."),
    output: Path = typer.Option(
        ..., "-o", "--output", readable=False, help="Output directory (created; resumed when a conversion was interrupted), or the .copc.laz file of --format copc, "
        "or one plain .las, .laz or .ply file of every point read (merged, filtered, thinned: no octree)."
    ),
    sampler: str | None = typer.Option(None, help="grid (first point per cell of a 128³ grid per node; the default) or poisson (minimum distance)."),
    memory_limit: str | None = typer.Option(None, "--memory-limit", help="Peak memory, e.g. 4G or 512M; kept from about 512M up (below it the process itself, ~200 MB, goes past a small limit: 64M peaked near 300 MB) (default: a quarter of the RAM; each of N local Dask workers': half the RAM among them, at most a quarter each; with --dask, the same from the workers' own memory). An input that fits is converted in memory; a larger one is spilled to OUTPUT/.partial in partitions."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing converted cloud in OUTPUT."),
    format: str | None = typer.Option(
        None,
        "--format",
        help="gigapoint (rendered directly), potree (Potree 2.0, for Potree's web viewers) or copc (one .copc.laz file, LAS 1.4); "
        "default: copc for an OUTPUT ending in .copc.laz, else gigapoint.",
    ),
    max_leaf: int | None = typer.Option(None, "--max-leaf", help="Most points a leaf node holds (default 20000)."),
    layout: str | None = typer.Option(
        None, "--layout", help="gigapoint format: compact (version 2, ~half the bytes, exact at the source's scale; the default) or words (version 1)."
    ),
    colors: str | None = typer.Option(None, "--colors", help="compact layout's colours: rgba (exact; the default) or rgb565 (16 bits, at most 4/255 off)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    dask: str | None = typer.Option(
        None,
        "--dask",
        metavar="ADDRESS",
        help="Convert on a running Dask cluster, e.g. tcp://host:8786; its workers read the inputs and write OUTPUT, "
        "which must be on a file system they all share (needs gigapoint\\[dask]).",  # \[: rich would take [dask] for markup and drop it
    ),
    workers: int | None = typer.Option(
        None, "--workers", help="Convert on a local Dask cluster of N single-threaded worker processes (needs gigapoint\\[dask])."
    ),
    recursive: RecursiveOption = False,
    classes: ClassesOption = None,
    drop_classes: DropClassesOption = None,
    clip: ClipOption = None,
    clip_polygon: ClipPolygonOption = None,
    thin: str | None = typer.Option(
        None,
        "--thin",
        metavar="SPACING",
        help="Plain point file only: keep one point per occupied cube cell of this edge, in the files' units (with --to-crs: the output's) "
        "(cells from coordinate 0, so tiles thinned apart line up), the first point in the files' order, over all the files.",
    ),
    to_crs: ToCrsOption = None,
    from_crs: FromCrsOption = None,
    exact_transform: ExactTransformOption = False,
    colorize: ColorizeOption = None,
    colorize_bits: ColorizeBitsOption = None,
) -> None:
    """Convert point clouds into a level-of-detail octree, out of core, resumable; or merge, filter and thin them into one .las, .laz or .ply file (-o ground.laz)."""
    from ..lod import ConvertError
    from ..lod import convert as run
    from ..lod.convert.state import local_path
    from ..lod.convert.to_file import is_point_file_name, refuse_octree_options
    from ..lod.kinds import is_copc_name, work_dir
    from ..lod.octree_dir import OctreeDir

    if dask is not None and workers is not None:
        raise ConvertError("--dask and --workers: give one of them (a running cluster's scheduler, or a local cluster's size)")
    output_crs = output_crs_keywords("convert", to_crs, from_crs, exact_transform, colorize, colorize_bits)
    point_filter = filter_options(classes, drop_classes, clip, "convert", clip_polygon)  # its errors name the options, before a cluster starts
    spacing = thin_option(thin, "convert")
    copc = format == "copc" or (format is None and is_copc_name(output))  # (convert's own default)
    to_file = format is None and is_point_file_name(output)  # one plain point file: nothing to watch, no cluster (convert refuses one)
    if to_file:  # said as the options typed (the library names its keywords); the path as it does, a file:// URL's local one
        typed = {"--sampler": sampler, "--memory-limit": memory_limit, "--max-leaf": max_leaf, "--layout": layout, "--colors": colors,
                 "--dask/--workers (client)": dask if dask is not None else workers}  # fmt: skip
        refuse_octree_options(Path(local_path(output, "the output", ConvertError)), [option for option, value in typed.items() if value is not None])
    watch = work_dir(output) if copc else output  # a COPC output appears only once complete
    # quoted as a shell needs it: `gigapoint view my scans` named two paths
    hint = None if quiet or to_file else lambda: print(f"while this runs, `gigapoint view {shlex.quote(str(watch))}` shows what has been read so far", file=sys.stderr)
    cluster = nullcontext(dask if dask is not None else workers)
    if not to_file and (dask is not None or workers is not None):
        from ..lod.convert.distributed import open_client

        cluster = open_client(dask if dask is not None else workers, announce=not quiet)  # prints the dashboard's address
    try:
        with cluster as client:
            result = run(
                [str(p) for p in inputs],
                output,
                sampler=sampler,
                memory_limit=memory_limit,
                overwrite=overwrite,
                format=format,
                max_leaf=max_leaf,
                layout=layout,
                colors=colors,
                progress=not quiet and sys.stderr.isatty(),
                client=client,
                recursive=recursive,
                **(point_filter.as_spec() if point_filter is not None else {}),
                thin=spacing,
                **output_crs,
                on_ready=hint,  # once OUT shows points: a refused run, or a first file that cannot be read, says only why
            )
    except (ConvertError, InputError) as exc:  # the library's keywords ('max_leaf must be ...', format='bogus') said as the options typed
        raise named_option(exc, {"max_leaf": "--max-leaf", f"convert: thin={spacing!r}": f"convert: --thin {thin}", **crs_options_named("convert", to_crs, from_crs),
                                 **keywords_as_options(output, colors, dask)}) from None  # fmt: skip
    except (KeyboardInterrupt, SystemExit):  # (Ctrl+C, SIGTERM) a bare "interrupted" left the user to guess whether OUT was lost
        if not to_file and OctreeDir(watch).read_state() is not None:
            print(f"{watch}: kept unfinished; run the same convert command again to resume it", file=sys.stderr)
        raise
    resumed = (" (resumed)" if result.resumed else "") + (", in memory" if result.in_memory else "")
    skipped = skipped_note(result.skipped)
    colored = uncolored_note(result.uncolored, colorize)
    if to_file:
        thinned = f", thinned from {result.thinned_from:,}" if result.thinned_from is not None else ""
        print(f"{output}: {counted(result.points, 'point')} ({result.format}){thinned}{colored}{skipped}, {result.seconds:.1f} s, {rate_note(result.points_per_second)}")
        return
    print(  # OUTPUT as given: a Dask run's result holds it absolute (its workers need that)
        f"{output}: {counted(result.points, 'point')} in {counted(result.nodes, 'node')} ({result.format}, {result.sampler}){colored}{skipped}, "
        f"{result.seconds:.1f} s, {rate_note(result.points_per_second)}{resumed}"
        + (f"; viewable after {result.first_view_seconds:.1f} s" if result.first_view_seconds is not None else "")
    )


def keywords_as_options(output: Path, colors: str | None, dask: str | None) -> dict[str, str]:
    """``named_option``'s blame for the library's words of convert's keywords (lod/convert:
    ``format: unknown format 'x'``, ``client='tcp://...': cannot reach ...``): the options typed."""
    return {
        "sampler": "--sampler",
        "format": "--format",
        "layout and colors": "--layout and --colors",  # (before "layout", which begins it)
        "layout": "--layout",
        "colors": "--colors",
        f"colors={colors!r}": f"--colors {colors}",
        f"{output}: thin": f"{output}: --thin",
        "client: a distributed conversion needs Dask": "--dask/--workers: a distributed conversion needs Dask",
        "client": "--workers",  # (a number of workers: an address is client='...')
        f"client={dask!r}": f"--dask {dask}",
    }
