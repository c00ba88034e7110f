"""The viewer's class toggles (Potree's classification filter): which LAS classes its Classes
panel lists, with their ASPRS names and the classification colour mode's colours.

A cloud in memory lists the classes it holds (counted once per version of its points); an
octree those its files list (a gigapoint octree's class counts, an EPT schema's counts, a
Potree histogram), else the ASPRS standard classes 0..18 (within the classification range its
metadata gives: a gigapoint octree's written before class counts), with those of the nodes
loaded so far and those hidden; an octree opened with a class filter lists only the classes it
keeps. A progressive octree lists the classes of the points added so far (counted as they come:
more as its loader brings others, complete once it is done). A cloud without classification
and a live cloud have the panel disabled, saying why; so has a progressive octree before its
first points (they fix its attributes), its panel not complete: the page asks again.
Unticking a class sets the ``hidden_classes`` render setting (the settings message).
"""

from __future__ import annotations

import numpy as np

from ..core.renderable import hidden_classes_refusal
from ..io.las_fields import STANDARD_CLASSES, class_name
from ..lod.class_counts import class_histogram
from ..render.cache import render_cache
from ..render.colors import classification_table


def held_classes(values) -> list[int]:
    """The distinct LAS classes (0..255) among ``values`` (a classification array)."""
    return np.flatnonzero(class_histogram(values)).tolist()  # (others cannot be hidden: parse_classes)


def entries(codes) -> list[dict]:
    """{code, name, color ('#rrggbb', as the classification colour mode draws it)} of each class."""
    table = classification_table()
    return [{"code": c, "name": class_name(c), "color": "#" + bytes(table[c, :3].tolist()).hex()} for c in sorted(codes)]


def refusal(cloud) -> str:
    """Why ``cloud`` hides no class, in one line ("" where it can): a live cloud's refusal, or a
    cloud without classification. The panel is disabled with it; settings that hide
    classes are refused with it."""
    from ..live import LiveCloud

    if isinstance(cloud, LiveCloud):
        return hidden_classes_refusal(cloud.name, cloud.KIND)
    if awaiting_first_points(cloud):  # (it was said to have no classification, as if for good)
        return f"hidden_classes: {cloud.name}'s first points are not in yet; its classes are listed once they are"
    if "classification" not in cloud.attribute_names:
        return f"hidden_classes: {cloud.name} has no classification attribute, so no class to hide"
    return ""


def awaiting_first_points(cloud) -> bool:
    """Whether ``cloud`` is a progressive octree loading whose first points are not in: they fix
    its attributes (none before them), so whether it can hide classes is not known yet. (By its
    points: a file of x, y, z alone has no attribute once they are in either.)"""
    from ..lod.progressive import ProgressiveOctree

    return isinstance(cloud, ProgressiveOctree) and cloud.loading and cloud.n_points == 0


def class_panel(cloud, hidden=(), seen: bool = True) -> dict:
    """The Classes panel of ``cloud`` (protocol.py's "classes" reply): enabled, reason, source,
    complete, classes. ``hidden``: the classes hidden now (an octree's list keeps them, so they
    can be ticked again); ``seen``: an octree's list takes in the classes of its resident nodes
    (False while a frame may be loading them)."""
    from ..core import PointCloud
    from ..lod.progressive import ProgressiveOctree
    from ..lod.store import OctreeCloud

    awaiting = awaiting_first_points(cloud)  # (read before the refusal: its points may come in between)
    reason = refusal(cloud)
    if reason:  # not complete while awaiting: the page asks again, and the panel enables itself once classes come
        return {"enabled": False, "reason": reason, "source": "none", "complete": not awaiting, "classes": []}
    if isinstance(cloud, PointCloud):
        cache = render_cache.arrays(cloud)  # (per version of its points: an edit counts again)
        if "__classes__" not in cache:
            cache["__classes__"] = held_classes(cloud.attributes["classification"])
        return {"enabled": True, "reason": "", "source": "cloud", "complete": True, "classes": entries(cache["__classes__"])}
    if isinstance(cloud, ProgressiveOctree):  # counted as its points come: complete once they all have
        return {"enabled": True, "reason": "", "source": "cloud", "complete": not cloud.loading, "classes": entries(cloud.class_facts().get("classes", []))}  # ({} where the loader dropped the attribute meanwhile)
    facts = cloud.class_facts() if isinstance(cloud, OctreeCloud) else {}
    if "classes" in facts:
        return {"enabled": True, "reason": "", "source": "metadata", "complete": True, "classes": entries(filter_kept(cloud, facts["classes"]))}
    lo, hi = facts.get("class_range", (0, 255))
    codes = {c for c in STANDARD_CLASSES if lo <= c <= hi} | set(hidden)
    if "class_range" in facts:
        codes.add(lo)  # (the lowest class is held; the highest only bounds them)
    arena = cloud.arena if isinstance(cloud, OctreeCloud) else None
    if seen and arena is not None:
        values = arena.resident_classification()
        codes |= set(held_classes(values if values is not None else []))
    return {"enabled": True, "reason": "", "source": "standard", "complete": False, "classes": entries(filter_kept(cloud, codes))}


def filter_kept(cloud, codes) -> list[int]:
    """Those of ``codes`` an octree's read filter keeps (opened with ``classes=`` or
    ``drop_classes=``): the others are never loaded, so their toggles would do nothing."""
    from ..lod.store import OctreeCloud

    keep = cloud.read_filter if isinstance(cloud, OctreeCloud) else None
    return [c for c in codes if keep is None or keep.keeps_class(c)]
