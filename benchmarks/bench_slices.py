"""The progressive loader's slice size (``loader.SLICE_POINTS``, points inserted at once while no
frame is drawn) against a progressive load of the town as LAS and LAZ (issue #18).

    OMP_WAIT_POLICY=passive PYTHONPATH=src .venv/bin/python benchmarks/bench_slices.py load 1M 2M 4M --rounds 3
    OMP_WAIT_POLICY=passive PYTHONPATH=src .venv/bin/python benchmarks/bench_slices.py memory 1M 2M 4M --rounds 2

- ``load``: ``gigapoint.open(FILE, progressive=True)`` to completion with each slice size in
  turn (the order reversed every other round), in one process, after a warm-up load of each, and
  laspy decoding alone once a round (the #18 baseline, as ``bench_progressive.py --parts load``):
  wall seconds, CPU seconds (this process and the LAZ decoding child of each file, once waited
  for; not the shared child that decodes files up to ``laz_process.SHARED_MAX`` whole: steadier
  than wall time on a shared host), insertions a load.
- ``memory``: each slice size's load in a process of its own (``bench_progressive.load_alone``), alternating:
  peak RSS, the octree's bytes when the last point is in (before ``trim``: what the memory limit
  counts) and once loaded.

The town's files (``bench_progressive._town_files``, scan order), those the run reads, are
written once into ``--data`` and reused by later runs.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import tempfile
import time
from pathlib import Path

import bench_progressive  # a sibling script: its folder is sys.path[0]

import gigapoint as gp
from gigapoint.bench import parse_counts
from gigapoint.lod.progressive import ProgressiveOctree, loader


def town_files(folder: Path, n: int, formats: list[str]) -> list[Path]:
    """The town of ``n`` points in ``folder`` as each of ``formats`` ("las", "laz"), those missing
    written (20 M: ~2 min a format), only those a run reads: the memory part reads LAS alone."""
    paths = [folder / f"town_{n}.{suffix}" for suffix in formats]
    missing = [path for path in paths if not path.is_file()]
    if missing:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            made = bench_progressive._town_files(Path(tmp), n, [path.suffix[1:] for path in missing])
            for written, path in zip(made, missing):
                written.rename(path)
    return paths


def _cpu_seconds() -> float:
    """User and system seconds of this process and of its children waited for (LAZ decoders)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _load(path: Path, slice_points: int) -> tuple[float, float, int]:
    """(wall s, CPU s, insertions) of a progressive load of ``path`` to completion with ``slice_points``."""
    loader.SLICE_POINTS = slice_points
    insertions, add = [0], ProgressiveOctree.add

    def counted(self, *args, **kwargs):
        insertions[0] += 1
        return add(self, *args, **kwargs)

    ProgressiveOctree.add = counted
    try:
        t, cpu = time.perf_counter(), _cpu_seconds()
        with gp.open(path, progressive=True) as cloud:
            cloud.wait()
        return time.perf_counter() - t, _cpu_seconds() - cpu, insertions[0]
    finally:
        ProgressiveOctree.add = add


def bench_load(paths: list[Path], sizes: list[int], rounds: int) -> None:
    for path in paths:
        bench_progressive._laspy_decode(path)
        for size in sizes:
            _load(path, size)  # warm-up: JIT, page cache
        wall, cpu, insertions, laspy = {s: [] for s in sizes}, {s: [] for s in sizes}, {}, []
        for r in range(rounds):
            t = time.perf_counter()
            bench_progressive._laspy_decode(path)
            laspy.append(time.perf_counter() - t)
            for size in sizes if r % 2 == 0 else reversed(sizes):
                seconds, cpu_seconds, insertions[size] = _load(path, size)
                wall[size].append(seconds)
                cpu[size].append(cpu_seconds)
            print(f"  {path.suffix[1:].upper()} round {r}: laspy alone {laspy[-1]:.2f} s; "
                  + "; ".join(f"{s / 1e6:g} M {wall[s][-1]:.2f} s (CPU {cpu[s][-1]:.2f})" for s in sizes), flush=True)  # fmt: skip
        base = statistics.median(laspy)
        print(f"load {path.suffix[1:].upper()}, medians of {rounds}: laspy alone {base:.2f} s; "
              + "; ".join(f"slices of {s / 1e6:g} M {statistics.median(wall[s]):.2f} s = {statistics.median(wall[s]) / base:.2f}x, "
                          f"CPU {statistics.median(cpu[s]):.2f} s, {insertions[s]} insertions" for s in sizes), flush=True)  # fmt: skip


def bench_memory(path: Path, n: int, sizes: list[int], rounds: int) -> None:
    got = {s: [] for s in sizes}
    for r in range(rounds):
        for size in sizes if r % 2 == 0 else reversed(sizes):
            seconds, filled, held, peak = bench_progressive.load_alone(path, size)
            got[size].append((filled, held, peak))
            print(f"  round {r}, slices of {size / 1e6:g} M: {seconds:.2f} s, peak RSS {peak / 2**20:.0f} MiB", flush=True)
    for size, runs in got.items():
        filled, held, peak = (statistics.median(run[k] for run in runs) for k in range(3))
        print(f"memory, slices of {size / 1e6:g} M: peak RSS {peak / 2**20:.0f} MiB (of {', '.join(f'{run[2] / 2**20:.0f}' for run in runs)}), "
              f"{filled / n:.1f} bytes a point when the last point is in, {held / n:.1f} once loaded")  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=["load", "memory"])
    ap.add_argument("slices", nargs="+", help="slice sizes (SLICE_POINTS) to compare: 1M 2M ...")
    ap.add_argument("--points", default="20M")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--formats", nargs="+", default=["las", "laz"], choices=["las", "laz"], help="the files the load part reads (memory reads LAS)")
    ap.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "gigapoint-bench-slices", help="where the town's files are kept")
    args = ap.parse_args(argv)
    n, *sizes = parse_counts(ap, ("--points", args.points), *(("slices", s) for s in args.slices))
    paths = town_files(args.data, n, args.formats if args.part == "load" else ["las"])
    print(f"{bench_progressive._cpu()}; {n:,} points; the loader's slices of {', '.join(f'{s:,}' for s in sizes)} points")
    if args.part == "load":
        bench_load(paths, sizes, args.rounds)
    else:
        bench_memory(paths[0], n, sizes, args.rounds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
