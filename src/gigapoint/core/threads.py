"""numba's threading layer and thread count for a block of work.

numba picks Intel TBB before OpenMP where both are installed (``pip install tbb``, Debian's
libtbb12): gigapoint's kernels were tuned on OpenMP, and on TBB (2021.8, numba 0.68) repeated
small parallel kernels slowed down as a process went on (a 50-point kernel 23 -> 257 us a call
over 18 000 calls, a 200 000-point one 0.6 -> 1.9 ms; OpenMP: 2 us and 0.5 ms throughout), and
a live stream of 100 000-point frames went 16 M points/s on OpenMP, 5 on TBB
(bench_small_batches.py). ``prefer_openmp`` puts OpenMP first unless the user chose a layer
(``NUMBA_THREADING_LAYER`` / ``NUMBA_THREADING_LAYER_PRIORITY``); where no OpenMP runtime
loads, numba goes on to TBB, then its own workqueue.

A parallel kernel wakes numba's sleeping worker threads, and on a virtual machine that wake-up
costs ~0.1 ms a kernel (measured on 2 vCPUs with numba's TBB, OpenMP and workqueue layers),
more than a small batch's work: an insertion of 50 points into the progressive octree runs ~10
parallel kernels and took ~1-2.5 ms, ~0.15 ms on one thread. ``threads_for`` runs batches below
``SMALL_BATCH`` points on the calling thread alone. OpenMP's threads spin a while before they
sleep unless ``OMP_WAIT_POLICY=passive`` (set by ``gigapoint view``): spinning, they wake at
once, and a progressive insertion of 500-5 000 points ran 0.74-0.93x as fast on one thread
while a live push still gained 1.15-1.3x: a caller says whether its batches gain on one thread
then too (``when_spinning``). Figures: benchmarks/bench_small_batches.py, docs/benchmarks.md.
"""

from __future__ import annotations

import os
from contextlib import contextmanager

import numba

#: points below which a batch is worked on the calling thread alone (two threads gain from here
#: on: bench_small_batches.py on 2 vCPUs)
SMALL_BATCH = 10_000


@contextmanager
def numba_threads(n_threads: int):
    """numba's parallel kernels run on ``n_threads`` threads (of this thread's calls: numba's
    setting is per thread) until the block ends."""
    previous = numba.get_num_threads()
    numba.set_num_threads(n_threads)
    try:
        yield
    finally:
        numba.set_num_threads(previous)


def threads_spin() -> bool:
    """Whether numba's idle threads spin (OpenMP without ``OMP_WAIT_POLICY=passive``) rather than
    sleep (passive OpenMP, TBB, workqueue; and before numba has loaded a layer)."""
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel kernel has run yet
        return False
    return layer == "omp" and os.environ.get("OMP_WAIT_POLICY", "").strip().lower() != "passive"


def threads_for(n_points: int, when_spinning: bool = True):
    """The block's kernels on one thread for a batch below SMALL_BATCH points, else on as many as
    numba has now; ``when_spinning`` False: on as many whatever the batch where idle threads
    spin (``threads_spin``: they wake at once)."""
    small = n_points < SMALL_BATCH and (when_spinning or not threads_spin())
    return numba_threads(1 if small else numba.get_num_threads())


def prefer_openmp() -> None:
    """numba's threading layers in the order OpenMP, TBB, workqueue (its default: TBB first),
    unless the user set one in the environment. Before any parallel kernel runs (at import):
    numba loads its layer once, at the first."""
    if not any(os.environ.get(v) for v in ("NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY")):
        numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]
