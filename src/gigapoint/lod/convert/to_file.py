"""``convert`` into one plain point file (``-o ground.laz``; .las, .laz or .ply, not .copc.laz):
every point of the input files that passes the filter, merged into one file, as PDAL's
translate and LAStools' las2las/lasmerge do. No octree: the chunks go from the readers to
io/write.py's writer as they are read, so no more than a chunk is held, however large the input.

The file is faithful to the inputs: the first LAS file's CRS, a LAS grid that holds every LAS
input's points exactly (their finest scale, the first file's offset: facts.input_facts, which
warns of files off it), colours as each file stored them (8-bit values or 16-bit ones), the
attributes every file has (as gp.open keeps them). Invalid points (NaN, inf) are skipped with
the usual warning. ``thin``: one point kept per occupied cell of that edge over the whole file
set, the first in the inputs' order (io/thin.py), after the filter."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ...atomic import same_file
from ...core.chunk import PointChunk, attributes_in_common, warn_dropped_attributes
from ...core.cloud import MAX_ABS_COORDINATE, check_valid_count
from ...errors import EmptyCloudError, InputError
from ...io import expand_paths, files_label, read_chunks, scan_angles_differ
from ...io._base import DEFAULT_CHUNK_SIZE
from ...io.filters import PointFilter, filtered
from ...io.las import LasReader, with_scan_angle
from ...io.las_fields import las_grid
from ...io.registry import reader_for
from ...io.thin import Thinning
from ...io.write import POINT_FILE_SUFFIXES, check_point_file_output, source_crs_records, write_points
from ..build import valid_bounds
from ..copc_write import is_copc_name
from .facts import input_facts
from .read import _skipped_if_empty


def is_point_file_name(out) -> bool:
    """Whether ``out`` names a plain point file (.las, .laz, .ply) that ``convert`` writes as one, not a COPC file."""
    return not is_copc_name(out) and Path(out).suffix.lower() in POINT_FILE_SUFFIXES


def write_point_file(inputs, out: Path, keep: PointFilter | None, overwrite: bool, chunk_size: int | None, progress, thin: tuple[float, str] | None = None) -> tuple[int, int, int]:
    """Write the points of the files and folders ``inputs`` that pass ``keep`` into ``out``, a
    chunk at a time (``progress``: lod/progress.py's, told of the points read); ``thin``:
    (spacing, the option as its errors name it), one point of each occupied cell kept. An
    existing ``out`` without ``overwrite`` is refused before anything is read, as is an ``out``
    that is one of the inputs, or cells too small for the headers' bounds. Returns (points
    written, invalid points skipped, valid points that passed the filter: those thinned)."""
    check_point_file_output(out, overwrite)
    files = expand_paths([inputs] if isinstance(inputs, (str, os.PathLike)) else inputs)
    if any(same_file(out, f) for f in files):
        raise InputError(f"{out}: is one of the inputs; write it elsewhere (it would replace the points being read)")
    label = files_label(files)
    chunk_size = chunk_size or DEFAULT_CHUNK_SIZE
    facts = input_facts(files, one_grid=True)  # the LAS grid; CRSs that differ, files off the grid: warned
    one_angle = scan_angles_differ(files)
    names = _attributes_in_common(files, one_angle, chunk_size, out)
    counts = [reader_for(f).point_count(f) for f in files]
    bounds = None
    if thin is not None:  # cells too small for the headers' bounds: refused here, before a point is read
        bounds = _headers_bounds(files, counts)
        Thinning(*thin, bounds, label)
    tally = {"points": 0, "skipped": 0}

    def chunks():  # called once a pass (a PLY file's 64-bit integers, points without a grid: a pass first)
        passing = keep.fresh() if keep is not None else None
        thinning = Thinning(*thin, bounds, label) if thin is not None else None  # (each pass meets every cell anew)
        tally.update(points=0, skipped=0)
        progress.phase("write", None if None in counts else sum(counts))  # (with a filter: an upper bound)
        for f in files:
            read = with_scan_angle(read_chunks(f, chunk_size)) if one_angle else read_chunks(f, chunk_size)
            for chunk in _skipped_if_empty(f, filtered(_told(read, progress), f, passing), len(files) > 1):
                valid = valid_bounds(chunk.xyz, MAX_ABS_COORDINATE)[0]
                n = int(np.count_nonzero(valid))
                rows = slice(None) if n == len(chunk) else valid
                tally["points"] += n
                tally["skipped"] += len(chunk) - n
                if n:
                    attributes = {a: chunk.attributes[a][rows] for a in names}
                    chunk = PointChunk(chunk.xyz[rows], chunk.rgba[rows], attributes, scale=chunk.scale, color_bits=chunk.color_bits)
                    yield chunk if thinning is None else thinning.kept(chunk, f)
        if passing is not None:  # "no point passes the filter", not "no valid points"
            passing.check_passed(label)
        if not tally["points"]:  # (raised in the write: no file is left)
            check_valid_count(label, 0, tally["skipped"])

    ply = out.suffix.lower() == ".ply"
    crs = [] if ply else source_crs_records(files)
    written = write_points(out, chunks, None, grid=None if ply else _las_inputs_grid(files, facts), crs_records=crs, color_bits=None)
    check_valid_count(label, written, tally["skipped"])  # the skipped points' warning
    return written, tally["skipped"], tally["points"]


def _headers_bounds(files, counts):
    """(lo, hi) of the files' points as their headers tell (those with points); None where one
    tells none (or an unfilled or impossible box: all 0, min above max, not finite)."""
    boxes = []
    for f, count in zip(files, counts):
        if count == 0:
            continue
        box = reader_for(f).header(f).get("bounds")
        lo, hi = (np.asarray(b, np.float64) for b in box) if box is not None else (np.zeros(3), np.zeros(3))
        if not (np.all(np.isfinite(lo) & np.isfinite(hi) & (lo <= hi)) and (lo.any() or hi.any())):
            return None
        boxes.append((lo, hi))
    return (np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)) if boxes else None


def _told(chunks, progress):
    """``chunks`` as read, each told to ``progress`` (before the filter: the bar counts the files' points)."""
    for chunk in chunks:
        progress.advance(len(chunk))
        yield chunk


def _attributes_in_common(files, one_angle: bool, chunk_size: int, out: Path) -> list[str]:
    """The attributes every file with points gives (gp.open's rule; the others warned of), from
    the headers where they tell (else a file's first chunk): known before a point is written,
    for the output's header."""
    names, dropped = None, set()
    for f in files:
        reader = reader_for(f)
        if reader.point_count(f) == 0:  # (skipped when read, with its warning)
            continue
        found = reader.header(f).get("attributes")
        if found is None:  # a text file: known once read
            try:
                found = list(next(iter(read_chunks(f, chunk_size)), PointChunk(np.empty((0, 3)))).attributes)
            except EmptyCloudError:  # (as above)
                continue
        if one_angle:  # las.with_scan_angle: formats 0-5's scan_angle_rank read as scan_angle
            found = ["scan_angle" if a == "scan_angle_rank" else a for a in found]
        names = attributes_in_common(names, found, dropped)
    warn_dropped_attributes(str(out), dropped)
    return names or []


def _las_inputs_grid(files, facts: dict):
    """The grid every point of LAS inputs lies on (their finest scale, the first file's offset),
    where their headers' bounds fit 32-bit integers on it; None where an input is no LAS file
    (a grid is then made from the points' bounds, a pass over them)."""
    if facts["scale"] is None or not all(isinstance(reader_for(f), LasReader) for f in files):
        return None
    bounds = [reader_for(f).header(f)["bounds"] for f in files]
    lo, hi = np.min([b[0] for b in bounds], axis=0), np.max([b[1] for b in bounds], axis=0)
    return las_grid(lo, hi, facts["scale"], facts["offset"])
