"""``prefetch``: the next item of an iterator made in a worker thread while the caller uses this one."""

from __future__ import annotations

from collections.abc import Generator, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextvars import copy_context
from typing import TypeVar

from ...errors import KeptWarnings, keep_warnings

T = TypeVar("T")
_END = object()


def prefetch(items: Iterable[T], name: str = "gigapoint-read") -> Iterator[T]:
    """The items of ``items`` in order, item k+1 made in one worker thread while the caller works
    on item k: decoding a LAS/LAZ chunk and writing the previous one to disk both release the
    GIL, so they overlap. One item of extra memory.

    An exception raised by ``items`` reaches the caller where its item would have, and the
    warnings gigapoint makes with an item (kept in the worker: errors.keep_warnings) are
    issued in the caller's thread when it takes the item (kept there where the caller's context
    keeps warnings: a progressive load's thread). When the caller stops early (``break``, an
    exception, closing this generator), the item in flight is waited for and a generator
    ``items`` is closed (its ``finally`` blocks run, files close).
    """
    it = iter(items)
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)
    ctx = copy_context()  # the caller's: the headers it read (io headers_once) are not read again in the thread
    kept = KeptWarnings()  # the worker's warnings, issued by ``take``
    ctx.run(keep_warnings, kept)

    def take():
        try:
            return pending.result()
        finally:
            kept.issue()

    try:
        pending = pool.submit(ctx.run, next, it, _END)
        while (item := take()) is not _END:
            pending = pool.submit(ctx.run, next, it, _END)
            yield item
    finally:
        pool.shutdown(wait=True, cancel_futures=True)  # no thread is left inside ``it``
        if isinstance(it, Generator):
            it.close()
