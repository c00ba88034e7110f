"""``tile``: the points of point files split into square LAS/LAZ tiles (LAStools' lastile,
PDAL's filters.splitter), for processing pipelines and delivery.

Tiles are squares of edge ``size`` in x and y on a grid anchored at coordinate 0: tile (i, j)
holds the points of [i·size, (i+1)·size) x [j·size, (j+1)·size), any z, and is named
``<name>_<xmin>_<ymin>.laz`` after its lower-left corner (lastile's convention). A point is
placed by the position its tile stores, on the LAS grid (``TileAxis``), so every tile's stored
points lie in its square: one on an edge always goes to the tile that starts there (x = 0.7 with
a size of 0.1: tile 0.7, where floats said 0.7 / 0.1 = 6.999999999999999), as lastile places
it, and a float position less than half a grid step below an edge, stored on it, too. Only tiles
holding points of their own are written. ``buffer``: a tile also holds the points within that
distance of its square (in x and y: its square grown by ``buffer`` on every side, edges
included), each flagged in the LAS 1.4 "overlap" bit of its classification flags, as lastile
flags its buffers in LAS 1.4 ("withheld" would make readers drop them as if they were bad
points); the tile's own points keep the overlap flag the inputs gave them (formats 6-10) and
are 0 otherwise.

Every tile is written as ``convert -o x.laz`` writes its one file (to_file.PointFiles): the
first CRS named, a LAS grid holding every input's points exactly (one for all the tiles of a
run: points without a grid, of float files, get one made once from all of them, in a pass
over them before they are tiled, so that merging tiles back moves no point), the attributes all inputs have, colours as each file
stored them; ``to_crs``: their points moved into that CRS as they are read (io/reproject.py),
so tiles, their size, buffer and clip box are in its coordinates; ``colorize``: their colours
from an orthophoto's pixels, after that (io/colorize.py).

The inputs are read once, a chunk at a time (float files, whose grid takes a pass of its own:
twice, but text once, its points kept for the tiling: ``_grid_of_points``); each chunk's points
are bucketed by tile and appended to that tile's raw spill file (records of position, colour and attributes) in a
hidden work folder (beside the output folder where the run makes it, or in the nearest existing
folder above it where the folders on its way are missing too, else inside it); once
every point is read, the tiles are written one at a time from their spill files, then moved
into place together: a folder the run makes is the work folder's tiles renamed, so it appears
with every tile or not at all, even where the run is killed. So no more than a chunk
and one writer are held, and no file stays open between chunks, however many tiles there are.
Keeping a LAZ writer open per tile holds a compressor and its buffered points each (unbounded
with the tile count); closing and reopening them in append mode (laspy's LasAppender) reads
and rewrites each LAZ file's chunk table at every (chunk, tile) append. Measured (2 M demo
points in 103 tiles, 100 000-point chunks, a shared 2-core host): the spill 3.4 s, laspy's
reopen-and-append 19.3 s for the same tiles, ``convert -o one.laz`` of the same points 2.0 s.
The spill costs disk: the points' raw records (~50 bytes a point) until their tile is written.
A run that fails or is interrupted removes its work folder: no tile of it appears (a run
killed outright leaves its hidden work folder). A folder that was there is swapped for a new one
of its other files (hard-linked) and the tiles, so it holds every old tile or every new one, never
a mix (``_swap_in``; where it cannot be swapped, a mount point for one, the tiles are moved in
one at a time).
"""

from __future__ import annotations

import glob
import math
import os
import re
import shutil
import tempfile
import time
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...atomic import append_file, folder_refusal, folders_for, nearest_folder, refuse, same_file, write_failure
from ...core.chunk import PointChunk
from ...core.chunked import ReadOnce
from ...core.cloud import check_valid_count
from ...core.coords import MAX_SPAN
from ...errors import GigapointWarning, InputError, check_switch, count_or_inf, count_text, counted, is_real, warn, warnings_kept
from ...io import given_paths, with_subfolders
from ...io.colorize import open_colorization
from ...io.filters import point_filter
from ...io.las_fields import las_grid
from ...io.registry import reader_for
from ...io.reproject import Reprojection
from ...io.write import write_points
from ..kinds import refuse_unwritten_copc
from ..progress import NullProgress, RichProgress
from .to_file import PointFiles

#: what ``tile`` writes
TILE_FORMATS = ("laz", "las")
#: most tiles a run may make: more, over the data's extent, is surely a size in the wrong unit
MAX_TILES = 1_000_000
#: the attribute a buffer point is flagged in (LAS 1.4 classification flags' bit 3)
BUFFER_FLAG = "overlap"


@dataclass
class TileResult:
    out: Path
    tiles: list[Path]  # in name order of their (xmin, ymin): by x, then y
    points_per_tile: list[int]  # each tile's points, its buffer's included
    points: int  # points tiled (valid, passing the filter), each once
    buffer_points: int  # points written into tiles as buffers (copies of their neighbours')
    skipped: int  # invalid points (NaN, inf) left out
    seconds: float
    uncolored: int | None = None  # colorize=: points that took no colour from the raster (outside it, under its mask); None: not coloured


def tile(
    inputs,
    out,
    size,
    *,
    buffer=0.0,
    format: str = "laz",
    name: str | None = None,
    classes=None,
    drop_classes=None,
    clip=None,
    clip_polygon=None,
    overwrite: bool = False,
    recursive: bool = False,
    chunk_size: int | None = None,
    progress: bool = False,
    to_crs=None,
    from_crs=None,
    exact_transform=False,
    colorize=None,
    colorize_bits=None,
) -> TileResult:
    """Split the points of the files and folders ``inputs`` into square tiles of edge ``size`` (in
    the files' units, on a grid anchored at 0) written into the folder ``out`` as
    ``<name>_<xmin>_<ymin>.laz`` (``format`` "las": .las). ``name``: by default the input file's
    stem, or ``out``'s name for several inputs. ``buffer``: each tile also holds the points within
    that distance of its square, flagged "overlap". ``classes``, ``drop_classes``, ``clip``,
    ``clip_polygon``: only the points passing them are tiled (as ``gp.open``'s); ``recursive=True``: folders' subfolders too.
    ``to_crs`` (needs pyproj): the points are moved into that CRS first (from each file's own, or
    ``from_crs``), as ``convert``'s: ``size``, ``buffer`` and ``clip`` are then in its units
    (``exact_transform``: as ``convert``'s).
    ``colorize`` (needs rasterio): an orthophoto whose pixels colour the points, as ``convert``'s
    (after ``to_crs``); the result's ``uncolored`` counts those outside it or under its mask;
    ``colorize_bits``: how many bits its values hold, as ``convert``'s.

    ``out`` is made if missing, with the folders missing on its way (once every tile is written); one holding LAS/LAZ files already is refused without
    ``overwrite``, which replaces the tiles of this run's names and leaves every other file.
    Tiles appear only once every one is written, all at once (a folder ``out`` that was missing
    appears with all of them; one that was there is swapped for one of its other files and them). A point is in the tile whose square holds its position as stored, on the
    tiles' LAS grid (``TileAxis``): one on an edge in the tile that starts there. Bad values (a size not above 0 or above 2e12, a buffer below
    0 or above the size, more than a million tiles over the headers' extent) are one-line
    InputErrors before a point is read; inputs without header bounds (text, .npy) are refused as
    their points pass a million tiles' extent, before a tile is written."""
    t0 = time.perf_counter()
    for switch, value in (("overwrite", overwrite), ("recursive", recursive), ("progress", progress)):
        check_switch(switch, value, "tile")
    if not (is_real(size) and size > 0):
        raise InputError(f"tile: size={size!r}: a tile's edge is a number above 0, in the files' units")
    if size > MAX_SPAN:  # (1e300: tile -1 was named by a 301-digit corner, and placing points overflowed int64)
        raise InputError(f"tile: size={size!r}: a tile's edge must be at most {MAX_SPAN:g}, the span points can have")
    if not (is_real(buffer) and 0 <= buffer <= size):
        raise InputError(f"tile: buffer={buffer!r}: a buffer is a number from 0 to the tile's edge ({size:g}), in the files' units")
    if format not in TILE_FORMATS:
        raise InputError(f"tile: format={format!r}: tiles are written as {' or '.join(TILE_FORMATS)}")
    if name is not None and not (isinstance(name, str) and name and Path(name).name == name):
        raise InputError(f"tile: name={name!r}: the tiles' name is a file name's start, without folders")
    if not isinstance(out, (str, os.PathLike)) or not os.fspath(out):
        raise InputError(f"tile: the output must be a folder's path, got {out!r}")
    keep = point_filter(classes, drop_classes, clip, "tile", clip_polygon=clip_polygon)
    if from_crs is not None and to_crs is None:
        raise InputError(f"tile: from_crs={from_crs!r}: the CRS the inputs are in, for to_crs; give to_crs too")
    reprojection = None if to_crs is None else Reprojection(to_crs, from_crs, "tile", exact_transform)
    if colorize is not None and not isinstance(colorize, (str, os.PathLike)):
        raise InputError(f"tile: colorize={colorize!r}: the path of an orthophoto (a GeoTIFF)")
    out = Path(out)
    given = given_paths(inputs, "tile")  # (None among them: named, not a TypeError from pathlib)
    refuse_unwritten_copc(given)  # a COPC file a conversion still writes: its work folder named, not a bare "no such file"
    _check_apart(out, given, recursive)
    _put_back_set_aside(out)
    _check_output_folder(out, overwrite)
    inputs = with_subfolders(given) if recursive else given
    colorization = open_colorization(colorize, colorize_bits, "tile")  # a raster that cannot be read: said before a point is
    files = PointFiles(inputs, out, chunk_size, reprojection=reprojection, colorization=colorization, where="tile")
    keep = files.points_filter(keep)  # (a clip polygon moved into the CRS the points are tiled in)
    name = name or (Path(files.files[0]).stem if len(files.files) == 1 else out.resolve().name)
    bounds = files.headers_bounds()
    if bounds is not None:  # a size in the wrong unit: refused before a point is read
        _check_tile_count(*(bounds if keep is None else keep.clipped_bounds(*bounds)), size, files.label)
    shown = RichProgress() if progress else NullProgress()
    created = not out.exists()  # then the tiles are written into a folder renamed ``out`` at the end
    # (hidden: folder walks pass it over; beside ``out`` where this run makes it, so it appears whole or not at all;
    # where folders on its way are missing, in the nearest existing one: they are made only once every tile is written)
    work = Path(tempfile.mkdtemp(prefix=f".{name}.", suffix=".tiling", dir=nearest_folder(out.parent) if created else out))
    tiles_folder = work / "tiles"
    try:
        tiles_folder.mkdir()  # (not mkdtemp's: its mode 0700 would become ``out``'s)
        tally = {"points": 0, "skipped": 0}

        def read():  # the points to tile, coloured: a pass over the files a call
            shown.phase("read", None if None in files.counts else sum(files.counts))
            for f, chunk in files.valid_chunks(keep, shown, tally):
                yield files.colored(f, chunk, tally)

        if files.las_grid is not None:  # (headers that tell no bounds, or bounds the points pass: the tiles' count checked as they come)
            grid, points = files.las_grid, _extent_checked(read, float(size), files.label)
        else:  # (checked in the pass that makes the grid, over every point before one is tiled)
            grid, points = _grid_of_points(files, keep, read, float(size), work, shown)
        spill = _TileSpill(work, float(size), float(buffer), files.label, grid)
        for chunk in points():
            spill.add(chunk)
        check_valid_count(files.label, tally["points"], tally["skipped"], from_files=True)  # (the skipped points' warning)
        written = spill.write_tiles(name, format, files, grid, tiles_folder, shown)
        if created:  # every tile whole: now they appear, all at once
            with folders_for(out):
                tiles_folder.rename(out)
        else:  # (into a folder that was there: it is swapped for one of its files and the tiles)
            _swap_in(out, tiles_folder, work.name, written)
    finally:
        shutil.rmtree(work, ignore_errors=True)
        shown.close()
        if colorization is not None:
            colorization.close()
    tiles = [out / p.name for p in written]
    _warn_stale_tiles(out, name, tiles)
    counts = [spill.held[key] for key in spill.written_keys]
    uncolored = None if colorization is None else tally["uncolored"]
    return TileResult(out, tiles, counts, tally["points"], sum(counts) - tally["points"], tally["skipped"], time.perf_counter() - t0, uncolored)


def _swap_in(out: Path, tiles_folder: Path, work_name: str, written: list[Path]) -> None:
    """Put the tiles of ``tiles_folder`` into ``out``, a folder that was there, all at once, as a
    folder the run makes appears: ``tiles_folder`` (in the work folder ``work_name``, inside
    ``out``) takes hard links of ``out``'s other entries (the user's files, tiles of other names:
    only tiles of this run's names are replaced), ``out`` is renamed away beside itself, then
    ``tiles_folder`` renamed ``out``, and the old folder removed. A failure between the renames
    puts the old folder back (a one-line InputError); a run killed there leaves no ``out``, its
    old folder whole beside it (hidden, ``.OUT.*.replaced``). Where ``out`` cannot be renamed or
    its entries linked (a mount point, a parent folder not writable, a file system without hard
    links, the working folder), the tiles are moved in one at a time (a run killed then leaves some)."""
    folder = out.resolve()  # (an output given through a link: the folder it names)
    old = None
    try:
        if Path.cwd().is_relative_to(folder):  # (renamed away, a shell's working folder would be gone)
            raise OSError("the working folder")
        for entry in folder.iterdir():
            if entry.name != work_name and not (tiles_folder / entry.name).exists():
                _link(entry, tiles_folder / entry.name)
        shutil.copystat(folder, tiles_folder)  # (its permissions, not the work folder's)
        old = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".replaced", dir=folder.parent))
        os.rename(folder, old)
    except OSError:
        if old is not None and old.is_dir() and not any(old.iterdir()):
            old.rmdir()
        for tile_path in written:
            os.replace(tile_path, out / tile_path.name)
        return
    try:
        os.rename(old / work_name / tiles_folder.name, folder)
    except OSError as exc:
        os.rename(old, folder)  # as it was
        raise InputError(f"{out}: the new tiles were not moved in ({write_failure(exc)}); the folder is as it was") from None
    except BaseException:
        os.rename(old, folder)
        raise
    _carry_over(old, folder, work_name, {p.name for p in written})
    shutil.rmtree(old, ignore_errors=True)


def _carry_over(old: Path, folder: Path, work_name: str, ours: set[str]) -> None:
    """Entries written into the old folder after its entries were linked (another run's tiles of
    other names, a user's file), moved into the new ``folder`` rather than removed with ``old``:
    those missing there, and files replaced since (another inode) unless they are this run's tiles."""
    for entry in old.iterdir():
        target = folder / entry.name
        if entry.name == work_name:
            continue
        if not os.path.lexists(target):
            os.rename(entry, target)
        elif entry.name not in ours and not entry.is_dir() and os.lstat(entry).st_ino != os.lstat(target).st_ino:
            os.replace(entry, target)


def _put_back_set_aside(out: Path) -> None:
    """The folder a rerun set aside (``_swap_in``) and was killed before its new one moved in, put
    back where ``out`` is missing, with a warning: it held the user's files, which the next run
    would otherwise leave hidden beside a folder of new tiles only."""
    folder = Path(os.path.realpath(out))  # (as _swap_in named it: an output given through a link, the folder it named)
    if folder.exists() or not folder.parent.is_dir():
        return
    # (mkdtemp's 8 random characters: '.tiles.*.replaced' took tiles.v2's, '.tiles.v2.XXXXXXXX.replaced')
    aside = sorted(folder.parent.glob(f".{glob.escape(folder.name)}.{'[a-z0-9_]' * 8}.replaced"), key=lambda p: p.stat().st_mtime)
    if not aside or not aside[-1].is_dir():
        return
    os.rename(aside[-1], folder)
    for work in folder.glob(".*.tiling"):  # (the killed run's own work, inside the folder it replaced)
        shutil.rmtree(work, ignore_errors=True)
    warn(f"{out}: put back as it was before a run that was stopped while replacing its tiles", GigapointWarning)


def _link(entry: Path, to: Path) -> None:
    """``entry`` (a file, a link, a folder: its tree) hard-linked as ``to``, its data not copied."""
    if entry.is_symlink():
        os.symlink(os.readlink(entry), to)
    elif entry.is_dir():
        shutil.copytree(entry, to, symlinks=True, copy_function=os.link)
    else:
        os.link(entry, to, follow_symlinks=False)


def _check_output_folder(out: Path, overwrite: bool) -> None:
    """Refuse, in one line naming ``out``, a tiles' folder that is a file, lies through a file or
    in a folder not writable, or holds LAS/LAZ files already without ``overwrite``."""
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: is a file, not a folder for tiles")
    refuse(out, folder_refusal(out), InputError)  # (folders missing on its way are made as the tiles move in)
    held = sorted(p.name for p in out.iterdir() if p.suffix.lower() in (".las", ".laz") and not p.name.startswith(".")) if out.is_dir() else []
    if held and not overwrite:
        shown = ", ".join(held[:3]) + (", ..." if len(held) > 3 else "")
        raise InputError(f"{out}: holds {len(held):,} LAS/LAZ files already ({shown}); pass overwrite=True to replace the tiles of the same names (other files are left as they are)")


def _check_apart(out: Path, inputs, recursive: bool) -> None:
    """One-line errors where the tiles' folder is an input folder, or lies in one read with
    ``recursive``: the next run read its tiles as input points (`tile rec -o rec/tiles
    --recursive` run twice: every point twice), and ``overwrite`` replaced files it was reading."""
    folders = [Path(p) for p in inputs if Path(p).is_dir()]
    if out.exists() and any(same_file(out, folder) for folder in folders):
        raise InputError(f"{out}: is one of the inputs; write it elsewhere (it would replace the points being read)")
    if recursive:
        inside = out.resolve()
        for folder in folders:
            if inside.is_relative_to(folder.resolve()):
                raise InputError(f"{out}: lies in {folder}, read with recursive=True; write the tiles elsewhere (the next run would read them as input points)")


def _grid_of_points(files: PointFiles, keep, read, size: float, work: Path, progress):
    """(the LAS grid of points that came without one (float files: text, NPY, PLY), the function
    giving the points to tile): one grid for the run, from all the points tiled (not one a tile:
    tiles of one survey share their grid), as ``convert -o x.laz`` makes it, in a pass over them
    before they are tiled: a point is placed by its position as the grid stores it
    (``TileAxis``), and one less than half a step below an edge is stored on it. The tiles' count
    is checked here, on the points read so far (these files' headers tell no bounds), and not
    again as they are tiled: every point was checked before one is.
    Files that read slowly (text, ASCII PLY, LAZ beside them: parsing is most of a run's time)
    are read once, by ``read``, their points kept in ``work`` (core/chunked.py's ReadOnce) for the
    tiling pass, which reads those back; the others (NPY, binary PLY: a read costs a copy) are
    read again by it, so this pass's warnings are dropped (the tiling pass says them). Kept too,
    a 4 M-point NPY (x, y, z, colour, 2 attributes; 103 tiles) took more, not less: 3.10 s of
    CPU a run against 2.95 s read twice (writing a chunk's points and reading them back costs
    more than copying them from the memory-mapped file again; a shared 2-core host), and a copy
    of its points on the work folder's disk (~124 MB) until they are tiled."""
    if any(reader_for(f).reads_slowly(f) for f in files.files):
        once = ReadOnce(read, work, files.label, writing=nullcontext)  # (a full disk: the spill's OSError, as the tiles')
        chunks, warnings_said = once.first(), nullcontext()
    else:
        progress.phase("scan", None if None in files.counts else sum(files.counts))
        once, chunks, warnings_said = None, (chunk for _, chunk in files.valid_chunks(keep, progress, {})), warnings_kept()
    extent = _Extent(size, files.label)
    with warnings_said:
        for chunk in chunks:
            extent.add(chunk)
    grid = las_grid(extent.lo, extent.hi)
    if once is None:
        return grid, read

    def kept():  # the points read, as read, each chunk's files removed once read back (the tiles' spill grows as they go)
        progress.phase("tile", extent.n)
        for chunk in once.last():
            yield chunk
            progress.advance(len(chunk))

    return grid, kept


class _Extent:
    """The bounds of the points read so far, the tiles' count over them checked as each chunk
    comes (``_check_tile_count``): points whose files' headers tell no bounds (text, NPY), or
    bounds they pass, are refused for a size in the wrong unit before a tile is written (was: a
    tile a point until MAX_TILES stopped them, minutes later)."""

    def __init__(self, size: float, where: str):
        self.size, self.where = size, where
        self.lo, self.hi, self.n = np.full(3, np.inf), np.full(3, -np.inf), 0

    def add(self, chunk: PointChunk) -> None:
        self.lo, self.hi, self.n = np.minimum(self.lo, chunk.xyz.min(axis=0)), np.maximum(self.hi, chunk.xyz.max(axis=0)), self.n + len(chunk)
        _check_tile_count(self.lo, self.hi, self.size, self.where)


def _extent_checked(points, size: float, where: str):
    """``points`` (a function giving the chunks to tile), each chunk's extent checked as it comes (``_Extent``)."""

    def checked():
        extent = _Extent(size, where)
        for chunk in points():
            extent.add(chunk)
            yield chunk

    return checked


def _check_tile_count(lo, hi, size: float, where: str) -> None:
    """More than MAX_TILES tiles over x and y of ``lo``..``hi``: a one-line InputError."""
    across = [max(0, count_or_inf(lambda a=a: math.floor(hi[a] / size) - math.floor(lo[a] / size) + 1)) for a in (0, 1)]  # (a clip beside the data: 0)
    if across[0] * across[1] > MAX_TILES:  # (count_text: a count past 1e15 as 1.2e+305, not in 306 digits)
        raise InputError(f"tile: size={size!r}: {count_text(across[0])} x {count_text(across[1])} tiles over the extent of {where}, above {MAX_TILES:,}; take larger tiles")


def tile_index(values: np.ndarray, size: float) -> np.ndarray:
    """The tile (on one axis) of each of ``values``: i with i·size <= v < (i+1)·size, those
    products as floats compute them (the names' corners): a division rounded across an edge is mended.
    For positions as stored (``TileAxis``)."""
    i = np.floor(values / size)
    i -= values < i * size
    i += values >= (i + 1) * size
    return i.astype(np.int64)


def _in_steps(value: float, scale: float) -> float:
    """``value`` in steps of ``scale``: a whole number where it is one but for float rounding
    (0.1 / 0.01 is 10.000000000000002), else as divided."""
    steps = value / scale
    whole = round(steps)
    return float(whole) if abs(steps - whole) <= 1e-9 * max(1.0, abs(steps)) and abs(whole) < 2**53 else steps


class TileAxis:
    """The tiles' edges on one axis (x or y): every ``size`` from 0, a tile's buffer ``buffer``
    beyond its edges. ``scale``, ``offset``: the LAS grid the tiles store positions on; each point
    is placed by its position as its tile stores it (the grid integer io/write.py rounds it to), so
    every tile's stored points lie in its square, [i·size, (i+1)·size) (a point less than half a
    grid step below an edge is stored on it: it is in the tile above). Where the size and the
    offset are whole numbers of steps (the usual case: a size of 0.1 on a grid of 0.01 or 0.001),
    in integers, exactly, so a point on an edge always goes to the tile that starts there (x = 0.7
    into tile 0.7..0.8, where floats said 0.7 / 0.1 = 6.999999999999999: tile 0.6); otherwise
    (edges between grid lines) by the stored position as readers compute it (X·scale + offset)
    against the edges, as floats compute them (``tile_index``)."""

    def __init__(self, size: float, buffer: float, scale: float, offset: float):
        self.size, self.buffer, self.scale, self.offset = size, buffer, scale, offset
        self.steps, self.start, self.reach = (_in_steps(v, scale) for v in (size, offset, buffer))  # in grid steps
        # (whole steps beyond 2^53 are no exact count, and their integers overflow int64: a size of 1e10 on a 1e-9 grid)
        self.exact = all(v.is_integer() and abs(v) < 2**53 for v in (self.steps, self.start))

    def _stored(self, values: np.ndarray) -> np.ndarray:
        """Each of ``values`` as its grid integer (float)."""
        return np.rint((values - self.offset) / self.scale)

    def _steps_from_0(self, values: np.ndarray) -> np.ndarray:
        """Each of ``values`` in whole grid steps from 0 (``exact`` grids)."""
        return self._stored(values).astype(np.int64) + int(self.start)

    def _read_back(self, values: np.ndarray) -> np.ndarray:
        """Each of ``values`` as a reader of the tile reads it back."""
        return self._stored(values) * self.scale + self.offset

    def index(self, values: np.ndarray) -> np.ndarray:
        """The tile of each of ``values``."""
        if self.exact:
            return self._steps_from_0(values) // int(self.steps)
        return tile_index(self._read_back(values), self.size)

    def near(self, values: np.ndarray, tile: np.ndarray) -> np.ndarray:
        """Whether each of ``values`` lies within the buffer of its ``tile`` (edges included), as stored."""
        if self.exact:  # whole steps from the edges, against the buffer in steps (off the grid or not: no float rounding)
            at = self._steps_from_0(values)
            return (at - tile * int(self.steps) >= -self.reach) & (at - (tile + 1) * int(self.steps) <= self.reach)
        at = self._read_back(values)
        return (at >= tile * self.size - self.buffer) & (at <= (tile + 1) * self.size + self.buffer)


def tile_groups(i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the distinct tiles (i, j) in order as rows, each point's row among them, the points in
    each): ``np.unique(np.column_stack([i, j]), axis=0, return_inverse=True, return_counts=True)``
    (``where`` flat), by one int64 key a point, counted in a table where the chunk's tiles span
    few keys. np.unique over rows sorts them as structured values (a generic comparison a step):
    16 of a 5 M-point file's 35 s of ``gigapoint tile``."""
    if not len(i):
        return np.empty((0, 2), np.int64), np.empty(0, np.intp), np.empty(0, np.intp)
    i0, j0 = int(i.min()), int(j.min())
    span_i, span_j = int(i.max()) - i0 + 1, int(j.max()) - j0 + 1
    span = span_i * span_j  # (Python ints: no overflow)
    if span >= 2**62:
        keys, where, counts = np.unique(np.column_stack([i, j]), axis=0, return_inverse=True, return_counts=True)
        return keys, where.ravel(), counts
    key = (i - i0) * span_j + (j - j0)
    if span <= max(1 << 20, 4 * len(key)):
        counts_all = np.bincount(key, minlength=span)
        uniq = np.flatnonzero(counts_all)
        index = np.zeros(span, np.intp)
        index[uniq] = np.arange(len(uniq))
        where, counts = index[key], counts_all[uniq]
    else:
        uniq, where, counts = np.unique(key, return_inverse=True, return_counts=True)
        where = where.ravel()
    return np.column_stack([uniq // span_j + i0, uniq % span_j + j0]), where, counts


def _corner(value: float) -> str:
    """A tile corner's coordinate as its name says it: an integer where it is one."""
    return str(int(value)) if value.is_integer() else f"{value:.15g}"


def tile_name(name: str, i: int, j: int, size: float, suffix: str) -> str:
    return f"{name}_{_corner(i * size)}_{_corner(j * size)}.{suffix}"


class _TileSpill:
    """Each tile's points as they come, appended to its raw file in ``folder`` (one record a point:
    position, colour, the colour bits of its file, its attributes; the layout of the first chunk);
    ``grid``: the (scale, offset) the tiles store positions on, which places the points."""

    def __init__(self, folder: Path, size: float, buffer: float, where: str, grid):
        self.folder, self.size, self.buffer, self.where = folder, size, buffer, where
        self.axes = [TileAxis(size, buffer, float(grid[0][a]), float(grid[1][a])) for a in (0, 1)]  # on the grid's (scale, offset) of x, of y
        self.dtype = None
        self.held: dict[tuple[int, int], int] = {}  # points spilled for each tile
        self.own: dict[tuple[int, int], int] = {}  # of them, the tile's own (not its buffer's)
        self.written_keys: list[tuple[int, int]] = []

    def path(self, key: tuple[int, int]) -> Path:
        return self.folder / f"{key[0]}_{key[1]}.points"

    def add(self, chunk: PointChunk) -> None:
        """Append the points of ``chunk`` to their tiles' files (and, with a buffer, to their neighbours')."""
        records = self._records(chunk)
        i, j = (self.axes[a].index(chunk.xyz[:, a]) for a in (0, 1))
        rows, ti, tj = [np.arange(len(chunk))], [i], [j]
        if self.buffer:
            reach = math.ceil(self.buffer / self.size)  # (a buffer up to the edge: the next tile on each side)
            near_x = {d: self.axes[0].near(chunk.xyz[:, 0], i + d) for d in range(-reach, reach + 1)}
            near_y = {d: self.axes[1].near(chunk.xyz[:, 1], j + d) for d in range(-reach, reach + 1)}
            for dx, in_x in near_x.items():
                for dy, in_y in near_y.items():
                    if dx or dy:
                        sel = np.flatnonzero(in_x & in_y)
                        rows.append(sel)
                        ti.append(i[sel] + dx)
                        tj.append(j[sel] + dy)
        # np.take, not records[...]: numpy's fancy indexing copies structured records ~10x slower
        # (1.7 M records of 52 bytes in random order: 3.4 s against 0.35 s, a shared AMD EPYC)
        if self.buffer:
            rows = np.concatenate(rows)
            records = np.take(records, rows)
            records[f"attribute {BUFFER_FLAG}"][len(chunk) :] = 1
        keys, where, counts = tile_groups(np.concatenate(ti), np.concatenate(tj))
        if self.buffer:
            order = np.lexsort((rows, where))  # by tile, each tile's points in the files' order (its buffer's among its own)
        else:  # rows are 0..n-1: a stable sort by tile is that order (a radix sort for up to 2^16 tiles)
            order = np.argsort(where.astype(np.uint16) if len(keys) <= 1 << 16 else where, kind="stable")
        own = np.bincount(where[: len(chunk)], minlength=len(keys))
        ends = np.cumsum(counts)
        for k, key in enumerate(map(tuple, keys.tolist())):
            if key not in self.held and len(self.held) >= MAX_TILES:
                raise InputError(f"tile: size={self.size!r}: more than {MAX_TILES:,} tiles over the points of {self.where}; take larger tiles")
            append_file(self.path(key), [np.take(records, order[ends[k] - counts[k] : ends[k]])])
            self.held[key] = self.held.get(key, 0) + int(counts[k])
            self.own[key] = self.own.get(key, 0) + int(own[k])

    def _records(self, chunk: PointChunk) -> np.ndarray:
        """The chunk's points as spill records (the first chunk sets their layout)."""
        attributes = dict(chunk.attributes)
        if self.buffer:  # buffer points get the flag; the tile's own keep theirs (0 where the files have none)
            attributes.setdefault(BUFFER_FLAG, np.zeros(len(chunk), np.uint8))
        if self.dtype is None:
            own = [(f"attribute {a}", v.dtype, v.shape[1:]) for a, v in attributes.items()]
            self.dtype = np.dtype([("xyz", np.float64, (3,)), ("rgba", np.uint8, (4,)), ("color_bits", np.uint8), *own])
        records = np.empty(len(chunk), self.dtype)
        records["xyz"], records["rgba"], records["color_bits"] = chunk.xyz, chunk.rgba, chunk.color_bits or 0
        for a, v in attributes.items():
            records[f"attribute {a}"] = v
        return records

    def chunks(self, key: tuple[int, int], chunk_size: int):
        """The points of tile ``key`` as PointChunks, in the order they came; each of one file's colour bits.
        Read a chunk at a time, not through a memory map: a map's pages, once read, count in the
        process's memory until it is unmapped, the whole tile's (a 1.35 M-point tile of 5 M points,
        51-byte records: 66 MiB; ``tile``'s peak 301 -> 261-272 MiB)."""
        names = [f[len("attribute ") :] for f in self.dtype.names if f.startswith("attribute ")]
        with open(self.path(key), "rb") as held:
            while len(part := np.fromfile(held, self.dtype, count=chunk_size)):
                for run in np.split(part, np.flatnonzero(np.diff(part["color_bits"])) + 1):
                    attributes = {a: np.array(run[f"attribute {a}"]) for a in names}
                    yield PointChunk(run["xyz"], run["rgba"], attributes, color_bits=int(run["color_bits"][0]) or None)

    def write_tiles(self, name: str, suffix: str, files: PointFiles, grid, folder: Path, progress) -> list[Path]:
        """Write each tile holding points of its own into ``folder``, one at a time, on the LAS
        ``grid`` (scale, offset), its spill file removed once written; returns their paths, by x
        then y (tiles of buffer points only: none)."""
        self.written_keys = sorted(key for key, n in self.own.items() if n)
        progress.phase("write", sum(self.held[key] for key in self.written_keys))
        written = []
        for key in self.written_keys:
            path = folder / tile_name(name, *key, self.size, suffix)
            write_points(
                path, lambda key=key: self.chunks(key, files.chunk_size), None, grid=grid, crs_records=files.crs_records, color_bits=None,
                has_color=files.has_color,
            )
            self.path(key).unlink()
            progress.advance(self.held[key])
            written.append(path)
        return written


def _warn_stale_tiles(out: Path, name: str, tiles: list[Path]) -> None:
    """Warn of files in ``out`` named as this run names tiles that it did not write (an earlier
    run's, of another size or extent): left as they were, they would pass for this run's."""
    pattern = re.compile(rf"{re.escape(name)}_-?[0-9.e+-]+_-?[0-9.e+-]+\.(las|laz)", re.IGNORECASE)
    ours = {p.name for p in tiles}
    stale = sorted(p.name for p in out.iterdir() if pattern.fullmatch(p.name) and p.name not in ours)
    if stale:
        shown = ", ".join(stale[:3]) + (", ..." if len(stale) > 3 else "")
        warn(f"{out}: tiles named as this run's but not written by it are left as they were ({counted(len(stale), 'tile')}: {shown}); remove them if they are an earlier run's", GigapointWarning)


__all__ = ["MAX_TILES", "TILE_FORMATS", "TileResult", "tile", "tile_index", "tile_name"]
