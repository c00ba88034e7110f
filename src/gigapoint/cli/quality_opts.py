"""Image-quality options of `gigapoint render` (issue #5): generated from RenderSettings by cli/settings_opts.py."""

from __future__ import annotations

from ..errors import warnings_kept


def check_color_attribute(inputs, settings) -> None:
    """A --color-attribute that no input file has, told from the files' headers before any is
    read (``missing_attribute``'s line: it came once every input was read). Octrees, and files
    whose headers do not list their attributes, are checked once read, as before."""
    from ..io import cloud_name, point_files_of, reader_for
    from ..io._base import headers_once
    from ..lod import is_lod_source
    from ..render.colors import missing_attribute

    name = settings.color_attribute
    if settings.color_mode != "attribute" or not name or any(is_lod_source(p) for p in inputs):
        return
    with headers_once():  # (point_files_of read each header to skip empty files: read once)
        with warnings_kept():  # a file named twice is warned about once, when read (not here: kept, dropped)
            files = point_files_of(inputs)
        heads = [reader_for(f).header(f, salvage=True).get("attributes") for f in files]  # salvage: a cut-off file is drawn
    if None in heads or any(name in head for head in heads):
        return
    raise missing_attribute(cloud_name(files), name, set(heads[0]).intersection(*heads[1:]))  # a merge keeps the shared ones


def prepare_cloud(cloud, settings) -> None:
    """Estimate normals when lighting or the normal color mode needs them and the cloud has none
    (a plain cloud: an octree's points are not all in memory)."""
    from ..core.cloud import PointCloud  # (not at import: numba's kernels, which --help needs none of)

    if not (settings.lighting or settings.color_mode == "normal") or not isinstance(cloud, PointCloud):
        return
    from ..render.colors import normals_of

    if normals_of(cloud) is None:
        from ..render.normals import estimate_normals

        estimate_normals(cloud)
