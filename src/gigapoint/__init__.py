"""gigapoint: render massive point clouds fast, from Python, by software rasterization."""

from __future__ import annotations

from .core import hooks as _hooks
from .errors import GigapointError, GigapointWarning
from .io import registry as _registry


def _set_up_numba() -> None:
    """numba set up for gigapoint's kernels, once numba is imported (before any kernel is defined
    or runs): kernels numba cannot cache compile in memory (core/kernel_cache.py); TBB from its
    wheel, else OpenMP (core/threads.py). ``import gigapoint`` imported numba to do it at once
    (~0.3 s): ``gigapoint --help`` and ``info`` of a LAS file need no kernel."""
    from .core.kernel_cache import compile_where_uncachable
    from .core.threads import choose_threading_layer

    choose_threading_layer()
    compile_where_uncachable()


_hooks.on_numba_import(_set_up_numba)  # now where numba is imported already (its layer not yet loaded: it is kept)


def _wire() -> None:
    """What the lower layers look up but cannot import (core/hooks.py ``wire``, on first use):
    the cpu and wgpu backends (render.backend), PointCloud.save's writer (io/write.py)."""
    from . import backends  # noqa: F401
    from .io import write  # noqa: F401


_hooks.register_wiring(_wire)


def _is_octree(path) -> bool:
    """lod's test of an octree, for io's folder walks (io cannot import lod). Registered here,
    as every import of gigapoint runs this first: registered by lod/reader.py, a walk before
    anything imported gigapoint.lod (``render --recursive``, ``io.expand_paths``) read a
    conversion's .npy arrays beside the tiles as points. lod is imported on the first test."""
    from .lod.reader import is_lod_source

    return is_lod_source(path)


_registry.register_dataset_folder(_is_octree)


def _dataset_part(path) -> str | None:
    """lod's word on a file that is part of an octree (a Potree octree's octree.bin), for io's
    reader choice: it was "unknown point cloud format"."""
    from .lod.kinds import potree_part

    return potree_part(path)


_registry.register_dataset_part(_dataset_part)

# the subpackage loaded now (cheap: its names are lazy), so that no later import of it makes
# ``gigapoint.render`` the package: it is the function (``_LAZY``), as it was
import importlib as _importlib

_importlib.import_module(f"{__name__}.render")  # (``from . import render`` would ask __getattr__ for the function)
del globals()["render"]  # (the import bound the package to the name)

__version__ = "0.1.0"


def demo(
    n_points: int = 1_000_000,
    seed: int = 0,
    progressive: bool = False,
    memory_limit: int | None = None,
    scale: float | None = 0.01,
    chunked: bool | None = None,
    attributes: bool = True,
    colors: str = "auto",
):
    """The procedural demo scene (terrain, roads, river, buildings, trees) as a PointCloud;
    ``progressive=True``: a ProgressiveOctree returned at once and filled in the background
    (stopping at ``memory_limit`` bytes, by default half the machine's memory).

    ``scale``: positions rounded to a grid of that step in metres (by default 0.01, as a LAS
    export of the town would be), held in the compact layout, exact at that scale (~5-7 bytes a
    point of position and colour instead of 16); None: the generator's float positions, held in
    three 32-bit words a point. ``chunked``: built in bounded memory (core/chunked.py: the same cloud,
    array for array, holding only the finished arrays and one partition of ~4 M points; the
    points go through a temporary folder, ~30 bytes a point of disk); None: chunked above
    50 M points. 10⁹ points at ``scale=0.01`` hold ~9 GB (``attributes=False``: ~6 GB, without
    the intensity and classification). ``colors``: how colours are held (``core.build_cloud``:
    "auto", "rgba", "rgb565" or "palette")."""
    from .errors import InputError, check_switch, check_whole, is_real
    from .io.demo import check_seed, demo_chunks

    n_points = check_whole("demo", "n_points", n_points, 1)  # 0 or -5: "no valid points"
    check_seed("demo", seed)
    for switch, value in (("progressive", progressive), ("attributes", attributes)):  # "no" was taken as true
        check_switch(switch, value, "demo")
    check_switch("chunked", chunked, "demo", allow_none=True)
    if scale is not None and not (is_real(scale) and 1e-6 <= scale <= 1000):
        raise InputError(f"demo: scale must be None (float positions) or a grid step between 1e-6 and 1000 metres, got {scale!r}")
    if progressive:
        from .lod.progressive import demo_sources, open_progressive

        # the octree's loader takes none of these: each was dropped without a word (as gp.open refuses them)
        dropped = [name for name, kept in (("scale", scale == 0.01), ("chunked", chunked is None), ("attributes", attributes is True), ("colors", colors == "auto")) if not kept]
        if dropped:
            raise InputError(f"demo(progressive=True) takes memory_limit= only, not {', '.join(dropped)}")
        return open_progressive(*demo_sources(n_points, seed), memory_limit=memory_limit)
    if memory_limit is not None:  # (dropped without a word: the limit of a progressive octree's loading)
        raise InputError("demo: memory_limit= goes with progressive=True (where loading stops); a PointCloud is built whole")
    name = f"demo({n_points:,})"
    from .core.chunked import CHUNKED_ABOVE, HELD_BYTES_MIN, IN_MEMORY_BYTES_MIN, SPILLED_BYTES_MIN, build_cloud_chunked, check_room

    instead = ": take fewer points, or progressive=True (an LOD octree filled up to a memory limit)"
    if chunked or (chunked is None and n_points > CHUNKED_ABOVE):
        check_room(name, n_points, HELD_BYTES_MIN, SPILLED_BYTES_MIN, instead=instead)
        source = lambda: demo_chunks(n_points, seed, chunk_size=2_000_000, scale=scale)
        return build_cloud_chunked(source, name=name, attributes=attributes, colors=colors)
    from .core import build_cloud

    check_room(name, n_points, IN_MEMORY_BYTES_MIN, instead=instead)
    chunks = demo_chunks(n_points, seed, scale=scale)
    if not attributes:
        from .core.chunk import PointChunk

        chunks = (PointChunk(c.xyz, c.rgba, scale=c.scale) for c in chunks)
    return build_cloud(chunks, name=name, colors=colors)


def _flat_paths(paths, where: str) -> tuple:
    """Paths with lists and tuples of them (at any depth) spread out, in order; anything else
    that is not a path (None, a number, an array) a one-line InputError naming it (``io.given_paths``)."""
    from .io import given_paths

    one_list = len(paths) == 1 and isinstance(paths[0], (list, tuple))  # gp.open([a, 5]): "paths[1]: 5 is not a path"
    return tuple(given_paths(paths[0] if one_list else paths, where, "paths"))


def open(*paths, progressive: bool = False, **options):
    """Read one or more files or directories (LAS/LAZ/PLY/E57/XYZ/XYZRGB/TXT/CSV/PTS/ASC/NPY/NPZ) into one PointCloud.

    One octree opens as an OctreeCloud drawn level of detail: a converted directory (gigapoint
    or Potree 2.0), a COPC file (``.copc.laz``, told by its COPC info VLR) or an EPT dataset
    (``ept.json`` or its folder), local or an ``http(s)://`` URL (read by range requests).

    ``progressive=True``: files open as a ProgressiveOctree, returned at once and filled by a
    background loader (``cloud.progress``, ``cloud.wait()``, which raises its error and issues its
    warnings, also listed in ``cloud.warnings``); it draws what is there at any moment (SimLOD). Loading stops with a one-line MemoryLimitError once the octree holds
    ``memory_limit=`` bytes or '8G' (by default half the machine's memory); what was loaded stays.

    A folder is read without its subfolders (``raw/`` and ``classified/`` copies of the same tiles
    would be read twice); ``recursive=True`` reads every point file below it, depth first in name
    order (hidden folders and octrees left out).

    A glob pattern (``"tiles/*.laz"``, ``"city/**/*.laz"`` at any depth) stands for the files and
    folders it matches, in name order (``io.pattern_matches``); a file of that very name is read as itself.

    Only some points are read with ``classes=[2, 6]`` (those LAS classes), ``drop_classes=[7, 18]``
    (all but those: noise) and ``clip=(xmin, ymin, xmax, ymax)`` (any z) or ``(xmin, ymin, zmin,
    xmax, ymax, zmax)``, in the files' coordinates, bounds included, and ``corridor=(x1, y1, x2, y2,
    width)``: within width / 2 of the line (x1, y1)-(x2, y2) and between its ends, any z (what
    ``gigapoint.section`` draws), and ``clip_polygon=`` a GeoJSON or WKT file, WKT text or a
    GeoJSON geometry dict: inside its polygons, holes left out, edges included, any z
    (io/polygon.py); a point must pass all those given. One octree given them opens as the
    OctreeCloud drawing only the points they keep, level of detail: frames skip the nodes that
    do not meet them and filter the others' points as they load (no point is read whole).

    Paths may also come as one list or tuple: ``gp.open([a, b])`` is ``gp.open(a, b)``."""
    from .io._base import headers_once

    with headers_once():  # one operation: its steps (patterns, folders, headers) each read once, the loader's thread too
        return _open(paths, progressive, options, "open")


def open_for(where: str, *paths, **options):
    """``open`` for an operation that reads its paths through it (section, orthophoto, volume,
    change): its errors name ``where`` ("section: no point file given: only octrees matched" was "open: ...")."""
    from .io._base import headers_once

    with headers_once():
        return _open(paths, False, options, where)


def _open(paths: tuple, progressive: bool, options: dict, where: str):
    from .errors import InputError, check_switch
    from .io import lone_match
    from .io.filters import point_filter
    from .lod.kinds import refuse_unwritten_copc
    from .lod.reader import refuse_octrees

    paths = tuple(lone_match(_flat_paths(paths, where)))  # (a pattern matching one octree opens it)
    refuse_unwritten_copc(paths)
    check_switch("progressive", progressive, where)  # (chunked= is open_cloud's to check)
    recursive = options.pop("recursive", False)
    check_switch("recursive", recursive, where)
    keep = point_filter(options.pop("classes", None), options.pop("drop_classes", None), options.pop("clip", None), where, corridor=options.pop("corridor", None),
                        clip_polygon=options.pop("clip_polygon", None))  # fmt: skip
    if recursive:
        from .io import with_subfolders

        paths = tuple(with_subfolders(paths))
    if progressive:
        from .io._base import headers_once
        from .lod.progressive import file_sources, memory_limit_bytes, open_progressive

        refuse_octrees(paths, "progressive=True builds an octree from point files")

        memory_limit = options.pop("memory_limit", None)
        if options:
            raise InputError(f"open(progressive=True) takes memory_limit= only, not {', '.join(sorted(options))}")
        memory_limit = memory_limit_bytes(memory_limit)  # checked before any file is read
        with headers_once():  # each file's header read once: by file_sources, then by the loader thread (it takes them along)
            return open_progressive(*file_sources(paths, point_filter=keep), memory_limit=memory_limit, point_filter=keep)
    if len(paths) == 1 and not options:
        from .lod import is_lod_source, open_octree
        from .lod.reader import open_filtered

        if is_lod_source(paths[0]):  # (with a filter: its nodes filtered as frames load them)
            return open_octree(paths[0]) if keep is None else open_filtered(paths[0], keep, "open the point files, or wait for the octree")
    refuse_octrees(paths, f"it takes no options ({', '.join(sorted(options))})" if len(paths) == 1 else "it cannot join other files")
    import inspect

    from .io import open_cloud

    known = [p for p in inspect.signature(open_cloud).parameters if p not in ("paths", "point_filter", "where")]
    unknown = sorted(set(options) - set(known))
    if unknown:  # a TypeError naming the internal open_cloud() before
        raise InputError(
            f"{where}: unknown option(s) {', '.join(unknown)}; it takes {', '.join(known)}, recursive=True, "
            "progressive=True (with memory_limit=), classes=, drop_classes=, clip=, corridor=, clip_polygon="
        )

    return open_cloud(*paths, point_filter=keep, where=where, **options)


# Imported on first use (PEP 562): numba and the kernels for most (``import gigapoint`` took
# ~0.4-1 s, and every CLI command paid it), heavier packages for some (Starlette/uvicorn,
# imageio, scipy).
_LAZY = {
    "PointChunk": ("gigapoint.core.chunk", "PointChunk"),
    "PointCloud": ("gigapoint.core.cloud", "PointCloud"),
    "from_arrays": ("gigapoint.core.cloud", "from_arrays"),
    "demo_arrays": ("gigapoint.io.demo", "demo_arrays"),
    "Camera": ("gigapoint.render.camera", "Camera"),
    "Frame": ("gigapoint.render.frame", "Frame"),
    "RenderSettings": ("gigapoint.render.settings", "RenderSettings"),
    "RenderStats": ("gigapoint.render.frame", "RenderStats"),
    "render": ("gigapoint.render.renderer", "render"),
    "render_frame": ("gigapoint.render.renderer", "render_frame"),
    "Viewer": ("gigapoint.viewer.jupyter", "Viewer"),
    "render_turntable": ("gigapoint.render.video", "render_turntable"),
    "render_flythrough": ("gigapoint.render.video", "render_flythrough"),
    "estimate_normals": ("gigapoint.render.normals", "estimate_normals"),
    "convert": ("gigapoint.lod.convert", "convert"),
    "LiveCloud": ("gigapoint.live", "LiveCloud"),
    "section": ("gigapoint.survey.section", "section"),
    "tile": ("gigapoint.lod.convert.tiles", "tile"),
    "Section": ("gigapoint.survey.section", "Section"),
    "change": ("gigapoint.survey.change", "change"),
    "Change": ("gigapoint.survey.change", "Change"),
    "classify_ground": ("gigapoint.survey.ground", "classify_ground"),
    "orthophoto": ("gigapoint.survey.orthophoto", "orthophoto"),
    "Orthophoto": ("gigapoint.survey.orthophoto", "Orthophoto"),
    "classify_noise": ("gigapoint.survey.noise", "classify_noise"),
    "height_above_ground": ("gigapoint.survey.heights", "height_above_ground"),
    "volume": ("gigapoint.survey.volume", "volume"),
    "Volume": ("gigapoint.survey.volume", "Volume"),
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value  # (looked up once)
        return value
    raise AttributeError(f"module 'gigapoint' has no attribute {name!r}")


def __dir__():
    """The public names and the subpackages loaded: tab completion offered none of the lazy
    names (gp.Viewer, gp.convert, ...) but ``annotations`` and ``choose_threading_layer``."""
    import types

    return sorted({*__all__, *(n for n, v in globals().items() if isinstance(v, types.ModuleType) and not n.startswith("_"))})


__all__ = [
    "Camera",
    "Change",
    "Frame",
    "GigapointError",
    "GigapointWarning",
    "LiveCloud",
    "Orthophoto",
    "PointChunk",
    "PointCloud",
    "RenderSettings",
    "RenderStats",
    "Section",
    "Viewer",
    "Volume",
    "__version__",
    "change",
    "classify_ground",
    "classify_noise",
    "convert",
    "demo",
    "demo_arrays",
    "estimate_normals",
    "from_arrays",
    "height_above_ground",
    "open",
    "orthophoto",
    "render",
    "render_flythrough",
    "render_frame",
    "render_turntable",
    "section",
    "tile",
    "volume",
]
