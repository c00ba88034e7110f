"""``KeepFreedMemory``: glibc keeps freed memory for reuse while a conversion runs.

The build phase allocates and drops many arrays of a partition's size. By default glibc
serves each large allocation with a fresh ``mmap`` and hands it back with ``munmap`` on
``free``, so every such array faults in new zeroed pages: about a third of a conversion's
time. Inside the context, ``mallopt`` turns that off (no mmap for large blocks, no trimming
of the heap's top), so freed blocks are reused; on leaving, glibc's defaults come back and
the kept memory is returned to the system (``malloc_trim``).

The settings are process-wide (glibc has no other kind); they are restored on exit. Elsewhere
than glibc (macOS, Windows, musl) the context does nothing.
"""

from __future__ import annotations

import ctypes
from typing import Self

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_MMAP_MAX = -1, -3, -4
_DEFAULTS = ((_M_MMAP_MAX, 65536), (_M_TRIM_THRESHOLD, 128 * 1024), (_M_MMAP_THRESHOLD, 128 * 1024))  # glibc's


class KeepFreedMemory:
    """``with KeepFreedMemory(): ...``: freed memory is kept for reuse inside, returned after."""

    def __enter__(self) -> Self:
        self.libc = None
        try:
            libc = ctypes.CDLL(None)
            libc.mallopt, libc.malloc_trim  # noqa: B018 - glibc only: AttributeError elsewhere
        except (OSError, AttributeError):
            return self
        if libc.mallopt(_M_MMAP_MAX, 0) and libc.mallopt(_M_TRIM_THRESHOLD, 2**31 - 1):
            self.libc = libc
        return self

    def __exit__(self, *exc) -> bool:
        if self.libc is not None:
            for param, value in _DEFAULTS:
                self.libc.mallopt(param, value)
            self.libc.malloc_trim(0)
        return False
