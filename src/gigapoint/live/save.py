"""Writing a live cloud's accumulated snapshots: LAS/LAZ or PLY (io/write.py, as a cloud's save), or an octree folder."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import InputError
from ..io.registry import is_supported_name
from ..io.write import POINT_FILE_SUFFIXES, check_point_file_output, write_points
from ..lod.kinds import is_copc_name


def save_snapshots(octree, path, overwrite: bool = False, has_color: bool = True) -> int:
    """Write every point of the snapshot octree to ``path`` (its suffix picks the format:
    .las, .laz, .ply, .copc.laz (the octree as COPC); a name without a point file's suffix a
    gigapoint octree folder). ``has_color``: the output gets colours (False: frames pushed without
    colours, whose grey is no colour of theirs: a point file without RGB, a COPC file in point
    format 6, an octree folder saying so, as ``convert`` writes colourless files). Returns the points written."""
    if not isinstance(path, (str, os.PathLike)) or not os.fspath(path):  # 5: a TypeError; "": an octree in the current folder
        raise InputError(f"save: the output must be a path (.las, .laz, .ply or an octree folder), got {path!r}")
    path = Path(path)
    suffix = path.suffix.lower()
    if is_copc_name(path):  # a COPC file (the octree's, convert's default for the name), not a plain LAZ under its name
        return int(octree.save(path, overwrite=overwrite, has_color=has_color).points)
    if suffix not in POINT_FILE_SUFFIXES and is_supported_name(path):  # "scan.xyz" was an octree folder of that name
        raise InputError(f"{path}: save writes .las, .laz or .ply files, an octree folder or a .copc.laz file, not {suffix}")  # (as convert says)
    if suffix not in POINT_FILE_SUFFIXES:
        return int(octree.save(path, overwrite=overwrite, has_color=has_color).points)
    check_point_file_output(path, overwrite)
    return write_points(path, octree.chunks, octree.n_points, has_color=has_color)  # (chunk by chunk: no joined copy of every snapshot)
