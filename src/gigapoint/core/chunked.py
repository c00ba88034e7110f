"""A PointCloud built in bounded memory: ``build_cloud``'s result, without its ~50 bytes a point.

``build_cloud`` holds every point's float64 xyz, colour, Morton code and the sort order at once
before it quantizes or compacts. ``build_cloud_chunked`` gives the same cloud, array for array
(the same Morton order, batches, boxes, words, extension streams and colours), while it holds
only the finished arrays (4-6 bytes a point of positions in the compact layout, 2 of colour,
the attributes) and one bounded partition at a time. It reads its source three times, so the
source is a function returning a fresh iterable of PointChunks (a demo generator, a file
reader); a source costly to read (a LAZ file's decoding, text) is read once instead
(``read_once``: its chunks kept in the spill folder for the later passes, ``ReadOnce``):

1. **survey**: point count, invalid points, bounds (hence the Morton cube), the attributes
   every chunk has, the finest scale, whether all colours are opaque;
2. **histogram** of the Morton codes' top ``3 * level`` bits (cells of 1/2^level of the cube's
   edge); consecutive cells are grouped into *partitions* of at most ``partition_points``
   points (a cell denser than that forms one partition alone): contiguous ranges of Morton
   codes, so partitions in turn are the global Morton order;
3. **spill**: each chunk's valid points bucketed by partition (a stable counting sort) and
   appended to per-partition files in a temporary folder (float64 xyz, colour, attributes);

then **finalize**, partition by partition: read it back (the input order: chunk order, so the
stable sort below is the in-memory build's), Morton-sort it, prepend the previous partition's
points that did not fill a batch (the carry), cut batches of ``batch_size`` at the same global
places as ``build_cloud``, compact (core/compact.py) or quantize them, and copy low words,
colours and attributes into the preallocated arrays; the extension streams go to a file read
back once at the end (their total length is known only then). The folder is removed on
return, also on an error.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Iterable
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path

import numpy as np
from numba import njit

from ..atomic import append_file, write_failure
from ..errors import InputError, MemoryLimitError
from .attributes import Attributes
from .chunk import PointChunk, attributes_in_common, warn_dropped_attributes
from .cloud import PointCloud, _valid_mask, check_valid_count, finest_scale, gather, scan_points, source_color_bits, storage_format
from .compact import compact_positions, ext_bits_per_point, pack_rgb565, stream_words
from .layout import BATCH_SIZE, PACK_DTYPE
from .morton import MORTON_BITS_PER_AXIS, counting_order, cube_of, morton_codes, morton_order
from .palette import block_errors, choose_palette, empty_palettes, palette_into
from .quantize import make_batches, quantize

#: ``gp.open`` and ``gp.demo`` build clouds of more points than this chunked (``chunked=None``):
#: ``build_cloud``'s ~50 bytes a point would be 2.5 GB and more
CHUNKED_ABOVE = 50_000_000

ChunkSource = Callable[[], Iterable[PointChunk]]

#: the fewest bytes a point takes, what the checks before a build (``check_room``) count: held
#: once a chunked build is finished (compact positions and a palette colour, attributes on top:
#: the demo town holds ~8.6), spilled to its temporary folder (float64 xyz and a colour), and
#: held while ``build_cloud`` sorts in memory (float64 xyz, colour, codes, order: ~55 measured)
HELD_BYTES_MIN = 5
SPILLED_BYTES_MIN = 28
IN_MEMORY_BYTES_MIN = 48


def physical_memory() -> int:
    """Bytes of this machine's physical memory (8 GB where the system does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not POSIX
        return 8 << 30


def _size(n_bytes: float) -> str:
    return f"{n_bytes / 1e12:,.1f} TB" if n_bytes >= 1e12 else f"{n_bytes / 1e9:,.1f} GB"


def check_room(name: str, n_points: int, held_bytes: int, spilled_bytes: int = 0, tmpdir=None, instead: str = "") -> None:
    """A one-line MemoryLimitError, before anything is read, where ``n_points`` points cannot be
    built: ``held_bytes`` a point exceed this machine's physical memory, or their ``spilled_bytes``
    a point the free disk of ``tmpdir`` (default: the system's temp folder). Without it a build
    of 10^10 points ran for hours, then was killed for memory or failed on a full disk.
    ``instead``: what to do instead, said after the figures."""
    memory = physical_memory()
    if n_points * held_bytes > memory:
        raise MemoryLimitError(
            f"{name}: {n_points:,} points held in memory take {_size(n_points * held_bytes)} or more, and this machine has "
            f"{_size(memory)}{instead}"
        )
    if spilled_bytes:
        folder = Path(tmpdir if tmpdir is not None else tempfile.gettempdir())
        try:
            free = shutil.disk_usage(folder).free
        except OSError:  # a folder that is not there: the build says so where it makes its own in it
            return
        if n_points * spilled_bytes > free:
            raise MemoryLimitError(
                f"{name}: building {n_points:,} points in bounded memory spills {_size(n_points * spilled_bytes)} or more to "
                f"{folder}, which has {_size(free)} free (TMPDIR names another folder){instead}"
            )


#: points a partition holds at most (unless one cell alone holds more): ~60-70 bytes a point of
#: transient memory while it is sorted and compacted (~130 MB at the default)
PARTITION_POINTS = 2_000_000
#: partitions are made of cells of the Morton cube's edge / 2^level (2^21 cells counted)
CELL_LEVEL = 7


def build_cloud_chunked(
    source: ChunkSource,
    name: str = "cloud",
    batch_size: int = BATCH_SIZE,
    layout: str = "auto",
    colors: str = "auto",
    attributes: bool = True,
    partition_points: int = PARTITION_POINTS,
    cell_level: int = CELL_LEVEL,
    tmpdir: str | Path | None = None,
    read_once: bool = False,
) -> PointCloud:
    """``build_cloud(source(), name, batch_size, layout, colors)`` in bounded memory (module doc).

    ``source``: called three times, each call returns the same PointChunks (a generator
    function, ``lambda: demo_chunks(n, scale=0.01)``). ``attributes=False``: leave the
    attributes out (3 bytes a point for the demo town's intensity and classification).
    ``partition_points``, ``cell_level``: the partitions' size (memory) and the cells they are
    cut from. ``tmpdir``: where the spill folder goes (default: the system's temp folder); it
    needs ~29-31 bytes a point of disk (float64 xyz, colour, attributes). ``read_once``: call
    ``source`` once and keep its chunks in that folder for the later passes (``ReadOnce``: for
    sources whose reading costs far more than a copy, a LAZ file's decoding); the same disk."""
    if batch_size < 1:
        raise InputError(f"{name}: batch size must be >= 1, got {batch_size}")
    if partition_points < 1:
        raise InputError(f"{name}: partition_points must be >= 1, got {partition_points}")
    if not 1 <= cell_level <= 8:
        raise InputError(f"{name}: cell_level must be 1..8, got {cell_level}")
    with tempfile.TemporaryDirectory(prefix="gigapoint_chunked_", dir=tmpdir) as tmp:
        folder = Path(tmp)
        passes = ReadOnce(source, folder, name) if read_once else None
        survey = _survey(passes.first if passes else source, attributes, name)
        n, skipped = survey["n"], survey["skipped"]
        check_valid_count(name, n, skipped)
        source_scale = finest_scale(survey["scales"])
        compact, color_format = storage_format(name, layout, colors, source_scale, survey["opaque"])
        short = color_format == "rgb565"  # spilled as RGB565 (palettes and "auto": as u32, quantized block by block when finalized)
        lo, hi = survey["lo"], survey["hi"]
        origin, edge = cube_of(lo, hi)
        shift = 3 * (MORTON_BITS_PER_AXIS - cell_level)
        clean = skipped == 0
        part_of_cell, n_parts = _cut_partitions(_histogram(passes.again if passes else source, clean, origin, edge, shift, cell_level), partition_points)
        attr_dtypes = survey["attributes"]
        with _spilling(name, folder, n):
            _spill(passes.last if passes else source, clean, folder, origin, edge, shift, part_of_cell, n_parts, short, attr_dtypes)
        cloud = _finalize(folder, n_parts, n, lo, hi, origin, edge, compact, color_format, attr_dtypes, batch_size, name, skipped, source_scale)
        cloud.source_color_bits = source_color_bits(survey["color_bits"])
        return cloud


@contextmanager
def _spilling(name: str, folder: Path, n: int | None):
    """An OSError writing to ``folder`` (a full disk, most likely) as one line that says where and
    how much the build needs (``n``: the points, where known)."""
    try:
        yield
    except OSError as exc:
        need = f", {30 * n / 1e9:.1f} GB" if n is not None else ""
        raise InputError(
            f"{name}: spilling {'' if n is None else f'{n:,} '}points to {folder} failed: {write_failure(exc)} (the chunked build needs "
            f"~30 bytes a point of free disk there{need}; pass tmpdir= for another place)"
        ) from exc


class ReadOnce:
    """A source read once: the first pass (the survey; gigapoint tile's pass for its grid) reads it
    and appends every chunk, as read, to files of the build's folder (a file a field, as the
    partitions' files: ``_read`` reads them back); the later passes read those files instead of
    the source (a LAZ file's decoding, ~0.3 us a point, is then paid once instead of three
    times), and the last removes each chunk's files once read, so the folder holds at most the
    points once (the spill grows as the chunk files go). The chunks read back are those read:
    points, colours (and their bits), attributes, scale. ``writing``: the context each chunk's
    files are written in (by default a failed write, a full disk most likely, is the chunked
    build's one-line error)."""

    def __init__(self, source: ChunkSource, folder: Path, name: str, writing: Callable[[], AbstractContextManager] | None = None):
        self.source, self.folder, self.name = source, folder, name
        self.writing = writing or (lambda: _spilling(name, folder, None))
        self.chunks: list[tuple] = []  # (points, scale, colour bits, {field: (dtype, shape of a value)})

    def _path(self, k: int, field: str) -> Path:
        return self.folder / f"source.{k}.{field}"

    def first(self):
        for k, chunk in enumerate(self.source()):
            fields = {"xyz": chunk.xyz, "rgba": chunk.rgba, **{f"a_{a}": v for a, v in chunk.attributes.items()}}
            with self.writing():  # (not the source's own errors)
                for key, v in fields.items():
                    append_file(self._path(k, key), [np.ascontiguousarray(v)])
            self.chunks.append((len(chunk), chunk.scale, chunk.color_bits, {key: (v.dtype, v.shape[1:]) for key, v in fields.items()}))
            yield chunk

    def again(self, remove: bool = False):
        for k, (n, scale, color_bits, fields) in enumerate(self.chunks):
            arrays = {}
            for key, (dtype, shape) in fields.items():
                arrays[key] = _read(self._path(k, key), (n, *shape), dtype, None)
                if remove:
                    self._path(k, key).unlink()
            yield PointChunk(arrays.pop("xyz"), arrays.pop("rgba"), {key[2:]: v for key, v in arrays.items()}, scale=scale, color_bits=color_bits)

    def last(self):
        return self.again(remove=True)


# --- the three passes over the source --------------------------------------------------------
def _kept(chunk: PointChunk, clean: bool):
    """The points of a chunk the build keeps (build_cloud's rule): all of them where the survey
    found no invalid point in the source (``clean``: no second scan), else a mask."""
    return slice(None) if clean else _valid_mask(chunk.xyz)


def _survey(source: ChunkSource, keep_attributes: bool, name: str) -> dict:
    n = skipped = 0
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    names: list[str] | None = None
    dropped: set[str] = set()
    dtypes: dict[str, tuple] = {}  # name -> (dtype, shape of one point's value)
    scales: list = []
    color_bits: list = []
    opaque = True
    for chunk in source():
        n_bad, chunk_lo, chunk_hi = scan_points(chunk.xyz)
        lo, hi = np.minimum(lo, chunk_lo), np.maximum(hi, chunk_hi)
        skipped += n_bad
        n += len(chunk.xyz) - n_bad
        names = attributes_in_common(names, chunk.attributes, dropped)
        for a, v in chunk.attributes.items():
            dtypes.setdefault(a, (np.asarray(v).dtype, np.asarray(v).shape[1:]))
        scales.append(chunk.scale)
        color_bits.append(chunk.color_bits)
        if opaque and len(chunk.rgba):
            keep = _kept(chunk, n_bad == 0)
            opaque = bool((chunk.rgba[keep, 3] == 255).all())
    if keep_attributes:
        warn_dropped_attributes(name, dropped)
    attrs = {a: dtypes[a] for a in (names or [])} if keep_attributes else {}
    return {"n": n, "skipped": skipped, "lo": lo, "hi": hi, "attributes": attrs, "scales": scales, "color_bits": color_bits, "opaque": opaque}


def _histogram(source: ChunkSource, clean: bool, origin, edge, shift: int, level: int) -> np.ndarray:
    hist = np.zeros(1 << (3 * level), np.int64)
    for chunk in source():
        keep = _kept(chunk, clean)
        codes = morton_codes(np.ascontiguousarray(chunk.xyz[keep], np.float64), origin, edge)
        hist += np.bincount((codes >> np.uint64(shift)).astype(np.int64), minlength=len(hist))
    return hist


@njit(cache=True)
def _cut(hist, budget, part_of_cell):
    """Consecutive cells into partitions of at most ``budget`` points (a fuller cell alone);
    empty cells join the partition before them. Returns the number of partitions."""
    part = 0
    held = 0
    for c in range(hist.shape[0]):
        h = hist[c]
        if held > 0 and held + h > budget:
            part += 1
            held = 0
        held += h
        part_of_cell[c] = part
    return part + 1 if held > 0 else part


def _cut_partitions(hist: np.ndarray, budget: int) -> tuple[np.ndarray, int]:
    part_of_cell = np.empty(len(hist), np.int32)
    n_parts = _cut(hist, budget, part_of_cell)
    return part_of_cell, max(int(n_parts), 1)


def _paths(folder: Path, p: int, attr_dtypes) -> dict[str, Path]:
    return {key: folder / f"{p}.{key}" for key in ("xyz", "color", *(f"a_{a}" for a in attr_dtypes))}


def _spill(source, clean, folder, origin, edge, shift, part_of_cell, n_parts, short, attr_dtypes) -> None:
    """Every chunk's points appended to their partitions' files (``atomic.append_file``: large
    appends through reserved memory maps, 4x faster than write() on the project's VMs; a full
    disk an OSError naming the file)."""
    for chunk in source():
        keep = _kept(chunk, clean)
        xyz = np.ascontiguousarray(chunk.xyz[keep], np.float64)
        if len(xyz) == 0:
            continue
        part = part_of_cell[(morton_codes(xyz, origin, edge) >> np.uint64(shift)).astype(np.int64)]
        order, per_part = counting_order(part, n_parts)
        starts = np.concatenate([[0], np.cumsum(per_part)])
        del part
        color = np.ascontiguousarray(chunk.rgba[keep], np.uint8).view(np.uint32).reshape(-1)
        if short:
            color = pack_rgb565(color)
        fields = {"xyz": gather(xyz, order), "color": gather(color, order)}
        for a, (dtype, _) in attr_dtypes.items():
            fields[f"a_{a}"] = gather(np.ascontiguousarray(chunk.attributes[a][keep], dtype), order)
        del xyz, color, order
        for p in np.flatnonzero(np.diff(starts)):
            s, e = starts[p], starts[p + 1]
            for key, path in _paths(folder, int(p), attr_dtypes).items():
                append_file(path, [fields[key][s:e]])


def _finalize(folder, n_parts, n, lo, hi, origin, edge, compact, color_format, attr_dtypes, batch_size, name, skipped, source_scale) -> PointCloud:
    batches = make_batches(n, batch_size)
    low = np.empty(n, np.uint32)
    med = high = None
    if compact is None:
        med, high = np.empty(n, np.uint32), np.empty(n, np.uint32)
    packing = np.zeros(len(batches), PACK_DTYPE) if compact is not None else None
    short = color_format == "rgb565"
    quantized_colors = color_format in ("palette", "auto")
    # an even-length buffer, as pack_rgb565's: rgb565_words views it as u32 without a copy
    color = np.zeros(n + (n & 1), np.uint16)[:n] if short else np.empty(0 if quantized_colors else n, np.uint32)
    palettes = pending = sse = None
    quantized = 0  # palettes: points quantized (whole blocks); ``pending`` the finished points' colours after them
    if quantized_colors:
        palettes, pending, sse = empty_palettes(n), np.empty(0, np.uint32), block_errors(n)
    # "auto": the RGB565 colours go to a file meanwhile, read back if the palette loses
    # (choose_palette decides on every block's errors, known only at the end); 2 bytes a point of
    # disk, not of memory
    rgb565_path = folder / "rgb565" if color_format == "auto" else None
    attrs = {a: np.empty((n, *shape), dtype) for a, (dtype, shape) in attr_dtypes.items()}
    color_dtype = np.uint16 if short else np.uint32
    ext_path = folder / "ext"
    ext_words = 0
    done = 0  # points written (a multiple of batch_size until the last partition)
    carry = None  # the previous partition's points past its last full batch, in Morton order
    with open(ext_path, "wb") as ext_file, open(rgb565_path or os.devnull, "wb") as rgb565_file:
        for p in range(n_parts):
            paths = _paths(folder, p, attr_dtypes)
            if not paths["xyz"].exists():
                continue
            # the carry, then the partition's points read in after it (no second copy)
            c = 0 if carry is None else len(carry[0])
            m = paths["xyz"].stat().st_size // 24
            xyz = _read(paths["xyz"], (c + m, 3), np.float64, None if carry is None else carry[0])
            col = _read(paths["color"], (c + m,), color_dtype, None if carry is None else carry[1])
            att = {
                a: _read(paths[f"a_{a}"], (c + m, *shape), dtype, None if carry is None else carry[2][a])
                for a, (dtype, shape) in attr_dtypes.items()
            }
            carry = None
            for path in paths.values():
                path.unlink()
            order = np.empty(c + m, np.uint32)
            order[:c] = np.arange(c, dtype=np.uint32)
            order[c:] = morton_order(morton_codes(xyz[c:], origin, edge))
            order[c:] += np.uint32(c)
            if done + len(order) > n:
                raise _changed(name, n)
            last = done + len(order) == n
            k = len(order) if last else len(order) // batch_size * batch_size
            if k:
                b0 = done // batch_size
                local = make_batches(k, batch_size)
                head = order[:k]
                if compact is None:
                    lw, mw, hw = quantize(xyz, head, local)
                    med[done : done + k], high[done : done + k] = mw, hw
                else:
                    lw, ext, pack = compact_positions(xyz, head, local, compact, origin=lo)
                    pack["ext_first"] += np.uint64(ext_words)
                    packing[b0 : b0 + len(local)] = pack
                    ext.tofile(ext_file)
                    ext_words += len(ext)
                    del ext
                low[done : done + k] = lw
                del lw
                batches["bbox_min"][b0 : b0 + len(local)] = local["bbox_min"]
                batches["bbox_max"][b0 : b0 + len(local)] = local["bbox_max"]
                if palettes is None:
                    color[done : done + k] = gather(col, head)
                else:  # whole palette blocks quantized as they are finished, the rest kept for the next partition
                    finished = gather(col, head)
                    if rgb565_path is not None:
                        pack_rgb565(finished).tofile(rgb565_file)
                    pending = np.concatenate([pending, finished])
                    del finished
                    whole = len(pending) if done + k == n else len(pending) >> palettes.shift << palettes.shift
                    palette_into(palettes, quantized, pending[:whole], sse)
                    pending, quantized = pending[whole:].copy(), quantized + whole
                for a, v in att.items():
                    attrs[a][done : done + k] = gather(v, head)
                done += k
            tail = order[k:]
            carry = (xyz[tail], col[tail], {a: v[tail] for a, v in att.items()}) if len(tail) else None
            del xyz, col, att, order
    if done != n:
        raise _changed(name, n)
    if rgb565_path is not None and not choose_palette(sse):
        palettes = None
        color = np.zeros(n + (n & 1), np.uint16)[:n]  # even length, as pack_rgb565's
        color[:] = np.fromfile(rgb565_path, np.uint16)
    ext = None
    if compact is not None:
        ext = np.fromfile(ext_path, np.uint64)
        counts = batches["count"].astype(np.int64)
        expected = int(stream_words(ext_bits_per_point(packing, counts), counts).sum())
        assert len(ext) == expected == ext_words, (len(ext), expected, ext_words)
    data_bounds = None if compact is None else (np.asarray(lo, np.float64).copy(), np.asarray(hi, np.float64).copy())
    attrs = Attributes(attrs, packed=True)  # each in its real range (core/attributes.py), as build_cloud's
    cloud = PointCloud(batches, low, med, high, color if palettes is None else palettes, attrs, name=name, skipped=skipped, ext=ext, packing=packing, data_bounds=data_bounds)
    cloud.source_scale = source_scale
    return cloud


def _read(path: Path, shape: tuple, dtype, head: np.ndarray | None) -> np.ndarray:
    """An array of ``shape``: ``head`` (the carry) and then the file's values."""
    out = np.empty(shape, dtype)
    c = 0 if head is None else len(head)
    if c:
        out[:c] = head
    with open(path, "rb") as f:
        view = memoryview(out[c:].reshape(-1).view(np.uint8))
        if f.readinto(view) != len(view):
            raise InputError(f"{path}: the spilled file is shorter than expected")
    return out


def _changed(name: str, n: int) -> InputError:
    return InputError(
        f"{name}: the chunk source gave other points on a later pass than its first ({n:,}); it must give the same points each time"
    )


__all__ = ["CELL_LEVEL", "PARTITION_POINTS", "ChunkSource", "ReadOnce", "build_cloud_chunked"]
