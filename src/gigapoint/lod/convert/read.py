"""Phase 1, read: input chunks (moved by ``--to-crs``, filtered, coloured by ``--colorize``)
validated, bounded and spilled to raw chunk files, with the conversion's preview sampled on the
way (../preview.py)."""

from __future__ import annotations

import contextlib
import time
from dataclasses import replace
from functools import cached_property

import numpy as np

from ...core.bounds import valid_bounds
from ...core.chunk import PointChunk, join_chunks, warn_dropped_attributes
from ...core.cloud import MAX_ABS_COORDINATE, check_valid_count
from ...errors import EmptyCloudError, GigapointError, InputError, value_text
from ...io import files_label, read_chunks, scan_angles_differ
from ...io.filters import filtered
from ...io.las import with_scan_angle
from ...io.paths import skip_empty
from ...io.registry import reader_for
from ...io.write import file_has_color, one_value_a_point
from ..preview import PreviewSampler, preview_points
from .prefetch import prefetch
from .spill import encode_xyz, las_xyz_code, load_raw_chunk, one_value, save_raw_chunk
from .state import Job


def _read_chunks(path, chunk_size: int):
    """The chunks of one input file (any format gigapoint.io reads); a seam the tests stop."""
    return read_chunks(path, chunk_size)


def _skipped_if_empty(path, chunks, several: bool, skipped: list | None = None):
    """``chunks``, but a file without points among several is skipped with a warning, as
    gp.open (and so render) skips it: a folder of tiles with an empty one was refused.
    ``skipped``: the file is added to it instead, for the caller to say (a Dask worker's
    warning does not reach the user)."""
    try:
        yield from chunks
    except EmptyCloudError:
        if not several:
            raise
        if skipped is not None:
            skipped.append(str(path))
        else:
            skip_empty(path)


def merge_attributes(attrs: dict | None, names: dict) -> dict:
    """The attributes every chunk so far has (``attrs``; None before the first) and this one's
    (``names``: {name: dtype str}) have alike, in the first chunk's order."""
    return names if attrs is None else {a: d for a, d in attrs.items() if names.get(a) == d}


def chunk_constants(kept: dict) -> dict:
    """A chunk's attributes ``kept`` ({name: values}) as ``merge_constants`` takes them: [dtype
    str, the one value] where every point holds one (``one_value``), else None; none for no point."""
    found = {a: one_value(v) for a, v in kept.items() if len(v)}
    return {a: None if c is None else [c.dtype.str, c.item()] for a, c in found.items()}


def merge_constants(constant: dict, found: dict) -> dict:
    """``constant`` (attribute -> [dtype str, the one value every point so far holds]; None: its
    values differ; absent: no point yet), a JSON-able part of the state, updated in place with
    the next points' (``chunk_constants``, or a read task's ``constant``); returned."""
    for a, c in found.items():
        if a not in constant:
            constant[a] = c
        elif constant[a] is not None and (c is None or c[0] != constant[a][0] or constant_value(c).tobytes() != constant_value(constant[a]).tobytes()):
            constant[a] = None  # (bit for bit: -0.0 is not 0.0)
    return constant


def constant_value(entry: list) -> np.generic:
    """A ``merge_constants`` entry's value, a numpy scalar of its dtype."""
    return np.array(entry[1], np.dtype(entry[0]))[()]


def valid_chunk(chunk) -> tuple:
    """A chunk's valid points: (xyz, rgba as u32, {attribute: values} of its attributes, one of
    several values a point a column each (io.write ``one_value_a_point``),
    {attribute: dtype str}, invalid points, bounds min, bounds max; the bounds are None without
    a valid point)."""
    n_in = len(chunk)
    valid, c_lo, c_hi = valid_bounds(chunk.xyz, MAX_ABS_COORDINATE)
    n_valid = int(np.count_nonzero(valid))
    keep = slice(None) if n_valid == n_in else valid
    xyz = chunk.xyz[keep]
    attributes = one_value_a_point(chunk.attributes)  # (N, 3) normals as nx, ny, nz, as a point file gets them
    names = {a: v.dtype.str for a, v in attributes.items()}
    rgba = np.ascontiguousarray(chunk.rgba[keep]).view(np.uint32).reshape(-1)
    kept = {a: np.ascontiguousarray(attributes[a][keep]) for a in names}
    return xyz, rgba, kept, names, n_in - n_valid, (c_lo if n_valid else None), (c_hi if n_valid else None)


def spill_chunk(raw, i: int, chunk, xyz_code=None) -> tuple:
    """Chunk ``i``'s valid points (``valid_chunk``'s results) spilled to ``raw``
    (spill.save_raw_chunk): its positions, colors and 1-D attributes; positions as int32 when
    ``xyz_code`` (a LAS file's scale and offset, spill.encode_xyz) gives every one of them back
    exactly; an attribute of one value as that value alone. Returns (``valid_chunk``'s results,
    the chunk's ``chunk_constants``: found once, for the spill and the state alike)."""
    taken = valid_chunk(chunk)
    xyz, rgba, kept = taken[:3]
    found = chunk_constants(kept)
    values = {a: v if found.get(a) is None else constant_value(found[a]) for a, v in kept.items()}
    ints = None if xyz_code is None else encode_xyz(xyz, xyz_code)
    if ints is None:
        save_raw_chunk(raw, i, xyz, rgba, values)
    else:
        save_raw_chunk(raw, i, ints, rgba, values, xyz_code)
    return taken, found


def _black(n: int) -> np.ndarray:
    """RGBA of ``n`` black points (opaque)."""
    rgba = np.zeros((n, 4), np.uint8)
    rgba[:, 3] = 255
    return rgba


def moved_and_blackened(chunks, path, reprojection, colorization):
    """The chunks of file ``path`` as the read phase filters them (here and in a Dask read task):
    moved into the target CRS where ``reprojection`` is given; where ``colorization`` is given and
    the file has no colours, black (those the raster gives none stay black, as a plain file's)."""
    if reprojection is not None:
        chunks = (reprojection.chunk(chunk, path) for chunk in chunks)
    if colorization is not None and not file_has_color(path):
        chunks = (replace(chunk, rgba=_black(len(chunk))) for chunk in chunks)
    return chunks


def _same(a, b) -> bool:
    """Whether ``a`` and ``b`` (arrays, tuples or None) hold the same values."""
    return (a is None) == (b is None) and (a is None or np.array_equal(a, b))


def _alike(a: tuple, b: tuple) -> bool:
    """Whether chunks (LAS grid, PointChunk) ``a`` and ``b`` may be joined: the same grid, scale and attributes."""
    kinds = [{k: (v.dtype, v.shape[1:]) for k, v in c.attributes.items()} for c in (a[1], b[1])]
    return _same(a[0], b[0]) and _same(a[1].scale, b[1].scale) and kinds[0] == kinds[1]


def _joined(items, size: int):
    """Chunks (LAS grid, PointChunk), in order, with consecutive alike ones (small files') joined
    into one of up to ``size`` points. A chunk a file was ~16 spill files, written, read twice
    and removed: a folder of 1 500 tiles of 2 000 points took 23 s out of core, one file 5 s."""
    held, n, items = [], 0, iter(items)
    while True:
        try:
            item = next(items, None)
        except Exception:  # a bad file: the files before it taken first, as they were alone (the stop then names it)
            if held:
                yield _join(held)
            raise
        if item is None:
            break
        if held and (n + len(item[1]) > size or not _alike(held[0], item)):
            yield _join(held)
            held, n = [], 0
        held.append(item)
        n += len(item[1])
        if n >= size:
            yield _join(held)
            held, n = [], 0
    if held:
        yield _join(held)


def _join(held: list) -> tuple:
    chunk = join_chunks([c for _, c in held])
    chunk.scale = held[0][1].scale  # (alike: every one's)
    return held[0][0], chunk


def _grid_of(path) -> np.ndarray | None:
    """``path``'s LAS grid (spill.las_xyz_code), None for other formats and where its header
    fails (an empty file among several is skipped; a broken one's error comes from reading it)."""
    try:
        return las_xyz_code(path)
    except GigapointError:
        return None


def _point_total(paths) -> int | None:
    try:
        total = 0
        for p in paths:
            n = reader_for(p).point_count(p)
            if n is None:
                return None
            total += n
        return total
    except Exception:  # noqa: BLE001 - only a progress-bar total: unknown is fine
        return None


class ReadPhase(Job):
    read_ahead = True  # the next chunk decoded in a thread while this one is spilled
    on_ready = None  # convert()'s on_ready: called once the output first shows points
    replacing = False  # a complete octree in the output is being replaced (converter.py): it opens until the new one is complete

    def shows_points(self, seconds: float) -> None:
        """The output is viewable (its first preview), ``seconds`` after the start: on_ready called, once.
        Not where a complete octree folder is being replaced: it opens as that one until the end
        (a COPC output's preview is in its work folder)."""
        if self.first_view is None and not (self.replacing and self.format != "copc"):
            self.first_view = seconds
            if self.on_ready is not None:
                self.on_ready()

    @cached_property
    def one_angle(self) -> bool:
        """Whether the input files hold the scan angle under both LAS names (io's ``scan_angles_differ``: formats 0-5's then read as scan_angle)."""
        return bool(self.paths) and scan_angles_differ(self.paths)

    @cached_property
    def point_total(self) -> int | None:
        """The input files' points by their headers (None: chunks, or a file that does not say)."""
        return _point_total(self.paths) if self.paths else None

    def _chunks(self):
        if self.paths is None:
            for i, chunk in enumerate(self.inputs):
                if not isinstance(chunk, PointChunk):  # [cloud] was an AttributeError ('no attribute xyz') further on
                    raise InputError(f"convert: inputs[{i}]: {value_text(chunk)} is neither a path nor a PointChunk (inputs are files and folders, a cloud, or PointChunks)")
                yield chunk
        else:
            for code, chunk in _joined(self._file_chunks(), self.chunk_size):
                self._spill_code = code
                yield chunk

    #: the conversion's filter as this run counts it (``point_filter``'s fresh copy, read()); None: no filter
    _passing = None

    def _file_chunks(self):
        """The input files' chunks, each with its file's LAS grid (``_grid_of``), through the
        filter; moved into the target CRS first where reprojected (as a plain point file's: the
        filter in the target's coordinates), off any file's grid then (spilled as float64).
        Where coloured from a raster, a file without colours gives black points (``read`` colours
        them: those the raster gives no colour stay black, as in a plain point file, not grey)."""
        for p in self.paths:
            code = _grid_of(p) if self.reprojection is None else None
            read = moved_and_blackened(_read_chunks(p, self.chunk_size), p, self.reprojection, self.colorization)
            chunks = _skipped_if_empty(p, filtered(read, p, self._passing), len(self.paths) > 1)
            chunks = with_scan_angle(chunks) if self.one_angle else chunks
            for chunk in prefetch(chunks) if self.read_ahead else chunks:
                yield code, chunk

    #: the LAS grid of the chunk being taken (spill.las_xyz_code): its positions spilled as its
    #: int32 where they are on it (12 bytes a point, not 24), as on Dask; None: float64
    _spill_code = None

    def _take_chunk(self, i: int, chunk) -> tuple:
        """Chunk ``i``'s valid points, kept for the later phases: spilled to the raw chunk files
        (``spill_chunk``'s results; in_memory.py holds them instead)."""
        taken, found = spill_chunk(self.dir.raw, i, chunk, self._spill_code)
        self._note_constants(found)
        return taken

    def _note_constants(self, found: dict) -> dict:
        """The attributes of one value so far (the state's ``constant``, ``merge_constants``) with
        a chunk's (``found``: its ``chunk_constants``): the partitions hold those as that value
        alone. Returns them as they were before."""
        constant = self.state.setdefault("constant", {})
        before = dict(constant)
        merge_constants(constant, found)
        return before

    def read(self) -> None:
        st = self.state
        self.dir.raw.mkdir(exist_ok=True)
        done = st.get("chunks", 0)
        lo = np.array(st.get("lo", [np.inf] * 3))
        hi = np.array(st.get("hi", [-np.inf] * 3))
        attrs: dict | None = st.get("attributes")
        if done and "constant" not in st:  # a run from before constants were noted: its chunks hold every attribute a point at a time
            st["constant"] = dict.fromkeys(attrs or {})
        total = st["total"] = self.point_total  # (with a filter: an upper bound of the points kept)
        preview = self._preview_sampler(total, done, attrs)
        dropped: set[str] = set()
        self.progress.phase("read", total)
        self._passing = self.point_filter.fresh() if self.point_filter is not None else None
        self._counted = 0
        try:
            for i, chunk in enumerate(self._chunks()):
                n_in = self._points_read(len(chunk))
                if i < done:  # (read again, from the start: the filter counts those too)
                    self.progress.advance(n_in)
                    continue
                uncolored = 0
                if self.colorization is not None:  # here, not as files are read: a resumed run's chunks read before are not coloured, nor counted, again
                    chunk, uncolored = self.colorization.colored(chunk, had_color=True)  # (a colourless file's points: black, _file_chunks)
                xyz, rgba, kept, names, invalid, c_lo, c_hi = self._take_chunk(i, chunk)
                if self.colorization is not None:  # the invalid points, skipped, lie on no pixel (NaN, inf; beyond ±1e12: no raster's)
                    st["uncolored"] = st.get("uncolored", 0) + uncolored - int(invalid)
                merged = merge_attributes(attrs, names)
                if attrs is not None:  # left out: one chunk lacks it, brings it alone, or in another dtype
                    dropped |= (set(attrs) | set(names)) - set(merged)
                attrs = merged
                sc, prev = getattr(chunk, "scale", None), st.get("chunk_scale", "unset")  # the chunks' grid (compact_plan)
                st["chunk_scale"] = None if sc is None or prev is None else (list(map(float, sc)) if prev == "unset" else np.minimum(prev, sc).tolist())
                if c_lo is not None:
                    lo = np.minimum(lo, c_lo)
                    hi = np.maximum(hi, c_hi)
                preview.add(xyz, rgba, {a: kept[a] for a in attrs})
                st.update(chunks=i + 1, lo=lo.tolist(), hi=hi.tolist(), attributes=attrs, points=st.get("points", 0) + len(xyz), skipped=st.get("skipped", 0) + int(invalid))
                if self._write_preview(preview):  # the state names the preview file's chunks: saved with it
                    self.save_state()
                else:
                    self.save_state_soon()
                self.progress.advance(n_in)
        except BaseException:  # stopped (Ctrl+C, a bad input): saved as it stands, a rerun resumes after the last chunk read
            with contextlib.suppress(OSError):
                self.save_state()
            raise
        self._write_preview(preview, force=True)
        warn_dropped_attributes(str(self.out), dropped)
        if self._passing is not None:
            st.update(filter_read=self._passing.read, filter_passed=self._passing.passed)
        self._end_read(lo, hi)

    _counted = 0  # the points read that the progress bar has been told of (``_points_read``)

    def _points_read(self, taken: int) -> int:
        """The points read since the last chunk, of which a chunk of ``taken`` points was kept: the
        progress total counts the points in the files, the filter's left out too."""
        if self._passing is None:
            return taken
        new = self._passing.read - self._counted
        self._counted = self._passing.read
        return new

    def _end_read(self, lo, hi) -> None:
        """Every input read (points, skipped, attributes saved): the octree's cube from the bounds
        ``lo``..``hi``; no valid point is an error, skipped points a warning."""
        st = self.state
        if self.point_filter is not None and "filter_passed" in st:  # not "no valid points" where the filter left none
            replace(self.point_filter, read=st["filter_read"], passed=st["filter_passed"]).check_passed(files_label(self.paths))
        # the plain cloud's error where no point is valid, its warning of the skipped ones, naming the files as it does (self.name is a file's stem)
        check_valid_count(files_label(self.paths) if self.paths else self.name, st.get("points", 0), st.get("skipped", 0), from_files=bool(self.paths))
        edge = float(np.max(hi - lo))
        st.setdefault("source", self.source_facts(self.paths or self.source_files))  # CRS, LAS grid, colors: for outputs that hold them
        st["compact"] = self.compact_plan()
        st.update(origin=lo.tolist(), edge=edge if edge > 0 else 1.0, phase="count")
        self.save_state()

    def _preview_sampler(self, total: int | None, done: int, attrs: dict | None) -> PreviewSampler:
        """The read phase's preview sample; a resumed run reloads it and re-offers the chunks read after its last write."""
        preview = PreviewSampler(self.dir.preview, preview_points(self.mem), total)
        meta = self.state.get("preview")
        if done and meta:
            preview.resume(meta["seen"], meta["stride"])
            for j in range(meta["chunks"], done):
                d = load_raw_chunk(self.dir.raw, j, attrs or {})
                preview.add(d["xyz"], d["rgba"], {a: d["attr." + a] for a in attrs or {}})
        return preview

    def _write_preview(self, preview: PreviewSampler, force: bool = False) -> bool:
        """The preview written if due (``force``: if it changed); True when it was."""
        if not preview.maybe_write(force):
            return False
        self.state["preview"] = {
            "chunks": self.state.get("chunks", 0),
            "seen": preview.seen,
            "stride": preview.stride,
            "points": preview.held,
        }
        self.shows_points(time.perf_counter() - self.t0)
        return True
