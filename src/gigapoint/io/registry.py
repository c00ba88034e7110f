"""The one registry of point cloud readers: chosen by magic bytes, then suffix, then content guess."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import InputError, UnsupportedFormatError

if TYPE_CHECKING:  # (_base imports numpy: ``import gigapoint`` registers its octree test here without it)
    from ._base import Reader

_READERS: list[Reader] = []


def register(reader: Reader) -> Reader:
    """Add a reader (an instance of a Reader subclass); later registrations win ties on suffix."""
    _READERS.insert(0, reader)
    return reader


def readers() -> list[Reader]:
    _load_builtin()
    return list(_READERS)


def supported_suffixes() -> list[str]:
    return sorted({s for r in readers() for s in r.suffixes})


def is_supported_name(path: Path | str) -> bool:
    """True when the file's suffix belongs to a registered reader (used to pick files in a directory)."""
    name = Path(path).name.lower()
    return any(name.endswith(s) for s in supported_suffixes())


#: tests of a folder that is one dataset, not a folder of tiles (an octree: gigapoint/__init__.py
#: registers lod's, as io cannot import lod); a folder walk (``--recursive``) leaves such subfolders out
_DATASET_FOLDERS: list[Callable[[Path], bool]] = []


def register_dataset_folder(test: Callable[[Path], bool]) -> None:
    _DATASET_FOLDERS.append(test)


def is_dataset_folder(path: Path) -> bool:
    return any(test(path) for test in _DATASET_FOLDERS)


def in_folder(path: Path) -> bool:
    """Whether a file found in a folder is one of its point files: a supported suffix, not
    hidden (macOS's ._tile.laz and .DS_Store beside every tile), and, for a suffix other files
    share (a tile folder's README.txt), points in its beginning (``Reader.shared_suffixes``)."""
    name = path.name.lower()
    if name.startswith(".") or not is_supported_name(name):
        return False
    shared = [r for r in readers() if any(name.endswith(s) for s in r.shared_suffixes)]
    if not shared:
        return True
    from ._base import read_head, read_once

    try:
        head = read_once("head", path, lambda: read_head(path))
    except InputError:
        return True  # (unreadable: its reader says so, as of any other file)
    return any(r.weak_sniff(head) for r in shared)


#: tests of a file that is part of a dataset, not a point file (a Potree octree's octree.bin:
#: gigapoint/__init__.py registers lod's, as io cannot import lod): what to say of it, else None
_DATASET_PARTS: list[Callable[[Path], str | None]] = []


def register_dataset_part(test: Callable[[Path], str | None]) -> None:
    _DATASET_PARTS.append(test)


def reader_by_name(name: str) -> Reader:
    for r in readers():
        if r.name.lower() == name.lower():
            return r
    raise UnsupportedFormatError(f"format: unknown format {name!r}; known: {', '.join(r.name for r in readers())}")


def reader_for(path: Path | str) -> Reader:
    """The reader for a file: a magic number in its first bytes wins, then its suffix, then a content guess."""
    from ._base import check_file, fail, read_head, read_once

    p = check_file(path)
    for test in _DATASET_PARTS:
        part = test(p)
        if part is not None:
            raise UnsupportedFormatError(part)
    head = read_once("head", p, lambda: read_head(p))  # (an operation asks several times a file: headers_once)
    all_readers = readers()
    for r in all_readers:
        if r.sniff(head):
            return r
    name = p.name.lower()
    for r in all_readers:
        if any(name.endswith(s) for s in r.suffixes):
            return r
    for r in all_readers:
        if r.weak_sniff(head):
            return r
    start = head[:8]
    raise fail(
        p,
        f"unknown point cloud format (suffix {p.suffix or 'none'!r}, starts with {start!r}); "
        f"supported: {', '.join(r.name for r in reversed(all_readers))}",
        UnsupportedFormatError,
    )


def file_header(path, salvage: bool = False) -> dict:
    """``reader_for(path).header(path, salvage)``, read once an operation (``read_once``): the
    empty-file check, the CRS and the read each ask for it (a text file's layout warns as read)."""
    from ._base import read_once

    return read_once("salvaged header" if salvage else "header", path, lambda: reader_for(path).header(path, salvage=salvage))


_loaded = False


def _load_builtin() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    from .e57 import E57Reader
    from .las import LasReader
    from .numpy_io import NpyReader, NpzReader
    from .ply import PlyReader
    from .text import TextReader

    # registered last = tried first; order only matters for suffix ties (there are none)
    for reader in (TextReader(), NpzReader(), NpyReader(), PlyReader(), E57Reader(), LasReader()):
        if not any(type(r) is type(reader) for r in _READERS):
            _READERS.append(reader)
