"""gigapoint's kernels where numba cannot write its cache: compiled in memory, with one warning.

The kernels are ``@njit(cache=True)``: numba keeps them in ``NUMBA_CACHE_DIR`` where set, else in
``__pycache__`` beside the sources, else in the user's cache folder (``~/.cache/numba``). Where
none is writable (a read-only install run with a read-only or unset HOME: a container image),
numba refused at each kernel's definition ("cannot cache function ...: no locator available"),
so ``import gigapoint`` failed with a traceback; and a cache write that failed (a full disk) failed
the kernel call that had just compiled. ``compile_where_uncachable`` (as numba is imported, before
any kernel is defined: gigapoint/__init__.py's hook, core/hooks.py) makes both compile in memory, as they do uncached, and says so once. The save's
fallback holds for every numba function of the process (a failed cache write only loses the
next run's head start); the first, for gigapoint's kernels only.
"""

from __future__ import annotations

import inspect
import os

from ..errors import GigapointWarning, warn

FIX = "set NUMBA_CACHE_DIR to a writable folder to keep them"
_done: set[str] = set()  # what is done once a process: the patch, the listener, each warning


def is_ours(dispatcher) -> bool:
    """A gigapoint kernel (numba's own helpers compile only inside one of ours)."""
    return getattr(getattr(dispatcher, "py_func", None), "__module__", "").startswith("gigapoint.")


def later_runs() -> str:
    """What a run that compiled kernels may promise the next ones (the CLI's closing lines)."""
    if {"listening", "save"} & _done:  # a kernel found no cache folder, or its save failed
        return "numba could not save them in its cache: later runs compile them again"
    return "later runs load them from numba's cache"


def _warn_once(key: str, message: str) -> None:
    if key not in _done:
        _done.add(key)
        warn(message, GigapointWarning)


def _say_uncached(listener: type) -> type:
    """The listener class (numba's ``event.Listener`` subclassed where numba is imported)."""

    class _SayUncached(listener):
        """Warns at the first compilation of an uncached gigapoint kernel: inside a command, where the
        CLI prints warnings as one line (at import it has not set that up yet)."""

        def __init__(self, where: str) -> None:
            self.where = where

        def on_start(self, ev) -> None:
            if is_ours(ev.data["dispatcher"]):
                _warn_once("uncached", f"numba can write its cache nowhere ({self.where}): gigapoint's kernels compile in memory on every run, which takes a while; {FIX}")

        def on_end(self, ev) -> None:
            pass

    return _SayUncached


def compile_where_uncachable() -> None:
    """numba's caching made to fall back to compiling in memory for gigapoint's kernels where
    no cache folder is writable, and for any kernel whose cache write fails; once a process."""
    if "installed" in _done:
        return
    _done.add("installed")
    from numba.core import caching, config, dispatcher, event  # (numba is imported when this runs: core/hooks.py)

    try:
        enable, save = dispatcher.Dispatcher.enable_caching, caching.Cache.save_overload
    except AttributeError:  # a numba that names them otherwise: its own behaviour, not an import that fails
        return

    def enable_caching(self):
        try:
            enable(self)
        except RuntimeError as exc:  # the kernel stays on numba's NullCache: compiled, not saved
            if "no locator available" not in str(exc) or not is_ours(self):
                raise
            if "listening" not in _done:
                _done.add("listening")
                chosen = f"NUMBA_CACHE_DIR={config.CACHE_DIR}, " if config.CACHE_DIR else ""
                source = os.path.join(os.path.dirname(inspect.getfile(self.py_func)), "__pycache__")
                event.register("numba:compile", _say_uncached(event.Listener)(f"{chosen}{source}, the user's cache folder"))

    def save_overload(self, sig, data):
        # numba saves a kernel after compiling it and adding it to the dispatcher: without the
        # save, it runs the same, and compiles again next run
        try:
            save(self, sig, data)
        except OSError as exc:
            _warn_once("save", f"numba could not save a compiled kernel in {self.cache_path} ({exc.strerror or exc}): the kernels run compiled in memory and compile again next run; free space there or {FIX}")

    dispatcher.Dispatcher.enable_caching = enable_caching
    caching.Cache.save_overload = save_overload
