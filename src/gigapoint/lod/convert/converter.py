"""The conversion's orchestrator: ``convert()`` checks the options, takes the output folder's
lock, prepares it (resume or start clean) and runs the phases in order."""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from ...core import pages
from ...core.renderable import PointSource
from ...errors import GigapointError, GigapointWarning, InputError, check_switch, check_whole, type_text, warn
from ...io import files_label, given_paths, with_subfolders
from ...io._base import check_file, headers_once
from ...io.colorize import open_colorization
from ...io.crs import files_crs
from ...io.filters import point_filter
from ...io.registry import is_supported_name
from ...io.reproject import Reprojection, output_grid
from ...io.thin import thin_spacing
from ..build import SAMPLERS
from ..code import code_version
from ..compact_octree import COLOR_FORMATS, LAYOUTS
from ..copc_write import check_copc_output
from ..kinds import is_copc_name, refuse_unwritten_copc
from ..octree_dir import STOPPED_BY_INPUT, STOPPED_RESUMES, ConvertError
from ..progress import NullProgress, RichProgress
from ..store import OctreeCloud
from .in_memory import InMemoryPhases
from .keep_freed_memory import KeepFreedMemory
from .options import DEFAULT_MAX_LEAF, ENCODINGS, FORMATS, parse_memory
from .partition import PartitionPhases
from .phases import BuildPhases
from .read import ReadPhase
from .seeded import GrownTree, SeededPhases
from .state import damaged_work_file, local_path
from .to_file import is_point_file_name, refuse_octree_options, write_point_file

PHASES = ("read", "count", "distribute", "build", "group", "upper", "write")


@dataclass
class ConvertResult:
    out: Path
    format: str
    sampler: str | None  # None: a plain point file (to_file.py), no octree
    points: int
    nodes: int
    skipped: int
    seconds: float
    resumed: bool
    phase_seconds: dict | None = None
    first_view_seconds: float | None = None  # until OUT first opened (its preview); 0: a resumed run's was there; None: none
    in_memory: bool = False  # the points waited between phases in memory (in_memory.py), not in spill files
    thinned_from: int | None = None  # thin=: the points thinned (valid, passing the filter) to ``points``; None: not thinned
    uncolored: int | None = None  # colorize=: the points written that took no colour from the raster (outside it, under its mask); None: not coloured

    @property
    def points_per_second(self) -> float:
        """Points converted a second: those thinned (``thinned_from``) where thinned, not the few kept."""
        done = self.points if self.thinned_from is None else self.thinned_from
        return done / self.seconds if self.seconds > 0 else 0.0


class _Converter(ReadPhase, PartitionPhases, BuildPhases):
    """One conversion (state.Job) with every phase: read (read.py), count and distribute
    (partition.py), build, group, upper and write (phases.py)."""

    def output_ready(self) -> None:
        """The output folder is prepared and the state saved; the phases come next (distributed.py checks its workers here)."""

    def _as_given(self, text: str) -> str:
        """``text`` with its paths as the user gave them: as it is in one process (distributed.py's
        driver resolves them for its workers, and says them as given again)."""
        return text

    def run(self, overwrite: bool) -> ConvertResult:
        self.t0 = time.perf_counter()
        fp = self.fingerprint_key()
        created = not self.dir.path.exists()
        self.prepared = False  # the output folder is this run's (prepare_output passed)
        try:
            with self.dir.lock():
                try:
                    return self._run_locked(overwrite, fp)
                except BaseException as exc:
                    # chunks from Python (a cloud's save): no rerun resumes them, so their work goes; on an interrupt
                    # too where it replaces an octree (that one opens, and the next save found the .partial beside it);
                    # a new one interrupted leaves its preview to look at, as a kill does
                    if fp is None and self.prepared and (isinstance(exc, Exception) or self.replacing):
                        self.discard(created)
                    raise
        except GigapointError as exc:
            # inputs that gave not one point (none valid, or corrupt from the start): the folder this
            # run made holds nothing a run could resume from, so it goes rather than being left
            # behind as an "unfinished conversion"
            if isinstance(exc, InputError) and created and not getattr(self, "state", {}).get("points"):
                shutil.rmtree(self.dir.path, ignore_errors=True)
            elif isinstance(exc, InputError) and fp is not None and self.state.get("phase") == "read":
                # a bad input: a rerun with it unchanged (the same fingerprint) stops the same way, and one
                # without it or with it mended starts over; saved, for info, gp.open and the viewer to say why
                with contextlib.suppress(OSError):
                    self.save_state_with(stopped_by=str(exc))
                if not self.replacing:
                    exc.args = (f"{exc}; the conversion to {self.out} stopped unfinished: {STOPPED_BY_INPUT}",)
            if self.replacing:
                exc.args = (f"{exc}; {self.kept()}",)
            raise
        except OSError as exc:  # a full disk most often: the CLI's line named no file, nor what became of the output
            if created and not self.state:  # nothing began (OUT under a file: ENOTDIR): nothing to resume
                shutil.rmtree(self.dir.path, ignore_errors=True)
                raise ConvertError(f"{exc.filename or self.dir.path}: {exc.strerror or exc}") from exc
            gone = exc.errno == errno.ENOENT and exc.filename and self.dir.partial in Path(exc.filename).parents
            if gone and fp is not None and getattr(self, "state", None):  # a work file missing: it will be missing next time too
                damage = f"{exc.filename}: a work file of the unfinished conversion is missing"
                with contextlib.suppress(OSError):
                    self.save_state_with(damaged=damage)
                raise ConvertError(f"{damage}; run it again with --overwrite to start over") from exc
            if self.replacing:
                raise ConvertError(f"{exc.filename or self.dir.path}: {exc.strerror or exc}; {self.kept()}") from exc
            again = STOPPED_RESUMES if fp is not None else "its work was removed: run it again once the cause is gone"
            raise ConvertError(f"{exc.filename or self.dir.path}: {exc.strerror or exc}; the conversion to {self.out} stopped unfinished ({again})") from exc
        finally:
            self.progress.close()

    def kept(self) -> str:
        """What a replacement that stopped left: the octree it was to replace, and whether a rerun resumes."""
        if self.state.get("stopped_by"):  # a bad input: unchanged, it stops the run again
            return f"{self.out} still holds the octree it was to replace (run it again with overwrite=True once that file is whole, or without it: it starts over)"
        again = "it resumes" if self.dir.state_file.is_file() and self.dir.resumable else "it starts over"
        return f"{self.out} still holds the octree it was to replace (run it again with overwrite=True once the cause is gone: {again})"

    def discard(self, created: bool) -> None:
        """Remove what this run wrote: the folder where it made it, else only the conversion's own files."""
        if created:
            shutil.rmtree(self.dir.path, ignore_errors=True)
        else:
            self.dir.start_over()

    def _run_locked(self, overwrite: bool, fp) -> ConvertResult:
        found = self.dir.read_state()  # once: whose work is here, and whether this run resumes it
        other_work = self.dir.other_work(fp, found)
        saved = self.dir.prepare_output(fp, overwrite, found)
        self.prepared = True
        if other_work is not None:  # hours of work may go: said, not done silently
            warn(self._as_given(f"{self.out}: the unfinished conversion there was started {other_work}: starting over"), GigapointWarning)
        # what OUT holds stays until the new one is complete (prepare_output let it, or atomic_open's rename for COPC)
        self.replacing = self.dir.complete or (self.format == "copc" and self.out.is_file())
        damage = (saved.get("damaged") or damaged_work_file(self.dir)) if saved is not None else None
        if damage and not overwrite:
            raise ConvertError(f"{damage}; run it again with --overwrite to start over")
        if damage:  # overwrite: the unfinished conversion goes, this one starts from the inputs
            self.dir.start_over()
            self.dir.partial.mkdir(parents=True)
            saved = None
        resumed = saved is not None
        self.state = self.resume_state(saved) if resumed else {"fingerprint": fp, "phase": "read"}
        self.state.pop("stopped_by", None)  # the last run's cause: this run says its own, if any
        self.state["code_version"] = code_version()  # readable: info says when a rerun under other code starts over
        self.save_state()
        self.output_ready()
        if resumed and self.dir.preview.is_file():
            self.shows_points(0.0)  # the interrupted run's preview: viewable from the start
        steps = {
            "read": self.read,
            "count": self.count,
            "distribute": self.distribute,
            "build": self.build,
            "group": self.group,
            "upper": self.upper,
        }
        timings = {}
        for ph in PHASES[PHASES.index(self.state["phase"]) :]:
            t = time.perf_counter()
            if ph == "write":
                n_nodes = self.write()
            else:
                steps[ph]()
            timings[ph] = round(time.perf_counter() - t, 3)
        return ConvertResult(
            self.out,
            self.format,
            self.sampler,
            int(self.state["points"]),
            n_nodes,
            int(self.state.get("skipped", 0)),
            time.perf_counter() - self.t0,
            resumed,
            timings,
            self.first_view,
            isinstance(self, InMemoryPhases) and not self.spilled,
        )


class _SeededConverter(SeededPhases, _Converter):
    """A conversion of a builder's grown tree (seeded.py): its partitions come from the leaves."""


class _InMemoryConverter(InMemoryPhases, _Converter):
    """A conversion in this process: its points held in memory while they fit the limit, else
    spilled (in_memory.py)."""


def _are_paths(inputs) -> bool:
    """Whether ``inputs`` name files and folders (a list or tuple of them: convert made a lone path a list)."""
    return isinstance(inputs, (list, tuple)) and all(isinstance(p, (str, os.PathLike)) for p in inputs)


@headers_once()  # each input's header read once, by the read phase's steps and facts alike
def convert(
    inputs,
    out,
    *,
    sampler: str | None = None,
    memory_limit=None,
    overwrite: bool = False,
    format: str | None = None,
    max_leaf: int | None = None,
    partition_points: int | None = None,
    chunk_size: int | None = None,
    progress: bool = False,
    name: str | None = None,
    encoding: str | None = None,
    upper_points: int | None = None,
    client=None,
    source_files=None,
    layout: str | None = None,
    colors: str | None = None,
    on_ready=None,
    recursive: bool = False,
    classes=None,
    drop_classes=None,
    clip=None,
    clip_polygon=None,
    thin=None,
    to_crs=None,
    from_crs=None,
    exact_transform=False,
    colorize=None,
    colorize_bits=None,
    has_color=None,
) -> ConvertResult:
    """Convert point cloud files (or a cloud, or an iterable of PointChunks) into an LOD octree directory ``out``.

    An ``out`` named as a plain point file (.las, .laz or .ply, not .copc.laz), without ``format``
    and with files or folders as ``inputs`` (a cloud is written by its ``save``), is written as one: every point of the input files that passes the filter, merged a chunk at
    a time (to_file.py); the octree's options (sampler, memory_limit, max_leaf, layout, colors,
    encoding, client, ...) are refused with it. Its result counts the points written, in 0 nodes.

    ``sampler``: grid (the default) | poisson. ``format``: gigapoint (rendered directly) | potree (Potree 2.0,
    ``encoding`` DEFAULT (the default) or BROTLI) | copc; None: copc for an ``out`` ending in .copc.laz, else
    gigapoint (a folder, so not named like a point file). ``memory_limit``: bytes or '4G'; bounds partition sizes
    (the limit less a fixed allowance for the runtime, not less what this process holds: the plan is
    the same wherever it is made, so a process holding much else wants a smaller limit). Only path
    inputs can resume after an interruption; chunk iterables always start clean.
    ``partition_points``, ``chunk_size`` and ``upper_points`` (the carried root points joined
    at once, default ``partition_points``) are tuning knobs, derived from the memory limit.

    ``client``: run the conversion as Dask tasks (distributed.py): a ``distributed.Client``, a
    scheduler address (``"tcp://host:8786"``: one connection, for the memory plan and the run,
    closed at the end) or a number of local single-threaded worker processes (a ``LocalCluster``,
    closed at the end). Workers read the inputs and write into
    ``out``, which must be a path every worker sees (a shared file system); the octree is the
    one this function makes without a client. ``memory_limit`` is then per worker (default: a
    quarter of the RAM; N local workers: half the RAM among them, at most a quarter each; another
    cluster's workers: the same rule for their memory, distributed.default_memory_limit).

    ``source_files``: where ``inputs`` are chunks, the LAS/LAZ/COPC files they came from; their
    headers give the output its CRS and LAS grid (a progressive octree's ``save``).

    ``has_color`` (a cloud or chunks as ``inputs``; files say it themselves): False where their
    points have no colours of their own (a live cloud's frames pushed without: drawn grey), so a
    COPC output gets a point format without RGB (6) and a gigapoint octree records it
    (``octree.json``'s ``has_color``), as for colourless files; None: as ``source_files`` say.

    ``inputs`` may also be a ``GrownTree`` (seeded.py): a builder's tree whose leaves are the
    partitions as they stand (``ProgressiveOctree.save``); it is converted in this process.

    ``layout`` (gigapoint format): "compact" writes format version 2, node payloads in bit
    streams (../compact_octree.py, about half the bytes; positions exact at the source's scale),
    "words" version 1 (three u32 words and 32-bit colours a point). ``colors`` (version 2):
    "rgba" keeps colours exact, "rgb565" stores 16 bits (at most 4/255 off a channel). None:
    "compact" and "rgba"; given with another format (or rgb565 with "words") they are refused.

    ``on_ready``: called with no argument once the output first shows points (the read phase's
    first preview; at the start where a resumed run finds one): the CLI says then how to watch
    it fill, and says nothing of it where the first file cannot be read.

    ``recursive=True``: a folder stands for every point file below it, not only its own
    (``io.with_subfolders``, as ``gp.open``'s).

    ``classes``, ``drop_classes``, ``clip``, ``clip_polygon``: only the points of the input files that pass them are
    read, as ``gp.open``'s (io/filters.py); a conversion resumes only under the same filter.

    ``thin`` (a plain point file only): the edge of cube cells on a grid anchored at coordinate
    0, in the inputs' units; one point is kept per occupied cell, the first in the inputs' order,
    over all of them (io/thin.py). The result's ``thinned_from`` counts the points before it.

    ``to_crs`` (input files only; needs pyproj: ``pip install 'gigapoint[gis]'``): the CRS
    the points are moved into ('EPSG:32610', a WKT, a PROJ string), from each file's own (its
    header's; ``from_crs`` for every file where given, and for files naming none), as they are read
    (io/reproject.py): the filter's clip box and ``thin``'s cells are then in its coordinates (a
    clip polygon moved there from its own CRS). z is transformed only between CRSs with a vertical
    part (compound ones), else kept (PROJ's rule). The output (a plain file, an octree, a COPC
    file) names ``to_crs`` (a WKT VLR, octree.json's crs) and keeps the inputs' precision in its units. The points
    are interpolated from PROJ's transform of a grid of control points, within a tenth of the
    output grid's step of PROJ's own (checked; else exactly); ``exact_transform=True``: every point
    through PROJ.

    ``colorize`` (input files only; needs rasterio: ``pip install 'gigapoint[gis]'``): an
    orthophoto (a GeoTIFF, any raster GDAL reads) whose pixels colour the points written, each the
    pixel it lies in, after ``to_crs`` (in the output's coordinates; io/colorize.py): bands 1-3 as
    red, green, blue. Points outside it or under its mask (alpha 0, nodata) keep their colour (0
    where their file had none), counted in the result's ``uncolored``. A raster in another CRS than
    the output's is refused (move the points into its CRS with ``to_crs``). The output (a plain
    file, an octree, a COPC file) has colours; an octree's points are coloured as they are read,
    and a conversion resumes only with the same raster, unchanged (its path, size, time). On a
    ``client``, the workers move and colour the points they read, and open the raster themselves:
    it must be at the same path on a file system they all share, as the inputs are.
    ``colorize_bits``: how many bits the raster's values hold (12 for 12-bit data in a 16-bit
    file naming no NBITS: scaled from 0-4095, not 0-65535, so not dark), in place of its NBITS or
    type's; a 16-bit raster naming no NBITS whose values reach fewer bits is warned of without it.
    """
    check_switch("overwrite", overwrite, "convert")
    check_switch("recursive", recursive, "convert")
    if isinstance(inputs, (str, os.PathLike)):  # (as a list: given_paths' below, which PointFiles takes)
        inputs = [inputs]
    if isinstance(inputs, (list, tuple)) and inputs and isinstance(inputs[0], (str, os.PathLike)):  # files, then None: None named
        inputs = given_paths(inputs, "convert")  # (taken as PointChunks: "item 0 is a str")
    if _are_paths(inputs):  # a COPC file a conversion still writes: its work folder named, not a bare "no such file"
        refuse_unwritten_copc(inputs)
    if isinstance(inputs, OctreeCloud):  # gp.open of an octree folder: as its folder's path is refused (was "got a CompactOctree")
        raise InputError(f"{inputs.path or inputs.name}: is a converted octree (opened), not an input point cloud; convert the point files it was made from")
    if recursive and not _are_paths(inputs):
        raise InputError("convert: recursive=True reads the subfolders of folders; the inputs are a cloud or PointChunks")  # (dropped without a word)
    if recursive:
        inputs = with_subfolders(inputs)
    keep = point_filter(classes, drop_classes, clip, "convert", clip_polygon=clip_polygon)  # before anything is read
    thin_label = f"convert: thin={thin!r}"
    spacing = thin_spacing(thin, thin_label)
    reprojection = None if to_crs is None else Reprojection(to_crs, from_crs, "convert", exact_transform)  # an unknown CRS: said before a point is read
    if from_crs is not None and to_crs is None:
        raise InputError(f"convert: from_crs={from_crs!r}: the CRS the inputs are in, for to_crs; give to_crs too")
    if colorize is not None and not isinstance(colorize, (str, os.PathLike)):
        raise InputError(f"convert: colorize={colorize!r}: the path of an orthophoto (a GeoTIFF)")
    if to_crs is not None and not _are_paths(inputs):
        raise InputError("convert: to_crs reprojects the points read from files; the inputs are a cloud or PointChunks")
    if colorize is not None and not _are_paths(inputs):
        raise InputError("convert: colorize colours the points read from files; the inputs are a cloud or PointChunks")
    if keep is not None and not _are_paths(inputs):  # (a cloud's or chunks' points are not read here)
        raise InputError(f"convert: the filter ({keep.describe()}) applies to the points read from files; the inputs are a cloud or PointChunks")
    check_switch("progress", progress, "convert")  # "yes"/"no" were both true
    check_switch("has_color", has_color, "convert", allow_none=True)
    if has_color is not None and _are_paths(inputs):
        raise InputError(f"convert: has_color={has_color!r} is for a cloud's or chunks' points; files say themselves whether they have colours")
    if name is not None and not isinstance(name, str):  # 5 went into octree.json as a number
        raise InputError(f"convert: name must be a string, got {name!r}")
    if source_files is not None:  # a path given alone was read letter by letter, a missing file skipped: no CRS, no word
        source_files = [check_file(p) for p in given_paths(source_files, "convert", "source_files", empty_ok=True)]
    out = local_path(out, "the output", ConvertError)  # a file:// URL names a path
    # the tuning knobs, before a folder is made: -5 partition points split down to single points
    # (a run of hours), 'abc' was a TypeError and a bad chunk_size blamed the first input file
    partition_points, upper_points, chunk_size = (
        None if value is None else check_whole("convert", knob, value, 1)  # (as ints: np.int64 50000 failed the state's JSON)
        for knob, value in (("partition_points", partition_points), ("upper_points", upper_points), ("chunk_size", chunk_size))
    )
    if format is None and out is not None and str(out) != "" and is_point_file_name(out) and _are_paths(inputs):  # -o ground.laz: one plain point file
        octree_options = {"sampler": sampler, "memory_limit": memory_limit, "max_leaf": max_leaf, "layout": layout, "colors": colors,
                          "encoding": encoding, "client": client, "name": name, "partition_points": partition_points,
                          "upper_points": upper_points, "source_files": source_files, "on_ready": on_ready}  # fmt: skip
        out = Path(out)  # (a str was "'str' object has no attribute 'is_dir'")
        refuse_octree_options(out, [keyword for keyword, value in octree_options.items() if value is not None])  # (the CLI refuses its options first)
        t0 = time.perf_counter()
        colorization = open_colorization(colorize, colorize_bits, "convert")  # a raster that cannot be read: said before a point is
        shown = RichProgress() if progress else NullProgress()
        try:
            points, skipped, passed, uncolored = write_point_file(
                inputs, out, keep, overwrite, chunk_size, shown, None if spacing is None else (spacing, thin_label), reprojection, colorization
            )
        finally:
            shown.close()
            if colorization is not None:
                colorization.close()
        thinned_from = None if spacing is None else passed
        return ConvertResult(
            out, out.suffix[1:].lower(), None, points, 0, skipped, time.perf_counter() - t0, False, thinned_from=thinned_from,
            uncolored=None if colorize is None else uncolored,
        )
    sampler = "grid" if sampler is None else sampler
    if sampler not in SAMPLERS:
        raise ConvertError(f"sampler: unknown sampler {sampler!r}; choose {' or '.join(SAMPLERS)}")
    max_leaf = DEFAULT_MAX_LEAF if max_leaf is None else max_leaf
    if format is None and out is not None and str(out) != "" and not is_copc_name(out) and is_supported_name(out):
        if _are_paths(inputs):  # -o out.csv said "a gigapoint octree is a folder", never that convert writes no CSV
            raise ConvertError(f"{out}: convert writes .las, .laz or .ply files, an octree folder or a .copc.laz file, not {Path(out).suffix.lower()}")
        if isinstance(inputs, PointSource) and is_point_file_name(out):  # (it said "a gigapoint octree is a folder")
            raise ConvertError(f"{out}: convert writes a cloud as an octree folder or a .copc.laz file; cloud.save({str(out)!r}) writes its points as that file")
    if format is None:  # -o scan.copc.laz without --format was a gigapoint folder of that name
        format = "copc" if is_copc_name(out) else "gigapoint"
    if format not in FORMATS:
        raise ConvertError(f"format: unknown format {format!r}; choose {' or '.join(FORMATS)}")
    if format != "copc" and out is not None and str(out) != "" and is_supported_name(out):  # -o scan.laz: a folder named so
        raise ConvertError(f"{out}: a {format} octree is a folder; name it without a point file's suffix, or write format='copc' into a .copc.laz file")
    if spacing is not None:  # (an octree's inner nodes are its thinned levels; its leaves hold every point)
        raise ConvertError(f"{out}: thin: an option of a plain .las, .laz or .ply file of the files' points, not of a {format} octree")
    if format == "copc" and out is not None and str(out) != "":
        check_copc_output(out, overwrite)
    given = [n for n, v in (("layout", layout), ("colors", colors)) if v is not None]
    if given and format != "gigapoint":  # --format potree --layout words wrote Potree's own layout, without a word
        raise ConvertError(f"{' and '.join(given)}: {'options' if len(given) > 1 else 'an option'} of the gigapoint format, not of {format}")
    if encoding is not None and format != "potree":
        raise ConvertError(f"encoding: an option of the potree format, not of {format}")
    if layout == "words" and colors == "rgb565":  # version 1 holds 32-bit colours
        raise ConvertError("colors='rgb565': an option of the compact layout; words holds 32-bit colours")
    layout, colors, encoding = layout or "compact", colors or "rgba", encoding or "DEFAULT"
    if not (isinstance(max_leaf, int) and max_leaf >= 100):
        raise ConvertError(f"max_leaf must be an integer >= 100, got {max_leaf!r}")
    if encoding not in ENCODINGS:
        raise ConvertError(f"encoding: unknown Potree encoding {encoding!r}; choose DEFAULT or BROTLI")
    if layout not in LAYOUTS:
        raise ConvertError(f"layout: unknown layout {layout!r}; choose {' or '.join(LAYOUTS)}")
    if colors not in COLOR_FORMATS:
        raise ConvertError(f"colors: unknown colour format {colors!r}; choose {' or '.join(COLOR_FORMATS)}")
    mem = parse_memory(memory_limit)
    if out is None or str(out) == "":
        raise ConvertError(f"convert: no output directory given (out={out!r})")
    if isinstance(inputs, PointSource):  # a cloud: gp.demo, from_arrays, open; a progressive octree (its save() keeps its tree)
        name, source_files = name or inputs.name, list(inputs.source_files) if source_files is None else source_files
        if not inputs.colors_exact:  # gp.open's colors="auto": its octree's colours were up to 12/255 off the file's, without a word
            files = ", ".join(str(f) for f in inputs.source_files)
            exact = f"convert its files ({files}) or open them with colors='rgba'" if files else "make the cloud with colors='rgba'"
            warn(f"{inputs.name}: the cloud holds its colours approximated (RGB565 or a palette), so the octree gets those; "
                          f"{exact} for exact colours", GigapointWarning)  # fmt: skip
        inputs = inputs.chunks()
    elif not isinstance(inputs, (str, os.PathLike, GrownTree, Iterable)):
        raise InputError(f"convert: inputs are files, folders, a cloud or PointChunks, got {type_text(inputs)}")
    cls = _InMemoryConverter  # held in memory where it fits, else out of core (in_memory.py)
    if isinstance(inputs, GrownTree):  # a progressive octree's save: its leaves are the partitions
        if client is not None:
            raise ConvertError("convert: a grown tree is converted in this process, not on a Dask client")
        cls = _SeededConverter
    with contextlib.ExitStack() as connection:
        if client is not None:
            from .distributed import DaskPhases, default_memory_limit, open_client  # dask is imported only when asked for

            if isinstance(client, str) and memory_limit is None:  # an address: one connection, for the memory plan and the run (closed at the end; given a limit, the inputs are checked before it is reached)
                client = connection.enter_context(open_client(client, announce=progress))
            if memory_limit is None:  # (workers on this machine share it; a cluster's say what they have)
                mem = default_memory_limit(client, say=progress)
            cls = type("_DaskConverter", (DaskPhases, _Converter), {})
        conv = cls(
            inputs,
            out,
            sampler,
            mem,
            format,
            max_leaf,
            partition_points,
            chunk_size,
            RichProgress() if progress else NullProgress(),
            name,
            encoding,
            upper_points,
            source_files,
            layout,
            colors,
            has_color,
        )
        conv.on_ready = on_ready
        conv.point_filter = keep
        if reprojection is not None:  # every file's CRS checked, the grid of the moved points made: before a point is read
            reprojection.check_files(conv.paths)
            conv.reprojection, conv.reprojected_grid = reprojection, output_grid(conv.paths, reprojection)
            conv.point_filter = reprojection.moved_filter(keep, conv.paths)  # (its clip polygon in the target CRS, where the points are filtered)
        conv.colorization = open_colorization(colorize, colorize_bits, "convert")  # a raster that cannot be read: said before a point is
        try:
            if conv.colorization is not None:  # (the points' CRS is the output's: the target's where reprojected)
                conv.colorization.check_crs(reprojection.target_wkt() if reprojection is not None else files_crs(conv.paths), files_label(conv.paths))
            if client is not None:  # (a Client, the caller's or connected above, is used as it is: not closed here)
                with open_client(client, announce=progress) as conv.client:
                    result = conv.run(overwrite)
            else:
                with KeepFreedMemory(), pages.numpy_small_pages():  # both: new pages are the slow part of a conversion here
                    result = conv.run(overwrite)
        finally:
            if conv.colorization is not None:
                conv.colorization.close()
        if conv.colorization is not None:  # (a resumed run's count: the chunks read before it too, from the state)
            result.uncolored = int(conv.state.get("uncolored", 0))
        return result
