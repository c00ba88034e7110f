"""The progressive octree (issue #18): insertion rate, loading overhead, first image, frames while loading, memory.

    .venv/bin/python benchmarks/bench_progressive.py                        # 8 M points, every part
    .venv/bin/python benchmarks/bench_progressive.py --points 20M --parts insert load

- ``insert``: points already decoded (the demo town, in its generator's order, which spreads
  every batch over the whole town, in scan order: 50 m strips, and in scan order as a LAS file
  holds them: on its 1 mm grid, with its six attributes), inserted in batches of 1 M
  with the root cube given (as from LAS headers); JIT warm-up excluded; the orders alternate
  ``--rounds`` times (medians). Reported: points/s,
  voxels per point, memory per point against gigapoint's quantized layout of the same points
  (16 bytes + the attributes), while filling and once trimmed; and the converter's split of the
  same points into the same tree (sort and ``split_tree``) for comparison.
- ``insert-ab``: the insertion of this revision against ``--base``'s (its package exported as
  ``gigapoint_base``, as bench_ab.py does), alternating ``--rounds`` times in one process, both
  orders: points/s, CPU seconds and the memory faulted in (minor page faults).
- ``load``: the same points written as LAZ and LAS (scan order); decoding them alone (laspy's
  records, the baseline; laspy's records with scaled xyz and colours, what a program needs of
  them; every chunk of ``gigapoint.io.read_chunks``) against ``gigapoint.open(...,
  progressive=True)`` to completion, alternately, in one process: the ratio is what LOD costs loading.
- ``memory``: bytes a point of the town as a LAS file loaded progressively (on the file's grid,
  attributes in their range, once loaded) against three words a point and the plain cloud's
  layout; what the octree held when its last point was in, before ``trim``; and the peak RSS
  of a process that only loads the file.
- ``first``: seconds from ``gigapoint.demo(10**9, progressive=True)`` (or ``gigapoint.open(FILE,
  progressive=True)`` with ``--first-source FILE``) to its first image with points (1920x1080),
  then the loader is closed.
- ``gil``: how long a thread that sleeps 1 ms at a time waits while another thread decodes a
  LAZ (laspy/lazrs: it holds the GIL while it decodes a call's points), while it loads one
  progressively, and while it only sleeps.
- ``first-files``: ``first`` of the demo and of the town (``--points``) as LAS and as LAZ, each
  in a new process, alternating.
- ``viewer``: ``gigapoint view --demo 1000000000`` (progressive: above the point budget):
  seconds from a client's connect (as the page does) to its first frame.
- ``save``: a progressive octree of the points (LAS, scan order, loaded to completion) saved
  as a gigapoint octree: ``save()`` (its leaves are the conversion's partitions,
  lod/convert/seeded.py) against converting its points again (``convert(cloud.chunks(), ...)``,
  what ``save`` did before), the same leaf size, alternately, each into a fresh folder.
- ``convert``: a LAS file (scan order) to a gigapoint octree through the progressive builder
  (``gigapoint.open(..., progressive=True)``, loaded, then ``save()``), against ``gigapoint
  convert`` of the same file and, with ``--potree-converter PATH``, PotreeConverter's
  ``--method random``, alternately (process-internal times for gigapoint, wall time of the
  PotreeConverter process).
- ``frames``: median (and 95th percentile) frame time at 1920x1080 with a 10 M budget (drawn by
  ``--backend``; on the GPU, with the bytes uploaded while loading) while the demo loads, of the same octree once loaded, and of a converted octree of the same points
  (alternately; views iso, close-up and top).
- ``select``: frames of the loaded demo with nodes selected by the box of their points and by
  their cubes (``ProgressiveOctree.select_by_points``), interleaved.
- ``sample``: frames of the loaded demo with its leaves' grid samples and with every leaf's
  points (the samples switched off), and of its converted octree, alternating (views as ``frames``).
- ``hidden``: the selection of a frame (``prepare``: its selections, through the load filter
  their costs) and the whole frame (``--backend``, one-pixel points, 10 M budget), with class 5
  (vegetation) hidden and without, alternating, of the loaded demo and of its points converted
  with 150-point leaves (10^5 nodes and more at 20 M points); views as ``frames``.
- ``sort``: a set's keys sorted by numpy's sort and by ``kernels.radix_sort`` (10^6 keys of the
  town, best of 5), then the insertion (as ``insert``, both orders) with each, alternately;
  which one this CPU's insertions use (timed once a process).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import gigapoint as gp
from gigapoint.bench import parse_counts, run_measured
from gigapoint.io import demo_arrays, read_chunks
from gigapoint.lod.progressive import ProgressiveOctree


def _cpu() -> str:
    from gigapoint.bench import cpu_model

    return cpu_model()


def _scan_order(xyz):
    return np.lexsort((xyz[:, 0], np.floor(xyz[:, 1] / 50.0)))


def bench_insert(n: int, batch: int, rounds: int) -> None:
    xyz, rgba, attrs = demo_arrays(n, seed=1)
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    cube = (lo - 0.5, float(np.max(hi - lo)) + 1.0)
    warm = ProgressiveOctree("warm", cube=cube)
    warm.add(xyz[:300_000], rgba[:300_000], **{a: v[:300_000] for a, v in attrs.items()})
    _converter_split_seconds(xyz[:300_000], cube, warm.max_leaf)  # its kernels compiled
    runs = (("generator order", np.arange(n), False), ("scan order", _scan_order(xyz), False),
            ("generator order, tree shaped first from every 32nd point (expect)", np.arange(n), True))  # fmt: skip
    inputs = {name: (xyz[order], rgba[order], {a: v[order] for a, v in attrs.items()}, shaped, None) for name, order, shaped in runs}
    # the points as a LAS file holds them (what gp.open(..., progressive=True) of one inserts): on
    # its 1 mm grid, which the octree is given, and with its attributes, constant ones too
    offset, order = np.floor(lo), _scan_order(xyz)
    las = {**attrs, "return_number": np.ones(n, np.uint8), "number_of_returns": np.ones(n, np.uint8),
           "point_source_id": np.zeros(n, np.uint16), "gps_time": np.zeros(n)}  # fmt: skip
    inputs["scan order, as a LAS file at 1 mm holds them (its grid given)"] = (
        offset + np.round((xyz[order] - offset) / 0.001) * 0.001, rgba[order], {a: v[order] for a, v in las.items()}, False, (offset, 0.001)
    )
    x, c, at, _, grid = inputs["scan order, as a LAS file at 1 mm holds them (its grid given)"]
    ProgressiveOctree("warm", cube=cube, grid=grid).add(x[:300_000], c[:300_000], **{a: v[:300_000] for a, v in at.items()})  # its kernels
    times, system, report = {name: [] for name in inputs}, {name: [] for name in inputs}, {}
    # the orders alternate, rounds times: a process's first run of this size pays for memory it
    # never had (faulted in from the host on these VMs), later ones reuse what the last one freed
    for _ in range(rounds):
        for name, (x, c, at, shaped, grid) in inputs.items():
            o = ProgressiveOctree("bench", cube=cube, capacity=n, grid=grid)
            sys0, t = resource.getrusage(resource.RUSAGE_SELF).ru_stime, time.perf_counter()
            if shaped:
                o.expect(x[::32], 32.0)
            for s in range(0, n, batch):
                o.add(x[s : s + batch], c[s : s + batch], **{a: v[s : s + batch] for a, v in at.items()})
            times[name].append(time.perf_counter() - t)
            system[name].append(resource.getrusage(resource.RUSAGE_SELF).ru_stime - sys0)  # page faults, mostly
            filling = o.nbytes
            o.trim()  # as the loader does when loading ends
            report[name] = (o.spilled / n, o.n_voxels / n, filling / n, o.nbytes / n, _chunk_fill(o))
            del o
    for name, (x, _c, at, _shaped, _grid) in inputs.items():
        layout = 16 + sum(v.dtype.itemsize for v in at.values())
        dt = statistics.median(times[name])
        spilled, voxels, filling, mem, full = report[name]
        each = ", ".join(f"{t:.2f}" for t in times[name])
        print(f"insert, {name}: {n / dt / 1e6:.2f} M points/s (median {dt:.2f} s of {each}; system time {statistics.median(system[name]):.2f} s), "
              f"{spilled:.2f} spilled and {voxels:.2f} voxels a point; memory {filling:.1f} bytes a point while filling (presized, work arrays "
              f"kept), {mem:.1f} once trimmed = {mem / layout:.2f}x the quantized layout ({layout} B), its chunks {full:.0%} full")  # fmt: skip
        split = _converter_split_seconds(x, cube, warm.max_leaf)
        print(f"  the converter's way to the same tree (lod/build: codes, sort_codes, split_tree; no voxels, nothing stored): "
              f"{n / split / 1e6:.2f} M points/s, {dt / split:.1f}x faster than the insertion")  # fmt: skip


def _converter_split_seconds(xyz, cube, max_leaf: int) -> float:
    """Seconds the converter's build phase takes to find the progressive octree's tree for
    ``xyz`` (the same nodes and leaves in the same cube: test_its_tree_is_the_converters_tree_of_the_same_cube)."""
    from gigapoint.lod.build import sort_codes, split_tree
    from gigapoint.lod.keys import ROOT_KEY, point_codes

    t = time.perf_counter()
    codes, _ = sort_codes(point_codes(xyz, cube[0], cube[1]))
    split_tree(codes, ROOT_KEY, max_leaf)
    return time.perf_counter() - t


def _write(path: Path, xyz, rgba, attrs) -> Path:
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [0.001] * 3
    header.offsets = np.floor(xyz.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rgb = rgba[:, :3].astype(np.uint16) * 257
    las.red, las.green, las.blue = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    las.intensity, las.classification = attrs["intensity"], attrs["classification"]
    las.write(str(path))
    return path


def _town_files(folder: Path, n: int, suffixes=("las",)) -> list[Path]:
    """The demo town of ``n`` points as ``folder``/town.<suffix> (LAS or LAZ) files, its points in
    scan order (as a scanner writes them)."""
    xyz, rgba, attrs = demo_arrays(n, seed=2)
    order = _scan_order(xyz)
    xyz, rgba, attrs = xyz[order], rgba[order], {a: v[order] for a, v in attrs.items()}
    return [_write(Path(folder) / f"town.{suffix}", xyz, rgba, attrs) for suffix in suffixes]


def _laspy_decode(path: Path) -> None:
    """The file decoded by laspy alone (lazrs in parallel where it is installed), 1 M points a call."""
    import laspy

    with laspy.open(str(path)) as reader:
        for _points in reader.chunk_iterator(1_000_000):
            pass


def _laspy_points(path: Path) -> None:
    """The file read by laspy as points a program can use: each chunk's scaled float64 x, y, z
    (and its colours), 1 M points a call. For a LAS file the records alone are a copy of the
    file's bytes (``_laspy_decode``), which no use of the points stops at."""
    import laspy

    with laspy.open(str(path)) as reader:
        for points in reader.chunk_iterator(1_000_000):
            np.column_stack([points.x, points.y, points.z])
            np.column_stack([points.red, points.green, points.blue])


@contextlib.contextmanager
def _laz_decoded(in_child: bool):
    """LAZ decoded by the child process (io/laz_process.py, the default) or in this process
    (GIGAPOINT_LAZ_PROCESS=0) within the block."""
    from gigapoint.io import laz_process

    os.environ[laz_process.ENV_SWITCH] = "1" if in_child else "0"
    try:
        yield
    finally:
        os.environ.pop(laz_process.ENV_SWITCH)


def bench_load(n: int, rounds: int) -> None:
    """Progressive loads to completion against decoding alone; a LAZ both ways: decoded by the
    child process (io/laz_process.py, the default) and in this process (GIGAPOINT_LAZ_PROCESS=0),
    rounds alternating."""

    def timed(run) -> float:
        t = time.perf_counter()
        run()
        return time.perf_counter() - t

    def load(path, child: bool) -> None:
        with _laz_decoded(child), gp.open(path, progressive=True) as cloud:
            cloud.wait()

    with tempfile.TemporaryDirectory() as tmp:
        for path in _town_files(tmp, n, ("laz", "las")):
            suffix = path.suffix[1:]
            runs = {
                "laspy alone": lambda path=path: _laspy_decode(path),
                "laspy, scaled xyz and colours": lambda path=path: _laspy_points(path),
                "read_chunks alone": lambda path=path: sum(len(c) for c in read_chunks(path, 1_000_000)),
                "progressive": lambda path=path: load(path, True),
            }
            if suffix == "laz":
                runs["progressive, decoded in this process"] = lambda path=path: load(path, False)
            for run in runs.values():  # warm-up: JIT, page cache
                run()
            times = {name: [] for name in runs}
            for _ in range(rounds):
                for name, run in runs.items():
                    times[name].append(timed(run))
            base = statistics.median(times["laspy alone"])
            cols = ", ".join(f"{name} {statistics.median(t):.2f} s = {statistics.median(t) / base:.2f}x" for name, t in times.items())
            print(f"load {suffix.upper()} {n / 1e6:g} M (medians of {rounds}): {cols}")


# one progressive load in a process of its own (load_alone; bench_slices.py's too): its seconds,
# the octree's bytes when the last point is in (before trim) and once loaded; argv[2], where
# given, the loader's slice size
_LOAD_ALONE = """
import sys, time
import gigapoint as gp
from gigapoint.lod.progressive import ProgressiveOctree, loader
if len(sys.argv) > 2:
    loader.SLICE_POINTS = int(sys.argv[2])
filled, trim = {}, ProgressiveOctree.trim
def recorded(octree):
    filled["bytes"] = octree.nbytes
    trim(octree)
ProgressiveOctree.trim = recorded
t = time.perf_counter()
with gp.open(sys.argv[1], progressive=True) as cloud:
    cloud.wait()
    print(f"{time.perf_counter() - t:.2f} {filled['bytes']} {cloud.nbytes}")
"""


def load_alone(path: Path, slice_points: int | None = None) -> tuple[float, int, int, int]:
    """``path`` loaded progressively to completion in a process of its own, with the loader's
    ``SLICE_POINTS`` = ``slice_points`` (None: its default): (seconds, the octree's bytes when
    the last point is in, its bytes once loaded, the process's peak RSS). The peak is taken
    through gigapoint.bench.run_measured: this process is large, and a child's own ru_maxrss
    would report this one's."""
    slices = [] if slice_points is None else [str(slice_points)]
    code, out, err, _, peak = run_measured([sys.executable, "-c", _LOAD_ALONE, str(path), *slices])
    if code != 0:
        raise SystemExit(f"the lone load failed: {err.decode()[-2000:]}")
    seconds, filled, held = out.decode().split()
    return float(seconds), int(filled), int(held), peak


def bench_memory(n: int) -> None:
    """Bytes a point of the town as a LAS file (scan order, 1 mm) loaded progressively (trimmed:
    point chunks on the file's grid, attributes in their range) against the quantized layouts of
    the same points: three words a point (16 bytes + the attributes at their dtypes: what points
    without a grid take) and the plain cloud (``gigapoint.open``: the compact layout, attributes
    in their range; with u32 colours, as the octree holds them, and with its default colours)."""
    from gigapoint.io import open_cloud

    filled, trim = {}, ProgressiveOctree.trim

    def recorded(octree):  # what the loader's memory limit counts when the last point is in
        filled.update(octree.memory())
        trim(octree)

    with tempfile.TemporaryDirectory() as tmp:
        (path,) = _town_files(tmp, n, ("las",))
        ProgressiveOctree.trim = recorded
        try:
            with gp.open(path, progressive=True) as cloud:
                cloud.wait()
                mem, voxels, chunks = cloud.memory(), cloud.n_voxels / n, _chunk_fill(cloud)
                words = 16 + sum(cloud.attributes[a].dtype.itemsize for a in cloud.attributes)
        finally:
            ProgressiveOctree.trim = trim
        plain = open_cloud(path, colors="rgba").nbytes / n
        default = open_cloud(path).nbytes / n
        seconds, _, _, peak = load_alone(path)
        alone = f"{seconds:.2f} s, peak RSS {peak / 2**20:.0f} MiB (the process's first load)"
    total = sum(mem.values()) / n
    parts = ", ".join(f"{k} {v / n:.1f}" for k, v in mem.items() if v)
    while_filling = ", ".join(f"{k} {v / n:.1f}" for k, v in filled.items() if v)
    print(f"memory, LAS {n / 1e6:g} M at 1 mm: {sum(filled.values()) / n:.1f} bytes a point when the last point is in, before trim "
          f"({while_filling}; presized room and build state included: what the memory limit counts)")
    print(f"memory, LAS {n / 1e6:g} M at 1 mm, loaded in a process of its own: {alone}")
    print(f"memory, LAS {n / 1e6:g} M at 1 mm: {total:.1f} bytes a point loaded ({parts}; {voxels:.2f} voxels a point, chunks {chunks:.0%} "
          f"full); the quantized layouts: three words {words} B = {total / words:.2f}x, the plain cloud's compact layout with u32 colours "
          f"{plain:.1f} B = {total / plain:.2f}x, with its default colours {default:.1f} B = {total / default:.2f}x")  # fmt: skip


def _chunk_fill(o: ProgressiveOctree) -> float:
    used = o.pool.batches["count"][: o._n_chunks]
    return float(used.sum() / max(1, used.size * o.pool.chunk))


def bench_save(n: int, rounds: int) -> None:
    import shutil

    from gigapoint.lod import convert

    with tempfile.TemporaryDirectory() as tmp:
        (path,) = _town_files(tmp, n)
        cloud = gp.open(path, progressive=True)
        cloud.wait()
        warm = ProgressiveOctree("warm", max_leaf=cloud.max_leaf)  # JIT warm-up of both paths
        warm.add(cloud.positions(cloud.node_entries(int(cloud.leaves()[0]))))
        warm.save(Path(tmp) / "w1")
        convert(warm.chunks(), Path(tmp) / "w2", max_leaf=warm.max_leaf)
        times: dict[str, list[float]] = {"save (its tree)": [], "convert its points again": []}
        for r in range(rounds):
            for name, runs in times.items():
                out = Path(tmp) / f"out{r}_{len(runs)}_{name[:4]}"
                t = time.perf_counter()
                if name.startswith("save"):
                    cloud.save(out)
                else:
                    convert(cloud.chunks(), out, max_leaf=cloud.max_leaf, source_files=cloud.source_files, name=cloud.name)
                runs.append(time.perf_counter() - t)
                shutil.rmtree(out)
        base = statistics.median(times["convert its points again"])
        for name, runs in times.items():
            m = statistics.median(runs)
            print(f"save {n / 1e6:g} M: {name}: {m:.2f} s ({n / m / 1e6:.2f} M points/s), {base / m:.2f}x converting again; runs {[round(t, 2) for t in runs]}")
        cloud.close()


def bench_convert_through_builder(n: int, rounds: int, potree: str | None) -> None:
    import shutil
    import sys

    from gigapoint.lod import convert

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_convert import run_potree

    with tempfile.TemporaryDirectory() as tmp:
        (path,) = _town_files(tmp, n)
        small = _write(Path(tmp) / "warm.las", *demo_arrays(20_000, seed=3))
        warm = gp.open(small, progressive=True)  # JIT warm-up of both paths
        warm.wait()
        warm.save(Path(tmp) / "w1")
        convert([small], Path(tmp) / "w2")
        warm.close()

        def through_builder(out):
            cloud = gp.open(path, progressive=True)
            cloud.wait()
            cloud.save(out)
            cloud.close()

        runs = {"through the progressive builder (open, load, save)": through_builder, "gigapoint convert": lambda out: convert([path], out)}
        if potree:
            runs["PotreeConverter --method random"] = lambda out: run_potree(potree, path, out, "random")
        times: dict[str, list[float]] = {k: [] for k in runs}
        for r in range(rounds):
            for name, fn in runs.items():
                out = Path(tmp) / f"out{r}"
                shutil.rmtree(out, ignore_errors=True)
                t = time.perf_counter()
                fn(out)
                times[name].append(time.perf_counter() - t)
                shutil.rmtree(out, ignore_errors=True)
        base = statistics.median(times["gigapoint convert"])
        for name, ts in times.items():
            m = statistics.median(ts)
            print(f"convert {n / 1e6:g} M LAS: {name}: {m:.2f} s ({n / m / 1e6:.2f} M points/s), {base / m:.2f}x gigapoint convert; "
                  f"runs {[round(t, 2) for t in ts]}")  # fmt: skip


def bench_first(source: str | None) -> None:
    """The first image of ``source`` (a file; None: the demo of 10^9 points), in this process."""
    cam = None
    t = time.perf_counter()
    cloud = gp.open(source, progressive=True) if source else gp.demo(10**9, progressive=True)
    while True:
        if cloud.n_points:
            cam = cam or gp.Camera.fit(cloud.bounds, view="iso", width=1920, height=1080)
            frame = gp.render_frame(cloud, cam)
            if frame.stats.visible_pixels:
                break
        time.sleep(0.005)
    name = Path(source).name if source else "demo(1,000,000,000)"
    print(f"first image of {name} progressive: {time.perf_counter() - t:.2f} s after open ({frame.stats.points_processed:,} points drawn)")
    cloud.close()


def bench_first_files(n: int, rounds: int) -> None:
    """The first image of the demo, of a LAS and of a LAZ file of the town (``n`` points), each in
    a new process (as a user's first image: numba's cache loaded, nothing compiled or warm),
    alternating; run it with bytecode written (``env -u PYTHONDONTWRITEBYTECODE``)."""
    import re
    import sys

    with tempfile.TemporaryDirectory() as tmp:
        files = _town_files(tmp, n, ("las", "laz"))
        sources = {"demo(10^9)": [], **{f.name: [] for f in files}}
        for r in range(rounds + 1):  # the first round fills numba's cache for these inputs, untimed
            for name, arg in zip(sources, [[], *(["--first-source", str(f)] for f in files)]):
                out = subprocess.run([sys.executable, __file__, "--parts", "first", *arg], capture_output=True, text=True, check=True).stdout
                if r:
                    sources[name].append(float(re.search(r"progressive: ([0-9.]+) s after open", out).group(1)))
        for name, ts in sources.items():
            print(f"first image of {name} progressive, new processes: median {statistics.median(ts):.2f} s after open; runs {ts}")


def bench_gil(n: int) -> None:
    """Whether decoding a LAZ in a thread stops the process's other threads: the town (``n``
    points) as LAZ, decoded by ``read_chunks`` in a thread while this thread sleeps 1 ms at a
    time; a sleep that ends late waited for the GIL (or a core). Then the same with a thread
    that only sleeps, for the baseline, and the progressive load of the file; decoding and
    loading both with the LAZ decoded in a child process (io/laz_process.py, the default) and
    in this process (GIGAPOINT_LAZ_PROCESS=0)."""
    import threading

    def stalls(work) -> str:
        thread = threading.Thread(target=work)
        thread.start()
        late = []
        while thread.is_alive():
            t = time.perf_counter()
            time.sleep(0.001)
            late.append(time.perf_counter() - t - 0.001)
        ms = np.array(late) * 1000
        return f"{len(ms)} sleeps, p99 {np.percentile(ms, 99):.1f} ms late, max {ms.max():.0f} ms, {int((ms > 20).sum())} over 20 ms"

    with tempfile.TemporaryDirectory() as tmp:
        (path,) = _town_files(tmp, n, ("laz",))
        gp.open(path, progressive=True).wait()  # warm-up

        def decode():
            for _chunk in read_chunks(path, 250_000):
                pass

        def load():
            with gp.open(path, progressive=True) as cloud:
                cloud.wait()

        for where, in_child in (("in a child process", True), ("in this process", False)):
            with _laz_decoded(in_child):
                print(f"a thread decoding {n / 1e6:g} M points of LAZ (250 k a call), {where}: {stalls(decode)}")
                print(f"a thread loading them progressively, decoded {where}: {stalls(load)}")
        print(f"a thread sleeping 2 s: {stalls(lambda: time.sleep(2.0))}")


def bench_viewer(n: int) -> None:
    """``gigapoint view --demo N`` in a subprocess; a client connects over the WebSocket as the
    page does: seconds to the first frame it receives."""
    import json
    import sys

    from websockets.sync.client import connect

    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "gigapoint.cli", "view", "--demo", str(n), "--no-browser"], stdout=subprocess.PIPE, text=True)
    try:
        page = proc.stdout.readline().strip()
        t_url = time.perf_counter()
        url = page.replace("http://", "ws://", 1).split("?")[0] + "ws"
        t1 = time.perf_counter()
        with connect(f"{url}?w=1920&h=1080", max_size=2**26, open_timeout=60) as ws:
            assert json.loads(ws.recv(timeout=60))["type"] == "hello"
            while not isinstance(ws.recv(timeout=120), bytes):
                pass
            t2 = time.perf_counter()
    finally:
        proc.terminate()
        proc.wait(10)
    print(f"viewer of demo({n:,}) progressive: URL printed {t_url - t0:.2f} s after start (Python, imports, first points); "
          f"first frame {t2 - t1:.2f} s after the page connects")  # fmt: skip


def _views(bounds) -> dict:
    """The frames' cameras, 1920x1080: the whole cloud from the side (iso), a close-up, from above."""
    lo, hi = bounds
    centre, span = tuple((lo + hi) / 2), float(np.max(hi - lo))
    return {"iso": gp.Camera.fit(bounds, view="iso", width=1920, height=1080),
            "close-up": gp.Camera.orbit(centre, -60.0, 30.0, span * 0.15, width=1920, height=1080),
            "top": gp.Camera.fit(bounds, view="top", width=1920, height=1080)}  # fmt: skip


def bench_frames(n: int, backend: str = "auto") -> None:
    from gigapoint.render.backend import get_backend

    s = gp.RenderSettings(point_budget=10_000_000, backend=backend)
    drawer = get_backend(backend)
    print(f"frames drawn by {drawer.describe()}")
    uploaded = lambda: getattr(drawer, "memory", {}).get("uploaded", 0)  # bytes sent to the GPU so far; 0 on the CPU
    cloud = gp.demo(n, progressive=True)
    while cloud.n_points == 0:
        time.sleep(0.01)
    times, sent = [], uploaded()
    while cloud.loading:
        cam = gp.Camera.fit(cloud.bounds, view="iso", width=1920, height=1080)
        t = time.perf_counter()
        gp.render_frame(cloud, cam, s)
        times.append(time.perf_counter() - t)
    with tempfile.TemporaryDirectory() as tmp:  # the same points converted (gigapoint convert), drawn alternately
        gp.convert(cloud.chunks(), Path(tmp) / "octree")
        converted = gp.open(Path(tmp) / "octree")
        # and converted with the progressive octree's leaf size: the same tree (its inner nodes
        # hold sampled points where the progressive octree's hold voxels)
        gp.convert(cloud.chunks(), Path(tmp) / "same_leaves", max_leaf=cloud.max_leaf)
        same_leaves = gp.open(Path(tmp) / "same_leaves")
        m, p95 = statistics.median(times), float(np.percentile(times, 95))
        print(f"frames of demo({n:,}) at 1920x1080, 10 M budget: while loading {len(times)} frames, median {m * 1e3:.1f} ms "
              f"({1 / m:.1f} fps), 95th percentile {p95 * 1e3:.1f} ms; loaded in {cloud.loader.finished_at - cloud.loader.started:.1f} s"
              + (f"; {(uploaded() - sent) / 2**20:.0f} MiB uploaded to the GPU while loading" if uploaded() else ""))  # fmt: skip
        for view, vcam in _views(cloud.bounds).items():
            for mode in ("auto", "fixed"):  # adaptive sizes (the default) and the one-pixel render
                ms = s.replace(size_mode=mode)
                after, conv, same = [], [], []
                for _ in range(7):
                    for target, out in ((cloud, after), (converted, conv), (same_leaves, same)):
                        gp.render_frame(target, vcam, ms)  # each once before timing: caches, arena loads
                        t = time.perf_counter()
                        frame = gp.render_frame(target, vcam, ms)
                        out.append(time.perf_counter() - t)
                        out.append(frame.stats.points_processed)
                a, c, sl = statistics.median(after[::2]), statistics.median(conv[::2]), statistics.median(same[::2])
                print(f"  once loaded, {view}, size_mode {mode}: {a * 1e3:.1f} ms ({1 / a:.1f} fps, {after[1]:,} points); the converted "
                      f"octree of the same points {c * 1e3:.1f} ms ({1 / c:.1f} fps, {conv[1]:,} points): {c / a:.2f}x its fps; converted "
                      f"with {cloud.max_leaf:,}-point leaves {sl * 1e3:.1f} ms ({same[1]:,} points): {sl / a:.2f}x")  # fmt: skip


def bench_select(n: int) -> None:
    """Frames of the loaded town with nodes selected by the box of their points, and by their
    cubes (ProgressiveOctree.select_by_points), interleaved in one process."""
    cloud = gp.demo(n, progressive=True)
    cloud.wait()
    try:
        for name, cam in _views(cloud.bounds).items():
            for mode in ("fixed", "auto"):
                s = gp.RenderSettings(point_budget=10_000_000, size_mode=mode)
                times, points = {True: [], False: []}, {}
                for _ in range(5):
                    for flag in (True, False):
                        ProgressiveOctree.select_by_points = flag
                        gp.render_frame(cloud, cam, s)
                        for _ in range(4):
                            t = time.perf_counter()
                            frame = gp.render_frame(cloud, cam, s)
                            times[flag].append(time.perf_counter() - t)
                        points[flag] = frame.stats.points_processed
                box, cube = (statistics.median(times[f]) for f in (True, False))
                print(f"select {name}, size_mode {mode}: by the points' boxes {box * 1e3:.2f} ms ({points[True]:,} points), by the "
                      f"cubes {cube * 1e3:.2f} ms ({points[False]:,}): {cube / box:.3f}x")  # fmt: skip
    finally:
        ProgressiveOctree.select_by_points = True


def bench_hidden(n: int, backend: str = "auto") -> None:
    """What hidden classes cost a frame's selection (its costs through the load filter, two or
    more selections a frame) and the frame, progressive and converted (docstring: ``hidden``)."""
    cloud = gp.demo(n, progressive=True)
    cloud.wait()
    with tempfile.TemporaryDirectory() as tmp:
        gp.convert(cloud.chunks(), Path(tmp) / "octree", max_leaf=150)  # small leaves: many nodes, as a big octree has
        converted = gp.open(Path(tmp) / "octree")
        for name, target, size in (("progressive", cloud, f"{cloud.n_nodes:,} nodes, {cloud.pool.n_chunks:,} chunks"),
                                   ("converted", converted, f"{len(converted.keys):,} nodes")):  # fmt: skip
            print(f"{name} octree of demo({n:,}): {size}")
            for view, cam in _views(cloud.bounds).items():
                times = {hidden: ([], []) for hidden in ((), (5,))}  # (prepare, frame) seconds
                points = {}
                for _ in range(7):
                    for hidden, (prepared, framed) in times.items():
                        s = gp.RenderSettings(point_budget=10_000_000, size_mode="fixed", backend=backend, hidden_classes=hidden)
                        gp.render_frame(target, cam, s)  # once before timing: what the view needs loaded (filtered)
                        for _ in range(3):
                            t = time.perf_counter()
                            target.prepare(cam.view(target.bounds), s)
                            prepared.append(time.perf_counter() - t)
                        t = time.perf_counter()
                        points[hidden] = gp.render_frame(target, cam, s).stats.points_processed
                        framed.append(time.perf_counter() - t)
                for hidden, (prepared, framed) in times.items():
                    p, f = (np.array(x) * 1e3 for x in (prepared, framed))
                    print(f"  {view}, hidden {list(hidden)}: selection {np.median(p):.2f} ms ({p.min():.2f}-{p.max():.2f}), frame "
                          f"{np.median(f):.1f} ms ({f.min():.1f}-{f.max():.1f}), {points[hidden]:,} points")  # fmt: skip


def bench_sample(n: int) -> None:
    """Frames of the loaded demo with its leaves' grid samples (ProgressiveOctree.order_leaves)
    and with every leaf's points (the samples switched off), and of its converted octree,
    alternating frame by frame in one process."""
    cloud = gp.demo(n, progressive=True)
    cloud.wait()
    sample = cloud.grid_sample.copy()

    def frame(target, cam, s, with_sample):
        cloud.grid_sample[:] = sample if with_sample else 0
        try:
            gp.render_frame(target, cam, s)  # once before timing: caches, arena loads
            t = time.perf_counter()
            f = gp.render_frame(target, cam, s)
            return time.perf_counter() - t, f.stats.points_processed
        finally:
            cloud.grid_sample[:] = sample

    with tempfile.TemporaryDirectory() as tmp:
        gp.convert(cloud.chunks(), Path(tmp) / "octree")
        converted = gp.open(Path(tmp) / "octree")
        runs = {"samples": (cloud, True), "all points": (cloud, False), "converted": (converted, True)}
        for view, cam in _views(cloud.bounds).items():
            for mode in ("fixed", "auto"):
                s = gp.RenderSettings(point_budget=10_000_000, size_mode=mode)
                times, points = {k: [] for k in runs}, {}
                for _ in range(11):
                    for k, (target, with_sample) in runs.items():
                        dt, points[k] = frame(target, cam, s, with_sample)
                        times[k].append(dt)
                m = {k: statistics.median(v) for k, v in times.items()}
                print(f"sample {view}, size_mode {mode}: leaves' samples {m['samples'] * 1e3:.2f} ms ({points['samples']:,} points), every "
                      f"leaf point {m['all points'] * 1e3:.2f} ms ({points['all points']:,}), converted {m['converted'] * 1e3:.2f} ms "
                      f"({points['converted']:,}): samples {m['all points'] / m['samples']:.2f}x every point; progressive / converted fps "
                      f"{m['converted'] / m['samples']:.2f}x (every point: {m['converted'] / m['all points']:.2f}x)")  # fmt: skip


def bench_sort(n: int, batch: int) -> None:
    import gigapoint.lod.progressive.octree as octree_module
    from gigapoint.lod.keys import point_codes
    from gigapoint.lod.progressive.kernels import radix_sort, sort_keys

    xyz, rgba, attrs = demo_arrays(n, seed=1)
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    cube = (lo - 0.5, float(np.max(hi - lo)) + 1.0)
    codes = point_codes(xyz[:1_000_000], *cube)
    index_bits = (len(codes) - 1).bit_length()
    keys, scratch = np.empty(len(codes), np.uint64), np.empty(len(codes), np.uint64)
    sort_keys(codes, index_bits, keys)
    took = {}
    for name in ("numpy", "radix"):
        times = []
        for _ in range(5):
            k = keys.copy()
            t = time.perf_counter()
            k.sort() if name == "numpy" else radix_sort(k, scratch, index_bits, 2)
            times.append(time.perf_counter() - t)
        took[name] = min(times)
    print(f"sort of {len(keys):,} keys: numpy {took['numpy'] * 1e3:.1f} ms, radix {took['radix'] * 1e3:.1f} ms "
          f"({took['numpy'] / took['radix']:.2f}x); insertions here use {octree_module._faster_key_sort(keys.copy(), index_bits, scratch)}")  # fmt: skip
    order = _scan_order(xyz)
    for name, idx in (("generator order", np.arange(n)), ("scan order", order)):
        x, c, at = xyz[idx], rgba[idx], {a: v[idx] for a, v in attrs.items()}
        rates = {"numpy": [], "radix": []}
        for _ in range(2):
            for kind, got in rates.items():
                octree_module._KEY_SORT[:] = [kind]
                o = ProgressiveOctree("bench", cube=cube, capacity=n)
                t = time.perf_counter()
                for s in range(0, n, batch):
                    o.add(x[s : s + batch], c[s : s + batch], **{a: v[s : s + batch] for a, v in at.items()})
                got.append(n / (time.perf_counter() - t) / 1e6)
                del o
        print(f"insert, {name}: numpy's sort {' / '.join(f'{r:.2f}' for r in rates['numpy'])} M points/s, the radix sort "
              f"{' / '.join(f'{r:.2f}' for r in rates['radix'])}")  # fmt: skip
    octree_module._KEY_SORT.clear()


def bench_insert_ab(n: int, batch: int, rounds: int, base_rev: str) -> None:
    """The insertion of this revision against ``base_rev``'s (bench_ab.load_base: its package as
    ``gigapoint_base``), alternating in one process, generator and scan order: points/s and the
    process's CPU seconds (less sensitive than wall time to a busy host) and MB faulted in."""
    from bench_ab import load_base

    with tempfile.TemporaryDirectory() as tmp:
        base = load_base(base_rev, Path(tmp))
        import gigapoint_base.lod.progressive as base_progressive  # (a package of its own: its kernels too)

        xyz, rgba, attrs = demo_arrays(n, seed=1)
        lo, hi = xyz.min(axis=0), xyz.max(axis=0)
        cube = (lo - 0.5, float(np.max(hi - lo)) + 1.0)
        codes = {"base": base_progressive.ProgressiveOctree, "new": ProgressiveOctree}
        for name, idx in (("generator order", np.arange(n)), ("scan order", _scan_order(xyz))):
            x, c, at = xyz[idx], rgba[idx], {a: v[idx] for a, v in attrs.items()}
            for cls in codes.values():  # compiled (or loaded from the cache) first
                cls("warm", cube=cube).add(x[:300_000], c[:300_000], **{a: v[:300_000] for a, v in at.items()})
            rate, cpu, faulted = {k: [] for k in codes}, {k: [] for k in codes}, {k: [] for k in codes}
            for r in range(rounds):
                for k in codes if r % 2 == 0 else reversed(codes):
                    o = codes[k]("bench", cube=cube, capacity=n)
                    t, t_cpu = time.perf_counter(), time.process_time()
                    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
                    for s in range(0, n, batch):
                        o.add(x[s : s + batch], c[s : s + batch], **{a: v[s : s + batch] for a, v in at.items()})
                    rate[k].append(n / (time.perf_counter() - t) / 1e6)
                    cpu[k].append(time.process_time() - t_cpu)
                    faulted[k].append((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults) * resource.getpagesize() / 1e6)
                    del o
            med = {k: statistics.median(v) for k, v in rate.items()}
            med_cpu = {k: statistics.median(v) for k, v in cpu.items()}
            med_mb = {k: statistics.median(v) for k, v in faulted.items()}
            print(f"insert, {name}: {base_rev} {med['base']:.2f} M points/s (CPU {med_cpu['base']:.2f} s, {med_mb['base']:.0f} MB faulted), "
                  f"this revision {med['new']:.2f} (CPU {med_cpu['new']:.2f} s, {med_mb['new']:.0f} MB): {med['new'] / med['base']:.3f}x "
                  f"(CPU {med_cpu['base'] / med_cpu['new']:.3f}x), medians of {rounds}, alternating")  # fmt: skip
        del base


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", default="8M")
    ap.add_argument("--batch", default="1M")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--parts", nargs="+", default=["insert", "load", "first", "viewer", "frames"])
    ap.add_argument("--first-source", default=None, help="a file for --parts first (default: the demo of 10^9 points)")
    ap.add_argument("--potree-converter", default=None, help="a PotreeConverter 2 binary for --parts convert (its --method random)")
    ap.add_argument("--backend", default="auto", choices=["auto", "cpu", "wgpu"], help="the rasterizer of --parts frames and hidden")
    ap.add_argument("--base", default="HEAD~1", help="the revision --parts insert-ab compares this one with")
    args = ap.parse_args(argv)
    n, batch = parse_counts(ap, ("--points", args.points), ("--batch", args.batch))
    print(f"{_cpu()}, {os.cpu_count()} cores; {n:,} points")
    if "insert" in args.parts:
        bench_insert(n, batch, args.rounds)
    if "insert-ab" in args.parts:
        bench_insert_ab(n, batch, args.rounds, args.base)
    if "load" in args.parts:
        bench_load(n, args.rounds)
    if "memory" in args.parts:
        bench_memory(n)
    if "save" in args.parts:
        bench_save(n, args.rounds)
    if "convert" in args.parts:
        bench_convert_through_builder(n, args.rounds, args.potree_converter)
    if "first" in args.parts:
        bench_first(args.first_source)
    if "gil" in args.parts:
        bench_gil(n)
    if "first-files" in args.parts:
        bench_first_files(n, args.rounds)
    if "viewer" in args.parts:
        bench_viewer(10**9)
    if "frames" in args.parts:
        bench_frames(n, args.backend)
    if "select" in args.parts:
        bench_select(n)
    if "sort" in args.parts:
        bench_sort(n, batch)
    if "sample" in args.parts:
        bench_sample(n)
    if "hidden" in args.parts:
        bench_hidden(n, args.backend)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
