"""``convert`` into one plain point file (``-o ground.laz``; .las, .laz or .ply, not .copc.laz):
every point of the input files that passes the filter, merged into one file, as PDAL's
translate and LAStools' las2las/lasmerge do. No octree: the chunks go from the readers to
io/write.py's writer as they are read, so no more than a chunk is held, however large the input.

The file is faithful to the inputs: the first LAS file's CRS, a LAS grid that holds every LAS
input's points exactly (their finest scale, the first file's offset: facts.input_facts, which
warns of files off it; centred, or coarser where 32-bit integers cannot span them: las_grid, which
says so), colours as each file stored them (8-bit values or 16-bit ones), the
attributes every file has (as gp.open keeps them), colours only where an input has them (LAS point
format 6, a PLY without red, green, blue where none has: not the grey the viewer draws them in;
black for the points of a colourless file among coloured ones, warned of). Invalid points (NaN, inf) are skipped with
the usual warning. ``reprojection`` (io/reproject.py: ``to_crs``): the points move into that CRS
as they are read, before the filter and the thinning (a clip box and cells in the output's
coordinates; a clip polygon moved there from its own CRS, the inputs' unless its GeoJSON names
another); the file then names that CRS and takes a grid of the inputs' precision in its units. ``thin``: one point kept per occupied cell of that edge over the whole file
set, the first in the inputs' order (io/thin.py), after the filter. ``colorization``
(io/colorize.py: ``colorize``): the points kept take their colours from an orthophoto, last (after
the reprojection, in the output's coordinates; after the filter and the thinning: no pixel is read
for a point left out)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...atomic import same_file
from ...core.bounds import valid_bounds
from ...core.chunk import PointChunk, attributes_in_common, warn_dropped_attributes
from ...core.cloud import MAX_ABS_COORDINATE, check_valid_count
from ...errors import EmptyCloudError, GigapointWarning, InputError, warn
from ...io import file_names, files_label, point_files_of, read_chunks, scan_angles_differ
from ...io._base import STREAM_CHUNK_SIZE
from ...io.colorize import Colorization
from ...io.crs import files_crs
from ...io.filters import PointFilter, filtered
from ...io.las import LasReader, with_scan_angle
from ...io.las_fields import las_grid
from ...io.registry import reader_for
from ...io.reproject import Reprojection, output_grid
from ...io.thin import Thinning
from ...io.write import POINT_FILE_SUFFIXES, check_point_file_output, file_has_color, source_crs_records, wkt_crs_records, write_points
from ..kinds import is_copc_name
from ..octree_dir import ConvertError
from .facts import input_facts
from .read import _skipped_if_empty
from .state import refuse_octrees


def is_point_file_name(out) -> bool:
    """Whether ``out`` names a plain point file (.las, .laz, .ply) that ``convert`` writes as one, not a COPC file."""
    return not is_copc_name(out) and Path(out).suffix.lower() in POINT_FILE_SUFFIXES


def refuse_octree_options(out: Path, given: list[str]) -> None:
    """A one-line ConvertError where options of an octree (``given``: convert's keywords, or the
    CLI's options) come with the plain point file ``out``: each meant something of an octree only."""
    if given:
        raise ConvertError(f"{out}: {', '.join(given)}: {'options' if len(given) > 1 else 'an option'} of an octree, not of a plain {out.suffix[1:].upper()} file")


class PointFiles:
    """The input files of a plain point file output (``write_point_file``) or of tiles (tiles.py),
    and what every output file takes from them, known from their headers before a point is read:
    ``files`` (folders and patterns expanded), ``label`` (their name in messages), ``names``
    (the attributes in common), ``counts`` (the headers' point counts; None: not told),
    ``las_grid`` (the grid holding every LAS input's points, else None) and ``crs_records``
    (the first CRS named; ``ply``: none), ``has_color`` (whether the output has colours: an input
    with points has them, or ``colorization``) and ``colorless`` (the files with points and none). ``valid_chunks`` reads them, a chunk at a time.
    ``reprojection``: their points moved into its CRS as they are read; the grid, the CRS records and
    the headers' bounds are then the target CRS's (each file's CRS checked before a point is read).
    ``colorization``: the points coloured from its raster (``colored``), whose CRS is checked
    against theirs (the output's) here. ``inputs``: paths as ``io.given_paths`` gives them (the
    caller's, under its argument's name); ``where``: the operation, as its errors name it.
    A file without points among several is skipped, said once (``io.point_files_of``)."""

    def __init__(
        self, inputs, out: Path, chunk_size: int | None, ply: bool = False, reprojection: Reprojection | None = None,
        colorization: Colorization | None = None, where: str = "convert",
    ):
        refuse_octrees(inputs)  # (an octree folder's .npy arrays were read as points)
        self.files = point_files_of(inputs, where=where)
        if any(same_file(out, f) for f in self.files):
            raise InputError(f"{out}: is one of the inputs; write it elsewhere (it would replace the points being read)")
        self.label = files_label(self.files)
        self.chunk_size = chunk_size or STREAM_CHUNK_SIZE
        self.reprojection = reprojection
        if reprojection is not None:  # (CRSs that differ are what it is for; every point leaves its grid)
            reprojection.check_files(self.files)
        else:
            facts = input_facts(self.files, one_grid=True)  # the LAS grid; CRSs that differ, files off the grid: warned
        self.one_angle = scan_angles_differ(self.files)
        self.names = _attributes_in_common(self.files, self.one_angle, self.chunk_size, out)
        self.counts = [reader_for(f).point_count(f) for f in self.files]
        self.crs_records = wkt_crs_records(reprojection.target_wkt()) if reprojection is not None else source_crs_records(self.files)
        if ply:  # (doubles on no grid; the CRS in a header comment: io/write.py)
            self.las_grid = None
        else:
            self.las_grid = output_grid(self.files, reprojection) if reprojection is not None else _las_inputs_grid(self.files, facts, out)
        self.colorization = colorization
        if colorization is not None:  # (the points' CRS is the output's: the target's where reprojected)
            colorization.check_crs(reprojection.target_wkt() if reprojection is not None else files_crs(self.files), self.label)
        self.colorless = {f for f, count in zip(self.files, self.counts) if count != 0 and not file_has_color(f)}
        self.has_color = colorization is not None or len(self.colorless) < sum(count != 0 for count in self.counts)
        if self.colorless and self.has_color and colorization is None:
            warn(f"{file_names(sorted(self.colorless))}: no colours; their points are written black (0, 0, 0) beside the other files' colours ({out})",
                 GigapointWarning)  # fmt: skip

    def colored(self, f, chunk: PointChunk, tally: dict) -> PointChunk:
        """``chunk`` (of file ``f``) coloured from the orthophoto, as it is without one; ``tally``'s
        "uncolored" counts the points that took no colour from it (outside it, under its mask)."""
        if self.colorization is None:
            return chunk
        chunk, uncolored = self.colorization.colored(chunk, f not in self.colorless)
        tally["uncolored"] += uncolored
        return chunk

    def points_filter(self, keep: PointFilter | None) -> PointFilter | None:
        """``keep`` as the points are filtered: in the target CRS where they are reprojected (its
        clip polygon moved there: ``Reprojection.moved_filter``)."""
        return keep if self.reprojection is None else self.reprojection.moved_filter(keep, self.files)

    def headers_bounds(self):
        """(lo, hi) of the files' points as their headers tell (in the target CRS where reprojected); None where one tells none."""
        return _headers_bounds(self.files, self.counts, self.reprojection)

    def valid_chunks(self, keep: PointFilter | None, progress, tally: dict):
        """(file, chunk) of every valid point (finite, within gigapoint's reach) that passes
        ``keep`` (counted afresh: a pass of its own), with the attributes in common; ``progress``
        told of the points read; ``tally``: {points: valid points that passed, skipped: invalid
        ones}. Once read, a filter that let nothing pass, or no valid point, is its error."""
        passing = keep.fresh() if keep is not None else None
        tally.update(points=0, skipped=0, uncolored=0)  # (uncolored: counted by ``colored``)
        for f in self.files:
            read = _told(with_scan_angle(read_chunks(f, self.chunk_size)) if self.one_angle else read_chunks(f, self.chunk_size), progress)
            if self.reprojection is not None:  # (before the filter: a clip box is in the output's coordinates; see points_filter)
                read = (self.reprojection.chunk(chunk, f) for chunk in read)
            for chunk in _skipped_if_empty(f, filtered(read, f, passing), len(self.files) > 1):
                valid = valid_bounds(chunk.xyz, MAX_ABS_COORDINATE)[0]
                n = int(np.count_nonzero(valid))
                rows = slice(None) if n == len(chunk) else valid
                tally["points"] += n
                tally["skipped"] += len(chunk) - n
                if n:
                    attributes = {a: chunk.attributes[a][rows] for a in self.names}
                    rgba = chunk.rgba[rows] if f not in self.colorless else _BLACK[np.zeros(n, np.intp)]  # (not the grey they are drawn in)
                    yield f, PointChunk(chunk.xyz[rows], rgba, attributes, scale=chunk.scale, color_bits=chunk.color_bits)
        if passing is not None:  # "no point passes the filter", not "no valid points"
            passing.check_passed(self.label)
        if not tally["points"]:  # (raised in the write: no file is left)
            check_valid_count(self.label, 0, tally["skipped"], from_files=True)


def write_point_file(
    inputs, out: Path, keep: PointFilter | None, overwrite: bool, chunk_size: int | None, progress, thin: tuple[float, str] | None = None,
    reprojection: Reprojection | None = None, colorization: Colorization | None = None,
) -> tuple[int, int, int, int]:
    """Write the points of the files and folders ``inputs`` that pass ``keep`` into ``out``, a
    chunk at a time (``progress``: lod/progress.py's, told of the points read); ``thin``:
    (spacing, the option as its errors name it), one point of each occupied cell kept. An
    existing ``out`` without ``overwrite`` is refused before anything is read, as is an ``out``
    that is one of the inputs, or cells too small for the headers' bounds; ``reprojection``: the
    points moved into its CRS (PointFiles); ``colorization``: the points written coloured from its
    raster. Returns (points written, invalid points skipped, valid points that passed the filter:
    those thinned, points written that took no colour from the raster)."""
    check_point_file_output(out, overwrite)
    ply = out.suffix.lower() == ".ply"
    inputs = PointFiles(inputs, out, chunk_size, ply, reprojection, colorization)
    keep = inputs.points_filter(keep)
    bounds = None
    if thin is not None:  # cells too small for the headers' bounds: refused here, before a point is read
        bounds = inputs.headers_bounds()
        Thinning(*thin, bounds, inputs.label)
    tally = {"points": 0, "skipped": 0}

    def chunks():  # called once a pass (a PLY file's 64-bit integers, points without a grid: a pass first)
        thinning = Thinning(*thin, bounds, inputs.label) if thin is not None else None  # (each pass meets every cell anew)
        progress.phase("write", None if None in inputs.counts else sum(inputs.counts))  # (with a filter: an upper bound)
        for f, chunk in inputs.valid_chunks(keep, progress, tally):
            yield inputs.colored(f, chunk if thinning is None else thinning.kept(chunk, f), tally)

    written = write_points(out, chunks, None, grid=inputs.las_grid, crs_records=inputs.crs_records, color_bits=None, has_color=inputs.has_color)
    check_valid_count(inputs.label, written, tally["skipped"], from_files=True)  # the skipped points' warning
    return written, tally["skipped"], tally["points"], tally["uncolored"]


#: the colour written for points of a file without colours among files with them
_BLACK = np.array([[0, 0, 0, 255]], np.uint8)


def _headers_bounds(files, counts, reprojection: Reprojection | None = None):
    """(lo, hi) of the files' points as their headers tell (those with points), each file's box
    in ``reprojection``'s CRS where given; None where one tells none (or an unfilled or impossible
    box: all 0, min above max, not finite)."""
    boxes = []
    for f, count in zip(files, counts):
        if count == 0:
            continue
        box = reader_for(f).header(f).get("bounds")
        lo, hi = (np.asarray(b, np.float64) for b in box) if box is not None else (np.zeros(3), np.zeros(3))
        if not (np.all(np.isfinite(lo) & np.isfinite(hi) & (lo <= hi)) and (lo.any() or hi.any())):
            return None
        boxes.append((lo, hi) if reprojection is None else reprojection.box(f, lo, hi))
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


def _las_inputs_grid(files, facts: dict, out: Path):
    """The grid every point of LAS inputs lies on (their finest scale, the first file's offset),
    where their headers' bounds fit 32-bit integers on it (else ``las_grid``'s, coarser where it
    must be: said, naming ``out``); None where an input is no LAS file (a grid is then made from
    the points' bounds, a pass over them)."""
    if facts["scale"] is None or not all(isinstance(reader_for(f), LasReader) for f in files):
        return None
    bounds = [reader_for(f).header(f)["bounds"] for f in files]
    lo, hi = np.min([b[0] for b in bounds], axis=0), np.max([b[1] for b in bounds], axis=0)
    return las_grid(lo, hi, facts["scale"], facts["offset"], out)
