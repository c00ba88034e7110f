"""Which files a user's paths name: file:// URLs and ``~``, quoted glob patterns (``tiles/*.laz``,
``city/**/*.laz``), folders (their point files; subfolders with ``recursive``; octrees left out),
and the names messages give a set of files."""

from __future__ import annotations

import glob
import os
import re
import urllib.parse
import urllib.request
from collections.abc import Iterable, Iterator
from pathlib import Path

from ..errors import EmptyCloudError, GigapointWarning, InputError, value_text, warn
from ._base import check_file, fail, read_once
from .http import shown_url
from .las import LasReader, read_las_header
from .registry import file_header, in_folder, is_dataset_folder, is_supported_name, reader_for, supported_suffixes

#: a URL (scheme, rest); http and https are lod/reader's, file:// is ``file_url_path``'s
URL_LIKE = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]+):/+(.*)$")  # (a Path of 'ftp://h/x' is 'ftp:/h/x'; 'C:/' is a drive)


def file_url_path(text: str) -> Path | None:
    """The path on this machine a ``file://`` URL names (``file:///data/a.laz``,
    ``file://localhost/...``; ``file:/data/a.laz``, a Path made of one), None for anything else;
    one naming another machine's file (``file://host/...``) is a one-line InputError."""
    if not re.match(r"(?i)^file:/", text):
        return None
    u = urllib.parse.urlsplit(text)
    if u.netloc not in ("", "localhost"):
        raise InputError(f"{shown_url(text)}: a file:// URL of another machine ({u.netloc.rpartition('@')[2]}); give a path on this one")
    return Path(urllib.request.url2pathname(u.path))


def given_paths(paths, where: str | None = None, name: str = "inputs", empty_ok: bool = False) -> list:
    """``paths`` as a list of paths: one path alone, or several (a list, a tuple, any iterable),
    lists and tuples among them spread out in order; anything else a one-line InputError naming
    the entry (``where``: the operation, ``name``: the argument), "tile: inputs[1]: None is not a
    path (a str or os.PathLike)": pathlib's TypeError ("expected str, bytes or os.PathLike object,
    not int") before, from deep inside. No path at all is "``where``: no file given" unless
    ``empty_ok`` (gp.section([]) said "open: no file given", gp.open's words)."""
    out = _spread_paths(paths, where, name)
    if not out and where is not None and not empty_ok:
        raise InputError(f"{where}: no file given")
    return out


def _spread_paths(paths, where: str | None, name: str) -> list:
    """``given_paths``' list, however short (lists within lists spread out)."""
    if isinstance(paths, (str, os.PathLike)):
        return [paths]
    if not isinstance(paths, Iterable) or isinstance(paths, bytes):
        raise _not_a_path(paths, where, name)
    out: list = []
    for i, p in enumerate(paths):
        if isinstance(p, (list, tuple)):
            out.extend(_spread_paths(p, where, f"{name}[{i}]"))
        elif isinstance(p, (str, os.PathLike)):
            out.append(p)
        else:
            raise _not_a_path(p, where, f"{name}[{i}]")
    return out


def _not_a_path(value, where: str | None, name: str) -> InputError:
    return InputError(f"{where + ': ' if where else ''}{name}: {value_text(value)} is not a path (a str or os.PathLike)")


#: what an http(s) URL among the point files of a conversion, tiling or classification is told
URL_NOT_POINT_FILES = (
    "a URL is read only as an octree (a COPC file or an EPT dataset), opened alone to draw it (open, info, render, section, view); "
    "point files are read from this machine: download it first"
)


def _local(p) -> Path:
    """A path as given, a ``file://`` URL's or ``~/...`` expanded; another URL a one-line InputError."""
    text = os.fspath(p) if isinstance(p, (str, os.PathLike)) else None
    if text is not None and not Path(p).exists():
        local = file_url_path(text)  # gp.open("file:///...") was "only http:// and https:// URLs are read"
        url = URL_LIKE.match(text) if local is None else None
        if url:
            shown = shown_url(f"{url.group(1)}://{url.group(2)}")
            if url.group(1).lower() in ("http", "https"):  # (was "only http:// and https:// URLs are read", of an http URL)
                raise InputError(f"{shown}: {URL_NOT_POINT_FILES}")
            raise InputError(f"{shown}: only http:// and https:// URLs are read (COPC and EPT octrees)")
        p = local if local is not None else Path(p).expanduser()  # "~/scans/a.laz" from Python (a shell expands it)
    return Path(p)


#: the characters that make a path a glob pattern: *, ? and [...] (``**``: any depth of folders)
GLOB_CHARS = re.compile(r"[*?[]")


def pattern_matches(p) -> list[Path] | None:
    """What a glob pattern matches (Python's glob, ``**`` any depth of folders; hidden files left
    out, as the shell does), in name order; None where ``p`` is no pattern: a path without glob
    characters, a file or folder of that very name (scan[1].laz), a URL (its ? starts a query).
    A quoted "tiles/*.laz" (Windows' shells, scripts, Makefiles, Python) was "no such file".
    A pattern matching nothing is a one-line InputError naming it."""
    text = os.fspath(p) if isinstance(p, (str, os.PathLike)) else None
    if text is None or not GLOB_CHARS.search(text) or URL_LIKE.match(text) or Path(os.path.expanduser(text)).exists():
        return None
    # once an operation (headers_once), as a folder's listing: its steps expand the paths again, and "**" walks a tree
    found = read_once("pattern", text, lambda: glob.glob(os.path.expanduser(text), recursive=True))
    if not found:
        raise InputError(f"{text}: matches no file")
    return sorted((Path(f) for f in found), key=lambda f: f.parts)


def lone_match(paths) -> list:
    """``paths``, but a glob pattern given alone that matches one path as that path: an octree it
    matches ("out/city*") is then opened as one, as when named (the point files' expansion leaves
    octrees out, and "out/city*" was "no file given")."""
    paths = list(paths)
    if len(paths) == 1:
        matches = pattern_matches(paths[0])
        if matches is not None and len(matches) == 1:
            return matches
    return paths


def _named(paths: Iterable) -> Iterator[tuple[object, bool]]:
    """(path, whether a pattern matched it) of each of ``paths``, patterns by their matches."""
    for p in paths:
        matches = pattern_matches(p)
        if matches is None:
            yield p, False
        else:
            yield from ((m, True) for m in matches)


def _octree_skipped(octree: Path) -> None:
    """Say that an octree among point files is not read (once an operation)."""
    read_once("octree skipped", octree, lambda: warn(f"{octree}: an octree, not read with the point files around it (open it alone)", GigapointWarning))


def _listed(folder: Path) -> list[Path]:
    """A folder's entries sorted by name; one that cannot be listed a one-line InputError."""
    try:
        return sorted(folder.iterdir(), key=lambda c: c.name)
    except OSError as exc:
        raise fail(folder, f"cannot list the folder ({exc.strerror or exc})") from None


def _point_files(entries: list[Path], quiet: bool = False) -> list[Path]:
    """A folder's own point files (``in_folder``) of its ``entries`` (``_listed``); a readme beside
    them skipped with a warning (unless ``quiet``), hidden files quietly (macOS leaves one beside every tile)."""
    found = []
    for c in entries:
        if not (c.is_file() and is_supported_name(c)):
            continue
        if in_folder(c):
            found.append(c)
        elif not quiet and not c.name.startswith("."):
            warn(f"{c}: no point rows at its beginning (a readme?), skipped", GigapointWarning)
    return found


def _subfolders(entries: list[Path], octrees: list | None = None) -> list[Path]:
    """A folder's subfolders of its ``entries`` (``_listed``), but hidden ones and octrees (a
    conversion's output beside its tiles: its .npy arrays are no points; appended to ``octrees``)."""
    out = []
    for c in entries:
        if c.is_dir() and not c.name.startswith("."):
            if not is_dataset_folder(c):
                out.append(c)
            elif octrees is not None:
                octrees.append(c)
    return out


def _folders_below(folder: Path, octrees: list | None = None) -> Iterator[list[Path]]:
    """The entries (``_listed``) of ``folder`` and of every folder below it (``_subfolders``),
    depth first in name order; a folder reached again through a symlink (a link to a parent: a
    loop) is left out."""
    seen: set = set()
    todo = [folder]
    while todo:
        d = todo.pop()
        if d.resolve() in seen:
            continue
        seen.add(d.resolve())
        entries = _listed(d)
        yield entries
        todo.extend(reversed(_subfolders(entries, octrees)))


def _holds_points(folder: Path) -> bool:
    """Whether a point file is anywhere below ``folder``."""
    try:
        return any(_point_files(entries, quiet=True) for entries in _folders_below(folder))
    except InputError:  # a subfolder that cannot be listed (a root-owned lost+found) is not read: not a reason to fail
        return False


def _folder_files(folder: Path, recursive: bool) -> tuple[list[Path], list[Path], list[Path]]:
    """(its point files, or every one below it where ``recursive``; else its subfolders that hold
    some, not read; the octrees below it, not read), each folder listed once."""
    octrees: list[Path] = []
    if recursive:
        return [f for entries in _folders_below(folder, octrees) for f in _point_files(entries)], [], octrees
    entries = _listed(folder)
    return _point_files(entries), [s for s in _subfolders(entries) if _holds_points(s)], octrees


#: how to read a folder's subfolders, said where they are not read
READ_SUBFOLDERS = "read every file below it with --recursive (recursive=True in Python), or name them"


def expand_paths(paths: Iterable, *, recursive: bool = False, where: str = "open") -> list[Path]:
    """Files named (paths, ``file://`` URLs, ``~/...``, glob patterns: ``pattern_matches``), with
    each directory replaced by its supported files sorted by name (``recursive``: also those of
    its subfolders, depth first, but hidden ones and octrees; an octree a pattern matches is left
    out too); a file named twice (or also through its folder) is read once, with
    a warning: its points were merged twice into one cloud or octree. Subfolders holding point
    files are not read otherwise (a folder's raw/ and classified/ copies of its tiles would be
    read twice): said in the error of a folder with no file of its own, else in a warning.
    Patterns matching only octrees leave no file: a one-line InputError under ``where`` (the
    operation's name) saying so."""
    out: list[Path] = []
    skipped: list[Path] = []  # octrees patterns matched, not read
    for p, matched in _named(given_paths(paths, where)):  # (5 among them: a TypeError from pathlib; none: "``where``: no file given")
        p = _local(p)
        if matched and p.is_dir() and is_dataset_folder(p):  # ("tiles/*": a conversion's output beside the tiles)
            _octree_skipped(p)
            skipped.append(p)
        elif p.is_dir():  # (once an operation, headers_once: each of its steps expands the paths again; a walk below is not cheap)
            found, below, octrees = read_once("recursive folder" if recursive else "folder", p, lambda p=p: _folder_files(p, recursive))
            if below and not found:
                raise fail(p, f"holds no point cloud file, but its subfolders {file_names(below)} do: {READ_SUBFOLDERS} ({p / '*'}/)", EmptyCloudError)
            if below:  # once an operation
                said = f"{p}: its subfolders {file_names(below)} hold point files too, not read: {READ_SUBFOLDERS}"
                read_once("subfolders", p, lambda said=said: warn(said, GigapointWarning))
            for o in octrees:
                _octree_skipped(o)
            if not found:
                what = "directory and its subfolders hold" if recursive else "directory holds"
                raise fail(p, f"{what} no supported point cloud file ({', '.join(supported_suffixes())})", EmptyCloudError)
            out.extend(found)
        else:
            out.append(check_file(p, empty_ok=True))  # (a 0-byte one among several: skipped by ``files_with_points``)
    if skipped and not out:  # (said "open: no file given" whatever the operation, and not why)
        raise InputError(f"{where}: no point file given: only octrees matched ({file_names(skipped)}), not read with point files (open one alone)")
    seen: set = set()
    once = []
    for f in out:
        try:  # one file: also through a hard link or a second mount, which resolve() tells apart
            st = f.stat()
            key = (st.st_dev, st.st_ino) if st.st_ino else f.resolve()  # (0: a file system without inode numbers)
        except OSError:
            key = f.resolve()
        if key in seen:
            read_once("named twice", f, lambda f=f: warn(f"{f}: named more than once; its points are read once", GigapointWarning))  # (said once an operation)
            continue
        seen.add(key)
        once.append(f)
    return once


def files_with_points(files: list[Path]) -> list[Path]:
    """``files`` (``expand_paths``'), but where there are several, those holding no point (0 bytes,
    a text file of blank lines, a header counting none) left out, each said once (``skip_empty``):
    what gp.open, its progressive load, convert and tile read. One file alone is kept (its
    reader's one-line error says it is empty); several all empty, "no file holds any point"."""
    if len(files) < 2:
        return files
    kept, empty = [], []
    for f in files:
        (empty if _holds_no_points(f) else kept).append(f)
    if not kept:
        from ..core.cloud import check_valid_count

        check_valid_count(files_label(files), 0, 0, from_files=True)  # (its "no file holds any point")
    for f in empty:
        skip_empty(f)
    return kept


def point_files_of(paths, *, where: str = "open", recursive: bool = False) -> list[Path]:
    """The files ``paths`` name (``expand_paths``) whose points are read: among several, those
    holding none left out (``files_with_points``). What every reader of several files' points goes by."""
    return files_with_points(expand_paths(paths, recursive=recursive, where=where))


def _holds_no_points(f: Path) -> bool:
    """Whether a file is empty, as its size or its header (read once an operation) tells."""
    try:
        return f.stat().st_size == 0 or file_header(f, salvage=True)["point_count"] == 0
    except EmptyCloudError:  # (a text file's header: "holds no points")
        return True


def skipped_message(path) -> str:
    """The warning of a file without points among several, skipped."""
    return f"{path}: holds no points, skipped"


def skip_empty(path) -> None:
    """Say that a file without points among several is skipped (once an operation: a conversion
    reads its files in several passes)."""
    read_once("empty skipped", path, lambda: warn(skipped_message(path), GigapointWarning))


def with_subfolders(paths) -> list:
    """``paths`` with each folder of point files (not an octree) replaced by every point file
    below it (``expand_paths(recursive=True)``): what ``recursive=True`` and ``--recursive`` read;
    a glob pattern by its matches (an octree among them left out, as ``expand_paths`` does);
    anything else as given (a file, an octree, a URL: its reader says what it is)."""
    out: list = []
    for p, matched in _named(paths):
        try:
            q = _local(p) if isinstance(p, (str, os.PathLike)) else None
        except InputError:  # (a URL: an octree's, read as one)
            q = None
        if q is not None and q.is_dir() and not is_dataset_folder(q):
            out.extend(expand_paths([q], recursive=True))
        elif matched and q is not None and q.is_dir():
            _octree_skipped(q)
        else:
            out.append(p)
    return out


def cloud_name(files) -> str:
    """The name of the cloud read from ``files`` (expand_paths'): the file's, or 'N files'."""
    return files[0].name if len(files) == 1 else f"{len(files)} files"


def files_label(files) -> str:
    """Files as an error names them: one as it is, several by the first three and '...' (a
    conversion of thousands of tiles named every one of them in its one line)."""
    files = [str(f) for f in files]
    return ", ".join(files[:3]) + (" ..." if len(files) > 3 else "")


def file_names(files) -> str:
    """Files as a warning lists them: the first three's names, then 'and N more'."""
    return ", ".join(Path(f).name for f in files[:3]) + (f" and {len(files) - 3} more" if len(files) > 3 else "")


def scan_angles_differ(files) -> bool:
    """Whether LAS/LAZ files of one scene name their scan angle both ways (point formats 0-5
    ``scan_angle_rank``, 6-10 ``scan_angle``): kept apart, neither was in every file and the
    scan angle was left out; such files are read through ``las.with_scan_angle``."""
    las = [f for f in files if isinstance(reader_for(f), LasReader)]
    return len(las) > 1 and len({read_las_header(f, salvage=True).point_format >= 6 for f in las}) == 2


def is_copc_name(out) -> bool:
    """Whether ``out`` is named as a COPC file (``*.copc.laz``): what a conversion (or a live
    cloud's save) without a format writes as COPC, and a plain point file's writer refuses."""
    return out is not None and Path(out).name.lower().endswith(".copc.laz")
