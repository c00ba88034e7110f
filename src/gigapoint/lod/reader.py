"""Opening an octree folder of any kind (octree_dir.py): a gigapoint octree (store.py), a
Potree 2.0 octree (potree.py) or an unfinished conversion, shown as its preview (preview.py);
and what ``gigapoint info`` says about one."""

from __future__ import annotations

import numpy as np

from ..core.cloud import PointCloud
from ..errors import InputError
from .octree_dir import FORMAT_VERSION, RESUME_HINT, OctreeDir
from .potree import read_potree
from .preview import open_preview
from .store import OctreeCloud, read_gigapoint


def is_octree_dir(path) -> bool:
    """A gigapoint or Potree 2.0 octree folder, or an unfinished conversion into one."""
    try:
        return OctreeDir(path).is_octree
    except (TypeError, OSError):
        return False


def open_octree(path) -> OctreeCloud | PointCloud:
    """Open an octree folder for rendering: an OctreeCloud (gigapoint or Potree 2.0), or for an
    unfinished conversion its preview (a ConversionPreview, with a warning)."""
    d = OctreeDir(path)
    if not d.path.is_dir():
        raise InputError(f"{d.path}: not a directory (an octree is a directory made by `gigapoint convert`)")
    kind = d.kind
    if kind == "gigapoint":
        return read_gigapoint(d)
    if kind == "potree":
        return read_potree(d)
    if kind == "unfinished":
        return open_preview(d)
    raise InputError(f"{d.path}: no {d.meta.name} or {d.potree_meta.name}: not a converted octree")


def octree_info(path) -> dict:
    """What ``gigapoint info`` says about an octree folder (gigapoint or Potree 2.0) or an
    unfinished conversion: ``file_info``'s keys plus nodes, levels, sampler, spacing or
    conversion (OctreeDir.status), and ``details``: {label: text} lines ready to print."""
    d = OctreeDir(path)
    p = d.path
    size = sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
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
            "details": _conversion_details(s),
        }
    cloud = open_octree(p)
    lo, hi = cloud.bounds
    potree = d.kind == "potree"
    levels = int(cloud.nodes["level"].max()) + 1
    sampler, spacing = cloud.meta.get("sampler"), cloud.meta.get("spacing")
    text = f"{len(cloud.keys):,} nodes in {levels} levels"
    text += (f", {sampler} sampler" if sampler else "") + (f", spacing {spacing:.6g}" if spacing else "")
    return {
        "path": str(p),
        "format": "Potree 2.0 octree" if potree else f"gigapoint octree {FORMAT_VERSION}",
        "encoding": cloud.meta.get("encoding") if potree else None,
        "point_count": int(cloud.n_points),
        "bounds": {"min": np.asarray(lo).tolist(), "max": np.asarray(hi).tolist()},
        "has_color": True,
        "attributes": sorted(cloud.attributes),
        "nodes": len(cloud.keys),
        "levels": levels,
        "sampler": sampler,
        "spacing": spacing,
        "file_size": size,
        "details": {"octree": text},
    }


def _conversion_details(s: dict) -> dict:
    total = f" of {s['total']:,}" if s.get("total") else ""
    lines = {
        "conversion": f"phase {s.get('phase') or '?'}, {s.get('points', 0):,}{total} points read, preview of {s.get('preview_points', 0):,} points"
    }
    if s.get("running") is not None:
        lines["state"] = "a conversion is writing into it" if s["running"] else f"stopped: {RESUME_HINT}"
    return lines
