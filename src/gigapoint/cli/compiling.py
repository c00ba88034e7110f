"""Say so while numba compiles kernels: a live spinner on a terminal, nothing when piped.

The kernels are ``@njit(cache=True)``: the first run after an install compiles them (seconds
to a minute) and later runs load them from numba's cache. numba announces every compilation
that its cache could not serve as a ``numba:compile`` event (numba.core.event; loading a
cached kernel raises none), so listening to those events says exactly when a run compiles,
before the compilation starts, and never on a warm run. The watch listens from numba's import
on (core/hooks.py): a command that runs no kernel (``--help``, ``info``) imports no numba.
"""

from __future__ import annotations

import contextlib
import threading
import time

from ..core import hooks
from ..core.kernel_cache import is_ours as _is_ours
from ..core.kernel_cache import later_runs

MESSAGE = "compiling render kernels, once per install…"
_GRACE_S = 0.6  # the spinner stays this long after a compilation ends (the next one often follows)


class CompileWatch:
    """Counts gigapoint's kernel compilations and their seconds; on a terminal console, shows
    ``MESSAGE`` with a spinner, the kernel being compiled and the seconds so far."""

    def __init__(self, console=None) -> None:
        self.console = console if console is not None and console.is_terminal else None
        self.kernels = 0  # compilations of gigapoint kernels started
        self.seconds = 0.0  # wall time spent inside them (outermost only)
        self.enabled = True  # False: no spinner (a command with its own display)
        self.sink = None  # a command's progress bar: told MESSAGE while compiling, None after (instead of the spinner)
        self._lock = threading.RLock()
        self._depth = 0
        self._started = 0.0  # this outermost compilation's start
        self._first = 0.0  # when the spinner appeared
        self._status = None  # the spinner shown
        self._noted = None  # the sink told MESSAGE (instead of the spinner)
        self._idle_timer: threading.Timer | None = None

    # --- numba's events (any thread)
    def on_start(self, ev) -> None:
        if not _is_ours(ev.data["dispatcher"]):
            return
        with self._lock:
            self.kernels += 1
            self._depth += 1
            if self._depth == 1:
                self._started = time.perf_counter()
            self._show(ev.data["dispatcher"].py_func.__name__)

    def on_end(self, ev) -> None:
        if not _is_ours(ev.data["dispatcher"]):
            return
        with self._lock:
            self._depth -= 1
            if self._depth == 0:
                self.seconds += time.perf_counter() - self._started
                if self._status is not None or self._noted is not None:
                    self._idle_timer = threading.Timer(_GRACE_S, self._hide_if_idle)
                    self._idle_timer.daemon = True
                    self._idle_timer.start()

    # --- the spinner
    def _show(self, kernel: str) -> None:
        if self.console is None or not self.enabled:
            return
        if self._idle_timer is not None:
            self._idle_timer.cancel()
            self._idle_timer = None
        if self.sink is not None:
            if self._noted is not self.sink:
                self._noted = self.sink
                self.sink(MESSAGE)
            return
        if self._status is None:
            self._first = time.perf_counter()
            self._status = self.console.status(MESSAGE, spinner="dots")
            self._status.start()
        elapsed = time.perf_counter() - self._first
        self._status.update(f"{MESSAGE} [dim]{kernel} ({elapsed:.0f} s)[/dim]")

    def _hide_if_idle(self) -> None:
        with self._lock:
            if self._depth == 0:
                self.hide()

    def hide(self) -> None:
        with self._lock:
            if self._idle_timer is not None:
                self._idle_timer.cancel()
                self._idle_timer = None
            if self._noted is not None:
                if self._noted is self.sink:  # (a progress bar that ended meanwhile shows nothing any more)
                    self._noted(None)
                self._noted = None
            if self._status is not None:
                self._status.stop()
                self._status = None


def _forward(listener: type, watch: CompileWatch):
    """numba's ``event.Listener`` (a subclass made where numba is imported) passing its events to ``watch``."""

    class Forward(listener):
        def on_start(self, ev) -> None:
            watch.on_start(ev)

        def on_end(self, ev) -> None:
            watch.on_end(ev)

    return Forward()


_current: CompileWatch | None = None


def current() -> CompileWatch | None:
    """The watch of the running command (None outside ``watching``)."""
    return _current


def compiled_seconds() -> float:
    """Seconds the running command has spent compiling kernels so far (0 outside ``watching``)."""
    return _current.seconds if _current is not None else 0.0


@contextlib.contextmanager
def watching(console=None):
    """Watch compilations for the duration of a command; on a terminal, end with one line
    saying how long compiling took (the next runs load the kernels from the cache)."""
    global _current
    watch = CompileWatch(console)
    previous, _current = _current, watch
    listening = []  # numba's listener, once numba is imported (core/hooks.py)

    def listen() -> None:
        if listening:  # (the command ended before numba was imported)
            return
        from numba.core import event

        listening.append(_forward(event.Listener, watch))
        event.register("numba:compile", listening[0])

    hooks.on_numba_import(listen)
    try:
        yield watch
    finally:
        if listening:
            from numba.core import event

            event.unregister("numba:compile", listening[0])
        listening.append(None)  # a later import of numba registers nothing
        watch.hide()
        _current = previous
        if watch.console is not None and watch.enabled and watch.seconds >= 1.0:
            watch.console.print(f"[dim]compiled the kernels in {watch.seconds:.0f} s; {later_runs()}[/dim]", highlight=False)
