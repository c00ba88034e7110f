"""numba's threading layer and thread count for a block of work.

numba's layers are TBB, OpenMP and its own workqueue; it takes the first that loads, TBB first.
gigapoint depends on PyPI's ``tbb`` wheel where PyPI has one (Linux x86-64 with glibc 2.28 on,
Windows x86-64) and loads its library by path as numba is imported (``load_wheel_tbb``, from gigapoint/__init__.py's
hook, core/hooks.py: numba opens
``libtbb.so.12`` by name, and the wheel puts it off the loader's path). On that TBB (2023.2)
a forked process draws (GNU OpenMP terminates a child forked after drawing: "fork() called
from a process already using GNU OpenMP"), and small kernels cost what they do on spinning
OpenMP (a 50-point kernel 2.9 us a call against 3.1; passive OpenMP 50-56). Insertion, loading
and drawing ran level with OpenMP, conversion 4-11 % slower (docs/benchmarks.md). Without the
wheel, or where numba loaded a layer before gigapoint's set-up, no TBB is loaded; OpenMP goes first
(``choose_threading_layer``): an older system TBB (Debian's 2021.8, numba 0.68) slowed
repeated small kernels down as a process went on (a 50-point kernel 23 -> 257 us a call over
18 000 calls; OpenMP 2 us throughout). A layer the user names (``NUMBA_THREADING_LAYER`` /
``NUMBA_THREADING_LAYER_PRIORITY``) is the one used (TBB then the wheel's, where installed).

A parallel kernel wakes numba's sleeping worker threads, and on a virtual machine that wake-up
costs ~0.1 ms a kernel (measured on 2 vCPUs with numba's passive OpenMP, workqueue and
Debian's TBB), more than a small batch's work: an insertion of 50 points into the progressive
octree runs ~10 parallel kernels and took ~1-2.5 ms, ~0.15 ms on one thread. ``threads_for``
runs batches below ``SMALL_BATCH`` points on the calling thread alone. Where idle threads take
up work at once (OpenMP's spin a while unless ``OMP_WAIT_POLICY=passive``, which ``gigapoint
view`` sets; the wheel's TBB), a progressive insertion of 1 000-5 000 points ran 0.74-0.95x as
fast on one thread while a live push still gained 1.04-1.3x: a caller says whether its batches
gain on one thread then too (``when_awake``). Figures: benchmarks/bench_small_batches.py,
docs/benchmarks.md.
"""

from __future__ import annotations

import ctypes
import importlib.metadata
import os
import sys
from contextlib import contextmanager

#: points below which a batch is worked on the calling thread alone (two threads gain from here
#: on: bench_small_batches.py on 2 vCPUs)
SMALL_BATCH = 10_000


@contextmanager
def numba_threads(n_threads: int):
    """numba's parallel kernels run on ``n_threads`` threads (of this thread's calls: numba's
    setting is per thread) until the block ends."""
    import numba  # (not at import: core/hooks.py sets numba up as numba is imported, with this module's functions)

    previous = numba.get_num_threads()
    numba.set_num_threads(n_threads)
    try:
        yield
    finally:
        numba.set_num_threads(previous)


def prepare_kernel_calls() -> None:
    """numba's CPU target set up now: what a process's first kernel call does before anything else
    (~0.45 s of imports on the AMD EPYC, 0.3 s of them scipy's, which numba's BLAS check imports
    where it is installed), for a thread that would otherwise only wait (io/las.py: while the
    LAZ child decodes the first records). Later calls cost nothing."""
    from numba.core.compiler_lock import global_compiler_lock
    from numba.core.registry import cpu_target

    with global_compiler_lock:  # as a kernel's compilation or cache load does it
        cpu_target.target_context.refresh()
        cpu_target.typing_context.refresh()


def skip_blas_check() -> None:
    """numba's one check for a BLAS (``numba.np.arraymath._HAVE_BLAS``, made when a process's
    first kernel call imports that module) answered "none" without importing scipy.linalg,
    which it imports where scipy is installed: 0.26 s of the first kernel call on the AMD EPYC.
    For processes that run only gigapoint's kernels, which use no BLAS (the CLI): numba then
    computes np.correlate and np.convolve with its own loop (the check's only use); np.dot and
    np.linalg still import scipy when they are compiled. Nothing is done once the check ran."""
    if "numba.np.arraymath" in sys.modules:
        return
    from numba.core.compiler_lock import global_compiler_lock
    from numba.np import linalg

    def no_blas():
        raise ImportError("gigapoint: BLAS check skipped")

    with global_compiler_lock:  # no compilation asks linalg for a BLAS meanwhile
        real, linalg.ensure_blas = linalg.ensure_blas, no_blas
        try:
            import numba.np.arraymath  # noqa: F401 - its import makes the check, with no_blas bound
        finally:
            linalg.ensure_blas = real


def _loaded_layer() -> str | None:
    """The threading layer numba has loaded, None before its first parallel kernel."""
    import numba

    try:
        return numba.threading_layer()
    except ValueError:
        return None


def threads_awake() -> bool:
    """Whether numba's idle threads take up new work at once: OpenMP's spin a while (but with
    ``OMP_WAIT_POLICY=passive``), TBB's (the wheel's 2023.2: a 50-point kernel 2.9 us a call)
    are woken cheaply; passive OpenMP's and workqueue's sleep (~0.1 ms a kernel to wake). False
    before numba has loaded a layer."""
    layer = _loaded_layer()
    return layer == "tbb" or (layer == "omp" and os.environ.get("OMP_WAIT_POLICY", "").strip().lower() != "passive")


def threads_for(n_points: int, when_awake: bool = True):
    """The block's kernels on one thread for a batch below SMALL_BATCH points, else on as many as
    numba has now; ``when_awake`` False: on as many whatever the batch where idle threads take
    up work at once (``threads_awake``)."""
    import numba

    small = n_points < SMALL_BATCH and (when_awake or not threads_awake())
    return numba_threads(1 if small else numba.get_num_threads())


#: the file name numba loads TBB by (numba/np/ufunc/parallel.py), per platform
_TBB_LIBRARY = {"linux": "libtbb.so.12", "win32": "tbb12.dll", "darwin": "libtbb.12.dylib"}


def wheel_tbb_library() -> str | None:
    """The path of the ``tbb`` wheel's library numba loads (None: no wheel here)."""
    name = _TBB_LIBRARY.get(sys.platform)
    try:
        files = importlib.metadata.files("tbb") or []
    except importlib.metadata.PackageNotFoundError:
        return None
    return next((str(f.locate()) for f in files if f.name == name), None)


def load_wheel_tbb() -> bool:
    """Load the TBB of the ``tbb`` wheel (a dependency where PyPI has one) by its path, so that
    numba's TBB layer finds it: numba opens the library by name, and the wheel puts it in the
    environment's ``lib`` folder, off the loader's path; once loaded, that name means it (and not
    an older system TBB). False where the wheel or its library is missing, or where numba has
    loaded its layer already (a parallel kernel ran before gigapoint was imported: a second TBB
    beside the one numba may hold is not to be had)."""
    if _loaded_layer() is not None:
        return False
    path = wheel_tbb_library()
    if path is None:
        return False
    try:
        ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
    except OSError:
        return False
    return True


def choose_threading_layer() -> str:
    """numba's threading layers in the order gigapoint runs best on, unless the user set one in
    the environment; before any parallel kernel runs (as numba is imported, core/hooks.py, or at
    ``import gigapoint`` where it was already: numba loads its layer once, at the first). With the ``tbb`` wheel: TBB first (numba's own order); else OpenMP first (an
    older system TBB would come first otherwise). Returns the layer put first ("" where the
    user chose)."""
    wheel = load_wheel_tbb()  # whatever the user chose: a choice of TBB means the wheel's too
    if any(os.environ.get(v) for v in ("NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY")):
        return ""
    first = "tbb" if wheel else "omp"
    import numba

    numba.config.THREADING_LAYER_PRIORITY = [first] + [layer for layer in ("omp", "tbb", "workqueue") if layer != first]
    return first
