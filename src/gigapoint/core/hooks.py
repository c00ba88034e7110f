"""What ``import gigapoint`` used to do at once, done when it is first needed.

``import gigapoint`` imported numba and every kernel module (~0.4-1 s) to set numba up and to
register the pieces that lower layers cannot import: a CLI command that needs no kernel
(``--help``, ``--version``, ``info`` of a LAS header) paid for all of it. Two hooks keep what
the eager import guaranteed:

- ``on_numba_import(set_up)``: ``set_up()`` runs once numba is imported, whoever imports it
  (a gigapoint kernel module, or the user's own code after ``import gigapoint``), before any
  kernel is defined or run: gigapoint/__init__.py sets numba's threading layer and its cache
  fallback up there (core/threads.py, core/kernel_cache.py). Where numba is imported already,
  now.
- ``register_wiring(wire)`` / ``wire()``: the registrations a layer cannot make itself
  (PointCloud.save's writer in io, the render backends), made on first use: ``wire()`` is
  called where they are looked up (PointCloud.save, render.backend).

This module imports nothing of numba's.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import threading
from collections.abc import Callable

_NUMBA_SET_UPS: list[Callable[[], None]] = []
_WIRINGS: list[Callable[[], None]] = []
_lock = threading.RLock()
_wired = False


class _Loader:
    """numba's own loader, then the set-ups (as soon as numba's package has executed). (Not
    importlib.abc's classes: their import takes ~15 ms; the import system asks for these methods.)"""

    def __init__(self, loader) -> None:
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        self._loader.exec_module(module)
        _run_numba_set_ups()

    def __getattr__(self, name):  # (resources, get_data: numba's loader answers)
        return getattr(self._loader, name)


class _NumbaFinder:
    """Finds numba as the other finders do, with a loader that runs the set-ups after it."""

    def find_spec(self, fullname, path, target=None):
        if fullname != "numba":
            return None
        with _lock:
            if self in sys.meta_path:
                sys.meta_path.remove(self)  # once: numba is found by the others from now on
        spec = importlib.util.find_spec("numba")
        if spec is None or spec.loader is None:
            return spec
        spec.loader = _Loader(spec.loader)
        return spec


_finder = _NumbaFinder()


def _run_numba_set_ups() -> None:
    with _lock:
        todo, _NUMBA_SET_UPS[:] = list(_NUMBA_SET_UPS), []
    for set_up in todo:
        set_up()


def on_numba_import(set_up: Callable[[], None]) -> None:
    """``set_up()`` once numba is imported: now where it is, else right after its import."""
    with _lock:
        if "numba" not in sys.modules:
            _NUMBA_SET_UPS.append(set_up)
            if _finder not in sys.meta_path:
                sys.meta_path.insert(0, _finder)
            return
    set_up()


def register_wiring(wire_up: Callable[[], None]) -> None:
    """``wire_up()`` to run at the first ``wire()`` (at once where that has happened)."""
    with _lock:
        _WIRINGS.append(wire_up)
        done = _wired
    if done:
        wire_up()


def wire() -> None:
    """The registrations made on first use (PointCloud.save's writer, the render backends)."""
    global _wired
    with _lock:
        if _wired:
            return
        _wired = True
        todo = list(_WIRINGS)
    for wire_up in todo:
        wire_up()


def lazy_names(package: str, names: dict, base: str | None = None):
    """The module ``__getattr__`` (PEP 562) of ``package`` (its ``__name__``) that imports its
    public names on first use: ``names`` maps each to the module defining it, relative to
    ``base`` (default: the package), or to (that module, the name there). core, io, render and
    lod load so: their modules define numba kernels, which ``import gigapoint`` and the CLI's
    ``--help`` and ``info`` need none of."""

    def __getattr__(name: str):
        where = names.get(name)
        if where is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module, attr = (where, name) if isinstance(where, str) else where
        return getattr(importlib.import_module(f"{base or package}.{module}"), attr)

    return __getattr__
