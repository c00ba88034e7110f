"""Progress bars of the long jobs (videos, benchmarks, the demo): on a terminal only, on stderr.

Piped or redirected, a command prints its results and nothing else; on a terminal a job of
more than a moment shows a bar (transient: it is gone when the job ends).
"""

from __future__ import annotations

import contextlib

from rich.console import Console

from . import compiling

_console: Console | None = None


def err_console() -> Console:
    """The one stderr console of a command (rich shows one live display at a time per console)."""
    global _console
    if _console is None:
        _console = Console(stderr=True)
    return _console


@contextlib.contextmanager
def progress_bar(description: str, total: int | None, console: Console | None = None):
    """Yields ``advance(done=None, text=None)``: moves the bar to ``done`` (else one step on) and
    shows ``text`` beside it. Off a terminal a no-op."""
    console = console or err_console()
    if not console.is_terminal:
        yield lambda done=None, text=None: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    columns = (SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    watch = compiling.current()
    with Progress(*columns, console=console, transient=True) as bar:
        task = bar.add_task(description, total=total)
        shown = {"text": None, "note": None}

        def show() -> None:
            parts = [description, shown["text"] and f": {shown['text']}", shown["note"] and f" [dim]({shown['note']})[/dim]"]
            bar.update(task, description="".join(p for p in parts if p))

        def advance(done=None, text=None) -> None:
            if done is None:
                bar.advance(task)
            else:
                bar.update(task, completed=done)
            if text is not None:
                shown["text"] = text
                show()

        def note(message) -> None:  # the compile watch's message, in the bar instead of a second live display
            shown["note"] = message
            show()

        previous = watch.sink if watch is not None else None
        if watch is not None:
            watch.sink = note
        try:
            yield advance
        finally:
            if watch is not None:
                watch.sink = previous


@contextlib.contextmanager
def status(text: str, console: Console | None = None):
    """A spinner with ``text`` while the block runs (a step of unknown length); off a terminal nothing."""
    console = console or err_console()
    if not console.is_terminal:
        yield
        return
    with progress_bar(text, None, console):
        yield
