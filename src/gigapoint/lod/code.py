"""The running gigapoint's code version (``code_version``): what a conversion's fingerprint holds
(convert/state.py) and its state names, so that a rerun under other code starts over and the
folder says so (octree_dir.py), and what each Dask worker must run (convert/distributed.py)."""

from __future__ import annotations

import hashlib
from pathlib import Path


def code_version() -> str:
    """gigapoint's version and a digest of its source files (12 ms): a worker that imports other
    code than the driver (another release, a stale checkout) writes other bytes, or fails; a
    resume under other code than the run it resumes mixes two versions' work files (fingerprint)."""
    global _CODE_VERSION
    if _CODE_VERSION is None:
        from importlib import metadata

        root = Path(__file__).parents[1]  # the gigapoint package (not imported: lod sits below it)
        h = hashlib.sha1()
        for f in sorted(root.rglob("*.py")):
            h.update(f"{f.relative_to(root).as_posix()}\0".encode() + f.read_bytes())
        try:
            release = metadata.version("gigapoint")
        except metadata.PackageNotFoundError:  # a source tree on the path
            release = "(source)"
        _CODE_VERSION = f"{release}+{h.hexdigest()[:12]}"
    return _CODE_VERSION


_CODE_VERSION: str | None = None
