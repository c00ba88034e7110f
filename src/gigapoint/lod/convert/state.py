"""What one conversion is (inputs, options, sizes, output folder) and what lets it resume:
the fingerprint of its inputs and options, and its saved state (``OctreeDir.write_state``).

A re-run resumes only when its fingerprint equals the saved one: the same input files (path,
size, modification time; ``--colorize``'s raster's too), the same options and the same
gigapoint code (``code_version``, lod/code.py; with ``--to-crs``, the same PROJ: ``Reprojection.proj_setup``);
anything else starts clean, with a warning where it discards another run's work (converter.py).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np

from ...atomic import same_file
from ...errors import InputError
from ...io import URL_LIKE, file_url_path, point_files_of, shown_url
from ...io.http import as_url
from ..code import code_version
from ..ept import ept_location
from ..kinds import work_dir as copc_work_dir
from ..octree_dir import OctreeDir, OutputExistsError
from .facts import input_facts
from .options import BYTES_PER_POINT_BUILD, MAX_PARTITION_POINTS, RUNTIME_BYTES

STATE_VERSION = 1
SAVE_EVERY_S = 1.0  # the state is saved (fsynced) at most this often while chunks or tasks finish (save_state_soon)


def local_path(p, what: str, error=InputError):
    """``p`` itself, or the path a ``file://`` URL names. Other URLs (``s3://``, ``memory://``, ...)
    are refused with ``error``: a conversion's workers read the inputs and write the output
    through the file system (on a Dask cluster, one they all share; mount other storage there)."""
    text = os.fspath(p) if isinstance(p, (str, os.PathLike)) else None
    url = URL_LIKE.match(text) if text is not None else None
    if url is None:
        return p
    # also a Path made of a URL (the CLI's: 'file:/x', 's3:/bucket/x'): -o s3://bucket/x wrote ./s3:/bucket/x
    if url.group(1).lower() == "file" and urllib.parse.urlsplit(text).netloc in ("", "localhost"):
        return file_url_path(text)
    raise error(f"{shown_url(f'{url.group(1)}://{url.group(2)}')}: {what} must be a path or a file:// URL on this machine (a file system every worker shares)")


def input_paths(inputs) -> list[Path] | None:
    """The input files of a conversion given files and directories (a directory stands for its
    supported files, ``io.expand_paths``, as for every other command); None for an iterable of
    PointChunks. An octree folder is refused: it is an output, not an input."""
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if not (isinstance(inputs, (list, tuple)) and all(isinstance(p, (str, os.PathLike)) for p in inputs)):
        return None
    if not inputs:
        raise InputError("convert: no input given")
    inputs = [local_path(p, "an input") for p in inputs]
    refuse_octrees(inputs)
    return point_files_of(inputs, where="convert")  # (an empty file among several: skipped, said once)


def refuse_octrees(inputs) -> None:
    """A one-line InputError for an input path that is an octree folder or an EPT dataset: an
    output of conversions, not point files to read."""
    for p in inputs:
        if as_url(p) is not None:  # (an EPT's URL was named here whole, its password and token too): expand_paths says it
            continue
        if OctreeDir(p).kind is not None:
            raise InputError(f"{p}: is a converted octree (or a conversion in progress), not an input point cloud")
        if ept_location(p) is not None:  # (was "holds no supported point cloud file", or an unknown .json)
            raise InputError(f"{p}: is an EPT dataset (an octree: open or render it as it is), not an input point cloud")


def file_identity(path: Path) -> list:
    """[resolved path, size, modification time (ns)] of a file: what a resumed run must find unchanged."""
    stat = path.stat()
    return [str(path.resolve()), stat.st_size, stat.st_mtime_ns]


def damaged_work_file(d: OctreeDir) -> str | None:
    """Before a resume: what is wrong with the first array of an unfinished conversion's work
    folder that does not read whole (its header, and as many bytes as it says), or None. A
    truncated one (a machine that crashed before the disk had it) was numpy's ValueError
    part-way through the resume, every time it was run again."""
    for path in sorted(d.partial.rglob("*.npy")):
        if path.name.startswith(".") or any(part.endswith(".tmp") for part in path.relative_to(d.partial).parts[:-1]):
            continue  # a write (atomic.py's hidden temporary) or a node set under way when the run stopped: done again
        try:
            np.load(path, mmap_mode="r")
        except (OSError, ValueError, EOFError) as exc:
            return f"{path}: a work file of the unfinished conversion is damaged ({' '.join(str(exc).split())})"
    return None


class Job:
    """One conversion: its inputs, options, the sizes derived from its memory limit, its output
    folder, progress display and state. The phases (read.py, partition.py, phases.py) are
    methods of subclasses that share it; converter.py runs them in order."""

    def __init__(
        self,
        inputs,
        out,
        sampler,
        memory_limit,
        format,
        max_leaf,
        partition_points,
        chunk_size,
        progress,
        name,
        encoding="DEFAULT",
        upper_points=None,
        source_files=None,
        layout="compact",
        colors="rgba",
        has_color=None,
    ):
        self.encoding = encoding
        self.has_color = has_color  # chunk inputs: whether their points have colours (None: as the source files say)
        self.layout = layout  # gigapoint format: "compact" (version 2, compact_octree.py) or "words" (version 1)
        self.colors = colors  # version 2's colours: "rgba" (exact) or "rgb565"
        self.out = Path(out)
        self.dir = OctreeDir(copc_work_dir(self.out) if format == "copc" else self.out)  # a COPC output is one file
        self.sampler = sampler
        self.format = format
        self.max_leaf = max_leaf
        self.mem = memory_limit
        usable = max(memory_limit - RUNTIME_BYTES, memory_limit // 4)  # from the options alone: the same plan anywhere
        self.usable = usable
        self.partition_points = partition_points or max(50_000, min(MAX_PARTITION_POINTS, usable // BYTES_PER_POINT_BUILD))
        self.partition_override = partition_points  # None: derived from the memory limit
        self.upper_points = upper_points or self.partition_points  # carried root points the group/upper phases join at once
        # chunks grouped between checkpoints (more: page faults on fresh memory cost more than the opens saved)
        self.distribute_bytes = int(min(256 << 20, max(64 << 20, usable // 8)))
        self.chunk_size = chunk_size or int(min(2_000_000, max(50_000, memory_limit // 600)))
        self.progress = progress
        self.inputs = inputs
        self.paths = input_paths(inputs)
        if format == "copc" and self.paths and self.out.exists() and any(same_file(self.out, p) for p in self.paths):
            raise OutputExistsError(f"{self.out}: is one of the inputs; write the COPC file elsewhere (it would replace the file it is read from)")
        self.source_files = list(source_files or [])  # chunk inputs: the files their points came from
        self.name = name or (self.paths[0].stem if self.paths else "cloud")
        self.state: dict = {}
        self.t0 = 0.0  # perf_counter() at the start of the run
        self.first_view: float | None = None  # seconds from the start until the first preview was written

    #: only the points it keeps are read (io/filters.py; convert's classes, drop_classes, clip); None: every point
    point_filter = None
    #: the points moved into another CRS as they are read (io/reproject.py's Reprojection: convert's to_crs); None: kept
    reprojection = None
    #: the LAS grid (scale, offset) of the moved points (reproject.output_grid; None: not LAS inputs), what the output stores them on
    reprojected_grid = None
    #: the orthophoto the points are coloured from as they are read (io/colorize.py's Colorization: convert's colorize); None: their own colours
    colorization = None

    def fingerprint(self) -> dict | None:
        """The inputs and options a saved state must match to be resumed (None: chunk inputs)."""
        if self.paths is None:
            return None
        files = [file_identity(p) for p in self.paths]
        return {
            "version": STATE_VERSION,
            "code": code_version(),  # a run resumed after an upgrade mixed two versions' work files
            "inputs": files,
            "sampler": self.sampler,
            "format": self.format,
            "encoding": self.encoding,
            "max_leaf": self.max_leaf,
            "memory_limit": self.mem,
            "partition_points": self.partition_override,  # (not upper_points: any grouping gives the same octree)
            "chunk_size": self.chunk_size,
            "layout": self.layout,
            "colors": self.colors,
            "chunks": "joined",  # small files' chunks joined (read._joined): a state of one chunk a file reads otherwise
            # a run resumed under another filter mixed points kept by one and by the other
            "filter": None if self.point_filter is None else self.point_filter.as_spec(),
        } | ({} if self.reprojection is None else {"reprojection": self.reprojection.as_spec(), "proj": self.reprojection.proj_setup()}) | (  # (a run without either: its fingerprint as before)
            {} if self.colorization is None  # (another raster, or this one changed, or read as of other bits: other colours)
            else {"colorize": file_identity(self.colorization.path), "colorize_bits": self.colorization.nbits}
        )

    def fingerprint_key(self) -> str | None:
        """``fingerprint`` as the state holds it: a digest. Held whole, 2 000 tiles' paths, sizes and
        times were written again with each chunk's state: quadratic (10 s of a 14 s conversion)."""
        fp = self.fingerprint()
        return None if fp is None else "sha256:" + hashlib.sha256(json.dumps(fp, sort_keys=True).encode()).hexdigest()

    def resume_state(self, saved: dict) -> dict:
        """The state a run resumes from, given the saved one of an unfinished run with the same fingerprint."""
        return saved

    def compact_plan(self) -> dict | None:
        """How the gigapoint format stores node payloads, decided once the inputs are read
        (``state["compact"]``): None for version 1 (or another format), else {"scale": the
        source grid's step per axis or None (the LAS inputs' finest scale, else the chunks'
        own), "colors"}."""
        if self.format != "gigapoint" or self.layout == "words":
            return None
        st = self.state
        scale = (st.get("source") or {}).get("scale")
        if scale is None and self.paths is None:
            scale = st.get("chunk_scale")
        return {"scale": scale if isinstance(scale, list) else None, "colors": self.colors}

    def source_facts(self, paths) -> dict:
        """``input_facts`` of ``paths`` (CRS, LAS grid, colours: ``state["source"]``), their
        ``has_color`` the chunks' own where convert was told (a live cloud's frames pushed without
        colours: its grey is no colour of theirs, so a COPC output gets no RGB); with ``--to-crs``
        the target's CRS and grid; with ``--colorize`` colours (``has_color``) whatever the files hold."""
        moved_to = None if self.reprojection is None else (self.reprojection.target_wkt(), self.reprojected_grid)
        facts = input_facts(paths, one_grid=self.format != "gigapoint", moved_to=moved_to)
        if self.has_color is not None:
            facts["has_color"] = bool(self.has_color)
        if self.colorization is not None:  # every point has a colour now (black where the raster gave none and its file had none)
            facts["has_color"] = True
        return facts

    _saved_at = float("-inf")  # time.monotonic() of the last save_state

    def save_state(self) -> None:
        self.dir.write_state(self.state)
        self._saved_at = time.monotonic()

    def save_state_soon(self) -> None:
        """The state saved if SAVE_EVERY_S passed since the last save: a save is an fsync (~2 ms
        here), once per chunk it was 3.5 of 23 s reading 1 500 tiles of 2 000 points. A stopped
        run resumes from the last save, reading again the chunks after it."""
        if time.monotonic() - self._saved_at >= SAVE_EVERY_S:
            self.save_state()

    def save_state_with(self, **changes) -> None:
        """The state saved with ``changes`` (``damaged``: the next run refuses to resume it)."""
        self.state.update(changes)
        self.save_state()
