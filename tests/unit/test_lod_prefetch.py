"""prefetch: the next input chunk decoded in a worker thread while the caller spills this one."""

from __future__ import annotations

import threading
import time

import pytest

from gigapoint.lod.convert.prefetch import prefetch


def _workers():
    return [t for t in threading.enumerate() if t.name.startswith("gigapoint-read")]


def test_items_in_order_made_one_ahead_in_a_worker_thread():
    made = []  # (item, thread name) as the source makes them
    got = []  # (item, items made by then) as the caller receives them

    def source():
        for i in range(6):
            made.append((i, threading.current_thread().name))
            yield i

    for item in prefetch(source()):
        time.sleep(0.02)  # the caller's work on the item: the worker makes the next one meanwhile
        got.append((item, len(made)))
    assert [i for i, _ in got] == list(range(6))
    assert all(name.startswith("gigapoint-read") for _, name in made)
    assert all(n == min(i + 2, 6) for i, n in got)  # exactly one item ahead, never more
    assert not _workers()


def test_an_error_of_the_source_reaches_the_caller_in_its_place():
    def source():
        yield 1
        yield 2
        raise ValueError("chunk 3 is corrupt")

    items = prefetch(source())
    assert [next(items), next(items)] == [1, 2]
    with pytest.raises(ValueError, match="chunk 3 is corrupt"):
        next(items)
    assert not _workers()


def test_stopping_early_waits_for_the_worker_and_closes_the_source():
    closed = threading.Event()

    def source():
        try:
            yield from range(100)
        finally:
            closed.set()

    for item in prefetch(source()):
        if item == 3:
            break
    assert closed.is_set() and not _workers()
    with pytest.raises(KeyboardInterrupt):
        for item in prefetch(source()):
            raise KeyboardInterrupt
    assert not _workers()


def _taken_recording_warnings(source):
    """Each item of ``prefetch(source)`` with the warnings issued by then, the warnings (every one
    recorded), and the line that took the first item (where they are issued)."""
    import inspect
    import warnings

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        items = prefetch(source)
        line = inspect.currentframe().f_lineno + 1
        got = [(next(items), len(seen))]
        got += [(i, len(seen)) for i in items]
    return got, seen, line


def test_a_warning_of_the_source_is_issued_in_the_caller_s_thread_with_its_item():
    """gigapoint's warning in the worker (a reader's, decoding a chunk) went through Python's
    machinery from that thread, at any moment; now kept and issued at the caller's line when it
    takes the item."""

    from gigapoint.errors import GigapointWarning, warn

    def source():
        for i in range(3):
            if i == 0:
                warn("invalid value encountered in cast", GigapointWarning)
            yield i

    got, seen, line = _taken_recording_warnings(source())
    assert got == [(0, 1), (1, 1), (2, 1)]
    assert [(str(w.message), w.filename, w.lineno) for w in seen] == [("invalid value encountered in cast", __file__, line)]
    assert not _workers()


def test_a_library_s_warning_in_the_worker_is_issued_once_in_the_caller_s_thread():
    """numpy's RuntimeWarning in the worker (decoding a chunk) went through Python's machinery
    from that thread, once a chunk: a catch around the caller's loop missed it (or took it at
    random), and it printed amid progress bars. Now kept like gigapoint's own, each distinct one
    once, issued at the caller's line when it takes the item, with numpy's category."""

    import numpy as np

    def source():
        for i in range(3):
            np.array([1e300]).astype(np.float32)  # "overflow encountered in cast", each item
            yield i

    got, seen, line = _taken_recording_warnings(source())
    assert got == [(0, 1), (1, 1), (2, 1)]
    assert [(str(w.message), w.category, w.filename, w.lineno) for w in seen] == [
        ("overflow encountered in cast", RuntimeWarning, __file__, line)]  # fmt: skip
    assert not _workers()
    with pytest.warns(RuntimeWarning, match="overflow encountered in cast"):  # the caller's own: shown as Python shows it
        np.array([1e300]).astype(np.float32)
