"""``gigapoint info``'s numbers of a file or a folder of files (headers only: ``file_info``,
``folder_info``; every point read: ``point_stats``) and their text (``format_info``,
``format_stats``)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..core.coords import MAX_ABS_COORDINATE, scale_decimals, value_decimals
from ..errors import InputError, counted
from ._base import STREAM_CHUNK_SIZE, check_file, headers_once
from .crs import crs_identity, crs_name, crs_units, first_crs
from .filters import point_filter
from .paths import cloud_name, file_names, files_label, point_files_of
from .registry import is_dataset_folder, reader_for
from .stats import PointStats, file_stats


@headers_once()  # (its LAS header: read for its info, then for its CRS's units)
def file_info(path) -> dict:
    """What a file holds: format, point_count, bounds {min, max}, attributes, file_size, and for
    LAS/LAZ las_version, point_format, scale, offset, crs (EPSG/WKT string or None) and
    units (io.crs_units of the crs, where it names one).

    LAS bounds come from the header; other formats are scanned (in chunks)."""
    p = check_file(path)
    reader = reader_for(p)
    info = reader.info(p)
    info.setdefault("crs", None)
    if info["crs"]:  # (feet or metres: the CRS's name rarely says, its numbers never)
        found = first_crs([p])  # (what measurements go by: a LAS file's GeoTIFF unit keys too)
        info["units"] = found[2] if found else crs_units(info["crs"])  # (else a CRS only pyproj read from laspy's header)
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
    if out.get("crs"):
        out["units"] = first.get("units")
    out["details"] = details
    out["file_size"] = sum(i.get("file_size") or 0 for i in infos)
    return out


def _coords(values, scale=None, on_grid: bool = True) -> str:
    """'636001.76, 848935.20, 406.26': each axis with the decimals of its stored resolution (a
    LAS scale), else 3 (6 significant digits below 1); no thousands separators in the list.
    ``on_grid`` False: values on no grid of the scale's (an octree's float positions, moved ones
    by --to-crs): the scale's decimals, not as many as reach them (494115.3218665)."""
    out = []
    for axis, v in enumerate(values):
        v = float(v)
        if scale is not None:
            decimals = value_decimals(v, float(scale[axis])) if on_grid else scale_decimals(float(scale[axis]))
            out.append(f"{v:.{decimals}f}")
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
        scale, on_grid = info.get("scale"), info.get("on_grid", True)
        lines.append(f"  bounds min:  {_coords(lo, scale, on_grid)}{src}")
        lines.append(f"  bounds max:  {_coords(hi, scale, on_grid)}")
        # (max - min is on the scale's grid whatever the offset: 40.67000000001 at scale 1e-7 showed float noise)
        lines.append(f"  extent:      {_coords([h - lo_ for lo_, h in zip(lo, hi)], scale, on_grid=False)}")
    lines.append(f"  color:       {'yes' if info.get('has_color') else 'no (default color)'}")
    attrs = info.get("attributes") or []
    lines.append(f"  attributes:  {', '.join(attrs) if attrs else 'none'}")
    if info.get("scale") is not None:
        lines.append(f"  scale:       {', '.join(f'{v:.15g}' for v in info['scale'])}")
    if info.get("offset") is not None:
        lines.append(f"  offset:      {', '.join(f'{v:.15g}' for v in info['offset'])}")
    if (info.get("crs") or info.get("las_version")) and "crs differs" not in (info.get("details") or {}):  # (a folder's tiles': said below)
        lines.append(f"  crs:         {crs_name(info.get('crs'))}")
        if info.get("crs"):
            lines.append(f"  units:       {units_text(info.get('units') or crs_units(info['crs']))}")  # (a dict made by hand: no units)
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
def point_stats(*paths, recursive: bool = False, chunk_size: int = STREAM_CHUNK_SIZE, classes=None, drop_classes=None, clip=None, clip_polygon=None) -> dict:
    """What the points of files, folders or glob patterns (``expand_paths``) hold, summed up:
    their true bounds (and the headers'), each attribute's min, max and mean, the
    classification histogram, returns, flight lines, gps_time, colour ranges, invalid points
    (io/stats.py: ``PointStats.result``). Every point is read once, a chunk at a time. Paths may
    also come as one list or tuple, as gp.open takes them. ``classes``, ``drop_classes``,
    ``clip``, ``clip_polygon``: of the points gp.open's filter of them keeps (``s["filter"]``:
    what it is, the points read and kept); one that keeps none is an EmptyCloudError."""
    if len(paths) == 1 and isinstance(paths[0], (list, tuple)):  # (a list was pathlib's TypeError)
        paths = tuple(paths[0])
    for path in paths:
        _refuse_octree_folder(path)
    keep = point_filter(classes, drop_classes, clip, "point_stats", clip_polygon=clip_polygon)  # (bad values: said before reading)
    files = point_files_of(paths, where="point_stats", recursive=recursive)  # (an empty file among several: skipped, as gp.open skips it)
    total = PointStats()
    for f in files:
        total.merge(file_stats(f, chunk_size, point_filter=keep))
    if keep is not None:
        keep.check_passed(files_label(files))
    return {"path": cloud_name(files) if len(files) > 1 else str(files[0]), **total.result()}


def _refuse_octree_folder(path) -> None:
    """A one-line InputError for an octree folder (converted, Potree, EPT): its nodes are read by
    lod, which io cannot import; read as a folder of files it failed on one of its arrays
    ("crc.npy: NPY array: expected an (N, 3) ... array") or on holding no point file."""
    if isinstance(path, (str, os.PathLike)) and Path(path).expanduser().is_dir() and is_dataset_folder(Path(path).expanduser()):
        raise InputError(f"{path}: an LOD octree; its statistics: gigapoint info --stats {path} or gigapoint.lod.query.octree_stats")


def _number(v) -> str:
    """A statistic: a whole number with thousands separators, else 10 significant digits."""
    return f"{int(v):,}" if float(v).is_integer() and abs(v) < 1e15 else f"{v:.10g}"


def format_stats(stats: dict) -> str:
    """Human-readable text of a ``point_stats`` dict (what ``gigapoint info --stats`` prints)."""
    n = stats["point_count"]
    lines = [f"{stats.get('path', '?')}" + (f" ({stats['files']:,} files)" if stats.get("files", 1) > 1 else "")]
    f = stats.get("filter")
    if f is not None:  # the figures below are of the points it kept
        lines.append(f"  filter:      {f['applied']}: {f['points_kept']:,} of {counted(f['points_read'], 'point')} read kept")
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


def units_text(units: dict) -> str:
    """'x, y: metre; z: US survey foot': a crs_units dict as ``format_info`` shows it."""
    h, v = units["horizontal"], units["vertical"]
    if h is None and v is None:
        return "not named (read as they are)"
    z = "not named" if v is None else v["name"] + (" (assumed: the CRS names no vertical unit)" if units.get("vertical_assumed") else "")
    return f"x, y: {'not named' if h is None else h['name']}; z: {z}"


def human_bytes(n: int) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:,} {unit}" if unit == "bytes" else f"{n:,.1f} {unit}"
        n /= 1024
    return str(n)
