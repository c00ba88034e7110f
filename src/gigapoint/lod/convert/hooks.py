"""Points where tests stop a conversion (they monkeypatch these; in use they do nothing)."""

from __future__ import annotations


def after_partition_built(done: int) -> None:
    """Called after each partition the build phase finished in this run (``done``: how many so far)."""


def task_started(kind: str, name: str) -> None:
    """Called on a Dask worker when a distributed conversion's task starts (distributed.py):
    ``kind`` is read, count, distribute, refine, build, group, upper, place or write; ``name`` names it."""


def task_done(kind: str, name: str) -> None:
    """Called on a Dask worker when that task has done its work, before its result goes back."""
