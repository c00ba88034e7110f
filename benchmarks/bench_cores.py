"""How much the machine's cores scale: the same compute-bound loop on 1 thread and on all of them,
the same for a loop that streams memory, and what a page costs new and reused.

    .venv/bin/python benchmarks/bench_cores.py            # 9 rounds, 1 and all threads alternating

Each thread runs the same number of iterations of 8 independent multiply-add chains in
registers (no memory traffic), so with N truly separate cores N threads take as long as
one. A ratio well below N (the speed-up printed) means the "cores" share an execution
core (SMT siblings on the host) or the host takes cycles away: no kernel can scale past
it, which bounds every multi-threaded figure in docs/benchmarks.md.

The memory part: each thread streams its own 256 MB (reads one array, writes another, warm
pages), so the speed-up is what the memory system gives two cores at once. Most of a
conversion's and an insertion's work is of this kind (sorts, gathers, scatters): its
parallel efficiency is bounded by this ratio, not by the compute one (issue #21's 0.85).

The page part: first writes to new memory (4 KiB pages, as core/pages.py asks for, and
numpy's default huge-page advice) and to memory this process freed a moment ago, in GB/s.
On the project's Firecracker VMs a new page comes from the host (free page reporting) and
costs several times a reused one; every figure that allocates swings with it.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numba
import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def multiply_add_chains(n_iterations, n_threads):
    out = np.zeros(n_threads)
    for t in prange(n_threads):
        a = np.full(8, 1.0 + t)  # 8 chains: enough independent work to fill the FP ports
        for _ in range(n_iterations):
            for k in range(8):
                a[k] = a[k] * 0.999999 + 1e-7
        out[t] = a.sum()
    return out


@njit(parallel=True, cache=True)
def stream_arrays(src, dst, n_threads, rounds):
    """Each thread: ``rounds`` passes of dst = 3 * src + 1 over its own slice."""
    step = src.shape[0] // n_threads
    for t in prange(n_threads):
        for r in range(rounds):
            for i in range(t * step, (t + 1) * step):
                dst[i] = src[i] * 3 + r


@njit(cache=True)
def first_writes(a):
    for i in range(a.shape[0]):
        a[i] = i


def page_rates(mb: int = 400, settle: float = 3.0) -> dict:
    """GB/s of first writes to ``mb`` MB of new memory (small pages, numpy's advice) and of memory
    just freed. Before a "new" one the process waits ``settle`` seconds: a guest that reports free
    pages hands what was freed back to its host after ~2 s (the kernel's PAGE_REPORTING_DELAY)."""
    from gigapoint.core import pages

    first_writes(np.zeros(16, np.int64))
    rates = {}
    for name, make in (("new, 4 KiB pages", lambda n: pages.empty(n, np.int64)), ("new, numpy's advice", lambda n: np.empty(n, np.int64)),
                       ("freed a moment ago", lambda n: np.empty(n, np.int64))):  # fmt: skip
        n = mb * (1 << 20) // 8
        if name.startswith("freed"):
            first_writes(np.empty(n, np.int64))  # touched and freed: the next array of that size reuses its pages
        else:
            time.sleep(settle)
        a = make(n)
        t0 = time.perf_counter()
        first_writes(a)
        rates[name] = mb / 1024 / (time.perf_counter() - t0)
        del a
    return rates


def steal_seconds() -> float | None:
    """CPU time the hypervisor gave to others, all CPUs together (Linux /proc/stat), or None."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=100_000_000, help="iterations per thread")
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--stream-mb", type=int, default=256, help="MB each thread streams through (well beyond the caches)")
    args = ap.parse_args(argv)
    all_threads = numba.config.NUMBA_NUM_THREADS
    multiply_add_chains(1000, all_threads)  # JIT warm-up
    times: dict[int, list[float]] = {1: [], all_threads: []}
    steal0, wall0 = steal_seconds(), time.perf_counter()
    for _ in range(args.rounds):
        for n, runs in times.items():
            numba.set_num_threads(n)
            t0 = time.perf_counter()
            multiply_add_chains(args.iterations, n)
            runs.append(time.perf_counter() - t0)
    one, many = statistics.median(times[1]), statistics.median(times[all_threads])
    print(f"compute: 1 thread: {one * 1e3:.0f} ms; {all_threads} threads, each the same work: {many * 1e3:.0f} ms (medians of {args.rounds})")
    print(f"compute: speed-up of {all_threads} threads over 1: {all_threads * one / many:.2f}x (ideal {all_threads}.00x)")
    per_thread = args.stream_mb * (1 << 20) // 8
    streams: dict[int, list[float]] = {1: [], all_threads: []}
    for n in streams:  # each size's arrays touched once first (warm pages), then timed
        src = np.ones(per_thread * n, np.int64)
        stream_arrays(src, np.empty_like(src), n, 1)
    for _ in range(args.rounds):
        for n, runs in streams.items():
            numba.set_num_threads(n)
            src = np.ones(per_thread * n, np.int64)
            dst = np.ones_like(src)
            t0 = time.perf_counter()
            stream_arrays(src, dst, n, 4)
            runs.append(time.perf_counter() - t0)
            del src, dst
    one, many = statistics.median(streams[1]), statistics.median(streams[all_threads])
    print(f"memory: 1 thread streams {args.stream_mb} MB x 4: {one * 1e3:.0f} ms; {all_threads} threads, each the same: {many * 1e3:.0f} ms")
    print(f"memory: speed-up of {all_threads} threads over 1: {all_threads * one / many:.2f}x (ideal {all_threads}.00x)")
    numba.set_num_threads(all_threads)
    for name, rate in page_rates().items():
        print(f"pages: first writes to memory {name}: {rate:.2f} GB/s")
    steal1 = steal_seconds()
    if steal0 is not None and steal1 is not None:
        wall = time.perf_counter() - wall0
        print(f"steal (CPU time the host gave elsewhere): {steal1 - steal0:.2f} s of {wall * all_threads:.1f} CPU-seconds ({(steal1 - steal0) / (wall * all_threads):.1%})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
