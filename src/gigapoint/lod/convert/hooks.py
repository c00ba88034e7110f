"""Points where tests stop a conversion (they monkeypatch these; in use they do nothing)."""

from __future__ import annotations


def after_partition_built(done: int) -> None:
    """Called after each partition the build phase finished in this run (``done``: how many so far)."""
