"""``read_chunks`` and ``open_cloud``: one file's points as chunks, files and folders as one
PointCloud (gigapoint.io's functions; here so that ``import gigapoint.io`` imports none of
the kernels the cloud is built with)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from ..core.chunk import PointChunk
from ..core.cloud import PointCloud, build_cloud, check_valid_count
from ..errors import EmptyCloudError, InputError, check_switch
from ._base import DEFAULT_CHUNK_SIZE, check_chunk_size, headers_once
from .crs import warn_mixed_crs
from .filters import PointFilter, filtered
from .las import with_scan_angle
from .paths import (
    cloud_name,
    files_label,
    point_files_of,
    scan_angles_differ,
    skip_empty,
)
from .registry import reader_for


def read_chunks(path, chunk_size: int = DEFAULT_CHUNK_SIZE) -> Iterator[PointChunk]:
    """Yield the points of one file as PointChunks of at most ``chunk_size`` points."""
    chunk_size = check_chunk_size(chunk_size)
    reader = reader_for(path)
    return reader.read_chunks(Path(path), chunk_size)


def _with_progress(path: Path, chunks: Iterator[PointChunk], total: int | None, progress) -> Iterator[PointChunk]:
    task = progress.add_task(path.name, total=total)
    for chunk in chunks:
        progress.advance(task, len(chunk))
        yield chunk


@headers_once()  # counts, scan angles, then the points: each file's header read once
def open_cloud(
    *paths,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    progress: bool = False,
    name: str | None = None,
    layout: str = "auto",
    colors: str = "auto",
    chunked: bool | None = None,
    point_filter: PointFilter | None = None,
    where: str = "open",
) -> PointCloud:
    """Read files and/or directories (all supported files inside, sorted by name) into one PointCloud.

    ``layout`` / ``colors``: how the points are held (``core.build_cloud``: by default compact
    where the files say their scale, LAS).

    Several files are merged (attributes they all have are kept). With several files, a file
    without any point is skipped with a warning; one file without points raises EmptyCloudError.
    ``progress=True`` shows a progress bar on stderr (rich). ``chunked=True``: built in bounded
    memory (core/chunked.py: the files read three times, LAZ and text files decoded once and
    their points kept for the later passes; the points spilled to a temporary folder; the same
    cloud), for files whose points do not fit in memory as floats; None (the
    default): chunked when the files' headers say they hold more than ``CHUNKED_ABOVE`` (50 M).
    ``point_filter``: only the points it keeps are read (io/filters.py; gp.open's ``classes``,
    ``drop_classes`` and ``clip``); the headers' counts are then upper bounds. ``where``: the
    operation reading them (gp.open, section, orthophoto...), as the paths' errors name it.
    """
    chunk_size = check_chunk_size(chunk_size)
    check_switch("chunked", chunked, where, allow_none=True)  # "no" was taken as true
    check_switch("progress", progress, where)
    if name is not None and not isinstance(name, str):  # the name every message and output of the cloud starts with
        raise InputError(f"{where}: name must be a string, got {name!r}")
    files = point_files_of(paths, where=where)  # (none: "``where``: no file given", given_paths')
    plan = [(f, reader_for(f)) for f in files]
    if name is None:
        name = cloud_name(files)
    several = len(files) > 1
    empty: list[Path] = []
    from ..core.chunked import CHUNKED_ABOVE, HELD_BYTES_MIN, IN_MEMORY_BYTES_MIN, SPILLED_BYTES_MIN, check_room

    counts = [reader.point_count(f) for f, reader in plan]  # None: a text file, counted only when read
    if chunked is None:
        chunked = None not in counts and sum(counts) > CHUNKED_ABOVE
    counted = sum(c for c in counts if c)
    instead = ": open it with progressive=True (an LOD octree filled up to a memory limit) or convert it (gigapoint convert)"
    if chunked:
        check_room(name, counted, HELD_BYTES_MIN, SPILLED_BYTES_MIN, instead=instead)
    else:
        check_room(name, counted, IN_MEMORY_BYTES_MIN, instead=instead + ", or build it in bounded memory (chunked=True)")

    one_angle = scan_angles_differ(files)
    warn_mixed_crs(files)

    def chunks(bar=None) -> Iterator[PointChunk]:
        passing = point_filter.fresh() if point_filter is not None else None  # counted again each pass (chunked: three)
        for (f, reader), count in zip(plan, counts):
            it = reader.read_chunks(f, chunk_size)
            if one_angle:
                it = with_scan_angle(it)
            if bar is not None:
                it = _with_progress(f, it, count, bar)  # (the headers' counts, read once above: the points read, not kept)
            try:
                yield from filtered(it, f, passing)
            except EmptyCloudError:
                if not several:
                    raise
                empty.append(f)
                skip_empty(f)
        if passing is not None:  # not "no valid points": the filter left none
            passing.check_passed(files_label(files))

    def build(stream) -> PointCloud:
        try:
            if chunked:  # ``stream``: a function giving the chunks, called once a pass
                from ..core.chunked import build_cloud_chunked

                read_once = any(reader.reads_slowly(f) for f, reader in plan)  # LAZ, text: decoded once, not three times
                cloud = build_cloud_chunked(stream, name=name, layout=layout, colors=colors, read_once=read_once)
            else:
                cloud = build_cloud(stream, name=name, layout=layout, colors=colors)
        except EmptyCloudError as exc:
            failed = str(exc).split(": ", 1)[-1]
        else:
            cloud.source_files = tuple(files)  # gp.convert(cloud) takes their CRS
            return cloud
        if len(set(empty)) == len(files):  # each skipped as empty: not "no valid points" (NaN or absurd positions)
            check_valid_count(files_label(files), 0, 0, from_files=True)  # (raises: "no file holds any point", no "During handling" above it)
        raise EmptyCloudError(f"{files_label(files)}: {failed}")

    if not progress:
        return build(chunks if chunked else chunks())
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, console=Console(stderr=True), transient=True) as bar:
        return build((lambda: chunks(bar)) if chunked else chunks(bar))
