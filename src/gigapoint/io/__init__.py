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

# Imported on first use (PEP 562): the readers' and the cloud's kernels (numba) are needed by
# none of ``gigapoint info``'s header reads, nor by ``import gigapoint`` (core/hooks.py).
_LAZY = {
    "DEFAULT_CHUNK_SIZE": "_base",
    "Reader": "_base",
    "check_chunk_size": "_base",
    "headers_once": "_base",
    "EPSG_LENGTH_UNITS": "crs",
    "crs_units": "crs",
    "crs_wkt": "crs",
    "files_crs": "crs",
    "files_crs_units": "crs",
    "files_units": "crs",
    "horizontal_epsg": "crs",
    "vertical_crs": "crs",
    "warn_mixed_crs": "crs",
    "demo_arrays": "demo",
    "demo_chunks": "demo",
    "PointFilter": "filters",
    "filtered": "filters",
    "shown_url": "http",
    "file_info": "info",
    "folder_info": "info",
    "format_info": "info",
    "format_stats": "info",
    "human_bytes": "info",
    "point_stats": "info",
    "with_scan_angle": "las",
    "READ_SUBFOLDERS": "paths",
    "URL_LIKE": "paths",
    "cloud_name": "paths",
    "expand_paths": "paths",
    "file_names": "paths",
    "file_url_path": "paths",
    "files_label": "paths",
    "files_with_points": "paths",
    "given_paths": "paths",
    "lone_match": "paths",
    "pattern_matches": "paths",
    "point_files_of": "paths",
    "scan_angles_differ": "paths",
    "with_subfolders": "paths",
    "reader_for": "registry",
    "readers": "registry",
    "register": "registry",
    "supported_suffixes": "registry",
    "PointStats": "stats",
    "file_stats": "stats",
    "read_chunks": "opening",
    "open_cloud": "opening",
}


from ..core.hooks import lazy_names

__getattr__ = lazy_names(__name__, _LAZY)


__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "EPSG_LENGTH_UNITS",
    "READ_SUBFOLDERS",
    "URL_LIKE",
    "PointStats",
    "Reader",
    "cloud_name",
    "crs_units",
    "crs_wkt",
    "demo_arrays",
    "demo_chunks",
    "expand_paths",
    "file_info",
    "file_names",
    "file_stats",
    "file_url_path",
    "files_crs",
    "files_crs_units",
    "files_label",
    "files_units",
    "files_with_points",
    "folder_info",
    "format_info",
    "format_stats",
    "given_paths",
    "horizontal_epsg",
    "human_bytes",
    "lone_match",
    "open_cloud",
    "pattern_matches",
    "point_files_of",
    "point_stats",
    "read_chunks",
    "reader_for",
    "readers",
    "register",
    "shown_url",
    "supported_suffixes",
    "vertical_crs",
    "warn_mixed_crs",
    "with_subfolders",
]
