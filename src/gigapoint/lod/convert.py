"""Out-of-core conversion of point clouds into a layered-point-cloud octree.

Phases (each resumable; state in ``OUT/.partial/state.json``, written atomically):

1. **read**: input chunks are validated, bounded and spilled to ``.partial/raw`` (the
   input is decoded once: LAZ decoding is usually the bottleneck).
2. **count**: spilled points are counted into a 128³ grid of the octree cube.
3. **distribute**: grid cells are merged into partitions (octree subtrees) holding at
   most what fits the memory limit; each spilled chunk is appended to its partitions'
   files, then deleted.
4. **build**: per partition, a local octree is split until nodes hold ≤ ``max_leaf``
   points and sampled bottom-up (build.py); the subtree's root points are carried up.
5. **upper**: the nodes above the partitions are sampled from the carried points.
6. **write**: node payloads are assembled into the output format; the metadata file
   (``octree.json`` or Potree's ``metadata.json``) is written last, atomically, and only
   then is ``.partial`` removed. OUT therefore never looks complete before it is.

A re-run after an interruption resumes where the state says (same inputs and options),
otherwise it starts clean.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.cloud import MAX_ABS_COORDINATE
from ..errors import EmptyCloudError, GigapointError, GigapointWarning, InputError
from .build import (
    SAMPLERS,
    color_sums,
    counting_order,
    filtered_colors,
    init_ownlevel,
    owned_order,
    sample_tree,
    sort_codes,
    split_tree,
    take,
    upper_tree,
    valid_bounds,
)
from .keys import CODE_BITS, point_codes
from .preview import PREVIEW_NAME, PreviewSampler, preview_points
from .progress import NullProgress, RichProgress

STATE_VERSION = 1
COUNT_LEVEL = 7  # the count grid: 128³ cells of the cube
BYTES_PER_POINT_BUILD = 220  # peak working set per point of a partition build
# Partitions above this gain nothing (every kernel is already parallel inside one) and lose a lot:
# 20 M points on the 2-core project machine convert at 1.2 M points/s as one partition, 2.5 M
# points/s in 4 M-point ones (page faults on a larger working set, cache misses in the sort).
MAX_PARTITION_POINTS = 4_000_000
DEFAULT_MAX_LEAF = 20_000
_IOV_MAX = min(1024, os.sysconf("SC_IOV_MAX")) if hasattr(os, "sysconf") else 16  # buffers per writev
FORMATS = ("gigapoint", "potree")
_OWN_FILES = (
    "octree.json",
    "metadata.json",
    "hierarchy.bin",
    "octree.bin",
    "nodes.npy",
    "keys.npy",
    "low.npy",
    "med.npy",
    "high.npy",
    "color.npy",
    "rgba.npy",
)


class ConvertError(GigapointError):
    """A conversion that cannot start or go on (bad options, output in the way)."""


class OutputExistsError(ConvertError):
    """The output directory already holds something that --overwrite is needed for."""


@dataclass
class ConvertResult:
    out: Path
    format: str
    sampler: str
    points: int
    nodes: int
    skipped: int
    seconds: float
    resumed: bool
    phase_seconds: dict | None = None
    first_view_seconds: float | None = None  # until OUT first opened (its preview); 0: a resumed run's was there; None: none

    @property
    def points_per_second(self) -> float:
        return self.points / self.seconds if self.seconds > 0 else 0.0


# --------------------------------------------------------------------------- helpers


def parse_memory(value) -> int:
    """'4G', '512M', '2GiB', '1.5g' or a byte count -> bytes; None -> a quarter of the RAM."""
    if value is None:
        try:
            total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError, AttributeError):
            total = 8 << 30
        return max(256 << 20, total // 4)
    if isinstance(value, (int, np.integer)):
        n = int(value)
    else:
        s = str(value).strip().lower().removesuffix("b").removesuffix("i")
        mult = {"k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}.get(s[-1:], 1)
        try:
            n = int(float(s[:-1] if s[-1:] in "kmgt" else s) * mult)
        except ValueError:
            raise ConvertError(f"--memory-limit: cannot read {value!r} (use e.g. 4G, 512M)") from None
    if n < 64 << 20:
        raise ConvertError(f"--memory-limit: {value!r} is below the 64M a conversion needs")
    return n


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _atomic_json(path: Path, obj) -> None:
    _atomic_write_bytes(path, json.dumps(obj, indent=1).encode())


def _save_npy(path: Path, arr: np.ndarray) -> None:
    tmp = path.with_name(path.name + ".tmp.npy")
    np.save(tmp, arr)
    os.replace(tmp, path)


def _append_file(path: Path, arrays: list) -> None:
    """Append contiguous arrays to ``path`` with gathering writes (writev): one open and, per
    1 024 arrays, one system call; no concatenated copy."""
    views = [memoryview(a).cast("B") for a in arrays if a.nbytes]
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        while views:
            batch = views[: _IOV_MAX]
            written = os.writev(fd, batch)
            for v in batch:  # a short write (a signal, a full disk) resumes where it stopped
                if written >= len(v):
                    written -= len(v)
                    views.pop(0)
                else:
                    views[0] = v[written:]
                    break
    finally:
        os.close(fd)


def _input_paths(inputs) -> list[Path] | None:
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if isinstance(inputs, (list, tuple)) and all(isinstance(p, (str, os.PathLike)) for p in inputs):
        paths = []
        for p in map(Path, inputs):
            if p.is_dir() and ((p / "octree.json").exists() or (p / "metadata.json").exists() or (p / ".partial").exists()):
                raise InputError(f"{p}: is a converted octree (or a conversion in progress), not an input point cloud")
            if p.is_dir():
                found = sorted(
                    q
                    for q in p.iterdir()
                    if q.is_file() and q.suffix.lower() in (".las", ".laz", ".ply", ".xyz", ".csv", ".txt", ".npy", ".npz", ".pts")
                )
                if not found:
                    raise InputError(f"{p}: directory holds no point cloud files")
                paths.extend(found)
            elif not p.exists():
                raise InputError(f"{p}: no such file")
            else:
                paths.append(p)
        if not paths:
            raise InputError("convert: no input given")
        return paths
    return None


def _read_chunks(path: Path, chunk_size: int):
    """The chunks of one input file (any format gigapoint.io reads); a seam the tests stop."""
    from ..io import read_chunks

    return read_chunks(path, chunk_size)


def _point_total(paths) -> int | None:
    try:
        from ..io.registry import reader_for

        total = 0
        for p in paths:
            n = reader_for(p).point_count(p)
            if n is None:
                return None
            total += n
        return total
    except Exception:  # noqa: BLE001 - only a progress-bar total: unknown is fine
        return None


def _rss_bytes() -> int:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError, AttributeError):
        return 0


class _KeepFreedMemory:
    """Within the conversion, glibc keeps freed memory for reuse instead of handing every large
    array back to the kernel (mmap/munmap): the build allocates and drops many arrays of the
    partition's size, and faulting fresh zeroed pages in cost about a third of the run. On leaving,
    the defaults come back and the kept memory is returned (malloc_trim)."""

    _M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_MMAP_MAX = -1, -3, -4

    def __enter__(self):
        self.libc = None
        try:
            import ctypes

            libc = ctypes.CDLL(None)
            libc.mallopt, libc.malloc_trim  # noqa: B018 - glibc only: AttributeError elsewhere
        except (OSError, AttributeError):
            return self
        if libc.mallopt(self._M_MMAP_MAX, 0) and libc.mallopt(self._M_TRIM_THRESHOLD, 2**31 - 1):
            self.libc = libc
        return self

    def __exit__(self, *exc):
        if self.libc is not None:
            self.libc.mallopt(self._M_MMAP_MAX, 65536)  # glibc's defaults
            self.libc.mallopt(self._M_TRIM_THRESHOLD, 128 * 1024)
            self.libc.mallopt(self._M_MMAP_THRESHOLD, 128 * 1024)
            self.libc.malloc_trim(0)
        return False


def _prefetch(chunks):
    """The chunks of ``chunks``, the next one decoded in a thread while the caller spills this one
    (LAS/LAZ decoding and file writes release the GIL): one chunk of extra memory."""
    import queue
    import threading

    q: queue.Queue = queue.Queue(maxsize=1)
    stop = threading.Event()
    done = object()

    def produce():
        try:
            for c in chunks:
                while not stop.is_set():
                    try:
                        q.put((c, None), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put((done, None))
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer, raised there
            q.put((None, exc))

    t = threading.Thread(target=produce, name="gigapoint-read", daemon=True)
    t.start()
    try:
        while True:
            c, exc = q.get()
            if exc is not None:
                raise exc
            if c is done:
                return
            yield c
    finally:
        stop.set()
        while t.is_alive():
            try:
                q.get(timeout=0.1)
            except queue.Empty:
                pass
        t.join()


def _interrupt_hook(done_partitions: int) -> None:
    """Test hook: GIGAPOINT_TEST_INTERRUPT=raise:N or kill:N stops after N built partitions."""
    spec = os.environ.get("GIGAPOINT_TEST_INTERRUPT")
    if not spec:
        return
    how, _, n = spec.partition(":")
    if done_partitions == int(n):
        if how == "kill":
            os.kill(os.getpid(), signal.SIGKILL)
        raise KeyboardInterrupt(f"test interrupt after {done_partitions} partitions")


def _plan_partitions(counts: np.ndarray, level: int, prefix: int, depth: int, budget: int) -> list[list[int]]:
    """Merge the cells of a count grid ``depth`` levels below node (level, prefix) into the largest
    subtrees holding at most ``budget`` points: [[level, prefix, count], ...] in Morton order."""
    pyramid = [counts]
    for _ in range(depth):
        pyramid.insert(0, pyramid[0].reshape(-1, 8).sum(axis=1))
    parts: list[list[int]] = []

    def visit(d: int, rel: int) -> None:
        c = int(pyramid[d][rel])
        if c == 0:
            return
        if c <= budget or d == depth:
            parts.append([level + d, (prefix << 3 * d) | rel, c])
        else:
            for k in range(8):
                visit(d + 1, rel * 8 + k)

    visit(0, 0)
    return parts


def _built_name(level: int, prefix: int) -> str:
    return f"p{(1 << 3 * level) | prefix:x}"


def _group_name(level: int, prefix: int) -> str:
    return f"g{(1 << 3 * level) | prefix:x}"


def _set_name(level: int, prefix: int, kind: str) -> str:
    """A built node set's directory name: a partition ("p") or a group of roots ("g")."""
    return (_built_name if kind == "p" else _group_name)(level, prefix)


def _save_carry(dest: Path, root_key: int, has_children: bool, gathered: dict, arrays: dict, idx) -> None:
    """A built set's root: the points it carries up (``carry.<name>.npy``: ``gathered`` maps a
    name to (array, its own indices), ``arrays`` to arrays taken at ``idx``) and root.npy (key,
    has children)."""
    for k, (v, i) in gathered.items():
        _save_npy(dest / f"carry.{k}.npy", take(v, i))
    for k, v in arrays.items():
        _save_npy(dest / f"carry.{k}.npy", take(v, idx))
    np.save(dest / "root.npy", np.array([root_key, 1 if has_children else 0], np.uint64))


def _plan_groups(carried: dict, budget: int) -> list[list]:
    """Partitions (level, prefix) -> [[level, prefix, [[plevel, pprefix], ...]], ...]: groups of
    partitions under a common ancestor node (level, prefix) whose carried points (their
    roots' samples) sum to at most ``budget``, at the coarsest level where every group fits.
    No groups when all carried points fit at once; a partition alone under its ancestor stays
    ungrouped (a group of one saves nothing)."""
    if sum(carried.values()) <= budget:
        return []
    deepest = max(lev for lev, _ in carried)
    best = None
    for level in range(1, deepest):
        groups: dict = {}
        for (lev, prefix), n in carried.items():
            if lev > level:
                g = groups.setdefault(prefix >> 3 * (lev - level), [0, []])
                g[0] += n
                g[1].append([lev, prefix])
        best = [[level, anc, sorted(members)] for anc, (_, members) in sorted(groups.items()) if len(members) > 1]
        if all(n <= budget for n, _ in groups.values()):
            break
    return best or []


# --------------------------------------------------------------------------- output directory


def _looks_like_output(out: Path) -> bool:
    return any((out / f).exists() for f in ("octree.json", "metadata.json", ".partial"))


def _clear_output(out: Path) -> None:
    shutil.rmtree(out / ".partial", ignore_errors=True)
    for f in _OWN_FILES:
        (out / f).unlink(missing_ok=True)
    for p in {*out.glob("attr.*.npy"), *out.glob("*.tmp"), *out.glob("*.tmp.npy")}:
        p.unlink(missing_ok=True)


def _lock_output(out: Path) -> int | None:
    """An exclusive lock on OUT (flock on the directory itself) held for the whole conversion, so
    that a second conversion into the same directory stops at once instead of clearing or
    interleaving the first one's files. The kernel drops it when the process ends, even killed.
    Returns the descriptor to close (None where flock does not exist)."""
    try:
        import fcntl
    except ImportError:  # Windows
        return None
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out}: exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(out, os.O_RDONLY)
    for attempt in range(10):  # a viewer's conversion_running probe holds a shared lock for microseconds
        if attempt:
            time.sleep(0.02)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return fd
        except OSError:
            pass
    os.close(fd)
    raise ConvertError(f"{out}: another conversion is writing into it; let it finish or stop it first")


def conversion_running(out) -> bool | None:
    """Whether a conversion holds OUT's lock (``_lock_output``) right now: False once it has
    ended, finished or killed. None where flock does not exist or OUT cannot be opened."""
    try:
        import fcntl
    except ImportError:  # Windows
        return None
    try:
        fd = os.open(out, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)  # closing drops the probe's own shared lock
    return False


def _prepare_output(out: Path, fingerprint: dict, overwrite: bool) -> dict | None:
    """Create/clean OUT; return the saved state when a matching partial run can resume."""
    from .store import octree_complete

    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out}: exists and is not a directory")
    if out.exists():
        complete = octree_complete(out)
        if complete and not overwrite:
            raise OutputExistsError(f"{out}: already holds a converted point cloud; pass --overwrite to replace it")
        if not complete and not _looks_like_output(out) and any(out.iterdir()):
            raise OutputExistsError(f"{out}: directory is not empty and is not a gigapoint/Potree output; refusing to write into it")
        if complete:
            _clear_output(out)
        else:
            state_file = out / ".partial" / "state.json"
            try:
                state = json.loads(state_file.read_text())
            except (OSError, ValueError):
                state = None
            if state and state.get("fingerprint") == fingerprint:
                return state
            _clear_output(out)
    (out / ".partial").mkdir(parents=True, exist_ok=True)
    return None


# --------------------------------------------------------------------------- the converter


class _Converter:
    def __init__(
        self, inputs, out, sampler, memory_limit, format, max_leaf, partition_points, chunk_size, progress, name, encoding="DEFAULT", upper_points=None
    ):
        self.encoding = encoding
        self.out = Path(out)
        self.partial = self.out / ".partial"
        self.sampler = sampler
        self.format = format
        self.max_leaf = max_leaf
        self.mem = memory_limit
        usable = max(memory_limit - _rss_bytes() - (48 << 20), memory_limit // 4)  # what the process already holds is not ours
        self.partition_points = partition_points or max(50_000, min(MAX_PARTITION_POINTS, usable // BYTES_PER_POINT_BUILD))
        self.partition_override = partition_points  # None: derived from the memory limit (and this process's size)
        self.upper_points = upper_points or self.partition_points  # carried root points the group/upper phases join at once
        self.distribute_bytes = int(min(256 << 20, max(64 << 20, usable // 8)))  # chunks grouped between checkpoints (more: page faults on fresh memory cost more than the opens saved)
        self.chunk_size = chunk_size or int(min(2_000_000, max(50_000, memory_limit // 600)))
        self.progress = progress
        self.inputs = inputs
        self.paths = _input_paths(inputs)
        self.name = name or (self.paths[0].stem if self.paths else "cloud")
        self.state: dict = {}
        self._outs: dict | None = None
        self._next: int | None = None  # next free offset in the output arrays (_next_offset)
        self.t0 = 0.0  # perf_counter() at the start of run()
        self.first_view: float | None = None  # seconds from the start until the first preview was written

    # -- state
    def fingerprint(self) -> dict | None:
        if self.paths is None:
            return None
        files = [[str(p.resolve()), p.stat().st_size, p.stat().st_mtime_ns] for p in self.paths]
        return {
            "version": STATE_VERSION,
            "inputs": files,
            "sampler": self.sampler,
            "format": self.format,
            "encoding": self.encoding,
            "max_leaf": self.max_leaf,
            "memory_limit": self.mem,
            "partition_points": self.partition_override,
            "chunk_size": self.chunk_size,
        }

    def save_state(self) -> None:
        _atomic_json(self.partial / "state.json", self.state)

    # -- phase 1
    def _chunks(self):
        if self.paths is None:
            yield from self.inputs
        else:
            for p in self.paths:
                yield from _prefetch(_read_chunks(p, self.chunk_size))

    def read(self) -> None:
        st = self.state
        raw = self.partial / "raw"
        raw.mkdir(exist_ok=True)
        done = st.get("chunks", 0)
        lo = np.array(st.get("lo", [np.inf] * 3))
        hi = np.array(st.get("hi", [-np.inf] * 3))
        attrs: dict | None = st.get("attributes")
        total = _point_total(self.paths) if self.paths else None
        st["total"] = total
        preview = self._preview_sampler(total, done, attrs)
        self.progress.phase("read", total)
        for i, chunk in enumerate(self._chunks()):
            n_in = len(chunk)
            if i < done:
                self.progress.advance(n_in)
                continue
            valid, c_lo, c_hi = valid_bounds(chunk.xyz, MAX_ABS_COORDINATE)
            n_valid = int(np.count_nonzero(valid))
            keep = slice(None) if n_valid == n_in else valid
            xyz = chunk.xyz[keep]
            st["skipped"] = st.get("skipped", 0) + int(n_in - n_valid)
            names = {a: v.dtype.str for a, v in chunk.attributes.items() if v.ndim == 1}
            if attrs is None:
                attrs = names
            else:
                attrs = {a: d for a, d in attrs.items() if names.get(a) == d}
            if n_valid:
                lo = np.minimum(lo, c_lo)
                hi = np.maximum(hi, c_hi)
            rgba = np.ascontiguousarray(chunk.rgba[keep]).view(np.uint32).reshape(-1)
            kept = {a: np.ascontiguousarray(chunk.attributes[a][keep]) for a in names}
            _save_npy(raw / f"c{i:06d}.xyz.npy", xyz)
            _save_npy(raw / f"c{i:06d}.rgba.npy", rgba)
            for a, v in kept.items():
                _save_npy(raw / f"c{i:06d}.attr.{a}.npy", v)
            preview.add(xyz, rgba, {a: kept[a] for a in attrs})
            st.update(chunks=i + 1, lo=lo.tolist(), hi=hi.tolist(), attributes=attrs, points=st.get("points", 0) + len(xyz))
            self._write_preview(preview)
            self.save_state()
            self.progress.advance(n_in)
        self._write_preview(preview, force=True)
        if st.get("points", 0) == 0:
            skipped = st.get("skipped", 0)
            detail = f" ({skipped:,} invalid points: NaN, inf or beyond ±{MAX_ABS_COORDINATE:g})" if skipped else ""
            raise EmptyCloudError(f"{self.name}: no valid points{detail}")
        if st.get("skipped"):
            warnings.warn(
                f"{self.name}: skipped {st['skipped']:,} invalid points (NaN, inf or beyond ±{MAX_ABS_COORDINATE:g})",
                GigapointWarning,
                stacklevel=3,
            )
        edge = float(np.max(hi - lo))
        st.update(origin=lo.tolist(), edge=edge if edge > 0 else 1.0, phase="count")
        self.save_state()

    def _preview_sampler(self, total: int | None, done: int, attrs: dict | None) -> PreviewSampler:
        """The read phase's preview sample; a resumed run reloads it and re-offers the chunks read after its last write."""
        preview = PreviewSampler(self.partial / PREVIEW_NAME, preview_points(self.mem), total)
        meta = self.state.get("preview")
        if done and meta:
            preview.resume(meta["seen"], meta["stride"])
            for j in range(meta["chunks"], done):
                d = self.raw_chunk(j, attrs or {})
                preview.add(d["xyz"], d["rgba"], {a: d["attr." + a] for a in attrs or {}})
        return preview

    def _write_preview(self, preview: PreviewSampler, force: bool = False) -> None:
        if preview.maybe_write(force):
            self.state["preview"] = {"chunks": self.state.get("chunks", 0), "seen": preview.seen, "stride": preview.stride, "points": preview.held}
            if self.first_view is None:
                self.first_view = time.perf_counter() - self.t0

    def raw_chunk(self, i: int, names) -> dict:
        raw = self.partial / "raw"
        d = {"xyz": np.load(raw / f"c{i:06d}.xyz.npy", mmap_mode="r"), "rgba": np.load(raw / f"c{i:06d}.rgba.npy", mmap_mode="r")}
        for a in names:
            d["attr." + a] = np.load(raw / f"c{i:06d}.attr.{a}.npy", mmap_mode="r")
        return d

    # -- phase 2
    def count(self) -> None:
        st = self.state
        origin, edge = np.array(st["origin"]), st["edge"]
        shift = np.uint64(3 * (CODE_BITS - COUNT_LEVEL))
        counts = np.zeros(8**COUNT_LEVEL, np.int64)
        self.progress.phase("count", st["points"])
        for i in range(st["chunks"]):
            xyz = np.ascontiguousarray(self.raw_chunk(i, [])["xyz"])
            if len(xyz):
                counts += np.bincount((point_codes(xyz, origin, edge) >> shift).astype(np.int64), minlength=len(counts))
            self.progress.advance(len(xyz))
        budget = st.setdefault("partition_points", self.partition_points)  # a resumed run keeps the first run's plan
        parts = _plan_partitions(counts, 0, 0, COUNT_LEVEL, budget)
        st.update(partitions=parts, part_counts=[0] * len(parts), distributed=0, phase="distribute")
        self.save_state()

    # -- phase 3
    def _part_files(self, level: int, prefix: int) -> dict[str, Path]:
        d = self.partial / "parts"
        stem = _built_name(level, prefix)  # named by node key: refined partitions never clash
        files = {"xyz": d / f"{stem}.xyz", "rgba": d / f"{stem}.rgba"}
        for a in self.state["attributes"]:
            files["attr." + a] = d / f"{stem}.attr.{a}"
        return files

    def _dtypes(self) -> dict[str, np.dtype]:
        dts = {"xyz": np.dtype(np.float64), "rgba": np.dtype(np.uint32)}
        for a, dt in self.state["attributes"].items():
            dts["attr." + a] = np.dtype(dt)
        return dts

    @staticmethod
    def _by_partition(data: dict, pid: np.ndarray, n_parts: int) -> tuple[dict, np.ndarray]:
        """The rows of ``data`` grouped by partition ``pid`` (stable), and each group's start (n_parts + 1)."""
        order, per = counting_order(pid, n_parts)
        return {k: take(np.asarray(v), order) for k, v in data.items()}, np.concatenate([[0], np.cumsum(per)])

    def _append(self, parts: list, pieces: list, counts: list) -> None:
        """Append grouped rows (``_by_partition`` results, in order) to their partitions' files.

        Each file is opened once for all pieces: with ~900 partitions of ~8 files, opening them
        for every 2 M-point chunk made the distribute phase quadratic (156 s of 618 at 10^9 points).
        """
        per = sum(np.diff(cuts) for _, cuts in pieces)
        for p in np.flatnonzero(per):
            for key, path in self._part_files(parts[p][0], parts[p][1]).items():
                _append_file(path, [sorted_data[key][cuts[p] : cuts[p + 1]] for sorted_data, cuts in pieces])
            counts[p] += int(per[p])

    def distribute(self) -> None:
        st = self.state
        (self.partial / "parts").mkdir(exist_ok=True)
        origin, edge = np.array(st["origin"]), st["edge"]
        parts = st["partitions"]
        counts = st["part_counts"]
        if len(parts) == 1:  # one partition: the build reads the spilled chunks themselves
            st.update(part_counts=[st["points"]], distributed=st["chunks"], from_raw=True, phase="build")
            self.save_state()
            return
        if st["distributed"] < st["chunks"]:
            lut = np.empty(8**COUNT_LEVEL, np.int32)
            for pid, (lev, prefix, _) in enumerate(parts):
                span = 8 ** (COUNT_LEVEL - lev)
                lut[prefix * span : (prefix + 1) * span] = pid
            dts = self._dtypes()
            # a chunk interrupted half-way: cut every partition file back to the last checkpoint
            for pid, (lev, prefix, _) in enumerate(parts):
                for key, path in self._part_files(lev, prefix).items():
                    if path.exists():
                        os.truncate(path, counts[pid] * dts[key].itemsize * (3 if key == "xyz" else 1))  # xyz rows are 3 values
            shift = np.uint64(3 * (CODE_BITS - COUNT_LEVEL))
            self.progress.phase("distribute", st["points"])
            pieces, held = [], 0  # chunks grouped since the last checkpoint, and their bytes
            for i in range(st["distributed"], st["chunks"]):
                data = self.raw_chunk(i, st["attributes"])
                xyz = np.ascontiguousarray(data["xyz"])
                if len(xyz):
                    pieces.append(self._by_partition(data, lut[(point_codes(xyz, origin, edge) >> shift).astype(np.int64)], len(parts)))
                    held += sum(v.nbytes for v in pieces[-1][0].values())
                del data
                if held >= self.distribute_bytes or i == st["chunks"] - 1:
                    # checkpoint: files hold every chunk up to i; only then are those spills deleted
                    self._append(parts, pieces, counts)
                    pieces, held = [], 0
                    first = st["distributed"]
                    st["distributed"] = i + 1
                    self.save_state()
                    for j in range(first, i + 1):
                        for f in (self.partial / "raw").glob(f"c{j:06d}.*"):
                            f.unlink()
                self.progress.advance(len(xyz))
        self._refine()
        st["phase"] = "build"
        self.save_state()

    def _refine(self) -> None:
        """Split partitions that still exceed the budget (dense spots finer than the count grid)."""
        st = self.state
        origin, edge = np.array(st["origin"]), st["edge"]
        budget = st["partition_points"]
        dts = self._dtypes()
        unsplittable = st.setdefault("unsplittable", [])
        while True:
            big = [
                i
                for i, (lev, prefix, _) in enumerate(st["partitions"])
                if st["part_counts"][i] > budget and lev < CODE_BITS and [lev, prefix] not in unsplittable
            ]
            if not big:
                return
            i = big[0]
            lev, prefix, _ = st["partitions"][i]
            n = st["part_counts"][i]
            sub = min(lev + COUNT_LEVEL, CODE_BITS)
            base = np.uint64(prefix << 3 * (sub - lev))
            shift = np.uint64(3 * (CODE_BITS - sub))
            files = self._part_files(lev, prefix)
            arrays = {k: np.memmap(path, dtype=dts[k], mode="r", shape=(n, 3) if k == "xyz" else (n,)) for k, path in files.items()}
            step = self.chunk_size
            counts = np.zeros(8 ** (sub - lev), np.int64)
            for s in range(0, n, step):
                rel = (point_codes(np.ascontiguousarray(arrays["xyz"][s : s + step]), origin, edge) >> shift) - base
                counts += np.bincount(rel.astype(np.int64), minlength=len(counts))
            plan = _plan_partitions(counts, lev, prefix, sub - lev, budget)
            if len(plan) == 1 and plan[0][0] == lev:
                unsplittable.append([lev, prefix])  # everything in one finest cell: it stays big
                self.save_state()
                continue
            lut = np.empty(len(counts), np.int32)
            for pid, (plev, pprefix, _) in enumerate(plan):
                span = 8 ** (sub - plev)
                rel0 = pprefix * span - int(base)
                lut[rel0 : rel0 + span] = pid
            for plev, pprefix, _ in plan:  # a run killed half-way left partial files: start them over
                for path in self._part_files(plev, pprefix).values():
                    path.unlink(missing_ok=True)
            new_counts = [0] * len(plan)
            for s in range(0, n, step):
                data = {k: np.ascontiguousarray(v[s : s + step]) for k, v in arrays.items()}
                rel = (point_codes(data["xyz"], origin, edge) >> shift) - base
                self._append(plan, [self._by_partition(data, lut[rel.astype(np.int64)], len(plan))], new_counts)
            del arrays
            st["partitions"][i : i + 1] = plan
            st["part_counts"][i : i + 1] = new_counts
            self.save_state()
            for path in files.values():
                path.unlink(missing_ok=True)

    # -- phase 4
    def build(self) -> None:
        st = self.state
        origin, edge = np.array(st["origin"]), st["edge"]
        built = self.partial / "built"
        built.mkdir(exist_ok=True)
        self.progress.phase("build", st["points"])
        done_now = 0
        for pid, (lev, prefix, _) in enumerate(st["partitions"]):
            n = st["part_counts"][pid]
            target = built / _built_name(lev, prefix)
            if target.exists() or n == 0:
                self.progress.advance(n)
                continue
            files = self._part_files(lev, prefix)
            if st.get("from_raw"):
                parts = [self.raw_chunk(i, st["attributes"]) for i in range(st["chunks"])]
                data = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
                files = {f"raw{i}": f for i, f in enumerate((self.partial / "raw").glob("c*.npy"))}
                del parts
            else:
                data = {
                    k: np.fromfile(path, dtype=np.float64 if k == "xyz" else (np.uint32 if k == "rgba" else st["attributes"][k[5:]]))
                    for k, path in files.items()
                }
                data["xyz"] = data["xyz"].reshape(-1, 3)
            root_key = (1 << 3 * lev) | prefix
            tmp = built / (_built_name(lev, prefix) + ".tmp")
            shutil.rmtree(tmp, ignore_errors=True)
            tmp.mkdir()
            self._build_subtree(data, root_key, origin, edge, tmp)
            os.replace(tmp, target)
            for path in files.values():
                path.unlink(missing_ok=True)
            self.progress.advance(n)
            done_now += 1
            _interrupt_hook(done_now)
        st["phase"] = "group"
        self.save_state()

    def _build_subtree(self, data: dict, root_key: int, origin, edge, dest: Path) -> None:
        xyz = data.pop("xyz")
        codes, order = sort_codes(point_codes(xyz, origin, edge))
        rgba_sorted = take(data["rgba"], order)
        # the grid sampler needs only codes; Poisson measures distances on sorted positions
        xyz_sorted = take(xyz, order) if self.sampler == "poisson" else np.zeros((1, 3))
        tree = split_tree(codes, root_key, self.max_leaf)
        own = init_ownlevel(tree, len(codes))
        wsum, wcount = color_sums(rgba_sorted)
        sample_tree(tree, codes, xyz_sorted, own, wsum, wcount, self.sampler, origin, edge)
        del xyz_sorted
        perm, counts = owned_order(tree, own)  # indices into the sorted arrays
        src = take(order, perm)  # the same points as indices into the input arrays
        del order
        n0 = int(counts[0])
        carry, rest = perm[:n0], perm[n0:]
        # carried up: the subtree root's points, with their color sums (xyz and data are in
        # input order, the rest sorted)
        inputs = {"xyz": xyz, **data}
        _save_carry(dest, root_key, not tree.leaf[0], {k: (v, src[:n0]) for k, v in inputs.items()}, {"codes": codes, "wsum": wsum, "wcount": wcount}, carry)
        # final: every node below the root
        del codes
        self._save_nodes(dest, tree.keys[1:], counts[1:], ~tree.leaf[1:], xyz, data, src[n0:], (rgba_sorted, wsum, wcount, rest))

    def _outputs(self) -> dict:
        """gigapoint format: the final point arrays (OUT/<name>.tmp.npy), which the build and upper
        phases fill in place; the write phase only renames them. {name: (path, dtype, data offset)}."""
        if self._outs is None:
            total = int(self.state["points"])
            dts = {k: np.dtype(np.uint32) for k in ("low", "med", "high", "color", "rgba")}
            dts.update({f"attr.{a}": np.dtype(d) for a, d in self.state["attributes"].items()})
            self._outs = {}
            for k, dt in dts.items():
                path = self.out / f"{k}.tmp.npy"
                arr = np.load(path, mmap_mode="r") if path.exists() else None
                if arr is None or arr.shape != (total,) or arr.dtype != dt:
                    arr = np.lib.format.open_memmap(path, mode="w+", dtype=dt, shape=(total,))
                self._outs[k] = (path, dt, arr.offset)
                del arr
        return self._outs

    def _output_slices(self, start: int, n: int) -> dict:
        """Memory maps of points start..start+n of every output array. Only this node set's pages
        are mapped, and only while it is written: whole-file maps would count every written page
        of the output in the process's resident memory."""
        return {
            k: np.memmap(path, dtype=dt, mode="r+", offset=off + start * dt.itemsize, shape=(n,))
            for k, (path, dt, off) in self._outputs().items()
        }

    def _close_outputs(self) -> None:
        """Output arrays on disk (fsync) before the write phase renames them and writes the metadata."""
        names = ["low", "med", "high", "color", "rgba", *(f"attr.{a}" for a in self.state.get("attributes", {}))]
        for path in (self.out / f"{k}.tmp.npy" for k in names):
            if not path.exists():  # a write phase resumed after its renames
                continue
            fd = os.open(path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        self._outs = None

    def _next_offset(self) -> int:
        """Where the next node set's points go in the output arrays: after every finished one.
        Read from the finished sets once per process, then kept: reading every set's span per
        set made the build and group phases quadratic (14 of 24 s with 400 sets)."""
        if self._next is None:
            built = self.partial / "built"
            ends = [int(np.load(p)[1]) for p in built.glob("*/span.npy") if not p.parent.name.endswith(".tmp")]
            self._next = max(ends, default=0)
        return self._next

    def _save_nodes(self, dest: Path, keys, counts, inner, xyz, data, idx, colors) -> None:
        """One node set: nodes ``keys`` holding ``counts`` points each, in order: the points
        ``xyz[idx]``, ``data[k][idx]``, with colors ``filtered_colors(*colors)``.

        gigapoint format: quantized (node records with tight bboxes, the three precision words)
        and written straight into the output arrays at the next free offset (``span.npy``), so
        every array is gathered and written once. Potree: float64 positions, in ``dest``."""
        keep = (counts > 0) | inner  # empty leaves are dropped; empty inner nodes keep the hierarchy whole
        keys = np.asarray(keys, np.uint64)[keep]
        counts = np.asarray(counts, np.int64)[keep]
        _save_npy(dest / "keys.npy", keys)
        _save_npy(dest / "counts.npy", counts)
        n = len(idx)
        if self.format != "gigapoint":
            _save_npy(dest / "xyz.npy", take(xyz, idx))
            _save_npy(dest / "color.npy", filtered_colors(*colors))
            for k, v in data.items():
                _save_npy(dest / f"{k}.npy", take(v, idx))
            return
        from ..core.layout import BATCH_DTYPE
        from ..core.quantize import _quantize_batches
        from .keys import level_of

        off = self._next_offset()
        outs = self._output_slices(off, n) if n else {k: np.empty(0, dt) for k, (_, dt, _) in self._outputs().items()}
        sl = slice(0, n)
        nodes = np.zeros(len(keys), BATCH_DTYPE)
        first = np.cumsum(counts) - counts
        nodes["count"] = counts
        nodes["level"] = level_of(keys)
        bmin = np.empty((len(keys), 3))
        bmax = np.empty((len(keys), 3))
        low, med, high = (np.asarray(outs[k][sl]) for k in ("low", "med", "high"))
        _quantize_batches(xyz, np.ascontiguousarray(idx), first, counts, bmin, bmax, low, med, high)
        nodes["bbox_min"], nodes["bbox_max"] = bmin, bmax
        nodes["first"] = (first + off).astype(np.uint64)
        filtered_colors(*colors, out=outs["color"][sl])
        for k, v in data.items():
            take(v, idx, out=outs[k][sl])
        del outs, low, med, high  # unmapped; a killed process's writes stay in the page cache
        _save_npy(dest / "nodes.npy", nodes)
        np.save(dest / "span.npy", np.array([off, off + n], np.int64))
        self._next = off + n

    # -- phase 5
    def group(self) -> None:
        """Partition roots joined under common ancestors, a group at a time (``_plan_groups``), so
        the upper phase never holds every root's sample at once: a 10^9-point input has ~900
        partitions whose roots carry ~22 M points, more than a 3 GB memory limit allows. A group
        is built like a partition: its nodes above the member roots, and its root's sample
        carried up; rounds repeat on the groups' roots until what is left fits. Sampling only
        ever looks at a node's children, so the tree is the same as without groups."""
        st = self.state
        built = self.partial / "built"
        if "top_sets" not in st:  # the built sets whose roots are not joined yet: [level, prefix, kind]
            st["top_sets"] = [[lev, pre, "p"] for lev, pre, _ in st["partitions"] if (built / _built_name(lev, pre)).exists()]
            st["groups"] = []
            st["round"] = None
        while True:
            dirs = {(lev, pre): built / _set_name(lev, pre, kind) for lev, pre, kind in st["top_sets"]}
            if st["round"] is None:
                carried = {k: int(np.load(d / "carry.codes.npy", mmap_mode="r").shape[0]) for k, d in dirs.items()}
                st["round"] = _plan_groups(carried, self.upper_points)
                self.save_state()
            if not st["round"]:
                break
            self.progress.phase("group", None)
            for level, prefix, members in st["round"]:
                target = built / _group_name(level, prefix)
                if target.exists():
                    continue
                tmp = built / (_group_name(level, prefix) + ".tmp")
                shutil.rmtree(tmp, ignore_errors=True)
                tmp.mkdir()
                self._join_roots([dirs[tuple(m)] for m in members], (1 << 3 * level) | prefix, tmp)
                os.replace(tmp, target)
            joined = {tuple(m) for _, _, members in st["round"] for m in members}
            st["top_sets"] = [t for t in st["top_sets"] if (t[0], t[1]) not in joined] + [[lev, pre, "g"] for lev, pre, _ in st["round"]]
            st["groups"] += [[lev, pre] for lev, pre, _ in st["round"]]
            st["round"] = None
            self.save_state()
        st["phase"] = "upper"
        self.save_state()

    def _top_sets(self) -> list[Path]:
        """The built sets whose roots the upper phase joins (every partition, before grouping)."""
        built = self.partial / "built"
        tops = self.state.get("top_sets") or [[lev, pre, "p"] for lev, pre, _ in self.state["partitions"]]
        paths = [built / _set_name(lev, pre, kind) for lev, pre, kind in tops]
        return [p for p in paths if p.exists()]

    def _join_roots(self, parts: list[Path], top: int, dest: Path) -> None:
        """The nodes from the roots of the built sets ``parts`` up to node ``top``, sampled from
        the points those roots carry, as a node set in ``dest``. ``top`` = 1 (the octree's root):
        the whole upper tree; else a group, whose root's own points are carried up in turn."""
        st = self.state
        origin, edge = np.array(st["origin"]), st["edge"]
        names = ["rgba"] + ["attr." + a for a in st["attributes"]]
        root_info = [np.load(p / "root.npy") for p in parts]
        roots = [int(r[0]) for r in root_info]
        inner_roots = np.array([r[0] for r in root_info if r[1]], np.uint64)
        cat = {k: np.concatenate([np.load(p / f"carry.{k}.npy") for p in parts]) for k in ["xyz", "codes", "wsum", "wcount", *names]}
        codes, order = sort_codes(cat.pop("codes"))  # the sorted codes come with the order: no gather
        for k in list(cat):  # one array at a time, so only one unsorted array is alive next to the sorted ones
            cat[k] = take(cat[k], order)
        del order
        xyz, wsum, wcount = cat.pop("xyz"), cat.pop("wsum"), cat.pop("wcount")
        tree = upper_tree(codes, roots, top)
        own = init_ownlevel(tree, len(codes))
        sample_tree(tree, codes, xyz, own, wsum, wcount, self.sampler, origin, edge)
        perm, counts = owned_order(tree, own)
        self.progress.advance(len(codes))
        inner = ~tree.leaf | np.isin(tree.keys, inner_roots)  # roots with children stay even when emptied
        if top == 1:
            self._save_nodes(dest, tree.keys, counts, inner, xyz, cat, perm, (cat["rgba"], wsum, wcount, perm))
            return
        n0 = int(counts[0])  # the keys are sorted: node ``top`` comes first
        carry, rest = perm[:n0], perm[n0:]
        _save_carry(dest, top, True, {}, {"xyz": xyz, "codes": codes, "wsum": wsum, "wcount": wcount, **cat}, carry)  # a group's root has children
        self._save_nodes(dest, tree.keys[1:], counts[1:], inner[1:], xyz, cat, rest, (cat["rgba"], wsum, wcount, rest))

    # -- phase 6
    def upper(self) -> None:
        st = self.state
        built = self.partial / "built"
        target = built / "upper"
        if target.exists():
            st["phase"] = "write"
            self.save_state()
            return
        self.progress.phase("upper", None)
        tmp = built / "upper.tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        self._join_roots(self._top_sets(), 1, tmp)
        os.replace(tmp, target)
        st["phase"] = "write"
        self.save_state()

    # -- phase 7
    def sources(self) -> list[Path]:
        built = self.partial / "built"
        groups = [built / _group_name(level, prefix) for level, prefix in self.state.get("groups", [])]
        parts = [built / _built_name(lev, prefix) for lev, prefix, _ in self.state["partitions"]]
        return [built / "upper"] + [p for p in groups + parts if p.exists()]

    def write(self) -> int:
        from .store import write_gigapoint

        st = self.state
        self.progress.phase("write", st["points"])
        if self.format == "potree":
            from .potree import write_potree

            n_nodes = write_potree(self.out, self.sources(), st, self.name, self.progress, self.encoding)
        else:
            self._close_outputs()
            n_nodes = write_gigapoint(self.out, self.sources(), st, self.name, self.sampler, self.max_leaf, self.progress)
        shutil.rmtree(self.partial, ignore_errors=True)
        return n_nodes

    def run(self, overwrite: bool) -> ConvertResult:
        self.t0 = time.perf_counter()
        fp = self.fingerprint()
        lock = None
        try:
            lock = _lock_output(self.out)
            return self._run_locked(overwrite, fp)
        finally:
            if lock is not None:
                os.close(lock)
            self.progress.close()

    def _run_locked(self, overwrite: bool, fp) -> ConvertResult:
        saved = _prepare_output(self.out, fp, overwrite)
        resumed = saved is not None
        if resumed and (self.partial / PREVIEW_NAME).is_file():
            self.first_view = 0.0  # the interrupted run's preview: viewable from the start
        self.state = saved or {"fingerprint": fp, "phase": "read"}
        self.save_state()
        phases = ["read", "count", "distribute", "build", "group", "upper", "write"]
        timings = {}
        for ph in phases[phases.index(self.state["phase"]) :]:
            t = time.perf_counter()
            if ph == "write":
                n_nodes = self.write()
            else:
                getattr(self, ph)()
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
        )


def convert(
    inputs,
    out,
    *,
    sampler: str = "grid",
    memory_limit=None,
    overwrite: bool = False,
    format: str = "gigapoint",
    max_leaf: int = DEFAULT_MAX_LEAF,
    partition_points: int | None = None,
    chunk_size: int | None = None,
    progress: bool = False,
    name: str | None = None,
    encoding: str = "DEFAULT",
    upper_points: int | None = None,
) -> ConvertResult:
    """Convert point cloud files (or an iterable of PointChunks) into an LOD octree directory ``out``.

    ``sampler``: grid | poisson. ``format``: gigapoint (rendered directly) | potree (Potree 2.0,
    ``encoding`` DEFAULT or BROTLI). ``memory_limit``: bytes or '4G'; bounds partition sizes. Only path
    inputs can resume after an interruption; chunk iterables always start clean.
    ``partition_points``, ``chunk_size`` and ``upper_points`` (the carried root points joined
    at once, default ``partition_points``) are tuning knobs, derived from the memory limit.
    """
    if sampler not in SAMPLERS:
        raise ConvertError(f"--sampler: unknown sampler {sampler!r}; choose {' or '.join(SAMPLERS)}")
    if format not in FORMATS:
        raise ConvertError(f"--format: unknown format {format!r}; choose {' or '.join(FORMATS)}")
    if not (isinstance(max_leaf, int) and max_leaf >= 100):
        raise ConvertError(f"max_leaf must be an integer >= 100, got {max_leaf!r}")
    if encoding not in ("DEFAULT", "BROTLI"):
        raise ConvertError(f"encoding: unknown Potree encoding {encoding!r}; choose DEFAULT or BROTLI")
    mem = parse_memory(memory_limit)
    if out is None or str(out) == "":
        raise ConvertError("convert: no output directory given (-o OUT)")
    conv = _Converter(
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
    )
    with _KeepFreedMemory():
        return conv.run(overwrite)
