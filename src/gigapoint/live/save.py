"""Writing a live cloud's accumulated snapshots: LAS/LAZ (laspy, lazrs), PLY (plyfile), or an octree folder."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..atomic import atomic_write, write_failure
from ..core.chunk import join_chunks
from ..errors import InputError, first_line
from ..io.registry import is_supported_name
from ..lod.copc_write import is_copc_name


def _collect(octree):
    points = join_chunks(list(octree.chunks()))
    return points.xyz, points.rgba, points.attributes


def save_snapshots(octree, path, overwrite: bool = False) -> int:
    """Write every point of the snapshot octree to ``path`` (its suffix picks the format:
    .las, .laz, .ply, .copc.laz (the octree as COPC); a name without a point file's suffix a
    gigapoint octree folder). Returns the points written."""
    if not isinstance(path, (str, os.PathLike)) or not os.fspath(path):  # 5: a TypeError; "": an octree in the current folder
        raise InputError(f"save: the output must be a path (.las, .laz, .ply or an octree folder), got {path!r}")
    path = Path(path)
    suffix = path.suffix.lower()
    if is_copc_name(path):  # a COPC file (the octree's, convert's default for the name), not a plain LAZ under its name
        return int(octree.save(path, overwrite=overwrite).points)
    if suffix not in (".las", ".laz", ".ply") and is_supported_name(path):  # "scan.xyz" was an octree folder of that name
        raise InputError(f"{path}: save writes .las, .laz or .ply files, or an octree folder (a name without a point file's suffix)")
    if suffix not in (".las", ".laz", ".ply"):
        return int(octree.save(path, overwrite=overwrite).points)
    if path.is_dir():  # overwrite=True was os.replace's IsADirectoryError: a folder is never replaced by a file
        raise InputError(f"{path}: is a directory, not a {suffix[1:].upper()} file; not replaced")
    if path.exists() and not overwrite:
        raise InputError(f"{path}: exists; pass overwrite=True to replace it")
    if not path.parent.is_dir():
        raise InputError(f"{path}: the folder {path.parent} does not exist")
    xyz, rgba, attrs = _collect(octree)
    from lazrs import LazrsError

    try:
        if suffix == ".ply":
            _write_ply(path, xyz, rgba, attrs)
        else:
            _write_las(path, xyz, rgba, attrs)
    except (OSError, LazrsError) as exc:  # a full disk: lazrs said "IoError: Failed to call write", naming no file, not an OSError
        reason = write_failure(exc) if isinstance(exc, OSError) else first_line(exc)
        raise InputError(f"{path}: not written ({reason}); nothing was left there") from None
    return len(xyz)


def _write_ply(path: Path, xyz, rgba, attrs) -> None:
    from plyfile import PlyData, PlyElement

    fields = [("x", "f8"), ("y", "f8"), ("z", "f8"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    fields += [(a, _ply_type(path, a, v)) for a, v in attrs.items()]
    data = np.empty(len(xyz), fields)
    for k, a in enumerate("xyz"):
        data[a] = xyz[:, k]
    for k, a in enumerate(("red", "green", "blue")):
        data[a] = rgba[:, k]
    for a, v in attrs.items():
        data[a] = v
    ply = PlyData([PlyElement.describe(data, "vertex")])
    atomic_write(path, lambda tmp: ply.write(str(tmp)))


def _ply_type(path: Path, name: str, values: np.ndarray) -> str:
    """The PLY type that holds an attribute exactly: PLY has no 64-bit integers, half floats or
    booleans (plyfile refused them with a ValueError traceback, numpy's default int64 among
    them), so 64-bit integers go to 32 bits when every value fits, and are refused otherwise."""
    dt = values.dtype
    if dt == np.bool_:
        return "u1"
    if dt.kind == "f":
        return "f8" if dt.itemsize == 8 else "f4"
    if dt.itemsize < 8:
        return dt.str
    for narrow in ("i4", "u4"):
        info = np.iinfo(narrow)
        if not len(values) or (int(values.min()) >= info.min and int(values.max()) <= info.max):
            return narrow
    far = values[np.argmax(np.abs(values.astype(np.float64)))].item()
    raise InputError(f"{path}: attribute {name!r} holds {dt} values PLY cannot hold (it has no 64-bit integers), e.g. {far}; save as .las, .laz or an octree folder")


def _write_las(path: Path, xyz, rgba, attrs) -> None:
    """Point format 7 (8 with ``nir``), LAS 1.4: attributes the format has a field for go to
    it, clipped to its range as the COPC writer does (they were added as extra bytes under the
    field's own name, which laspy refused: "field 'intensity' occurs more than once"); others
    as extra bytes (lod/copc_write.extra_attributes: booleans as u8, half floats as f4)."""
    import laspy

    from ..lod.copc import field_attributes
    from ..lod.copc_write import LAS_FIELD_OF, choose_point_format, extra_attributes, las_field_values
    from ..lod.grid import las_grid

    fmt = choose_point_format(attrs)
    header = laspy.LasHeader(point_format=fmt, version="1.4")
    # a millimetre grid at most, finer for a small scene, coarser where 32-bit integers need it
    # (a fixed millimetre overflowed them past 2 147 km, and cut a 10 cm object to 100 steps)
    header.scales, header.offsets = las_grid(xyz.min(axis=0), xyz.max(axis=0))
    extra = extra_attributes({a: v.dtype for a, v in attrs.items()}, where=str(path), point_format=fmt)
    for a, dt in extra.items():
        header.add_extra_dim(laspy.ExtraBytesParams(name=a, type=dt))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.red, las.green, las.blue = (rgba[:, k].astype(np.uint16) * 257 for k in range(3))
    for a, v in attrs.items():
        if a in field_attributes(fmt):
            las[LAS_FIELD_OF.get(a, a)] = las_field_values(a, v).astype(las[LAS_FIELD_OF.get(a, a)].dtype)
        elif a in extra:
            las[a] = v.astype(extra[a])

    def write(tmp: Path) -> None:
        las.write(str(tmp), do_compress=path.suffix.lower() == ".laz")

    atomic_write(path, write)
