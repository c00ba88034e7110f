"""`gigapoint info FILE...`: what point cloud files hold (format, points, bounds, attributes, CRS);
``--stats``: what their points hold, every point read (io/stats.py; an octree's node by node,
lod/query.py), or those the read filters keep (``--classes``, ``--clip-polygon``, ...: what is
inside a site boundary, the ground's heights)."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import typer

from ..errors import GigapointError
from .app import app
from .cloud_opts import (
    ChunkedOption,
    ClassesOption,
    ClipOption,
    ClipPolygonOption,
    ColorsOption,
    DropClassesOption,
    RecursiveOption,
    cloud_options,
    filter_options,
    option_names,
)
from .progress import progress_bar

#: a folder of more files than this is shown as one block (a city's 1 500 tiles were 21 000 lines)
FOLDER_LISTED = 10


@app.command()
def info(
    files: list[Path] = typer.Argument(
        ..., readable=False, help="Point cloud files (LAS/LAZ/PLY/E57/XYZ/XYZRGB/TXT/CSV/PTS/ASC/NPY/NPZ), directories, octrees, COPC/EPT files or URLs. A quoted glob pattern ('tiles/*.laz', 'city/**/*.laz') stands for what it matches."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of text: an object per file, or per folder or pattern summed up."),
    each: bool = typer.Option(False, "--each", help=f"Show each file of a folder or pattern of more than {FOLDER_LISTED} files, or of any with --stats (by default summed up in one block)."),
    stats: bool = typer.Option(
        False, "--stats", help="Read every point and show what they hold: true bounds (against the header's), each attribute's min/max/mean, classes, returns, flight lines, gps_time, colour ranges, invalid points."
    ),
    recursive: RecursiveOption = False,
    memory: bool = typer.Option(False, "--memory", help="Also load the points and print the bytes a point each component holds in memory."),
    colors: ColorsOption = "auto",
    chunked: ChunkedOption = None,
    classes: ClassesOption = None,
    drop_classes: DropClassesOption = None,
    clip: ClipOption = None,
    clip_polygon: ClipPolygonOption = None,
) -> None:
    """Show format, point count, bounds, attributes, LAS version/scale/offset and CRS of files.

    With --stats, statistics of their points (read once, in bounded memory), or of those the filters (--classes, --drop-classes, --clip, --clip-polygon) keep."""  # (one line: click keeps a docstring's line breaks)
    options = cloud_options(colors, chunked)
    given = {"--classes": classes, "--drop-classes": drop_classes, "--clip": clip, "--clip-polygon": clip_polygon}
    filters = [name for name, value in given.items() if value is not None]
    if filters and not stats:  # without --stats no point is read: a filter would do nothing
        raise GigapointError(f"{' and '.join(filters)}: only with --stats (info reads the headers only; --stats reads the points, those the filter keeps)")
    point_filter = filter_options(classes, drop_classes, clip, "info", clip_polygon)  # its errors name the options, before anything is read
    if stats and memory:
        raise GigapointError("--stats and --memory: one at a time (--stats reads the points a chunk at a time, holding none)")
    if options and not memory:  # without --memory nothing is loaded: the option would do nothing
        raise GigapointError(f"{option_names(options)}: only with --memory (how the loaded points are held)")
    from ..io import (
        PointStats,
        expand_paths,
        file_info,
        file_stats,
        files_label,
        folder_info,
        format_info,
        format_stats,
        pattern_matches,
        shown_url,
    )
    from ..lod import is_local_copc, is_lod_source, octree_info
    from ..lod.kinds import refuse_unwritten_copc

    # an octree (folder, COPC file, EPT dataset, URL) is one dataset, not a folder of files;
    # (path, octree?, its error, the folder argument it is summed up in or None)
    paths: list[tuple[Path, bool, GigapointError | None, Path | None]] = []
    for f in files:
        try:
            refuse_unwritten_copc([f])  # "no such file" sent users looking for a file a conversion is still making
            # a local COPC file is a LAZ file too, each point stored once: --stats reads its points as one
            lod = is_lod_source(f) and not (stats and is_local_copc(f))
            found = [] if lod else expand_paths([f], recursive=recursive)
            # a pattern names a folder's files: summed as a folder is ("tiles/*.laz" was a block a tile); one it matches alone is that file
            named = f.is_dir() or (len(found) > 1 and pattern_matches(f) is not None)
            summed = f if (stats or len(found) > FOLDER_LISTED) and named and not (each or memory) else None
            # a folder's COPC files listed one by one: shown as naming one shows it (its octree's lines, not 'LAZ 1.4')
            listed_copc = [summed is None and not stats and is_local_copc(p) for p in found]
            paths.extend([(f, True, None, None)] if lod else [(p, copc, None, summed) for p, copc in zip(found, listed_copc)])
        except GigapointError as exc:  # a missing file among several stopped the others from being shown
            paths.append((f, False, exc, None))
    failed = shown = 0
    infos: list = []  # those of the folder being summed up, so far (--stats: PointStats)
    # --stats reads every point: a bar on a terminal, as render's reading shows one
    reading = progress_bar("reading points", points_to_read(paths)) if stats else contextlib.nullcontext()
    with reading as advance:
        done = 0

        def read_points(n: int) -> None:
            nonlocal done
            done += n
            advance(done)

        for i, (path, octree, missing, folder) in enumerate(paths):
            data = None
            try:
                if missing is not None:
                    raise missing
                if stats and octree:  # its nodes read one at a time: each point is in one of them
                    from ..lod.query import octree_stats  # (its readers' numba kernels: loaded for an octree only)

                    data = octree_stats(path, on_chunk=read_points, point_filter=point_filter)
                elif stats:
                    data = file_stats(path, on_chunk=read_points, point_filter=point_filter)
                else:
                    data = octree_info(path) if octree else file_info(path)
            except GigapointError as exc:
                if len(paths) == 1:
                    raise
                failed += 1  # one damaged tile of a folder: said, and the others still shown
                typer.echo(json.dumps({"path": shown_url(path), "error": str(exc)}) if as_json else f"error: {exc}", err=not as_json)
            if folder is not None:  # shown once its last file is read
                infos += [data] if data is not None else []
                if (i + 1 < len(paths) and paths[i + 1][3] is folder) or not infos:
                    continue
                data, infos = summed_stats(folder, infos) if stats else folder_info(folder, infos), []
            if data is None:
                continue
            if isinstance(data, PointStats):
                data = {"path": shown_url(path), **data.result()}
            if point_filter is not None and shown == 0 and i + 1 == len(paths):  # the one block: the filter's error, not its stats of no point
                point_filter.check_passed(data["path"])
            if as_json:
                typer.echo(json.dumps(data))
            else:
                if shown:
                    typer.echo("")
                typer.echo(format_stats(data) if stats else format_info(data))
            shown += 1
            if memory and octree:  # it printed nothing of memory, without a word
                why = "an octree is read node by node as views need them; --memory measures point files"
                typer.echo(json.dumps({"path": shown_url(path), "memory": None, "why": why}) if as_json else f"memory: {why}")
            elif memory:  # (a point file, checked above: gp.open would check it for a conversion's unwritten COPC again)
                from ..io import open_cloud  # (here: the readers' kernels load numba, which info's other lines never need)

                cloud = open_cloud(path, **options)
                held = attributes_held(cloud)
                if as_json:
                    row = {"path": shown_url(path), "layout": cloud.layout, "n_points": cloud.n_points, "memory": cloud.memory(), "attributes": held}
                    typer.echo(json.dumps(row))
                else:
                    typer.echo(memory_line(cloud))
                    if held:
                        n = max(cloud.n_points, 1)
                        typer.echo("attributes held: " + ", ".join(f"{k} {v['bytes'] / n:.2f} ({v['held']})" for k, v in held.items()))
    if failed:
        raise GigapointError(f"info: {failed} of {len(paths)} files could not be read (said above)")
    if point_filter is not None:  # several blocks shown, of none it kept a point
        point_filter.check_passed(files_label(files))


def points_to_read(paths) -> int | None:
    """The points ``info --stats`` reads (its progress bar's total): the point files' header
    counts; None where one does not say (a text file) or cannot be read (its error comes later),
    or where an octree is read (its nodes are counted as they are read)."""
    from ..io import reader_for

    if any(octree for _, octree, _, _ in paths):
        return None
    try:
        counts = [reader_for(p).point_count(p) for p, octree, missing, _ in paths if not missing]
    except GigapointError:
        return None
    return None if None in counts else sum(counts)


def summed_stats(folder: Path, files: list) -> dict:
    """The ``PointStats`` of a folder's files, summed up, as ``--stats`` prints them."""
    from ..io import PointStats

    total = PointStats()
    for one in files:
        total.merge(one)
    return {"path": str(folder), **total.result()}


def memory_line(cloud) -> str:
    """``memory: 2.6 MiB, 23.9 bytes/point: positions 5.67, color 4.00, ... (compact layout)``: what
    a cloud holds per component (``PointCloud.memory``, ``ProgressiveOctree.memory``), or what the process
    holds for other kinds."""
    from ..core import PointCloud
    from ..io import human_bytes
    from ..lod.progressive import ProgressiveOctree

    n = max(int(cloud.n_points), 1)
    rss = peak_rss()
    tail = f", peak RSS {rss / 2**20:,.0f} MiB" if rss else ""
    if not isinstance(cloud, (PointCloud, ProgressiveOctree)):  # ('CompactOctree has no breakdown' named a class)
        return f"memory: {tail.removeprefix(', ') or 'not known'} (bytes per component are given for clouds held in memory, not octrees read by node)"
    m = cloud.memory()
    total = sum(m.values())
    parts = ", ".join(f"{k} {v / n:.2f}" for k, v in m.items())
    return f"memory: {human_bytes(total)}, {total / n:.2f} bytes/point: {parts} ({cloud.layout} layout){tail}"  # (a small cloud's was '0.0 MiB')


def attributes_held(cloud) -> dict:
    """Per attribute of a PointCloud: bytes held and how (core/attributes.py: 'uint8 + 1200',
    'constant 7326', or the dtype as read); {} for other kinds of cloud."""
    from ..core import PointCloud

    if not isinstance(cloud, PointCloud):
        return {}
    a = cloud.attributes
    return {k: {"bytes": a.nbytes_of(k), "held": a.held_dtype(k)} for k in a}


def peak_rss() -> int:
    """Peak resident memory of this process in bytes (0 where unknown)."""
    try:
        import resource
        import sys

        kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return int(kb) if sys.platform == "darwin" else int(kb) * 1024
    except (ImportError, OSError):
        return 0
