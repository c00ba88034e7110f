"""The conversion on Dask: the same phases, split into tasks that Dask workers run.

``convert(inputs, out, client=...)`` (``gigapoint convert --dask ADDRESS`` or ``--workers N``).
The driver (this process) holds the output's lock and its state, plans the tasks and runs
the write phase; workers read the inputs and write into ``out``, which must be a path every
worker sees the same (a local or a shared network file system). The tasks:

=============  ==============================================================  ===============
phase          one task per                                                    done when
=============  ==============================================================  ===============
read           ``READ_CHUNKS`` chunks of a LAS/LAZ file (a point range), or a    its result is in
               whole file of another format: decoded, spilled to raw chunks;     the state
               a thinning of its points comes back for the preview
count          read task: the count grid of its chunks (sparse)                 (recomputed)
distribute     read task: its points grouped by partition into one file per    ``parts/t*.json``
               array (``parts/t<task>.<array>``), its raw chunks then removed
refine         partition denser than the count grid shows (rare)               the state
build          partition: ``BuildPhases.build_partition``                       ``built/p<key>``
group, upper   group of partition roots; the nodes above everything            ``built/g<key>``,
                                                                               ``built/upper``
place          a few node sets: their points copied into the output arrays     ``span.npy``
               at the offsets the single-process converter gives them, as
               soon as the sets before them are built (during the builds)
write          (the driver) the same write phase as without Dask; its steps    ``octree.json``
               that need not wait for each other (a format-2 stream joined,
               a range of nodes' checksums) a task each
=============  ==============================================================  ===============

The octree is the single-process converter's, file for file: points keep their input order
(ranges in file order, partitions' pieces in task order), the partition plan is made from the
same count grid, and node sets are built by the same code; only where their points go in the
gigapoint format's arrays is decided once all are built (``place``), in the order the
single-process converter fills them.

Faults: every task writes under temporary names and renames, or finds its result there and
returns it, so a task that Dask runs again (its worker died: the scheduler gives it to another
one) writes the same files. The driver saves the state as tasks finish; a run killed as a
whole resumes from it when the same command (any cluster) runs again. Errors come back as
one-line ``gigapoint.errors`` exceptions; a task whose workers keep dying fails the run after
Dask's ``allowed-failures``; a cluster without workers for ``NO_WORKER_S`` fails it too. Every
worker runs the driver's code and sees and may write ``out``: the driver checks the workers there
when the run starts (``_probe``), and a worker that joins later checks itself before its first task.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import sys
import tempfile
import threading
import time
import weakref
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ...atomic import atomic_json, atomic_open
from ...core import chunked, pages
from ...core.chunk import ColorScaler, warn_dropped_attributes
from ...errors import GigapointError, GigapointWarning, warn
from ...io._base import one_line
from ...io.colorize import Colorization
from ...io.filters import PointFilter, filtered
from ...io.las import with_scan_angle
from ...io.paths import skipped_message
from ...io.registry import reader_for
from ...io.reproject import Reprojection
from ..code import code_version
from ..keys import CODE_BITS
from ..octree_dir import STOPPED_RESUMES, ConvertError, OctreeDir
from ..preview import PreviewSampler, preview_points
from ..progress import NullProgress
from . import hooks
from .keep_freed_memory import KeepFreedMemory
from .options import MIN_DEFAULT_MEMORY, MIN_MEMORY_LIMIT, parse_memory, task_share
from .partition import COUNT_LEVEL, CellCounts, PartitionPhases, built_name, grid_cells, group_name, partition_lut
from .phases import BuildPhases, place_set
from .read import (
    ReadPhase,
    _read_chunks,
    _skipped_if_empty,
    merge_attributes,
    merge_constants,
    moved_and_blackened,
    spill_chunk,
)
from .spill import copy_range, decode_xyz, las_xyz_code, load_raw_chunk, load_raw_chunks, raw_chunk_files, raw_xyz_code

READ_CHUNKS = 1  # chunks (``chunk_size`` points, 2 M by default) a read task decodes: one a task
CHUNK_STRIDE = 1 << 20  # read task t spills chunks t·CHUNK_STRIDE + 0, 1, ...: sorted ids are the input order
PLACE_POINTS = 4_000_000  # node sets a place task copies: about this many points
CONNECT_TIMEOUT_S = 10.0  # reaching the scheduler
WORKER_WAIT_S = 60.0  # for a first worker to join the scheduler
NO_WORKER_S = 120.0  # a run whose cluster has had no worker this long fails
EARLIER_RUN_S = 600.0  # for tasks of an earlier, killed run into the same output to end
POLL_S = 0.5


# A worker runs its tasks on a thread of its own, whose allocations glibc serves from a thread
# arena: heaps of at most 64 MiB, of which every one but the first is unmapped as soon as it
# empties, whatever mallopt says, so KeepFreedMemory kept little there and every task faulted
# its arrays in afresh (a read task: 18 000 page faults, 60 % of its time in the kernel). One
# arena (the main one, which KeepFreedMemory does keep) for the workers that open_client starts
# (Dask puts it in this process's environment too, to spawn them); a cluster started elsewhere
# gets the same by running its workers with MALLOC_ARENA_MAX=1 (docs/lod.md, docs/scale.md).
WORKER_MALLOC_ENV = {"MALLOC_ARENA_MAX": "1"}
# Dask's housekeeping in the LocalCluster that open_client starts, whose scheduler and nannies share
# the cores with the workers: no statistical profiler (a thread in every worker that samples the
# task's stack every 10 ms; the dashboard's Profile page stays empty) and event-loop health ticks
# every 500 ms instead of 20 ms. With both, Dask's own threads used 0.3 s of CPU instead of 0.8 s
# over 5 s of two busy workers (docs/scale.md).
OWN_CLUSTER_CONFIG = {"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "500ms"}
# clients of the LocalClusters open_client started: their number of workers
_OWN_WORKERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_KEPT: list = []  # in a worker of such a cluster: the KeepFreedMemory entered for the process's life
# In a worker: the tasks of each output (output_tag) running now. A task whose driver was
# interrupted or died runs on to its end, but the scheduler forgets it at once (processing()
# no longer lists it): a re-run into that output asks the workers themselves (_running).
_RUNNING: dict[str, int] = {}
_RUNNING_LOCK = threading.Lock()


def output_tag(out: Path) -> str:
    """The part of a task's key, and of _RUNNING, that names its output (an absolute path)."""
    return hashlib.sha1(str(out).encode()).hexdigest()[:10]


def _running(tag: str) -> int:
    """On a worker: how many tasks into the output ``tag`` run now."""
    return _RUNNING.get(tag, 0)


def _distributed():
    try:
        import distributed
    except ImportError:
        raise ConvertError("client: a distributed conversion needs Dask: pip install 'gigapoint[dask]'") from None
    return distributed


def _has_bokeh() -> bool:
    try:
        import bokeh  # noqa: F401 - the dashboard's pages need it
    except ImportError:
        return False
    return True


def dashboard_link(client, local: bool = False) -> str | None:
    """The Dask dashboard's address when the scheduler serves one, else None. ``local``: the
    scheduler runs here (a LocalCluster), whose pages need bokeh installed here."""
    try:
        services = client.scheduler_info().get("services", {})
    except Exception:  # noqa: BLE001 - only a link to print
        return None
    if "dashboard" not in services or (local and not _has_bokeh()):
        return None
    return client.dashboard_link


MAX_WORKERS_PER_CORE = 4  # local worker processes a core at most (each single-threaded)


@contextmanager
def open_client(client, announce: bool = False):
    """A ``distributed.Client`` for ``client``: a Client (used as it is), a scheduler address
    (connected to, closed at the end) or a number of workers (a LocalCluster of that many
    single-threaded worker processes, closed at the end). ``announce``: print the dashboard's
    address on stderr."""
    dd = _distributed()
    if isinstance(client, dd.Client):
        yield client
        return
    cluster = None
    if isinstance(client, int) and not isinstance(client, bool):
        if client < 1:
            raise ConvertError(f"client: needs at least 1 worker, got {client}")
        cores = os.cpu_count() or 1
        if client > MAX_WORKERS_PER_CORE * cores:  # 1000 started 1000 processes on 2 cores: the run never came back
            raise ConvertError(
                f"client: {client} local worker processes on a machine of {cores} cores (at most {MAX_WORKERS_PER_CORE * cores}: each "
                "runs one thread); for more, start a Dask cluster and give client its scheduler's address"
            )
        import dask

        # glibc reads MALLOC_* when a process starts: Dask sets them before it spawns the workers
        settings = {**OWN_CLUSTER_CONFIG, **{f"distributed.nanny.pre-spawn-environ.{k}": v for k, v in WORKER_MALLOC_ENV.items()}}
        with dask.config.set(settings):
            cluster = dd.LocalCluster(
                n_workers=client,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",  # any free port (another cluster may hold 8787)
                silence_logs=logging.CRITICAL,  # a task's failure comes back as the conversion's one line, not also as
                # the worker's "Compute Failed" log of seven (a full disk, a damaged input)
                env={"NUMBA_NUM_THREADS": "1"},  # one core a worker: numba's kernels run on the task's thread
                # no memory limit of Dask's own: the conversion's (--memory-limit, default_memory_limit) sizes each
                # task. Dask's default, the RAM split N ways, paused a worker at 80 % of it, for good (it keeps freed
                # memory: the run hung), and killed it at 95 %, below what its tasks were allowed (the default a
                # quarter of the RAM each, 1 GB with --workers 4 on a 4 GB machine; or --memory-limit's)
                memory_limit=None,
            )
        c = dd.Client(cluster)
        _OWN_WORKERS[c] = client
    elif isinstance(client, str) and client.strip():
        try:
            _handshake(dd, client)
            c = dd.Client(client, timeout=CONNECT_TIMEOUT_S)
        except ConvertError:
            raise
        except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError, ValueError (a bad address) alike
            raise ConvertError(f"client={client!r}: cannot reach a Dask scheduler there ({one_line(exc) or type(exc).__name__})") from None
    else:
        raise ConvertError(f"client: a distributed.Client, a scheduler address or a number of workers, got {client!r}")
    try:
        if announce and (link := dashboard_link(c, local=cluster is not None)):
            print(f"Dask dashboard: {link}", file=sys.stderr)
        yield c
    finally:
        c.close()
        if cluster is not None:
            cluster.close()


def default_memory_limit(client, say: bool = False) -> int:
    """The conversion's memory limit, a task's, where none is given: as in one process, a quarter
    of the memory a task draws on. The N workers of a LocalCluster here (``--workers N``,
    ``client=N``) share this machine: half its RAM among them, at most a quarter each (4 workers
    planning a quarter each held all of a small machine's RAM). A cluster elsewhere (``--dask``, a
    Client of one's own): the same rule for its workers' memory (``_cluster_memory_limit``), not the
    driver's, which says nothing of theirs; the driver's quarter only where no worker has joined yet.
    ``convert(client=ADDRESS)`` asks them over the Client it runs on (connected once: converter.py).
    ``say``: where a cluster's limit came from, said on stderr."""
    if client in _OWN_WORKERS:  # the CLI's --workers N: open_client started them
        return task_share(chunked.physical_memory(), _OWN_WORKERS[client], MIN_DEFAULT_MEMORY)
    if isinstance(client, int):  # convert(client=N): open_client starts them (and refuses N < 1)
        return task_share(chunked.physical_memory(), max(1, client), MIN_DEFAULT_MEMORY)
    if isinstance(client, str):  # (an address: convert connects first and passes its Client)
        raise TypeError(f"default_memory_limit: a Client, a number of workers or None, got the address {client!r}")
    found = _cluster_memory_limit(client) if isinstance(client, _distributed().Client) else None  # (open_client refuses others)
    if found is None:
        return parse_memory(None)
    limit, source = found
    if say:
        print(f"Dask: each task planned for {limit >> 20} MiB, from {source} (--memory-limit sets it)", file=sys.stderr)
    return limit


def _workers(client) -> dict:
    """The cluster's workers, every one: some Dask releases list 5 by default
    (``scheduler_info(n_workers=5)``); those before the argument list them all."""
    try:
        return client.scheduler_info(n_workers=-1)["workers"]
    except TypeError:  # (a release without the argument)
        return client.scheduler_info()["workers"]


def _cluster_memory_limit(client) -> tuple[int, str] | None:
    """The smallest ``task_share`` of the cluster's workers, and whose, in words: a worker's Dask
    memory limit shared by its threads (each runs a task at once); a worker without one, its
    machine's memory shared by the threads of every such worker there. None: no worker yet."""
    dd = _distributed()
    try:
        workers = _workers(client)
    except Exception:  # noqa: BLE001 - a scheduler gone: the run says so
        return None
    unlimited = [w for w, info in workers.items() if not info["memory_limit"]]  # (0 where none was given)
    # (distributed's own function, which a worker that lacks gigapoint runs too: the run's check names that worker)
    machine = client.run(dd.system.memory_limit, workers=unlimited, on_error="return") if unlimited else {}
    threads_there: dict[str, int] = {}
    for w in unlimited:
        threads_there[workers[w]["host"]] = threads_there.get(workers[w]["host"], 0) + workers[w]["nthreads"]
    shares = []
    for w, info in workers.items():
        if info["memory_limit"]:
            memory, tasks, what = info["memory_limit"], info["nthreads"], "Dask memory limit"
        elif isinstance(machine.get(w), int):
            memory, tasks, what = machine[w], threads_there[info["host"]], "machine's memory, without a Dask limit"
        else:  # (gone meanwhile)
            continue
        shares.append((task_share(memory, tasks, MIN_MEMORY_LIMIT), w, f"{memory >> 20} MiB ({what}) among {tasks} thread(s)"))
    if not shares:
        return None
    limit, worker, source = min(shares)
    return limit, f"worker {worker}'s {source}"


def _handshake(dd, address: str) -> None:
    """A Dask handshake with ``address`` within CONNECT_TIMEOUT_S. Client() waits for the other
    end's answer without end once the connection is made: the dashboard's port (an HTTP server
    that waits for a request) hung the run for good; another service's bytes gave a MemoryError."""
    import asyncio
    import socket
    from concurrent.futures import ThreadPoolExecutor

    scheme, where = dd.comm.parse_address(address)
    if scheme == "tcp":  # Dask retries a refused connection, an unknown host, until its timeout: they are said at once
        try:
            host, port = dd.comm.parse_host_port(where)  # (ValueError: no port)
            if not 0 < port < 65536:  # (the resolver wraps it)
                raise ValueError(f"port {port} is not a TCP port")
            socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S).close()
        except (OSError, ValueError) as exc:
            why = "nothing listens on that port" if isinstance(exc, ConnectionRefusedError) else one_line(exc) or type(exc).__name__
            raise ConvertError(f"client={address!r}: cannot reach a Dask scheduler there ({why})") from None

    async def hello() -> None:
        try:
            comm = await asyncio.wait_for(dd.comm.connect(address, timeout=CONNECT_TIMEOUT_S), CONNECT_TIMEOUT_S)
        except TimeoutError:  # (asyncio.wait_for's; an OSError too, so first) connected, no answer
            raise ConvertError(
                f"client={address!r}: something listens there but does not answer as a Dask scheduler within {CONNECT_TIMEOUT_S:.0f} s "
                "(the dashboard's port? a scheduler listens on 8786 unless told otherwise)"
            ) from None
        except (OSError, ValueError):  # nothing listens there (Dask's message says so), a bad address
            raise
        except Exception as exc:  # noqa: BLE001 - another service's bytes decoded as Dask's
            raise ConvertError(f"client={address!r}: something listens there but does not speak Dask's protocol ({one_line(exc)})") from None
        await comm.close()

    with ThreadPoolExecutor(1) as pool:  # a loop of its own: the caller's thread may run one (Jupyter)
        pool.submit(asyncio.run, hello()).result()


# ---------------------------------------------------------------------------------------- workers


class _Task(PartitionPhases, BuildPhases):
    """The phases' code on a worker, for one task: options and the state it needs from the
    driver (``spec``), no progress display, and no state of its own (the driver saves it)."""

    def __init__(self, spec: dict, source=None):
        self.out = Path(spec["out"])
        self.dir = OctreeDir(spec["dir"])  # OUT itself, or a COPC output's working folder beside it
        self.sampler = spec["sampler"]
        self.format = spec["format"]
        self.max_leaf = spec["max_leaf"]
        self.encoding = spec["encoding"]
        self.chunk_size = spec["chunk_size"]
        self.mem = spec["memory_limit"]
        self.progress = NullProgress()
        self.state = dict(spec["state"])
        self.local_sets = self.format == "gigapoint"  # placed once every set is built (place_set)
        self.potree_in_place = False  # workers write their node sets' files; the driver writes octree.bin
        # a partition's input: ("pieces", [[task, row, rows, xyz code], ...]), ("raw", chunk ids) or None (its own files)
        self.source = source

    def save_state(self) -> None:
        pass

    def _partition_input(self, lev: int, prefix: int) -> tuple[dict, list[Path]]:
        if self.source is None:  # a refined partition: files of its own, removed once built
            return super()._partition_input(lev, prefix)
        kind, items = self.source
        if kind == "raw":  # the only partition: the spilled chunks (the driver removes them)
            return self._with_constants(load_raw_chunks(self.dir.raw, items, self._varying())), []
        n = sum(rows for _, _, rows, _ in items)
        data = {}
        for key, dt in self._dtypes().items():
            width = 3 if key == "xyz" else 1
            arr = np.empty((n, width) if width > 1 else n, dt)
            flat = memoryview(arr.reshape(-1).view(np.uint8))
            row, at = dt.itemsize * width, 0
            coded = [rows for _, _, rows, code in items if code is not None] if key == "xyz" else []
            buf = np.empty((max(coded, default=0), 3), np.int32)
            for t, start, rows, code in items:  # in task order: the input order
                if key == "xyz" and code is not None:  # int32 positions: decoded into place
                    ints = buf[:rows]
                    _read_into(_piece_file(self.dir, t, key), start * 12, memoryview(ints.reshape(-1).view(np.uint8)))
                    decode_xyz(ints, code, arr[at : at + rows])
                else:
                    _read_into(_piece_file(self.dir, t, key), start * row, flat[at * row : (at + rows) * row])
                at += rows
            data[key] = arr
        return self._with_constants(data), []


def _read_into(path: Path, offset: int, buf: memoryview) -> None:
    """Bytes ``offset``.. of ``path`` read straight into ``buf`` (no copy through a bytes object)."""
    with open(path, "rb", buffering=0) as f:
        f.seek(offset)
        done = 0
        while done < len(buf):
            k = f.readinto(buf[done:])
            if not k:
                raise OSError(f"{path}: ends before byte {offset + len(buf):,}")
            done += k


def _piece_file(d: OctreeDir, t: int, key: str) -> Path:
    """Distribute task ``t``'s rows of array ``key``, grouped by partition."""
    return d.parts / f"t{t:06d}.{key}"


def _piece_result(d: OctreeDir, t: int) -> Path:
    """Distribute task ``t``'s result: [[partition, first row, rows], ...]; written last."""
    return d.parts / f"t{t:06d}.json"


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "a Dask worker"


def _numba_threads_from_environment() -> None:
    """numba's config read again before its threads start. A worker spawned from a script that
    imports gigapoint at its top imports it again (as ``__mp_main__``) before Dask sets the
    worker's NUMBA_NUM_THREADS=1, so numba kept the default thread count, and the worker's
    first compile (which re-reads the environment) failed: "Cannot set NUMBA_NUM_THREADS to a
    different value once the threads have been launched". A worker whose threads already run
    with another count than its environment says gets that as a one-line error."""
    from numba.core import config

    try:
        config.reload_config()
    except RuntimeError as exc:
        raise ConvertError(
            f"Dask worker {_worker_name()}: numba's threads started with another count than NUMBA_NUM_THREADS says ({one_line(exc)}); "
            "start the workers with NUMBA_NUM_THREADS=1 in their environment"
        ) from None



def _first_failed_read(dd, failed, name: str, index: int, futures: dict):
    """(future, name) of the read task that fails first in the inputs' order: ``failed`` (the
    ``index``-th read), or one before it still running, waited for; and the reads before that
    one, which ended well, as [(future, on_done, i), ...] in order. Read tasks end in any order,
    and each task over a damaged LAZ chunk names another of its points: the run said whichever
    ended first (a message that changed from run to run)."""
    earlier = sorted(((j, g, n, on_done) for g, (k, n, on_done, j) in futures.items() if k == "read" and j < index), key=lambda t: t[0])
    dd.wait([g for _, g, _, _ in earlier])
    ended = []
    for j, g, n, on_done in earlier:
        if g.status != "finished":
            return g, n, ended
        ended.append((g, on_done, j))
    return failed, name, ended


def _task(kind: str, name: str, spec: dict, fn, *args):
    """Run one task on a worker: numba's kernels on this thread only, freed memory kept while it
    runs (keep_freed_memory.py; for the life of the process in the workers of a LocalCluster
    that open_client started), an OSError turned into a one-line error naming the worker; counted
    in _RUNNING while it runs."""
    with _RUNNING_LOCK:
        _RUNNING[spec["tag"]] = _RUNNING.get(spec["tag"], 0) + 1
    try:
        return _run_task(kind, name, spec, fn, *args)
    finally:
        with _RUNNING_LOCK:
            _RUNNING[spec["tag"]] -= 1


def _run_task(kind: str, name: str, spec: dict, fn, *args):
    import numba

    hooks.task_started(kind, name)
    if "run" in spec:  # (the driver's tasks; tests run bare ones)
        _worker_checked(spec)
    _numba_threads_from_environment()
    numba.set_num_threads(1)
    try:
        if spec.get("own_workers"):  # a worker of ours: freed memory kept for the next task too
            if not _KEPT:
                _KEPT.append(KeepFreedMemory().__enter__())
            with pages.numpy_small_pages():
                result = fn(spec, *args)
        else:  # someone else's worker: glibc's settings come back after each task
            with KeepFreedMemory(), pages.numpy_small_pages():
                result = fn(spec, *args)
        hooks.task_done(kind, name)
        return result
    except GigapointError:
        raise
    except OSError as exc:
        where = exc.filename or spec["out"]
        raise ConvertError(
            f"{where}: {exc.strerror or one_line(exc)} (on Dask worker {_worker_name()}, {kind} task {name}); "
            f"the conversion to {spec['out']} stopped unfinished ({STOPPED_RESUMES})"  # (as one process says it)
        ) from None


def _unseen(path: str, what: str, rule: str, spec: dict) -> ConvertError:
    """The error of a file the driver saw when it planned the task that this worker does not see
    (it runs elsewhere): not an InputError, the file is fine, and the run resumes once the workers see it."""
    return ConvertError(
        f"{path}: Dask worker {_worker_name()} does not see this {what}, which the driver does ({rule} at the "
        f"same path on a file system every worker shares); the conversion to {spec['out']} stopped unfinished ({STOPPED_RESUMES})"
    )


@contextmanager
def _moving_and_coloring(spec: dict):
    """(Reprojection, Colorization) of the conversion's ``--to-crs`` and ``--colorize`` (None where
    not given) for read tasks, made again from the driver's spec: the raster opened here (on a
    file system every worker shares, as the inputs are), closed at the end."""
    reprojection = None if spec["reprojection"] is None else Reprojection.from_spec(spec["reprojection"])
    raster = spec["colorize"]
    if raster is None:
        yield reprojection, None
        return
    if not os.path.exists(raster):
        raise _unseen(raster, "raster (--colorize)", "it must be", spec)
    colorization = Colorization(raster, "convert", spec["colorize_bits"])  # (the driver's bit depth: not sampled, nor warned of, again)
    try:
        yield reprojection, colorization
    finally:
        colorization.close()


def _read_task(
    spec: dict, t: int, path: str, start: int | None, stop: int | None, color_mode: str | None, stride: int, reprojection=None, colorization=None
) -> dict:
    """Read task ``t``: points start..stop of ``path`` (None: the whole file) spilled to raw chunks
    t·CHUNK_STRIDE + j. ``color_mode``: the file's color decision before ``start``. Its result
    has every ``stride``-th valid point for the preview ("preview"; the driver's, not the state's).
    ``reprojection``, ``colorization``: ``_moving_and_coloring``'s, which move each chunk before the
    filter and colour it after, as one process does (read.py); the points that took no colour
    are counted ("uncolored")."""
    if not os.path.exists(path):  # the driver saw it when it planned this task: this worker is elsewhere
        raise _unseen(path, "input", "inputs must be", spec)
    raw = OctreeDir(spec["dir"]).raw
    scaler, xyz_code, empty = None, None, []
    if start is None:  # an empty file among several (one whose header has no count: text) skipped, said by the driver
        chunks = _skipped_if_empty(Path(path), _read_chunks(Path(path), spec["chunk_size"]), spec["several"], empty)
    else:
        scaler = ColorScaler()
        scaler.mode = color_mode
        chunks = reader_for(path).read_chunks(Path(path), spec["chunk_size"], start=start, stop=stop, scaler=scaler)
        if reprojection is None:  # a range of a LAS/LAZ file: its positions spilled as the file's int32 (spill.encode_xyz); moved ones are off its grid
            xyz_code = las_xyz_code(path)
    chunks = moved_and_blackened(chunks, path, reprojection, colorization)
    if spec["one_angle"]:
        chunks = with_scan_angle(chunks)
    passing = PointFilter.from_spec(spec["filter"])  # the driver's filter, as the task's own count
    chunks = filtered(chunks, path, passing)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    attrs, constant, n_chunks, n_in, points, skipped, eight, uncolored = None, {}, 0, 0, 0, 0, False, 0
    sample: list[dict] = []
    for j, chunk in enumerate(chunks):
        if j >= CHUNK_STRIDE:
            raise ConvertError(f"{path}: more than {CHUNK_STRIDE:,} chunks in one read task")
        if colorization is not None:
            chunk, missed = colorization.colored(chunk, had_color=True)  # (a colourless file's points: black, moved_and_blackened)
        (xyz, rgba, _, names, invalid, c_lo, c_hi), found = spill_chunk(raw, t * CHUNK_STRIDE + j, chunk, xyz_code)
        if colorization is not None:  # the invalid points, skipped, lie on no pixel (as ReadPhase.read counts them)
            uncolored += missed - int(invalid)
        merge_constants(constant, found)
        pick = slice((-points) % stride, None, stride)
        sample.append({"xyz": np.array(xyz[pick]), "rgba": np.array(rgba[pick])})
        eight |= scaler is not None and scaler.mode == "8"
        attrs = merge_attributes(attrs, names)
        if c_lo is not None:
            lo, hi = np.minimum(lo, c_lo), np.maximum(hi, c_hi)
        n_chunks, n_in, points, skipped = j + 1, n_in + len(chunk), points + len(xyz), skipped + int(invalid)
    return {
        "chunks": n_chunks,
        "input": n_in if passing is None else passing.read,  # points read (the progress total's), the filter's left out too
        "passed": None if passing is None else passing.passed,
        "points": points,
        "skipped": skipped,
        "uncolored": uncolored,  # (0 without --colorize)
        "empty": bool(empty),
        "lo": lo.tolist(),
        "hi": hi.tolist(),
        "attributes": attrs,
        "constant": constant,  # (read.merge_constants)
        "ends16": scaler is not None and scaler.mode == "16",
        "eight": eight,  # a chunk was decoded as 8-bit colors: wrong if an earlier part of the file was 16-bit
        # positions as float32 offsets from the task's corner, no attributes: what the driver takes in is a third
        "preview": (lo, (np.concatenate([p["xyz"] for p in sample]) - lo).astype(np.float32), np.concatenate([p["rgba"] for p in sample]))
        if points
        else None,
    }


def _read_batch(spec: dict, reads: list, stride: int) -> list[dict]:
    """Read tasks ``reads`` [(t, path, start, stop, color mode), ...] in one Dask task (``DaskPhases._batches``): their results."""
    with _moving_and_coloring(spec) as (reprojection, colorization):
        return [_read_task(spec, *r, stride, reprojection, colorization) for r in reads]


def _count_task(spec: dict, ids: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """The count grid of chunks ``ids``: (cells, points) of its non-empty cells."""
    st = spec["state"]
    raw = OctreeDir(spec["dir"]).raw
    counting = CellCounts()
    for i in ids:
        xyz = load_raw_chunk(raw, i, [])["xyz"]
        if len(xyz):
            counting.add(grid_cells(xyz, np.array(st["origin"]), st["edge"]))
    counts = counting.total()
    cells = np.flatnonzero(counts)
    return cells.astype(np.int32), counts[cells]


def _distribute_task(spec: dict, t: int, ids: list[int], partitions: list) -> dict:
    """Task ``t``'s chunks ``ids`` grouped by partition: one file per array, each partition's
    rows together, in partition order (chunks in order within each); the chunks are then
    removed. Positions stay int32 when every chunk has them so under one code (spill.encode_xyz).
    Returns {"pieces": [[partition, first row, rows], ...], "xyz_code": the code or None} (also
    written, last: a repeated task returns it)."""
    d = OctreeDir(spec["dir"])
    result = _piece_result(d, t)
    if result.exists():
        return json.loads(result.read_text())
    w = _Task(spec)
    st = w.state
    origin, edge = np.array(st["origin"]), st["edge"]
    lut = partition_lut(partitions)
    pieces = []
    try:
        codes = [raw_xyz_code(d.raw, i) for i in ids]
        code = codes[0] if codes and all(c is not None and np.array_equal(c, codes[0]) for c in codes) else None
        for i, c in zip(ids, codes):
            data = load_raw_chunk(d.raw, i, w._varying(), decode=code is None)
            if len(data["xyz"]):
                xyz = data["xyz"] if code is None else decode_xyz(data["xyz"], c)
                pieces.append(w._by_partition(data, lut[grid_cells(xyz, origin, edge)], len(partitions)))
    except FileNotFoundError:
        if result.exists():  # the same task, run twice at once (a worker thought dead), finished first
            return json.loads(result.read_text())
        raise
    per = sum((np.diff(cuts) for _, cuts in pieces), np.zeros(len(partitions), np.int64))
    touched = np.flatnonzero(per)
    for key in w._dtypes():
        with atomic_open(_piece_file(d, t, key)) as f:
            for p in touched:
                for sorted_data, cuts in pieces:
                    if cuts[p + 1] > cuts[p]:
                        f.write(memoryview(np.ascontiguousarray(sorted_data[key][cuts[p] : cuts[p + 1]])).cast("B"))
    starts = np.cumsum(per) - per
    out = {"pieces": [[int(p), int(starts[p]), int(per[p])] for p in touched], "xyz_code": None if code is None else code.tolist()}
    atomic_json(result, out)
    for f in raw_chunk_files(d.raw, ids):
        f.unlink(missing_ok=True)
    return out


def _refine_task(spec: dict, lev: int, prefix: int, n: int, items: list) -> tuple[list, list, list]:
    """A partition above the budget (a spot denser than the count grid): its pieces gathered into
    files of its own, then split like the single-process converter does (PartitionPhases._refine).
    Returns its sub-partitions, their points and the unsplittable ones."""
    w = _Task(spec)
    dts = w._dtypes()
    for key, path in w._part_files(lev, prefix).items():  # the pieces, in order, copied in the kernel: no partition in memory
        row = dts[key].itemsize * (3 if key == "xyz" else 1)
        with atomic_open(path) as f:
            f.truncate(n * row)
            at = 0
            for t, start, rows, code in items:
                src = _piece_file(w.dir, t, key)
                if key == "xyz" and code is not None:  # int32 positions: decoded (the partition's files hold float64)
                    ints = np.fromfile(src, np.int32, rows * 3, offset=start * 12).reshape(rows, 3)
                    buf, done = memoryview(decode_xyz(ints, code)).cast("B"), 0
                    while done < len(buf):
                        done += os.pwrite(f.fileno(), buf[done:], at * row + done)
                else:
                    copy_range(src, start * row, f.fileno(), at * row, rows * row)
                at += rows
    w.state.update(partitions=[[lev, prefix, n]], part_counts=[n], unsplittable=[])
    w._refine()
    return w.state["partitions"], w.state["part_counts"], w.state["unsplittable"]


def _set_points(d: Path) -> int:
    """The points a built node set holds (below its root: the root's are carried up)."""
    return int(np.load(d / "counts.npy").sum())


def _build_task(spec: dict, lev: int, prefix: int, n: int, source) -> int:
    """Partition (lev, prefix) built; returns its node set's points."""
    w = _Task(spec, source)
    w.build_partition(lev, prefix, n)
    return _set_points(w.dir.built / built_name(lev, prefix))


def _group_task(spec: dict, level: int, prefix: int, members: list[str]) -> None:
    _Task(spec).join_group(level, prefix, [Path(m) for m in members])


def _upper_task(spec: dict, tops: list[str]) -> None:
    w = _Task(spec)
    if not (w.dir.built / "upper").exists():
        w.build_upper([Path(p) for p in tops])


def _place_task(spec: dict, sets: list, outputs: dict) -> int:
    """Node sets [(folder, offset), ...] copied into the output arrays, which are then flushed to
    disk (here, while other workers compute, rather than all at once in the write phase)."""
    outs = {k: (Path(path), np.dtype(dt), off) for k, (path, dt, off) in outputs.items()}
    n = sum(place_set(Path(d), outs, off) for d, off in sets)
    for path, _, _ in outs.values():
        fd = os.open(path, os.O_RDONLY)
        try:
            getattr(os, "fdatasync", os.fsync)(fd)  # macOS has no fdatasync
        finally:
            os.close(fd)
    return n


def _call_task(spec: dict, fn, *args):
    """A step of the write phase (writer.py's ``run``): ``fn(*args)``."""
    return fn(*args)


# In a worker: the runs (their state's token) whose check (_probe) this process passed
_CHECKED: set[str] = set()
_CHECKED_LOCK = threading.Lock()


def _worker_checked(spec: dict) -> None:
    """The driver's check of its workers (_probe), made on this worker once a run, before its
    first task: the driver checks the workers there when the run starts, and one that joins
    later (an autoscaling cluster) ran tasks unchecked, under other code or writing where the
    driver never looks."""
    with _CHECKED_LOCK:  # (a worker of several threads: one check)
        if spec["run"] in _CHECKED:
            return
        problem = _probe(spec["dir"], spec["run"], spec["version"])
    if problem:
        raise ConvertError(f"{spec['out']}: Dask worker {_worker_name()} {problem}")


def _gigapoint_import_check():
    """A function that says why ``module`` cannot be imported where it runs (None: it can). Defined
    in here, so Dask's cloudpickle sends its code (by value), which runs where gigapoint is missing."""

    def import_problem(module: str) -> str | None:
        import importlib

        try:
            importlib.import_module(module)
        except ImportError as exc:
            return str(exc)
        return None

    return import_problem


def _probe(out: str, token: str, version: str) -> str | None:
    """On each worker before its first task: does it run the driver's code (``version``), does it
    see the driver's output folder, and may it write there? (None: yes; noted in _CHECKED)"""
    if version != code_version():
        return (
            f"runs gigapoint {code_version()}, the driver {version} (version+digest of the source): "
            "install the same gigapoint on every worker and restart them"
        )
    d = OctreeDir(out)
    st = d.read_state()
    if st is None or st.get("run") != token:
        return "does not see the files the driver writes there (the output must be on a file system every worker shares)"
    try:
        fd, name = tempfile.mkstemp(dir=d.partial, prefix=".probe.", suffix=".tmp")
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        return f"cannot write into it ({exc.strerror or exc})"
    _CHECKED.add(token)
    return None


# ----------------------------------------------------------------------------------------- driver


class DaskPhases(ReadPhase, PartitionPhases, BuildPhases):
    """The phases run as Dask tasks; the driver's side. converter.py puts it in front of its
    ``_Converter`` (which runs the phases in order) when ``convert`` gets a client."""

    potree_in_place = False  # the workers build the node sets (_Task)

    client = None  # set by convert() before run()

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.paths is None:
            raise ConvertError("client: a distributed conversion reads files (its workers open them); got point chunks")
        # workers get absolute paths; errors and warnings name them as given, as one process does (_as_given)
        self._given = {str(p.resolve()): str(p) for p in (self.out, self.dir.path, *self.paths)}
        self.out = self.out.resolve()
        self.dir = OctreeDir(self.dir.path.resolve())
        self.paths = [p.resolve() for p in self.paths]
        self._out_tag = output_tag(self.out)
        self._run_tag = os.urandom(4).hex()
        self._tasks_run = 0  # in this run: each task's key is unique
        self._last_preview = None  # the read phase's preview sample, written in full while the distribute tasks run

    def _as_given(self, text: str) -> str:
        """``text`` with the output's and inputs' absolute paths as the user gave them (the longest
        first: a work file's path under OUT's becomes OUT as given and the rest)."""
        for full in sorted(self._given, key=len, reverse=True):
            text = text.replace(full, self._given[full])
        return text

    def fingerprint(self) -> dict | None:
        fp = super().fingerprint()
        # the state's layout differs from a single-process run's (and from that before int32 spills)
        return None if fp is None else {**fp, "engine": "dask", "spill": "xyz-int32"}

    # ------------------------------------------------------------------ running tasks

    def _spec(self) -> dict:
        st = self.state
        keep = ("origin", "edge", "attributes", "constant", "partition_points", "compact")
        return {
            "out": str(self.out),
            "tag": self._out_tag,
            "dir": str(self.dir.path),
            "sampler": self.sampler,
            "format": self.format,
            "max_leaf": self.max_leaf,
            "encoding": self.encoding,
            "chunk_size": self.chunk_size,
            "several": len(self.paths) > 1,
            "one_angle": self.one_angle,
            "filter": None if self.point_filter is None else self.point_filter.as_spec(),  # (with --to-crs: its polygon moved already)
            "reprojection": None if self.reprojection is None else self.reprojection.as_spec(),
            "colorize": None if self.colorization is None else str(self._raster()),
            "colorize_bits": None if self.colorization is None else self.colorization.nbits,
            "memory_limit": self.mem,
            "run": st["run"],  # each worker checks itself with these before its first task (_worker_checked)
            "version": code_version(),
            "own_workers": self.client in _OWN_WORKERS,
            "state": {k: st[k] for k in keep if k in st},
        }

    def _raster(self) -> Path:
        """The ``--colorize`` raster's absolute path, for the workers; errors name it as given (_as_given)."""
        full = self.colorization.path.resolve()
        self._given.setdefault(str(full), str(self.colorization.path))
        return full

    def _run(self, kind: str, calls: list, on_done, also: tuple | None = None, meanwhile=None) -> None:
        """Run ``calls`` [(name, function, args, priority), ...] as ``kind`` tasks; ``on_done(i,
        result)`` runs in the driver as each one finishes and may return more tasks to run
        alongside, as (kind, calls, on_done), as ``also`` is. ``meanwhile()`` runs once the tasks
        are submitted. The first error cancels the rest and is raised."""
        dd = _distributed()
        spec = self._spec()
        futures: dict = {}

        def submit(kind: str, calls: list, on_done) -> set:
            new = set()
            for i, (name, fn, args, priority) in enumerate(calls):
                self._tasks_run += 1
                key = f"gigapoint-{self._out_tag}-{self._run_tag}-{kind}-{self._tasks_run}"
                f = self.client.submit(_task, kind, name, spec, fn, *args, key=key, priority=priority, pure=False)
                futures[f] = (kind, name, on_done, i)
                new.add(f)
            return new

        stop = threading.Event()
        lost = []  # the watchdog's finding: the cluster has had no worker for NO_WORKER_S

        def watchdog() -> None:
            since = None
            while not stop.wait(POLL_S):
                try:
                    workers = _workers(self.client)
                except Exception:  # noqa: BLE001 - a scheduler gone: the futures fail on their own
                    return
                since = None if workers else (since or time.monotonic())
                if since is not None and time.monotonic() - since > NO_WORKER_S:
                    lost.append(True)
                    self.client.cancel([f for f in futures if not f.done()])
                    return

        # as_completed is event driven: distributed.wait(FIRST_COMPLETED) costs O(pending) a
        # call, which made 10 000 pending tasks quadratic (bench_dask.py --overhead-tasks)
        completed = dd.as_completed(submit(kind, calls, on_done) | (submit(*also) if also else set()))
        guard = threading.Thread(target=watchdog, name="gigapoint-dask-watchdog", daemon=True)
        guard.start()
        try:
            if meanwhile is not None:
                meanwhile()
            for f in completed:
                kind, name, callback, i = futures.pop(f)
                if lost:
                    raise ConvertError(f"{self.out}: the Dask cluster has had no worker for {NO_WORKER_S:.0f} s; {self._resume_hint()}")
                if f.status != "finished":
                    if kind == "read":  # a damaged file fails every read of it: named, as one process does, by the first
                        f, name, ended = _first_failed_read(dd, f, name, i, futures)
                        # the reads before it are taken in: their points counted, as one process counts those before
                        # a bad input, so OUT stays and the error says so (converter.run); a read failing before they
                        # were taken in left none counted: OUT was removed and the line lacked what became of it
                        for g, take_in, j in ended:
                            del futures[g]
                            take_in(j, g.result())
                    raise self._task_error(kind, name, f)
                more = callback(i, f.result())
                f.release()
                if more:
                    completed.update(submit(*more))
        except (KeyboardInterrupt, SystemExit):  # (Ctrl+C, the CLI's SIGTERM) the cancelled tasks that run go on writing into OUT
            stop.set()
            self.client.cancel(list(futures))
            say = "{} Dask tasks still run into the output: waiting for them to end (Ctrl+C again leaves them; a re-run waits for them)"
            self._wait_for_running(say, EARLIER_RUN_S)
            raise
        finally:
            stop.set()
            if futures:
                self.client.cancel(list(futures))

    def _task_error(self, kind: str, name: str, future) -> Exception:
        try:
            exc = future.exception()
        except Exception as e:  # noqa: BLE001 - a cancelled future has none
            exc = e
        if isinstance(exc, GigapointError):
            return exc
        if type(exc).__name__ == "KilledWorker":
            return ConvertError(
                f"{self.out}: the {kind} task {name} failed because its worker died every time it ran "
                f"(out of memory? see the workers' logs); {self._resume_hint()}"
            )
        if type(exc).__name__ in ("CancelledError", "FutureCancelledError"):
            return ConvertError(f"{self.out}: the {kind} task {name} was cancelled by the Dask scheduler; {self._resume_hint()}")
        return exc

    def _resume_hint(self) -> str:
        return "run the same command again to resume"

    def run(self, overwrite: bool):
        """The conversion (converter.py's ``run``), once a worker is there and the tasks of an
        earlier run into this output, if any are still running, have ended: before the output
        folder is prepared (a fresh start clears it) and before any task writes into it."""
        try:
            self._cluster_ready()
            return super().run(overwrite)
        except GigapointError as exc:  # (a worker's names the absolute paths it was given)
            exc.args = (self._as_given(str(exc)),)
            raise

    def _cluster_ready(self) -> None:
        try:
            try:
                self.client.wait_for_workers(1, timeout=WORKER_WAIT_S)
            except TimeoutError:
                where = getattr(self.client.scheduler, "address", "the Dask scheduler")
                raise ConvertError(f"{where}: no Dask worker joined the scheduler within {WORKER_WAIT_S:.0f} s") from None
            self._wait_for_earlier_run()
        except BaseException:
            self.progress.close()  # super().run closes it otherwise
            raise

    def output_ready(self) -> None:
        """Before the first task: every worker runs this code, sees the output folder and may write into it."""
        token = os.urandom(8).hex()
        self.state["run"] = token
        self.save_state()
        answers = self.client.run(_probe, str(self.dir.path), token, code_version(), on_error="return")
        if any(isinstance(problem, BaseException) for problem in answers.values()) and (lacking := self._lacking_gigapoint()):
            raise lacking  # (Dask's answer there: its failure to unpickle _probe, as a bare Exception)
        for worker, problem in sorted(answers.items()):
            if isinstance(problem, BaseException):  # (an older gigapoint's _probe)
                problem = f"failed the driver's check ({one_line(problem)}): install the driver's gigapoint on every worker"
            if problem:
                raise ConvertError(f"{self.out}: Dask worker {worker} {problem}")

    def _lacking_gigapoint(self) -> ConvertError | None:
        """The error naming a worker that cannot import gigapoint, if one is there: Dask cannot
        unpickle _probe there, and says so as a bare Exception naming no package to install. (One
        that joins later cannot unpickle its first task: Dask drops its connection, and the task
        goes to another worker.)"""
        answers = self.client.run(_gigapoint_import_check(), __name__, on_error="return")  # (the tasks' module)
        for worker, problem in sorted(answers.items()):
            if isinstance(problem, str):
                return ConvertError(
                    f"{self.out}: Dask worker {worker} cannot import gigapoint ({one_line(problem)}): "
                    f"install gigapoint {code_version()} there (the driver's version+digest of the source)"
                )
        return None

    def _wait_for_earlier_run(self) -> None:
        """A killed driver's tasks that had started run to their end on the workers; its re-run
        waits for them, so that no two tasks write the same files at once."""
        if self._wait_for_running("{} Dask tasks of an earlier run into the output still run: waiting for them to end", EARLIER_RUN_S):
            raise ConvertError(f"{self.out}: tasks of an earlier conversion into it are still running on the Dask cluster")

    def _wait_for_running(self, say: str, limit_s: float) -> bool:
        """Until no task into this output runs on a worker, ``say`` (its count in {}) said on stderr
        once if any does; True if some still run after ``limit_s``."""
        t0 = time.monotonic()
        while busy := sum(n for n in self.client.run(_running, self._out_tag, on_error="return").values() if isinstance(n, int)):
            if say:
                print(say.format(busy), file=sys.stderr)
                say = ""
            if time.monotonic() - t0 > limit_s:
                return True
            time.sleep(POLL_S)
        return False

    # ------------------------------------------------------------------ read

    def _plan_reads(self) -> list:
        """[[file index, first point, end point, color mode], ...]: ranges of READ_CHUNKS chunks of
        files whose reader reads ranges (LAS, LAZ), whole files (None, None) otherwise."""
        reads = []
        step = READ_CHUNKS * self.chunk_size
        for f, p in enumerate(self.paths):
            reader = reader_for(p)
            n = reader.point_count(p)  # (the header's; None where it has none: text. An empty file among several: left out by input_paths)
            if n and getattr(reader, "reads_ranges", False):
                reads += [[f, s, min(s + step, n), None] for s in range(0, n, step)]
            else:
                reads.append([f, None, None, None])
        return reads

    def _chunk_ids(self, t: int) -> list[int]:
        return [t * CHUNK_STRIDE + j for j in range(self.state["read_results"][str(t)]["chunks"])]

    def _batches(self, ts: list[int], points) -> list[list[int]]:
        """Read tasks ``ts`` (in order) batched, consecutive ones up to ``chunk_size`` points
        (``points(t)``) a batch, a Dask task each: a task a tile of 2 000 points cost ~39 ms
        (1 500 tiles: 67 s on two workers, one file of their points 9 s)."""
        out: list[list[int]] = []
        n = 0
        for t in ts:
            k = points(t)
            if out and n + k <= self.chunk_size:
                out[-1].append(t)
                n += k
            else:
                out.append([t])
                n = k
        return out

    def _points_read(self, t: int) -> int:
        return self.state["read_results"][str(t)]["points"]

    def read(self) -> None:
        st = self.state
        self.dir.raw.mkdir(exist_ok=True)
        if "reads" not in st:
            st.update(reads=self._plan_reads(), read_results={})
            self.save_state()
        results = st["read_results"]
        st["total"] = self.point_total
        self.progress.phase("read", st["total"])
        for res in results.values():
            self.progress.advance(res["input"])
        again = False
        # the preview: read tasks send every stride-th point (~target in all), the sampler thins further if need be
        preview = PreviewSampler(self.dir.preview, preview_points(self.mem), None)
        stride = max(1, (st["total"] or self.chunk_size * len(st["reads"])) // preview.target)
        while True:
            todo = [t for t in range(len(st["reads"])) if str(t) not in results]
            batches = self._batches(todo, lambda t: self.chunk_size if st["reads"][t][1] is None else st["reads"][t][2] - st["reads"][t][1])

            def done(i, batch_res, batches=batches, again=again):
                for t, res in zip(batches[i], batch_res):
                    sample = res.pop("preview")
                    results[str(t)] = res
                    if res.get("empty"):  # a file that had no count in its header
                        warn(self._as_given(skipped_message(self.paths[st["reads"][t][0]])), GigapointWarning)
                    if not again:
                        # points read so far, as one process counts them: a bad input then keeps OUT (converter.run) and info shows them
                        st["points"] = st.get("points", 0) + res["points"]
                        self.progress.advance(res["input"])
                        if sample is not None:
                            corner, xyz, rgba = sample
                            preview.add(xyz.astype(np.float64) + corner, rgba, {})
                            self._write_preview(preview)
                self.save_state_soon()

            calls = []
            for batch in batches:
                reads = [(t, str(self.paths[st["reads"][t][0]]), *st["reads"][t][1:]) for t in batch]
                calls.append((f"{Path(reads[0][1]).name}:{reads[0][2] or 0}", _read_batch, (reads, stride), 0))
            self._run("read", calls, done)
            redo = self._color_redo()
            if not redo:
                break
            for t in redo:  # rare: a dark part of a 16-bit file read before its bright start was known
                st["reads"][t][3] = "16"
                del results[str(t)]
            again = True
        self._last_preview = preview  # its last write waits for the distribute tasks to be under way (distribute)
        lo, hi, attrs, constant, dropped = np.full(3, np.inf), np.full(3, -np.inf), None, {}, set()
        for t in range(len(st["reads"])):
            res = results[str(t)]
            lo, hi = np.minimum(lo, res["lo"]), np.maximum(hi, res["hi"])
            if res["attributes"] is not None:
                merged = merge_attributes(attrs, res["attributes"])
                if attrs is not None:  # (left out without a word, where one process says so: ReadPhase.read)
                    dropped |= (set(attrs) | set(res["attributes"])) - set(merged)
                attrs = merged
            merge_constants(constant, res.get("constant", dict.fromkeys(res["attributes"] or {})))  # (none noted: a run from before)
        st.update(
            chunks=sum(r["chunks"] for r in results.values()),
            points=sum(r["points"] for r in results.values()),
            skipped=sum(r["skipped"] for r in results.values()),
            lo=lo.tolist(),
            hi=hi.tolist(),
            attributes=attrs or {},
            constant=constant,
        )
        if self.colorization is not None:  # (every task's, those of a resumed run's earlier runs too: convert() reports it)
            st["uncolored"] = sum(r["uncolored"] for r in results.values())
        if self.point_filter is not None:  # (ReadPhase._end_read: "no point passes the filter" where it left none)
            st.update(filter_read=sum(r["input"] for r in results.values()), filter_passed=sum(r["passed"] for r in results.values()))
        warn_dropped_attributes(self._as_given(str(self.out)), dropped)
        self._end_read(lo, hi)

    def _color_redo(self) -> list[int]:
        """Read tasks whose file's colors were 16-bit before their range began, but which decided
        8-bit on a dark chunk of their own (io's ColorScaler never goes back from 16-bit)."""
        st = self.state
        redo, bright = [], set()
        for t, (f, start, _, _) in enumerate(st["reads"]):
            res = st["read_results"][str(t)]
            if start is not None and f in bright and res["eight"]:
                redo.append(t)
            if res["ends16"]:
                bright.add(f)
        return redo

    # ------------------------------------------------------------------ count, distribute

    def _read_tasks(self) -> list[int]:
        return [t for t in range(len(self.state["reads"])) if self.state["read_results"][str(t)]["chunks"]]

    def count(self) -> None:
        st = self.state
        counts = np.zeros(8**COUNT_LEVEL, np.int64)
        self.progress.phase("count", st["points"])
        batches = self._batches(self._read_tasks(), self._points_read)

        def done(i, res):
            cells, n = res
            counts[cells] += n
            self.progress.advance(sum(map(self._points_read, batches[i])))

        self._run("count", [(f"t{b[0]}", _count_task, ([i for t in b for i in self._chunk_ids(t)],), 0) for b in batches], done)
        self._plan(counts)

    def _final_preview(self) -> None:
        """The read phase's whole preview sample written (the phase ended between two writes),
        while the distribute tasks run. Not while the count tasks run: that phase is short and
        waited for this write (two workers took as long over it as one, 0.52 s)."""
        preview, self._last_preview = self._last_preview, None
        if preview is not None:
            self._write_preview(preview, force=True)

    def distribute(self) -> None:
        st = self.state
        parts = st["partitions"]
        if len(parts) == 1:  # one partition: the build reads the spilled chunks themselves
            self._final_preview()
            st.update(part_counts=[st["points"]], from_raw=True, phase="build")
            self.save_state()
            return
        self.dir.parts.mkdir(exist_ok=True)
        results = st.setdefault("distributed_tasks", {})
        self.progress.phase("distribute", st["points"])
        # batches of read tasks (their first one's number names the pieces); the same in a resumed run: read_results are saved
        batches = self._batches(self._read_tasks(), self._points_read)
        todo = [b for b in batches if str(b[0]) not in results]
        for b in batches:
            if str(b[0]) in results:
                self.progress.advance(sum(map(self._points_read, b)))

        def done(i, res):
            results[str(todo[i][0])] = res
            self.progress.advance(sum(map(self._points_read, todo[i])))
            self.save_state_soon()

        calls = [(f"t{b[0]}", _distribute_task, (b[0], [i for t in b for i in self._chunk_ids(t)], parts), 0) for b in todo]
        self._run("distribute", calls, done, meanwhile=self._final_preview)
        counts = [0] * len(parts)
        pieces: dict = {}
        for t in sorted(map(int, results)):  # task order: the input order
            res = results[str(t)]
            for pid, start, rows in res["pieces"]:
                counts[pid] += rows
                pieces.setdefault(built_name(*parts[pid][:2]), []).append([t, start, rows, res["xyz_code"]])
        st.update(part_counts=counts, pieces=pieces)
        self.save_state()
        self._refine_pieces()
        st["phase"] = "build"
        self.save_state()

    def _refine_pieces(self) -> None:
        """Partitions above the budget split as the single-process converter splits them, a task each."""
        st = self.state
        parts, counts = st["partitions"], st["part_counts"]
        big = [i for i, (lev, _, _) in enumerate(parts) if counts[i] > st["partition_points"] and lev < CODE_BITS]
        if not big:
            return
        results = {}

        def done(i, res):
            results[big[i]] = res

        calls = []
        for i in big:
            lev, prefix, _ = parts[i]
            calls.append(
                (built_name(lev, prefix), _refine_task, (lev, prefix, counts[i], st["pieces"][built_name(lev, prefix)]), counts[i])
            )
        self._run("refine", calls, done)
        new_parts, new_counts = [], []
        for i, (p, n) in enumerate(zip(parts, counts)):
            if i in results:
                sub, sub_counts, unsplittable = results[i]
                new_parts += sub
                new_counts += sub_counts
                st.setdefault("unsplittable", []).extend(unsplittable)
            else:
                new_parts.append(p)
                new_counts.append(n)
        st.update(partitions=new_parts, part_counts=new_counts)

    # ------------------------------------------------------------------ build, group, upper

    def _build_partitions(self, parts: list) -> None:
        """The partitions' builds as tasks, the largest first; gigapoint format: each set placed
        into the output arrays as soon as every set before it is built (``_Placer``)."""
        st = self.state
        built = self.dir.built
        pieces = st.get("pieces", {})
        sets = [(lev, prefix, n) for lev, prefix, n in parts if n]  # the partitions that make a node set, in order
        todo = [(lev, prefix, n) for lev, prefix, n in sets if not (built / built_name(lev, prefix)).exists()]
        self.progress.advance(sum(n for _, _, n in parts) - sum(n for _, _, n in todo))
        refs: dict[int, int] = dict.fromkeys(map(int, st.get("distributed_tasks", {})), 0)
        for lev, prefix, _ in todo:
            for t, *_ in pieces.get(built_name(lev, prefix), []):
                refs[t] += 1
        for t in [t for t, r in refs.items() if r == 0]:
            self._remove_pieces(t, refs)
        placer = _Placer(self, [built / built_name(lev, prefix) for lev, prefix, _ in sets]) if self.format == "gigapoint" else None
        first_places = None
        if placer is not None:
            pending = {(lev, prefix) for lev, prefix, _ in todo}
            done_before = [built / built_name(lev, prefix) for lev, prefix, _ in sets if (lev, prefix) not in pending]
            placer.sizes.update({s: _set_points(s) for s in done_before})
            first_places = placer.built(done_before[0], placer.sizes[done_before[0]]) if done_before else None
        done_now = 0

        def done(i, set_points):
            nonlocal done_now
            lev, prefix, n = todo[i]
            self.progress.advance(n)
            done_now += 1
            hooks.after_partition_built(done_now)
            for t, *_ in pieces.get(built_name(lev, prefix), []):
                refs[t] -= 1
                if refs[t] == 0:
                    self._remove_pieces(t, refs)
            return None if placer is None else placer.built(built / built_name(lev, prefix), set_points)

        calls = []
        for lev, prefix, n in todo:
            name = built_name(lev, prefix)
            if st.get("from_raw"):
                source = ("raw", [i for t in self._read_tasks() for i in self._chunk_ids(t)])
            elif name in pieces:
                source = ("pieces", pieces[name])
            else:
                source = None  # a refined partition's own files
            calls.append((name, _build_task, (lev, prefix, n, source), n))  # the largest first
        self._run("build", calls, done, first_places)
        if st.get("from_raw"):
            for f in raw_chunk_files(self.dir.raw):
                f.unlink(missing_ok=True)

    def _remove_pieces(self, t: int, refs: dict) -> None:
        for key in self._dtypes():  # the arrays a distribute task writes
            _piece_file(self.dir, t, key).unlink(missing_ok=True)
        refs.pop(t, None)

    def _join_groups(self, groups: list) -> None:
        calls = [(f"g{level}-{prefix:x}", _group_task, (level, prefix, [str(m) for m in members]), 0) for level, prefix, members in groups]
        self._run("group", calls, lambda i, res: None)

    def build_upper(self, tops: list[Path]) -> None:
        self._run("upper", [("upper", _upper_task, ([str(p) for p in tops],), 0)], lambda i, res: None)

    # ------------------------------------------------------------------ place, write

    def _placing_order(self) -> list[Path]:
        """The node sets in the order the single-process converter fills the output arrays: the
        partitions (in order), the groups (round by round), the upper nodes."""
        built = self.dir.built
        st = self.state
        sets = [built / built_name(lev, prefix) for lev, prefix, _ in st["partitions"]]
        sets += [built / group_name(lev, pre) for lev, pre in st.get("groups", [])]
        return [p for p in sets if p.exists()] + [built / "upper"]

    def _output_spec(self) -> dict:
        """gigapoint format: the output arrays (made here if need be), as the place tasks take them."""
        return {k: (str(path), dt.str, int(off)) for k, (path, dt, off) in self._outputs().items()}

    def _place(self) -> None:
        """Every node set not placed yet (the groups', the upper nodes', a resumed run's) placed."""
        sets = self._placing_order()
        if all((s / "span.npy").exists() for s in sets):
            return  # placed (and maybe renamed already by an interrupted write)
        placer = _Placer(self, sets)
        self.progress.phase("place", sum(_set_points(s) for s in sets if not (s / "span.npy").exists()))
        for s in sets[:-1]:
            placer.sizes[s] = _set_points(s)
        self._run(*placer.built(sets[-1], _set_points(sets[-1])))

    def write(self) -> int:
        if self.format == "gigapoint":
            self._place()
        return super().write()

    def _write_steps(self, fn, calls: list) -> list:
        """The write phase's independent steps (a stream joined, a range of checksums) as tasks
        where the cluster has two workers or more: on two they took 0.45 s instead of 0.56 s,
        while both would otherwise wait for the driver (on one, 0.1 s longer than here)."""
        try:
            workers = len(_workers(self.client))
        except Exception:  # noqa: BLE001 - a scheduler gone: the tasks fail with the usual error
            workers = 2
        if workers < 2:
            return super()._write_steps(fn, calls)
        results: list = [None] * len(calls)

        def done(i, res):
            results[i] = res

        self._run("write", [(f"{fn.__name__}-{i}", _call_task, (fn, *args), 0) for i, args in enumerate(calls)], done)
        return results


class _Placer:
    """gigapoint format: the node sets ``order`` (in the order the single-process converter fills
    the output arrays) placed as soon as the sizes of all sets before them are known."""

    def __init__(self, conv: DaskPhases, order: list[Path]):
        self.order = order
        self.sizes: dict[Path, int] = {}
        self.next = 0  # order[:next] are placed (or being placed)
        self.offset = 0  # where order[next] goes
        self.outputs = conv._output_spec()
        self.progress = conv.progress if conv.state.get("phase") == "write" else None  # the build phase's bar counts builds

    def built(self, path: Path, points: int) -> tuple | None:
        """Set ``path`` holds ``points``: the place tasks that can go now, as _run takes them."""
        self.sizes[path] = points
        batches: list[list] = []
        held = PLACE_POINTS
        while self.next < len(self.order) and self.order[self.next] in self.sizes:
            s = self.order[self.next]
            if not (s / "span.npy").exists():
                if held >= PLACE_POINTS:
                    batches.append([])
                    held = 0
                batches[-1].append((str(s), self.offset))
                held += self.sizes[s]
            self.offset += self.sizes[s]
            self.next += 1
        if not batches:
            return None
        calls = [(Path(b[0][0]).name, _place_task, (b, self.outputs), -1) for b in batches]
        return "place", calls, lambda i, n: self.progress and self.progress.advance(n)
