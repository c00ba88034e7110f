"""The octree folder: the one place that knows its layout, kind, state, lock and completeness.

An octree folder ``OUT`` is made by ``gigapoint convert`` (or PotreeConverter) and holds one of:

- a **gigapoint octree** (store.py reads it, writer.py writes it; arrays are .npy files):

  - ``octree.json``: metadata (format, version, points, nodes, cube, bounds, sampler,
    attributes), written last: its presence means the folder is complete
  - ``nodes.npy``: one BATCH_DTYPE record per node (first, count, level, tight bbox), sorted by key
  - ``keys.npy``: the u64 node key of each record (keys.py)
  - ``low.npy``, ``med.npy``, ``high.npy``: u32 node-relative 10-bit precision words per point
  - ``color.npy``: u32 RGBA, inner nodes' colors averaged over the points they stand for
  - ``rgba.npy``: u32 RGBA as read (source colors)
  - ``attr.<name>.npy``: per-point attributes (intensity, classification, ...)
  - ``classes.npy`` (optional, both versions): per node the count of each LAS class its points
    hold (class_counts.py); written where the points have a classification

  That is version 1 (``convert(layout="words")``). Version 2, the default (compact_octree.py),
  keeps ``octree.json``, ``nodes.npy``, ``keys.npy`` and ``low.npy`` and holds the rest per node
  in bit streams: ``pack.npy`` + ``ext.npy`` (positions below the low word), ``fields.npy`` +
  ``field.<name>.npy`` (rgba, color, attr.<name>), about half the bytes.

- a **Potree 2.0 octree** (potree.py): ``metadata.json`` (written last), ``hierarchy.bin``,
  ``octree.bin``;

- an **unfinished conversion**: ``.partial/`` with ``state.json`` (the resumable state, written
  atomically after every step; it names the gigapoint that began it, ``code_version``),
  ``preview.npz`` (preview.py) and the converter's working folders ``raw/`` (spilled input
  chunks), ``parts/`` (partition files) and ``built/`` (built node sets). A gigapoint conversion also fills ``<array>.tmp.npy`` in ``OUT`` itself; the
  write phase renames them.

A conversion with overwrite leaves the complete octree it replaces in place, beside its
``.partial``, until its write phase: that moves the old files into ``.partial/old``
(``set_aside``), metadata first, and the new octree's metadata, written last, completes the
swap; a write phase that fails puts them back (``restore``). So the old octree opens until the
new one is complete, at the cost of the disk of both at once.

A conversion holds an exclusive ``flock`` on the folder itself for as long as it runs
(``lock``); ``running`` probes it. The kernel drops the lock when the process ends, even
killed, so a stopped conversion is told apart from a running one.

Every other module asks an ``OctreeDir`` for these names; none spells them.
"""

from __future__ import annotations

import json
import os
import shutil
import time
import tokenize
from pathlib import Path
from typing import Literal, Self

import numpy as np

from ..atomic import atomic_json, temp_files
from ..errors import GigapointError, InputError
from .code import code_version

GIGAPOINT_META = "octree.json"
FORMAT_NAME = "gigapoint-octree"  # octree.json's "format"
FORMAT_VERSION = 2  # written by default (compact_octree.py); version 1 is still read and written
FORMAT_VERSION_WORDS = 1  # three u32 words a point (store.read_gigapoint; `layout="words"`)
FORMAT_VERSIONS = (FORMAT_VERSION_WORDS, FORMAT_VERSION)
POINT_ARRAYS = ("low", "med", "high", "color", "rgba")  # one entry per point each (version 1)
COMPACT_ARRAYS = ("low", "pack", "ext", "fields", "crc")  # version 2, besides field.<name>.npy (crc: since #22, optional)
CLASSES = "classes"  # both versions: per-node class counts (class_counts.py; optional, older octrees have none)
POTREE_META = "metadata.json"
POTREE_HIERARCHY = "hierarchy.bin"
POTREE_OCTREE = "octree.bin"
PARTIAL = ".partial"
STATE = "state.json"
PREVIEW = "preview.npz"
RESUME_HINT = "run `gigapoint convert` again to resume it"  # what a stopped conversion needs
STOPPED_RESUMES = "run it again once the cause is gone: it resumes"  # how a run stopped by an error (a full disk) goes on
STOPPED_BY_INPUT = "run it again once that file is whole, or without it: it starts over"  # what a run stopped by a bad input needs (a rerun with it, unchanged, stops the same way)
NO_RESUME_HINT = "its points were given from Python (a cloud's save), so it cannot resume: save the cloud again"  # what a stopped one of chunks needs

# an octree's files besides attr.*.npy and field.*.npy, metadata first: what a conversion replaces (never anything else)
_OWN_FILES = (GIGAPOINT_META, POTREE_META, POTREE_HIERARCHY, POTREE_OCTREE, "nodes.npy", "keys.npy", *(f"{a}.npy" for a in (*POINT_ARRAYS, *COMPACT_ARRAYS[1:], CLASSES)))

Kind = Literal["gigapoint", "potree", "unfinished"]


def _resumable(state: dict) -> bool:
    """A stopped conversion's state that a run resumes: not one of chunks given from Python (no fingerprint)."""
    return not ("fingerprint" in state and state["fingerprint"] is None)


def _other_gigapoint(state: dict) -> str | None:
    """The gigapoint that began the conversion of ``state``, where that is not this one (its
    fingerprint holds the code version, so a rerun here starts over), else None. A state of
    files that names none (``code_version``) was saved by an older gigapoint than this one."""
    if state.get("fingerprint") is None:  # chunks given from Python: no rerun resumes them anyway
        return None
    saved = state.get("code_version")
    if saved == code_version():
        return None
    return f"gigapoint {saved}" if isinstance(saved, str) else "an older gigapoint"


class ConvertError(GigapointError):
    """A conversion that cannot start or go on (bad options, output in the way)."""


class OutputExistsError(ConvertError):
    """The output directory already holds something that --overwrite is needed for."""


class DirLock:
    """An exclusive flock on an octree folder (``OctreeDir.lock``), held until ``release``."""

    def __init__(self, fd: int | None):
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the lock
            self._fd = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


class OctreeDir:
    """An octree folder (see the module's docstring), which need not exist yet. ``path``: a
    path or an OctreeDir (os.PathLike through ``__fspath__``)."""

    def __init__(self, path):
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"OctreeDir({str(self.path)!r})"

    def __fspath__(self) -> str:
        return os.fspath(self.path)

    def __eq__(self, other) -> bool:
        return isinstance(other, OctreeDir) and other.path == self.path

    def __hash__(self) -> int:
        return hash(self.path)

    # ------------------------------------------------------------------ paths

    @property
    def meta(self) -> Path:
        """A gigapoint octree's metadata (``octree.json``)."""
        return self.path / GIGAPOINT_META

    @property
    def potree_meta(self) -> Path:
        return self.path / POTREE_META

    @property
    def potree_hierarchy(self) -> Path:
        return self.path / POTREE_HIERARCHY

    @property
    def potree_octree(self) -> Path:
        return self.path / POTREE_OCTREE

    def array(self, name: str) -> Path:
        """A gigapoint octree's array ``name``: nodes, keys, one of POINT_ARRAYS, attr.<attribute>,
        or (version 2) one of COMPACT_ARRAYS or field.<name>."""
        return self.path / f"{name}.npy"

    def load(self, name: str, mmap: bool = True) -> np.ndarray:
        """Array ``name`` read (memory-mapped unless ``mmap`` is False); a missing, short or
        garbled file is a one-line InputError naming it (numpy's parse of a garbled header
        raised tokenize's TokenError or a SyntaxError: a traceback)."""
        path = self.array(name)
        try:
            return np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
        except (OSError, ValueError, SyntaxError, tokenize.TokenError) as exc:
            raise InputError(f"{path}: cannot read it ({' '.join(str(exc).split())})") from None

    def array_in_progress(self, name: str) -> Path:
        """Array ``name`` while a conversion fills it (renamed to ``array(name)`` by the write phase)."""
        return self.path / f"{name}.tmp.npy"

    @property
    def potree_octree_in_progress(self) -> Path:
        """Potree's octree.bin while the build places each node set's nodes in it (lod/potree.py,
        ``place_node_set``); moved to ``potree_octree`` by the write phase."""
        return self.partial / "octree.bin"

    def stream_in_progress(self, name: str) -> Path:
        """Version 2's bit stream ``name`` (ext, field.<name>) while the build appends each node
        set's words to it (lod/writer.py, ``append_streams``); moved to ``array(name)`` once complete."""
        return self.partial / f"{name}.stream.npy"

    @property
    def partial(self) -> Path:
        """An unfinished conversion's working folder (removed once the octree is complete)."""
        return self.path / PARTIAL

    @property
    def old(self) -> Path:
        """The complete octree a conversion with overwrite replaces, moved here by its write phase
        (``set_aside``) and removed with ``partial`` once the new one is complete."""
        return self.partial / "old"

    @property
    def state_file(self) -> Path:
        return self.partial / STATE

    @property
    def preview(self) -> Path:
        return self.partial / PREVIEW

    @property
    def raw(self) -> Path:
        """Spilled input chunks (read phase)."""
        return self.partial / "raw"

    @property
    def parts(self) -> Path:
        """Partition files (distribute phase)."""
        return self.partial / "parts"

    @property
    def built(self) -> Path:
        """Built node sets (build, group and upper phases)."""
        return self.partial / "built"

    # ------------------------------------------------------------------ what it is

    @property
    def kind(self) -> Kind | None:
        """gigapoint or potree (complete), unfinished (a conversion's working folder only), or
        None: not an octree folder (or not a folder at all)."""
        if not self.path.is_dir():
            return None
        if self.meta.is_file():
            return "gigapoint"
        if self.potree_meta.is_file():
            return "potree"
        if self.partial.exists():
            return "unfinished"
        return None

    @property
    def complete(self) -> bool:
        """A finished octree: its metadata file (gigapoint's or Potree's) is written last, atomically."""
        return self.meta.is_file() or self.potree_meta.is_file()

    @property
    def is_octree(self) -> bool:
        """Opens as an octree: a gigapoint or Potree 2.0 octree, or an unfinished conversion that
        has saved its state (so that ``gigapoint.open`` treats the folder as one dataset)."""
        kind = self.kind
        return (
            kind == "gigapoint"
            or (kind == "potree" and self.potree_hierarchy.is_file())
            or (kind == "unfinished" and self.state_file.is_file())
        )

    @property
    def awaiting_preview(self) -> bool:
        """An unfinished conversion that has not written its preview yet."""
        return self.state_file.is_file() and not self.preview.is_file() and not self.complete

    # ------------------------------------------------------------------ conversion state

    def read_state(self) -> dict | None:
        """The saved conversion state; None when there is none (or it cannot be read)."""
        try:
            state = json.loads(self.state_file.read_text())
        except (OSError, ValueError):
            return None
        return state if isinstance(state, dict) else None

    def write_state(self, state: dict) -> None:
        """Save the conversion state, atomically and durably (a killed run resumes from it);
        compact JSON: json's C encoder (an indented one is pure Python: 2 000 tiles' fingerprint
        took 13 ms a save)."""
        atomic_json(self.state_file, state, indent=None, durable=True)

    def status(self) -> dict:
        """What an unfinished conversion's state says: phase, points read, input total, preview
        size, attributes, and whether a conversion is still running (``running``: False once it
        stopped; None: unknown). {} without a saved state."""
        st = self.read_state()
        if st is None:
            return {}
        preview = st.get("preview") or {}
        return {
            "phase": st.get("phase"),
            "points": st.get("points", 0),
            "total": st.get("total"),
            "preview_points": preview.get("points", 0),
            "attributes": sorted(st.get("attributes") or {}),
            "running": self.running,
        }

    @property
    def resumable(self) -> bool:
        """False where the stopped conversion here was of chunks given from Python (a cloud's
        save: its state has no fingerprint), which no run resumes."""
        return _resumable(self.read_state() or {})

    @property
    def resume_hint(self) -> str:
        """What the stopped conversion here needs: run again (it resumes), or a new save; where an
        input stopped it (``stopped_by``, converter.py), that input's error and what to do instead."""
        st = self.read_state() or {}  # (once: resumable would read it again)
        if isinstance(st.get("stopped_by"), str):
            return f"{st['stopped_by']}; {STOPPED_BY_INPUT}"
        other = _other_gigapoint(st)  # an upgrade since: "run again to resume it" was wrong, the rerun started over
        if other is not None:
            return f"it was started by {other}, not this gigapoint {code_version()}: running `gigapoint convert` again starts it over"
        return RESUME_HINT if _resumable(st) else NO_RESUME_HINT

    def other_work(self, fingerprint, state: dict | None) -> str | None:
        """Where a conversion whose inputs and options are ``fingerprint`` would start over another
        run's unfinished work here (another fingerprint; ``state``: ``read_state``'s, read once by
        the conversion for this and ``prepare_output``): who started that one, to say so (another
        gigapoint, named where known), else None. Chunks' work (no run resumes it) is no one's."""
        st = state or {}
        if st.get("fingerprint") is None or st["fingerprint"] == fingerprint:
            return None
        other = _other_gigapoint(st)
        return "with other inputs or options" if other is None else f"by {other} (this is {code_version()})"

    # ------------------------------------------------------------------ lock

    @property
    def running(self) -> bool | None:
        """Whether a conversion holds the folder's lock (``lock``) right now: False once it has
        ended, finished or killed. None where flock does not exist or the folder cannot be opened."""
        try:
            import fcntl
        except ImportError:  # Windows
            return None
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except OSError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return True
        finally:
            os.close(fd)  # closing drops the probe's own shared lock
        return False

    def lock(self) -> DirLock:
        """An exclusive lock on the folder (flock on the directory itself, which is created),
        held by a writer for the whole conversion, so that a second conversion into the same
        folder stops at once instead of clearing or interleaving the first one's files. The
        kernel drops it when the process ends, even killed. A no-op where flock does not exist."""
        try:
            import fcntl
        except ImportError:  # Windows
            return DirLock(None)
        if self.path.exists() and not self.path.is_dir():
            raise OutputExistsError(f"{self.path}: exists and is not a directory")
        self.path.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDONLY)
        for attempt in range(10):  # a viewer's ``running`` probe holds a shared lock for microseconds
            if attempt:
                time.sleep(0.02)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return DirLock(fd)
            except OSError:
                pass
        os.close(fd)
        raise ConvertError(f"{self.path}: another conversion is writing into it; let it finish or stop it first")

    # ------------------------------------------------------------------ as an output

    def prepare_output(self, fingerprint, overwrite: bool, state: dict | None) -> dict | None:
        """Make the folder ready for a conversion whose inputs and options are ``fingerprint``:
        the saved ``state`` (``read_state``'s, read once by the conversion for this and
        ``other_work``) when an unfinished conversion with the same fingerprint can resume,
        else None, the conversion's work cleared and ``.partial`` created. A complete octree is
        replaced only with ``overwrite``, and stays until the new one is complete (``set_aside``);
        a folder that is not an octree is written into only when empty."""
        out = self.path
        if out.exists() and not out.is_dir():
            raise OutputExistsError(f"{out}: exists and is not a directory")
        if out.exists():
            same = state and fingerprint is not None and state.get("fingerprint") == fingerprint  # (chunks never resume)
            if same and (overwrite or not self.complete):  # an unfinished conversion, or replacement, resumes
                return state
            self.restore()  # a replacement killed in its write phase: the octree it was to replace is back
            complete = self.complete
            if complete and not overwrite:
                raise OutputExistsError(f"{out}: already holds a converted point cloud; pass overwrite=True to replace it")
            if not complete and self.kind is None and any(out.iterdir()):
                raise OutputExistsError(f"{out}: directory is not empty and is not a gigapoint/Potree output; refusing to write into it")
            self.start_over()
        self.partial.mkdir(parents=True, exist_ok=True)
        return None

    def remove_partial(self) -> None:
        """Remove an unfinished conversion's working folder (once the octree is complete)."""
        shutil.rmtree(self.partial, ignore_errors=True)

    def _octree_files(self) -> list[Path]:
        """The octree's files here (either format's), metadata first; no work or temporary file."""
        found = [self.path / f for f in _OWN_FILES] + sorted({*self.path.glob("attr.*.npy"), *self.path.glob("field.*.npy")})
        return [p for p in found if p.is_file() and not p.name.endswith(".tmp.npy")]

    def set_aside(self) -> None:
        """Move the octree here into ``old``, for a write phase to put the new one in its place:
        metadata first, so a stop part-way leaves an unfinished folder, never a mix of two."""
        for p in self._octree_files():
            self.old.mkdir(exist_ok=True)
            os.replace(p, self.old / p.name)

    def restore(self) -> bool:
        """Put the octree set aside in ``old`` back, metadata last, where the new one's write phase
        did not finish; the new files that took its place go (where the state says they were being
        written), and so does the conversion's work, which no longer resumes. False where nothing
        is set aside."""
        metas = (GIGAPOINT_META, POTREE_META)
        if not any((self.old / m).is_file() for m in metas):
            return False
        if (self.read_state() or {}).get("aside"):
            for p in self._octree_files():
                p.unlink()
        for p in sorted(self.old.iterdir(), key=lambda p: p.name in metas):
            os.replace(p, self.path / p.name)
        self.clear_work()
        return True

    def start_over(self) -> None:
        """Clear the folder for a conversion from the inputs: a complete octree (put back where
        a replacement had set it aside) stays, for the conversion to replace once complete."""
        self.restore()
        if self.complete:
            self.clear_work()
        else:
            self.clear()

    def clear_work(self) -> None:
        """Remove an unfinished conversion's work (its folder and temporary files); nothing else."""
        shutil.rmtree(self.partial, ignore_errors=True)
        stale = {*self.path.glob("*.tmp"), *self.path.glob("*.tmp.npy"), *temp_files(self.path)}
        for p in stale:
            p.unlink(missing_ok=True)

    def clear(self) -> None:
        """Remove what a conversion writes here (a fresh start); nothing else."""
        self.clear_work()
        for p in self._octree_files():
            p.unlink()
