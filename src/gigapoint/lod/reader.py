"""Opening an octree folder of any kind (octree_dir.py): a gigapoint octree (store.py), a
Potree 2.0 octree (potree.py) or an unfinished conversion, shown as its preview (preview.py);
a COPC file (copc.py) or an EPT dataset (ept.py), local or over HTTP; and what ``gigapoint
info`` says about one."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlsplit, urlunsplit

import numpy as np

from ..errors import EmptyCloudError, InputError, counted
from ..io.http import HttpNotFound, as_url, open_source, shown_url
from .kinds import copc_file_kind, ept_location
from .octree_dir import FORMAT_VERSION, GIGAPOINT_META, POTREE_META, OctreeDir

if TYPE_CHECKING:
    from ..core.cloud import PointCloud
    from ..io.filters import PointFilter
    from .store import OctreeCloud

# The readers of each kind are imported where one is opened (numba's kernels: ``gigapoint info``
# of a point file asks ``is_lod_source`` alone).


def is_octree_dir(path) -> bool:
    """A gigapoint or Potree 2.0 octree folder, or an unfinished conversion into one."""
    try:
        return OctreeDir(path).is_octree
    except (TypeError, OSError):
        return False


def lod_source_kind(path) -> str | None:
    """What ``path`` opens as an octree: "folder" (is_octree_dir), "copc" (a file with the COPC
    info VLR, or an http(s) URL that is not EPT's), "ept" (an ept.json, its folder or their
    URL), or None (a file or folder of point cloud files; a COPC file whose hierarchy is cut
    off but whose points are whole: copc_file_kind's "laz")."""
    if as_url(path) is not None:
        return "ept" if ept_location(path) is not None else "copc"
    try:
        if is_octree_dir(path):
            return "folder"
        if ept_location(path) is not None:
            return "ept"
        return "copc" if copc_file_kind(path) == "copc" else None
    except (TypeError, OSError):
        return None


def is_lod_source(path) -> bool:
    """Opens as one octree (``open_octree``): an octree folder, a COPC file, an EPT dataset, a URL."""
    return lod_source_kind(path) is not None


def is_local_copc(path) -> bool:
    """A COPC file on disk: a LAZ 1.4 file too, whose points are each stored once (its nodes are
    chunks of it), so what reads point files one point at a time reads it as that LAZ file."""
    return as_url(path) is None and lod_source_kind(path) == "copc"


def refuse_octrees(paths, why: str) -> None:
    """A one-line InputError for the first of ``paths`` that is an octree a point file reader
    cannot read (a converted folder, an EPT dataset, a URL: each opens alone, as itself),
    ending in ``why``. A local COPC file passes: it is a LAZ file too."""
    for path in paths:
        kind = lod_source_kind(path)
        if kind is not None and not is_local_copc(path):
            what = {"folder": "a converted octree folder", "ept": "an EPT dataset"}.get(kind, "a URL")
            raise InputError(f"{shown_url(as_url(path) or path)}: {what} opens alone, drawn level of detail as stored; {why}")  # (a Path of a URL: http:/host)


def refuse_local_only_octree(folder_url: str) -> None:
    """A one-line InputError where the folder URL ``folder_url`` (no ept.json there) holds a
    Potree or gigapoint octree, which open from a local folder only: a Potree folder's URL was
    "…/ept.json: HTTP 404 Not Found". Asked only once ept.json is not found."""
    ept = open_source(ept_location(folder_url))
    try:
        for name, what in ((POTREE_META, "a Potree octree folder"), (GIGAPOINT_META, "a converted octree folder")):
            try:
                ept.sibling(name).read_head(1)
            except InputError:
                continue
            raise InputError(f"{shown_url(folder_url)}: {what} ({name}); Potree and converted octrees open from a local folder (over HTTP: COPC files and EPT datasets)")
    finally:
        ept.close()


def open_octree(path) -> OctreeCloud | PointCloud:
    """Open an octree for rendering: an OctreeCloud (gigapoint or Potree 2.0 folder; a COPC file
    or EPT dataset, local or an http(s) URL), or for an unfinished conversion its preview (a
    ConversionPreview, with a warning)."""
    from .class_counts import read_class_counts
    from .compact_octree import read_compact
    from .copc import open_copc
    from .ept import open_ept
    from .potree import read_potree
    from .preview import open_preview
    from .store import read_gigapoint, read_meta

    kind = lod_source_kind(path)
    if kind == "copc":
        url = as_url(path)
        try:
            parts = urlsplit(url) if url is not None else None
        except ValueError:  # 'http://[::1': the HTTP client says so, naming the URL
            parts = None
        if parts is None or "." in parts.path.rsplit("/", 1)[-1]:
            return open_copc(path)
        try:
            return open_copc(path)
        except HttpNotFound as exc:
            # no file there: an EPT folder given without its '/' (typer's Path drops it:
            # `gigapoint info https://host/ept/` asked for https://host/ept as a COPC file)
            folder = urlunsplit(parts._replace(path=parts.path + "/"))
            try:
                return open_ept(folder)
            except HttpNotFound:
                refuse_local_only_octree(folder)
                raise exc from None
    if kind == "ept":
        try:
            return open_ept(path)
        except HttpNotFound as exc:
            # '…/scan.copc.laz/': a file's URL with a '/' after it (no ept.json there); the CLI's
            # Path drops the '/' and opened the file while gp.open said ".../ept.json: HTTP 404"
            parts = urlsplit(as_url(path) or "")
            name = parts.path.rstrip("/").rsplit("/", 1)[-1]
            if parts.path.endswith("/") and "." not in name:
                refuse_local_only_octree(as_url(path))
            if not parts.path.endswith("/") or "." not in name:
                raise
            try:
                return open_copc(urlunsplit(parts._replace(path=parts.path.rstrip("/"))))
            except HttpNotFound:
                raise exc from None
    d = OctreeDir(path)
    if not d.path.is_dir():
        raise InputError(f"{d.path}: not a directory (an octree is a directory made by `gigapoint convert`)")
    kind = d.kind
    if kind == "gigapoint":
        meta = read_meta(d)
        cloud = read_compact(d, meta) if meta["version"] == FORMAT_VERSION else read_gigapoint(d, meta)
        cloud.class_counts = read_class_counts(d, cloud.nodes)  # (classes.npy: the same file whatever the layout)
        return cloud
    if kind == "potree":
        return read_potree(d)
    if kind == "unfinished":
        return open_preview(d)
    raise InputError(f"{d.path}: no {d.meta.name} or {d.potree_meta.name}: not a converted octree")


def open_filtered(path, keep: PointFilter, instead: str) -> OctreeCloud:
    """The octree at ``path`` (``open_octree``) drawing only the points ``keep`` keeps, level of
    detail (``OctreeCloud.read_only``: no point is read here); an EmptyCloudError where no node
    meets the filter's region, an unfinished conversion's preview (a sample of the points) a
    one-line InputError: ``instead``, what to do instead, ends it."""
    from .store import OctreeCloud
    from .voxel_octree import VoxelOctree

    octree = open_octree(path)
    if not isinstance(octree, OctreeCloud):
        raise InputError(f"{shown_url(path)}: an unfinished conversion; its preview holds a sample of the points: {instead}")
    octree.read_only(keep, shown_url(path))
    if not octree.meeting_read_filter()[0]:  # (the root's box holds every point)
        if isinstance(octree, VoxelOctree):  # (a URL's connections)
            octree.close()
        region = "no node of the octree meets the filter's region"
        raise EmptyCloudError(f"{shown_url(path)}: no point passes the filter ({keep.describe()}): {region}{keep.polygon_hint()}")
    return octree


def bytes_under(folder: Path) -> int:
    """The bytes of the files under ``folder``. A running conversion removes work files and folders
    meanwhile (`info OUT.copc.laz.work` said "built/g282.tmp: No such file or directory"): those
    count nothing (os.walk skips a folder gone before it is listed)."""
    total = 0
    for root, _, names in os.walk(folder):
        for name in names:
            try:
                total += os.stat(os.path.join(root, name)).st_size
            except FileNotFoundError:
                continue
    return total


def octree_info(path) -> dict:
    """What ``gigapoint info`` says about an octree folder (gigapoint or Potree 2.0) or an
    unfinished conversion: ``file_info``'s keys plus nodes, levels, sampler, spacing or
    conversion (OctreeDir.status), ``on_grid`` (False: its bounds are not values on the scale's
    grid, io.format_info prints them at the scale's decimals) and ``details``: {label: text}
    lines ready to print."""
    if lod_source_kind(path) in ("copc", "ept"):
        return _voxel_info(path)
    d = OctreeDir(path)
    p = d.path
    size = bytes_under(p)
    if not d.complete:
        s = d.status()
        return {
            "path": str(p),
            "format": "unfinished conversion",
            "point_count": int(s.get("points", 0)),
            "has_color": True,
            "attributes": s.get("attributes", []),
            "conversion": s,
            "file_size": size,
            "details": _conversion_details(s, d.resume_hint),
        }
    from .potree import PotreeCloud

    cloud = open_octree(p)
    lo, hi = cloud.bounds
    potree = isinstance(cloud, PotreeCloud)
    # the source's grid (a LAS input's; a Potree octree's metadata.json): bounds print at its decimals
    scale, offset = (cloud.scale.tolist(), cloud.offset.tolist()) if potree else (cloud.meta.get("scale"), None)
    attributes, crs = sorted(cloud.attributes), cloud.meta.get("crs")
    levels = int(cloud.nodes["level"].max()) + 1
    sampler, spacing = cloud.meta.get("sampler"), cloud.meta.get("spacing")
    text = f"{counted(len(cloud.keys), 'node')} in {counted(levels, 'level')}"
    text += (f", {sampler} sampler" if sampler else "") + (f", spacing {spacing:.6g}" if spacing else "")
    has_color = bool(cloud.meta.get("has_color", True))  # false: converted from points without colours (a folder older than the key: assumed)
    if potree:  # its nodes are decoded on demand: the metadata names what they hold (as gigapoint names them)
        attributes = list(cloud.extra)
        has_color = any(a["name"] == "rgb" for a in cloud.potree_attributes)  # (PotreeConverter --attributes intensity: none)
        source = cloud.meta.get("source_points")
        if isinstance(source, int) and 0 < source < cloud.n_points:
            text += f"; {cloud.n_points - source:,} of the points are copies of the metadata's {source:,} in inner nodes (PotreeConverter's poisson_average)"
    return {
        "path": str(p),
        "format": "Potree 2.0 octree" if potree else f"gigapoint octree {cloud.meta.get('version')}",
        "encoding": cloud.meta.get("encoding") if potree else None,
        "point_count": int(cloud.n_points),
        "bounds": {"min": np.asarray(lo).tolist(), "max": np.asarray(hi).tolist()},
        "has_color": has_color,
        "attributes": attributes,
        "crs": crs,
        "units": cloud_units(cloud),
        "scale": scale,
        "offset": offset,
        "on_grid": False,  # its positions are floats (reprojected ones on no grid): no more decimals than the scale's
        "nodes": len(cloud.keys),
        "levels": levels,
        "sampler": sampler,
        "spacing": spacing,
        "file_size": size,
        "details": {"octree": text} if potree else {"octree": text, "on disk": _bytes_a_point(d, cloud.n_points)},
    }


def _bytes_a_point(d: OctreeDir, n: int) -> str:
    """A gigapoint octree's files per point on disk, by what they hold (either format version)."""
    parts = {"positions": 0, "colour": 0, "attributes": 0, "nodes": 0}
    for f in d.path.glob("*.npy"):
        name = f.name.removesuffix(".npy").removeprefix("field.")
        kind = "attributes" if name.startswith("attr.") else "colour" if name in ("color", "rgba") else None
        kind = kind or ("positions" if name in ("low", "med", "high", "ext") else "nodes")
        parts[kind] += f.stat().st_size
    n = max(n, 1)
    return ", ".join(f"{k} {v / n:.2f}" for k, v in parts.items()) + f" bytes a point ({sum(parts.values()) / n:.2f} in all)"


def _voxel_info(path) -> dict:
    """``octree_info`` of a COPC file or EPT dataset: every hierarchy page read, no point."""
    cloud = open_octree(path)
    try:
        cloud.load_hierarchy()
        meta = cloud.meta
        lo, hi = cloud.bounds
        per_level = cloud.points_per_level()
        copc = meta["format"] == "copc"
        url = as_url(path)
        if url is not None:
            size = None
        elif copc:
            size = Path(path).stat().st_size
        else:  # the whole dataset: ept.json's folder
            size = bytes_under(Path(ept_location(path)).parent)
        details = {
            "octree": f"{counted(len(cloud.keys), 'node')} in {counted(len(per_level), 'level')}, {counted(cloud.pages_read, 'hierarchy page')}"
            + (f", spacing {meta['spacing']:.6g}" if meta.get("spacing") else ""),
            "per level": ", ".join(f"{lv}: {n:,}" for lv, n in enumerate(per_level)),
        }
        if "stated_points" in meta:  # the count is the nodes' (PDAL's bcbf EPT: ept.json says 10, its 5 nodes hold 1 each)
            said = "the LAS header" if copc else "ept.json"
            details["mismatch"] = f"the hierarchy's nodes hold {cloud.n_points:,} points, {said} says {meta['stated_points']:,}"
        return {
            "path": shown_url(url or path),  # (a URL's password and token not printed)
            "format": "COPC" if copc else f"EPT ({meta.get('data_type')})",
            "las_version": meta.get("las_version"),
            "point_format": meta.get("point_format"),
            "point_count": int(cloud.n_points),
            "bounds": {"min": np.asarray(lo).tolist(), "max": np.asarray(hi).tolist()},
            "has_color": (meta.get("point_format") or 0) >= 7 if copc else "Red" in (meta.get("schema") or []),
            "attributes": cloud.attribute_names,
            "scale": meta.get("scale"),
            "offset": meta.get("offset"),
            "crs": meta.get("crs"),
            "units": cloud_units(cloud),
            "generating_software": meta.get("generating_software"),
            "nodes": len(cloud.keys),
            "levels": len(per_level),
            "points_per_level": per_level,
            "spacing": meta.get("spacing"),
            "file_size": size,
            "details": details,
        }
    finally:
        cloud.close()


def _conversion_details(s: dict, hint: str) -> dict:
    total = f" of {s['total']:,}" if s.get("total") else ""
    lines = {
        "conversion": f"phase {s.get('phase') or '?'}, {s.get('points', 0):,}{total} points read, preview of {s.get('preview_points', 0):,} points"
    }
    if s.get("running") is not None:
        lines["state"] = "a conversion is writing into it" if s["running"] else f"stopped: {hint}"
    return lines


def _crs_source(cloud) -> tuple[str | None, tuple]:
    """(an octree's CRS, from its metadata: COPC, EPT, converted; the files a plain cloud or a
    progressive octree was read from, whose headers name theirs): where a cloud's CRS is told."""
    from ..core.renderable import PointSource
    from .store import OctreeCloud

    if isinstance(cloud, OctreeCloud):
        return cloud.meta.get("crs") or None, ()
    if isinstance(cloud, PointSource):
        return None, tuple(cloud.source_files)
    return None, ()


def cloud_crs(cloud) -> str | None:
    """The CRS a cloud's points are in, as its readers give it (WKT, or 'EPSG:n' of LAS GeoTIFF
    keys); None for any other (arrays, a live stream, other formats, files that name none)."""
    from ..io import files_crs

    crs, files = _crs_source(cloud)
    return files_crs(files) if files else crs


def cloud_units(cloud) -> dict:
    """io.crs_units of the cloud's CRS (a file's GeoTIFF unit keys too): what lengths measured in
    its coordinates are in; unknown for any other."""
    return cloud_crs_units(cloud)[1]


def cloud_crs_units(cloud) -> tuple[str | None, dict]:
    """(``cloud_crs``, ``cloud_units``) of a cloud, from one read of a file's header naming the CRS."""
    from ..io import crs_units, files_crs_units

    crs, files = _crs_source(cloud)
    return files_crs_units(files) if files else (crs, crs_units(crs))
