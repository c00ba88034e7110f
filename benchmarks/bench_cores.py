"""How much the machine's cores scale: the same compute-bound loop on 1 thread and on all of them.

    .venv/bin/python benchmarks/bench_cores.py            # 9 rounds, 1 and all threads alternating

Each thread runs the same number of iterations of 8 independent multiply-add chains in
registers (no memory traffic), so with N truly separate cores N threads take as long as
one. A ratio well below N (the speed-up printed) means the "cores" share an execution
core (SMT siblings on the host) or the host takes cycles away: no kernel can scale past
it, which bounds every multi-threaded figure in docs/benchmarks.md.
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
    print(f"1 thread: {one * 1e3:.0f} ms; {all_threads} threads, each the same work: {many * 1e3:.0f} ms (medians of {args.rounds})")
    print(f"speed-up of {all_threads} threads over 1: {all_threads * one / many:.2f}x (ideal {all_threads}.00x)")
    steal1 = steal_seconds()
    if steal0 is not None and steal1 is not None:
        wall = time.perf_counter() - wall0
        print(f"steal (CPU time the host gave elsewhere): {steal1 - steal0:.2f} s of {wall * all_threads:.1f} CPU-seconds ({(steal1 - steal0) / (wall * all_threads):.1%})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
