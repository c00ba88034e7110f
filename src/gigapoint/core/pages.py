"""Arrays in 4 KiB pages where huge pages are slow to fault in.

numpy advises the kernel to back every allocation of 4 MiB or more with 2 MiB transparent huge
pages (``madvise(MADV_HUGEPAGE)``). On a virtual machine that hands its free memory back to
its host (virtio-balloon *free page reporting*, as on the Firecracker VMs gigapoint is
measured on), a free 2 MiB block is exactly what the guest has reported and the host dropped,
and a huge page fault there cost ~2.5 ms a MB against ~0.4 ms a MB in 4 KiB pages (800 MB
written once: 2.0 s against 0.34 s, docs/benchmarks.md). Bulk arrays written once and read
in order (the progressive octree's pool, voxel state, voxel table and work arrays; the demo
generator's output; build_cloud's joined chunks) gain little from the TLB reach of huge
pages; they are made with ``zeros`` / ``empty`` / ``full`` of this module, which advise 4 KiB pages
(``MADV_NOHUGEPAGE``) before the first write. Frame buffers, reused every frame and written
at random, keep numpy's advice.

``numpy_small_pages()`` turns numpy's own advice off while a block runs (a conversion, whose
every array is written once or twice and whose reads of a LAS chunk faulted in huge pages:
its read phase 2.9 -> 2.2 s of 20 M points, docs/benchmarks.md), where the same condition holds.

``GIGAPOINT_SMALL_PAGES=1`` / ``0`` forces the advice on or off; by default it is on where a
virtio balloon reports free pages (Linux sysfs), and these functions are numpy's elsewhere.
"""

from __future__ import annotations

import ctypes
import os
import threading
from contextlib import contextmanager
from functools import cache
from pathlib import Path

import numpy as np

_MADV_NOHUGEPAGE = 15  # Linux
_MIN_BYTES = 1 << 22  # numpy advises huge pages from 4 MiB on
_PAGE = 4096
_VIRTIO_BALLOON = "0x0005"
_BALLOON_F_REPORTING = 5  # virtio-balloon feature bit: free page reporting


def _balloon_reports_free_pages(devices: Path = Path("/sys/bus/virtio/devices")) -> bool:
    """Whether a virtio balloon with free page reporting is bound (its features: a string of 0/1 by bit)."""
    try:
        devs = list(devices.iterdir())
    except OSError:  # no virtio bus (not Linux, not a VM)
        return False
    for dev in devs:
        try:  # a device without these files is not the balloon: look at the next one
            if (dev / "device").read_text().strip() != _VIRTIO_BALLOON:
                continue
            features = (dev / "features").read_text().strip()
        except OSError:
            continue
        if len(features) > _BALLOON_F_REPORTING and features[_BALLOON_F_REPORTING] == "1":
            return True
    return False


@cache
def _madvise():
    """libc's madvise where small pages are wanted, else None."""
    forced = os.environ.get("GIGAPOINT_SMALL_PAGES", "").strip()
    if forced not in ("", "0", "1"):
        forced = ""
    if forced == "0" or (forced == "" and not _balloon_reports_free_pages()):
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).madvise
    except (OSError, AttributeError):  # not Linux
        return None
    fn.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
    fn.restype = ctypes.c_int
    return fn


def small_pages(a: np.ndarray) -> np.ndarray:
    """``a``, its (not yet written) memory advised into 4 KiB pages where that is wanted. The
    whole pages inside ``a`` only: a neighbour's memory keeps its advice."""
    madvise = _madvise()
    if madvise is not None and a.nbytes >= _MIN_BYTES:
        start = -(-a.ctypes.data // _PAGE) * _PAGE
        end = (a.ctypes.data + a.nbytes) // _PAGE * _PAGE
        madvise(start, end - start, _MADV_NOHUGEPAGE)  # advice only: a failure leaves numpy's
    return a


def empty(shape, dtype) -> np.ndarray:
    return small_pages(np.empty(shape, dtype))


def zeros(shape, dtype) -> np.ndarray:
    return small_pages(np.zeros(shape, dtype))


def full(shape, value, dtype) -> np.ndarray:
    a = small_pages(np.empty(shape, dtype))
    a.fill(value)
    return a


_numpy_advice_lock = threading.Lock()
_numpy_advice_holders = 0
_numpy_advice_before = True


@cache
def _set_numpy_advice():
    """numpy's switch of its huge-page advice (a private function of numpy 1.x and 2.x), or None."""
    for module in ("numpy._core.multiarray", "numpy.core.multiarray"):
        try:
            fn = getattr(__import__(module, fromlist=["_set_madvise_hugepage"]), "_set_madvise_hugepage", None)
        except ImportError:
            continue
        if fn is not None:
            return fn
    return None


@contextmanager
def numpy_small_pages():
    """Inside: numpy's arrays get no huge-page advice where small pages are wanted (``_madvise``);
    elsewhere, or without numpy's switch, nothing changes. Process-wide, as numpy's switch is:
    the first of overlapping blocks (any threads) turns the advice off, the last one restores it."""
    global _numpy_advice_holders, _numpy_advice_before
    switch = _set_numpy_advice() if _madvise() is not None else None
    if switch is None:
        yield
        return
    with _numpy_advice_lock:
        if _numpy_advice_holders == 0:
            _numpy_advice_before = bool(switch(False))
        _numpy_advice_holders += 1
    try:
        yield
    finally:
        with _numpy_advice_lock:
            _numpy_advice_holders -= 1
            if _numpy_advice_holders == 0:
                switch(_numpy_advice_before)
