"""Sources of points: readers of LAS/LAZ, PLY, E57, XYZ/TXT/CSV/PTS, NPY, NPZ files and the procedural
demo town (demo.py), all yielding bounded PointChunks.

>>> for chunk in read_chunks("tile.laz", chunk_size=1_000_000): ...   # never loads the file whole
>>> cloud = open_cloud("tiles/")                                       # every supported file, merged
>>> print(format_info(file_info("tile.laz")))

The format is chosen by content (magic bytes) first, then by suffix (``registry.py``).
Every bad input raises a ``gigapoint.errors.InputError`` subclass with a one-line message
that starts with the file's path.
"""

from __future__ import annotations

import glob
import math
import os
import re
import urllib.parse
import urllib.request
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from ..core.chunk import PointChunk
from ..core.cloud import MAX_ABS_COORDINATE, PointCloud, build_cloud, value_decimals
from ..errors import EmptyCloudError, GigapointError, GigapointWarning, InputError, check_switch, warn
from . import write as _write  # noqa: F401  (PointCloud.save's writer: core cannot import io)
from ._base import DEFAULT_CHUNK_SIZE, Reader, check_chunk_size, check_file, fail, headers_once, read_once
from .demo import demo_arrays, demo_chunks
from .filters import PointFilter, filtered
from .http import shown_url
from .las import LasReader, first_crs_header, geokeys, read_las_header, with_scan_angle
from .registry import in_folder, is_dataset_folder, is_supported_name, reader_for, readers, register, supported_suffixes
from .stats import PointStats, file_stats


def read_chunks(path, chunk_size: int = DEFAULT_CHUNK_SIZE) -> Iterator[PointChunk]:
    """Yield the points of one file as PointChunks of at most ``chunk_size`` points."""
    chunk_size = check_chunk_size(chunk_size)
    reader = reader_for(path)
    return reader.read_chunks(Path(path), chunk_size)


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


def _local(p) -> Path:
    """A path as given, a ``file://`` URL's or ``~/...`` expanded; another URL a one-line InputError."""
    text = os.fspath(p) if isinstance(p, (str, os.PathLike)) else None
    if text is not None and not Path(p).exists():
        local = file_url_path(text)  # gp.open("file:///...") was "only http:// and https:// URLs are read"
        url = URL_LIKE.match(text) if local is None else None
        if url:
            raise InputError(f"{shown_url(f'{url.group(1)}://{url.group(2)}')}: only http:// and https:// URLs are read (COPC and EPT octrees)")
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


def expand_paths(paths: Iterable, recursive: bool = False) -> list[Path]:
    """Files named (paths, ``file://`` URLs, ``~/...``, glob patterns: ``pattern_matches``), with
    each directory replaced by its supported files sorted by name (``recursive``: also those of
    its subfolders, depth first, but hidden ones and octrees; an octree a pattern matches is left
    out too); a file named twice (or also through its folder) is read once, with
    a warning: its points were merged twice into one cloud or octree. Subfolders holding point
    files are not read otherwise (a folder's raw/ and classified/ copies of its tiles would be
    read twice): said in the error of a folder with no file of its own, else in a warning."""
    out: list[Path] = []
    for p, matched in _named(paths):
        p = _local(p)
        if matched and p.is_dir() and is_dataset_folder(p):  # ("tiles/*": a conversion's output beside the tiles)
            _octree_skipped(p)
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
            out.append(check_file(p))
    if not out:
        raise InputError("open: no file given")
    seen: set = set()
    once = []
    for f in out:
        try:  # one file: also through a hard link or a second mount, which resolve() tells apart
            st = f.stat()
            key = (st.st_dev, st.st_ino) if st.st_ino else f.resolve()  # (0: a file system without inode numbers)
        except OSError:
            key = f.resolve()
        if key in seen:
            warn(f"{f}: named more than once; its points are read once", GigapointWarning)
            continue
        seen.add(key)
        once.append(f)
    return once


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


#: The EPSG code a WKT CRS ends with (WKT1 AUTHORITY, WKT2 ID): the whole CRS's, not a part's
WKT_EPSG = re.compile(r'(?:AUTHORITY|ID)\[\s*"EPSG"\s*,\s*"?(\d+)"?\s*\]\s*\]\s*$', re.IGNORECASE)

#: The name a WKT CRS starts with (PROJCS["WGS 84 / UTM zone 10N",...)
WKT_NAME = re.compile(r'\s*[A-Z_]+\[\s*"([^"]+)"')


def crs_name(crs: str | None) -> str:
    """A CRS as ``gigapoint info`` says it: a WKT by its name and EPSG code (the code ends it,
    past where 100 characters cut it), 'unknown' where none is named."""
    name, code = WKT_NAME.match(crs or ""), WKT_EPSG.search(crs or "")
    if name:
        return f"{name.group(1)} ({f'EPSG:{code.group(1)}' if code else 'WKT'})"
    return crs or "unknown"


def crs_identity(crs: str) -> str:
    """What tells two CRSs apart: 'EPSG:n' where a WKT ends with its code (the same CRS as WKT in
    one tile, as GeoTIFF keys in another), else the text. warn_mixed_crs and folder_info compare by it."""
    code = WKT_EPSG.search(crs)
    return f"EPSG:{code.group(1)}" if code else crs


#: Symbols of the length units coordinates come in, by their size in metres (WKT names one unit
#: many ways: "US survey foot", "Foot_US"); another unit is shown by its name
LENGTH_SYMBOLS = ((1.0, "m"), (0.3048, "ft"), (1200 / 3937, "US ft"))
#: The length units of GeoTIFF keys (ProjLinearUnitsGeoKey, VerticalUnitsGeoKey) by EPSG code
EPSG_LENGTH_UNITS = {9001: ("metre", 1.0), 9002: ("foot", 0.3048), 9003: ("US survey foot", 1200 / 3937)}
_WKT_TOKEN = re.compile(r'\s*(?:"((?:[^"]|"")*)"|([\[\](),])|([^\[\](),"\s]+))')
_WKT_KINDS = {  # the CRS keywords of WKT1 and WKT2 whose axes' units are read
    "PROJCS": "projected", "PROJCRS": "projected", "PROJECTEDCRS": "projected",
    "GEOGCS": "geographic", "GEOGCRS": "geographic", "GEOGRAPHICCRS": "geographic",
    "VERT_CS": "vertical", "VERTCRS": "vertical", "VERTICALCRS": "vertical",
}  # fmt: skip


def _wkt_tree(text: str) -> list | None:
    """A WKT as nested lists, KEYWORD[a, b, ...] -> [KEYWORD, a, b, ...] (numbers and enum words
    as text); None where the text is not WKT ('EPSG:2992')."""
    stack = [[]]
    for quoted, bracket, word in _WKT_TOKEN.findall(text):
        if bracket in ("[", "("):
            if not stack[-1] or not isinstance(stack[-1][-1], str):
                return None
            node = [stack[-1].pop().upper()]
            stack[-1].append(node)
            stack.append(node)
        elif bracket in ("]", ")"):
            if len(stack) < 2:
                return None
            stack.pop()
        elif bracket != ",":
            stack[-1].append(word or quoted)
    root = stack[0][0] if len(stack) == 1 and len(stack[0]) == 1 else None
    return root if isinstance(root, list) else None


def _wkt_unit(node: list, angle: bool) -> dict | None:
    """{name, symbol, metres} of a UNIT / LENGTHUNIT / ANGLEUNIT node; an angle's metres are None."""
    try:
        name, size = str(node[1]), float(node[2])
    except (IndexError, ValueError):
        return None
    if angle or node[0] == "ANGLEUNIT":
        return {"name": name, "symbol": "°" if name.lower().startswith("deg") else name, "metres": None}
    return {"name": name, "symbol": next((s for m, s in LENGTH_SYMBOLS if math.isclose(size, m, rel_tol=1e-9)), name), "metres": size}


def _wkt_units(crs: list) -> tuple[dict | None, dict | None]:
    """(horizontal, vertical) units of one WKT CRS (a compound CRS's parts' in turn): those of its
    own axes (WKT2 may give each AXIS its unit; else the one UNIT for all), not its base CRS's."""
    kind = _WKT_KINDS.get(crs[0])
    if kind is None:  # a compound CRS: its parts; any other (geocentric, engineering): unknown
        parts = [_wkt_units(p) for p in crs[1:] if isinstance(p, list)] if crs[0] in ("COMPD_CS", "COMPOUNDCRS") else []
        return next((h for h, _ in parts if h), None), next((v for _, v in parts if v), None)
    nodes = [c for c in crs[1:] if isinstance(c, list)]
    units = [u for a in nodes if a[0] == "AXIS" for u in a if isinstance(u, list) and u[0].endswith("UNIT")]
    units = [_wkt_unit(u, kind == "geographic" and u[0] != "LENGTHUNIT") for u in units or [c for c in nodes if c[0].endswith("UNIT")]]
    if kind == "vertical":
        return None, units[0] if units else None
    if kind == "geographic":  # a 3D one's ellipsoidal height has a length unit
        return (units[0] if units else None), next((u for u in units if u and u["metres"] is not None), None)
    return (units[0] if units else None), (units[2] if len(units) == 3 else None)


def crs_units(crs: str | None, geokeys: dict[int, int] | None = None) -> dict:
    """The units of a CRS's coordinates, for lengths measured in them: {"horizontal": U,
    "vertical": U, "vertical_assumed": bool}, each U {name, symbol, metres} or None (unknown).

    From a WKT (``crs``: the projected CRS's axes' UNIT, a compound CRS's vertical part's), else
    from LAS GeoTIFF keys (``geokeys``: ProjLinearUnitsGeoKey 3076, VerticalUnitsGeoKey 4099), else
    from an EPSG code ('EPSG:n', or the keys' ProjectedCSTypeGeoKey 3072 / GeographicTypeGeoKey 2048
    without a unit key, as LAS 1.2 files often name theirs) through pyproj's axes where pyproj is
    installed (``_epsg_units``; without it such a code says none). A geographic CRS's horizontal
    unit is an angle (metres None: its x and y are no lengths). Where a CRS names no vertical unit, heights
    are taken to be in the horizontal length unit (LAS files are; ``vertical_assumed`` says so).
    """
    tree = _wkt_tree(crs or "")
    horizontal, vertical = _wkt_units(tree) if tree else (None, None)
    keys = geokeys or {}
    if horizontal is None and keys.get(1024) == 2:  # GTModelTypeGeoKey: geographic
        horizontal = {"name": "degree", "symbol": "°", "metres": None}
    elif horizontal is None and keys.get(3076) in EPSG_LENGTH_UNITS:
        horizontal = _wkt_unit(["UNIT", *EPSG_LENGTH_UNITS[keys[3076]]], angle=False)
    if vertical is None and keys.get(4099) in EPSG_LENGTH_UNITS:
        vertical = _wkt_unit(["UNIT", *EPSG_LENGTH_UNITS[keys[4099]]], angle=False)
    code = _epsg_code(crs, keys) if horizontal is None else None
    if code is not None:  # ("unknown" units in the viewer for EPSG:2994's feet, EPSG:26910's metres)
        horizontal, up = _epsg_units(code)
        vertical = vertical or up
    assumed = vertical is None and horizontal is not None and horizontal["metres"] is not None
    return {"horizontal": horizontal, "vertical": horizontal if assumed else vertical, "vertical_assumed": assumed}


def horizontal_epsg(crs: str | None) -> int | None:
    """The EPSG code of a CRS's horizontal part: an 'EPSG:n''s n; a WKT projected or geographic
    CRS's own AUTHORITY / ID (a compound CRS's horizontal part's: its whole one names no map
    grid GeoTIFF keys can hold); None where none is named (autzen's WKT names only its datum's
    and unit's codes, inside it)."""
    tree = _wkt_tree(crs or "")
    if tree is None:
        return _epsg_code(crs, {})
    if tree[0] in ("COMPD_CS", "COMPOUNDCRS"):
        tree = next((p for p in tree[1:] if isinstance(p, list) and _WKT_KINDS.get(p[0]) in ("projected", "geographic")), None)
    if tree is None or _WKT_KINDS.get(tree[0]) not in ("projected", "geographic"):
        return None
    codes = [n[2] for n in tree[1:] if isinstance(n, list) and n[0] in ("AUTHORITY", "ID") and len(n) > 2 and str(n[1]).upper() == "EPSG"]
    return int(codes[-1]) if codes and str(codes[-1]).isdigit() else None


def _epsg_code(crs: str | None, keys: dict[int, int]) -> int | None:
    """The EPSG code of an 'EPSG:n' ``crs`` (LasHeader.crs of GeoTIFF keys), else of the keys'
    projected or geographic CRS (not 32767: user-defined); None without one."""
    named = re.fullmatch(r"\s*EPSG:(\d+)\s*", crs or "", re.IGNORECASE)
    if named:
        return int(named.group(1))
    return next((keys[k] for k in (3072, 2048) if 0 < keys.get(k, 0) < 32767), None)


def _epsg_units(code: int) -> tuple[dict | None, dict | None]:
    """(horizontal, vertical) units of EPSG:``code`` by pyproj's axes (``axis_info``: east/north
    and up ones; a geographic CRS's across in angles; a geocentric one's none), (None, None) where
    pyproj is not installed (an optional dependency) or knows no such code."""
    try:
        import pyproj

        crs = pyproj.CRS.from_epsg(code)
        axes, geographic = list(crs.axis_info), bool(crs.is_geographic)
    except Exception:  # noqa: BLE001 - pyproj missing or the code unknown to it: units unknown
        return None, None
    across = [a for a in axes if str(a.direction).lower() in ("east", "north", "west", "south")]
    up = [a for a in axes if str(a.direction).lower() == "up"]
    horizontal = _wkt_unit(["UNIT", across[0].unit_name, across[0].unit_conversion_factor], angle=geographic) if across else None
    return horizontal, (_wkt_unit(["UNIT", up[0].unit_name, up[0].unit_conversion_factor], angle=False) if up else None)


def files_units(files) -> dict:
    """``crs_units`` of the first LAS/LAZ file of ``files`` that names a CRS (its WKT, else its
    GeoTIFF keys); all unknown without one."""
    hdr = first_crs_header(files)
    return crs_units(hdr.crs(), geokeys(hdr.vlrs)) if hdr else crs_units(None)


def files_crs(files) -> str | None:
    """The CRS of the first LAS/LAZ file of ``files`` that names one: its WKT, else 'EPSG:n' of
    its GeoTIFF keys (LasHeader.crs); None without one."""
    hdr = first_crs_header(files)
    return hdr.crs() if hdr else None


def crs_wkt(crs: str | None) -> str | None:
    """WKT of a CRS as the readers give it: an 'EPSG:n' through pyproj when it is installed (else
    None); any other is WKT already."""
    if not crs or not crs.upper().startswith("EPSG:"):
        return crs or None
    try:
        import pyproj

        return pyproj.CRS.from_user_input(crs).to_wkt()
    except Exception:  # noqa: BLE001 - pyproj missing or the code unknown: no WKT
        return None


def warn_mixed_crs(files, then: str = "") -> None:
    """Warn where LAS/LAZ files read as one cloud name different CRSs, or some name one and
    others none (lost with their VLRs, or another CRS unsaid): their coordinates are used as
    they are, nothing is reprojected, so such tiles may not line up (``then``: what follows,
    added to the message). Once an operation (``headers_once``: open_sized reads the files twice)."""
    if len(files) < 2:
        return
    first: dict = {}  # CRS (its EPSG code where a WKT ends with one): the first file naming it
    have, none = 0, []  # how many LAS files name a CRS; those naming none
    for f in files:
        try:  # (the header the read uses: no second open; salvage: as scan_angles_differ)
            if not isinstance(reader_for(f), LasReader):  # (no CRS to name: not said to lack one)
                continue
            crs = read_las_header(f, salvage=True).crs()
        except GigapointError:  # a bad file: reading its points says so, in its own words
            continue
        if crs:
            first.setdefault(crs_identity(crs), f)
            have += 1
        else:
            none.append(f)
    lacking = f"{file_names(none)} {'names' if len(none) == 1 else 'name'} no CRS"
    if len(first) > 1:
        named = "; ".join(f"{Path(f).name}: {crs[:60]}" for crs, f in list(first.items())[:3])
        said = f"the files name {len(first)} different CRSs ({named}{'; ...' if len(first) > 3 else ''}){'; ' + lacking if none else ''}"
        line_up = "so they do not line up"
    elif first and none:  # (the others' points probably in another CRS, or their VLRs lost)
        crs, f = next(iter(first.items()))
        others = f"{Path(f).name} names" if have == 1 else f"{Path(f).name} and {have - 1} more name"
        said, line_up = f"{lacking}, where {others} {crs[:60]}", "so they may not line up"
    else:
        return
    message = f"{said}: their coordinates are used as they are, not reprojected, {line_up}{then}"
    read_once("mixed CRSs", "\n".join(map(str, files)), lambda: warn(message, GigapointWarning))


def _with_progress(path: Path, chunks: Iterator[PointChunk], total: int | None, progress) -> Iterator[PointChunk]:
    task = progress.add_task(path.name, total=total)
    for chunk in chunks:
        progress.advance(task, len(chunk))
        yield chunk


@headers_once()  # counts, scan angles, then the points: each file's header read once
def open_cloud(
    *paths,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    progress: bool = False,
    name: str | None = None,
    layout: str = "auto",
    colors: str = "auto",
    chunked: bool | None = None,
    point_filter: PointFilter | None = None,
) -> PointCloud:
    """Read files and/or directories (all supported files inside, sorted by name) into one PointCloud.

    ``layout`` / ``colors``: how the points are held (``core.build_cloud``: by default compact
    where the files say their scale, LAS).

    Several files are merged (attributes they all have are kept). With several files, a file
    without any point is skipped with a warning; one file without points raises EmptyCloudError.
    ``progress=True`` shows a progress bar on stderr (rich). ``chunked=True``: built in bounded
    memory (core/chunked.py: the files read three times, LAZ and text files decoded once and
    their points kept for the later passes; the points spilled to a temporary folder; the same
    cloud), for files whose points do not fit in memory as floats; None (the
    default): chunked when the files' headers say they hold more than ``CHUNKED_ABOVE`` (50 M).
    ``point_filter``: only the points it keeps are read (io/filters.py; gp.open's ``classes``,
    ``drop_classes`` and ``clip``); the headers' counts are then upper bounds.
    """
    if not paths:
        raise InputError("open: no file given")
    chunk_size = check_chunk_size(chunk_size)
    check_switch("chunked", chunked, "open", allow_none=True)  # "no" was taken as true
    check_switch("progress", progress, "open")
    if name is not None and not isinstance(name, str):  # the name every message and output of the cloud starts with
        raise InputError(f"open: name must be a string, got {name!r}")
    files = expand_paths(paths)
    plan = [(f, reader_for(f)) for f in files]
    if name is None:
        name = cloud_name(files)
    several = len(files) > 1
    empty: list[Path] = []
    from ..core.chunked import CHUNKED_ABOVE, HELD_BYTES_MIN, IN_MEMORY_BYTES_MIN, SPILLED_BYTES_MIN, check_room

    counts = [reader.point_count(f) for f, reader in plan]  # None: a text file, counted only when read
    if chunked is None:
        chunked = None not in counts and sum(counts) > CHUNKED_ABOVE
    counted = sum(c for c in counts if c)
    instead = ": open it with progressive=True (an LOD octree filled up to a memory limit) or convert it (gigapoint convert)"
    if chunked:
        check_room(name, counted, HELD_BYTES_MIN, SPILLED_BYTES_MIN, instead=instead)
    else:
        check_room(name, counted, IN_MEMORY_BYTES_MIN, instead=instead + ", or build it in bounded memory (chunked=True)")

    one_angle = scan_angles_differ(files)
    warn_mixed_crs(files)

    def chunks(bar=None) -> Iterator[PointChunk]:
        passing = point_filter.fresh() if point_filter is not None else None  # counted again each pass (chunked: three)
        for (f, reader), count in zip(plan, counts):
            it = reader.read_chunks(f, chunk_size)
            if one_angle:
                it = with_scan_angle(it)
            if bar is not None:
                it = _with_progress(f, it, count, bar)  # (the headers' counts, read once above: the points read, not kept)
            try:
                yield from filtered(it, f, passing)
            except EmptyCloudError:
                if not several:
                    raise
                empty.append(f)
                warn(f"{f}: holds no points, skipped", GigapointWarning)
        if passing is not None:  # not "no valid points": the filter left none
            passing.check_passed(files_label(files))

    def build(stream) -> PointCloud:
        try:
            if chunked:  # ``stream``: a function giving the chunks, called once a pass
                from ..core.chunked import build_cloud_chunked

                read_once = any(reader.reads_slowly(f) for f, reader in plan)  # LAZ, text: decoded once, not three times
                cloud = build_cloud_chunked(stream, name=name, layout=layout, colors=colors, read_once=read_once)
            else:
                cloud = build_cloud(stream, name=name, layout=layout, colors=colors)
        except EmptyCloudError as exc:
            detail = str(exc).split(": ", 1)[-1]
            raise EmptyCloudError(f"{files_label(files)}: {detail}") from None
        cloud.source_files = tuple(files)  # gp.convert(cloud) takes their CRS
        return cloud

    if not progress:
        return build(chunks if chunked else chunks())
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, console=Console(stderr=True), transient=True) as bar:
        return build((lambda: chunks(bar)) if chunked else chunks(bar))


def file_info(path) -> dict:
    """What a file holds: format, point_count, bounds {min, max}, attributes, file_size, and for
    LAS/LAZ las_version, point_format, scale, offset, crs (EPSG/WKT string or None).

    LAS bounds come from the header; other formats are scanned (in chunks)."""
    p = check_file(path)
    reader = reader_for(p)
    info = reader.info(p)
    info.setdefault("crs", None)
    info["reader"] = reader.name
    return info


def folder_info(folder, infos: list[dict]) -> dict:
    """One ``file_info`` dict of a folder's files (``infos``: theirs) for ``format_info``:
    points and sizes summed, bounds joined, the attributes they all have; what they do not
    share is said in ``details`` (a city's 1 500 tiles were 21 000 lines of ``gigapoint info``);
    ``files``: how many (``info --json`` prints the dict as it is)."""
    n = len(infos)
    out = {"path": str(folder), "files": n, "point_count": sum(i.get("point_count") or 0 for i in infos)}
    details = {}

    def shared(label: str, text) -> bool:
        """Whether every file's ``text(info)`` is the same; where not, the most common ones, counted, in ``details``."""
        kinds: dict = {}
        for i in infos:
            kinds[text(i)] = kinds.get(text(i), 0) + 1
        if len(kinds) > 1:
            ranked = sorted(kinds.items(), key=lambda kv: -kv[1])
            details[label] = "; ".join(f"{k} ({c:,} file{'s' * (c > 1)})" for k, c in ranked[:3]) + (" ..." if len(ranked) > 3 else "")
        return len(kinds) == 1

    def numbers(key: str, form: str):
        return lambda i: "none" if i.get(key) is None else ", ".join(f"{x:{form}}" for x in i[key])

    named: dict = {}  # a CRS's identity -> its name as the first file gives it (WKT and GeoTIFF keys of one EPSG: one CRS)

    def crs_text(i) -> str:
        return named.setdefault(crs_identity(i["crs"]), crs_name(i["crs"])) if i.get("crs") else crs_name(None)

    first = infos[0]
    out["format"] = first.get("format", "?")
    if shared("formats", lambda i: f"{i.get('format', '?')} {i.get('las_version') or ''} point format {i.get('point_format')}"):
        out.update(las_version=first.get("las_version"), point_format=first.get("point_format"))
    elif not shared("format", lambda i: i.get("format", "?")):
        out["format"] = "mixed"
    spans = [i["bounds"] for i in infos if i.get("point_count") and (i.get("bounds") or {}).get("min") is not None]  # (an empty tile's header: 0, 0, 0)
    if spans:
        out["bounds"] = {"min": np.min([b["min"] for b in spans], axis=0).tolist(), "max": np.max([b["max"] for b in spans], axis=0).tolist()}
        out["bounds_source"] = "header" if all(i.get("bounds_source") == "header" for i in infos) else "data"
    colored = sum(bool(i.get("has_color")) for i in infos)
    out["has_color"] = colored == n
    if 0 < colored < n:
        details["colored"] = f"{colored:,} of the {n:,} files (the others: default color)"
    out["attributes"] = [a for a in first.get("attributes") or [] if all(a in (i.get("attributes") or []) for i in infos)]
    for key, label, text in (("scale", "scales", numbers("scale", ".15g")), ("offset", "offsets", numbers("offset", ".15g")),
                             ("crs", "crs differs", crs_text),
                             ("generating_software", "software", lambda i: i.get("generating_software") or "unknown")):  # fmt: skip
        if shared(label, text):
            out[key] = first.get(key)
    out["details"] = details
    out["file_size"] = sum(i.get("file_size") or 0 for i in infos)
    return out


def _coords(values, scale=None) -> str:
    """'636001.76, 848935.20, 406.26': each axis with the decimals of its stored resolution (a
    LAS scale), else 3 (6 significant digits below 1); no thousands separators in the list."""
    out = []
    for axis, v in enumerate(values):
        v = float(v)
        if scale is not None:
            out.append(f"{v:.{value_decimals(v, float(scale[axis]))}f}")
        else:
            out.append(f"{v:.3f}" if abs(v) >= 1 or v == 0 else f"{v:.6g}")
    return ", ".join(out)


def format_info(info: dict) -> str:
    """Human-readable text of a ``file_info`` dict (what ``gigapoint info`` prints); a
    ``details`` entry ({label: text}) adds lines as they are."""
    lines = [f"{info.get('path', '?')}" + (f" ({info['files']:,} files)" if "files" in info else "")]  # (a folder's: folder_info)
    fmt = info.get("format", "?")
    if info.get("las_version"):
        fmt += f" {info['las_version']}, point format {info.get('point_format')}"
    if info.get("encoding"):
        fmt += f" ({info['encoding']})"
    lines.append(f"  format:      {fmt}")
    lines.append(f"  points:      {info.get('point_count', 0):,}")
    b = info.get("bounds") or {}
    if b.get("min") is not None:
        lo, hi = b["min"], b["max"]
        src = " (header)" if info.get("bounds_source") == "header" else ""
        scale = info.get("scale")
        lines.append(f"  bounds min:  {_coords(lo, scale)}{src}")
        lines.append(f"  bounds max:  {_coords(hi, scale)}")
        lines.append(f"  extent:      {_coords([h - lo_ for lo_, h in zip(lo, hi)], scale)}")
    lines.append(f"  color:       {'yes' if info.get('has_color') else 'no (default color)'}")
    attrs = info.get("attributes") or []
    lines.append(f"  attributes:  {', '.join(attrs) if attrs else 'none'}")
    if info.get("scale") is not None:
        lines.append(f"  scale:       {', '.join(f'{v:.15g}' for v in info['scale'])}")
    if info.get("offset") is not None:
        lines.append(f"  offset:      {', '.join(f'{v:.15g}' for v in info['offset'])}")
    if (info.get("crs") or info.get("las_version")) and "crs differs" not in (info.get("details") or {}):  # (a folder's tiles': said below)
        lines.append(f"  crs:         {crs_name(info.get('crs'))}")
    if info.get("generating_software"):
        lines.append(f"  software:    {info['generating_software']}")
    if info.get("columns"):
        lines.append(f"  columns:     {' '.join(info['columns'])} ({info.get('delimiter')}{', header line' if info.get('header_line') else ''})")
    for label, text in (info.get("details") or {}).items():  # ready lines from other layers (an octree's, lod/reader.py)
        lines.append(f"  {label + ':':<13}{text}")
    size = info.get("file_size")
    if size is not None:
        lines.append(f"  file size:   {human_bytes(size)}")
    return "\n".join(lines)


@headers_once()  # (a folder listed once)
def point_stats(*paths, recursive: bool = False, chunk_size: int = DEFAULT_CHUNK_SIZE) -> dict:
    """What the points of files, folders or glob patterns (``expand_paths``) hold, summed up:
    their true bounds (and the headers'), each attribute's min, max and mean, the
    classification histogram, returns, flight lines, gps_time, colour ranges, invalid points
    (io/stats.py: ``PointStats.result``). Every point is read once, a chunk at a time. Paths may
    also come as one list or tuple, as gp.open takes them."""
    if len(paths) == 1 and isinstance(paths[0], (list, tuple)):  # (a list was pathlib's TypeError)
        paths = tuple(paths[0])
    files = expand_paths(paths, recursive=recursive)
    total = PointStats()
    for f in files:
        total.merge(file_stats(f, chunk_size))
    return {"path": cloud_name(files) if len(files) > 1 else str(files[0]), **total.result()}


def _number(v) -> str:
    """A statistic: a whole number with thousands separators, else 10 significant digits."""
    return f"{int(v):,}" if float(v).is_integer() and abs(v) < 1e15 else f"{v:.10g}"


def format_stats(stats: dict) -> str:
    """Human-readable text of a ``point_stats`` dict (what ``gigapoint info --stats`` prints)."""
    n = stats["point_count"]
    lines = [f"{stats.get('path', '?')}" + (f" ({stats['files']:,} files)" if stats.get("files", 1) > 1 else "")]
    lines.append(f"  points:      {n:,}, {stats['invalid_points']:,} of them invalid (NaN, inf or beyond ±{MAX_ABS_COORDINATE:g}): skipped")
    b, h, stale, scale = stats.get("bounds"), stats.get("header_bounds"), stats.get("header_bounds_differ"), stats.get("scale")
    if b is not None:
        whose = " (the points'; the header's the same)" if h is not None and not stale else " (the points')"
        lines.append(f"  bounds min:  {_coords(b['min'], scale)}{whose}")
        lines.append(f"  bounds max:  {_coords(b['max'], scale)}")
    if h is not None and stale:  # a stale header: tools that trust it crop or misplace the points
        lines.append(f"  header min:  {_coords(h['min'], scale)}")
        lines.append(f"  header max:  {_coords(h['max'], scale)}")
        lines.append(f"  stale:       the header's bounds are not its points' ({file_names(stale)})")
    if stats["attributes"]:
        lines.append(f"  {'attribute':<22}{'min':>16}{'max':>16}{'mean':>18}")
        for name, a in stats["attributes"].items():
            lines.append(f"    {name:<20}{_number(a['min']):>16}{_number(a['max']):>16}{_number(a['mean']):>18}")
    for c in stats.get("classification") or []:
        label = "classes:" if c is stats["classification"][0] else ""
        lines.append(f"  {label:<13}{c['class']:>3} {c['name']:<26}{c['count']:>14,} {c['percent']:6.2f}%")
    r = stats.get("returns")
    if r is not None:
        odd = f", invalid {r['invalid']:,} (return 0 or above the number of returns)" if r["invalid"] else ""
        lines.append(f"  returns:     single {r['single']:,}, first {r['first']:,}, last {r['last']:,}, intermediate {r['intermediate']:,}{odd}")
        lines += [f"    return {k['return_number']} of {k['number_of_returns']}:{k['count']:>14,}" for k in r["by_number"]]
    s = stats.get("point_source_ids")
    if s is not None:
        each = ", ".join(f"{k}: {v:,}" for k, v in s["points"].items()) if s["points"] else ""
        lines.append(f"  sources:     {s['count']:,} flight line{'s' * (s['count'] > 1)} (point_source_id{f' {each}' if each else ''})")
    t = stats.get("gps_time")
    if t is not None:
        when = f": {t['first']} .. {t['last']} GPS" if "first" in t else ": no date" if t["kind"] == "seconds of a GPS week" else ""
        lines.append(f"  gps_time:    {t['min']:.6f} .. {t['max']:.6f} ({t['kind']}{when})")
    c = stats.get("color")
    if c is not None:
        depth = {8: " (8-bit values in 16-bit LAS fields)", 16: " (16-bit, shown as 8-bit: >> 8)"}.get(c["bits"], "")
        lines.append("  color:       " + ", ".join(f"{k} {lo}..{hi}" for k, lo, hi in zip(("red", "green", "blue"), c["min"], c["max"])) + depth)
    else:
        lines.append("  color:       none")
    return "\n".join(lines)


def human_bytes(n: int) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:,} {unit}" if unit == "bytes" else f"{n:,.1f} {unit}"
        n /= 1024
    return str(n)


__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "PointStats",
    "Reader",
    "cloud_name",
    "crs_units",
    "demo_arrays",
    "demo_chunks",
    "expand_paths",
    "file_info",
    "file_stats",
    "files_label",
    "files_units",
    "folder_info",
    "format_info",
    "format_stats",
    "horizontal_epsg",
    "lone_match",
    "open_cloud",
    "point_stats",
    "read_chunks",
    "reader_for",
    "readers",
    "register",
    "supported_suffixes",
    "warn_mixed_crs",
    "with_subfolders",
]
