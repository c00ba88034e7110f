"""Spill files: the read phase's raw input chunks (``OctreeDir.raw``); the partitions' files
are filled by ``atomic.append_file``."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from numba import njit

from ...atomic import atomic_npy
from ...io.registry import reader_for


def _raw_path(raw: Path, i: int, key: str) -> Path:
    return raw / f"c{i:06d}.{key}.npy"


# Positions as a LAS file stores them: int32 X, Y, Z (12 bytes a point instead of 24) and the
# file's scale and offset, from which decode_xyz gives back the float64 positions bit for bit
# (encode_xyz checks every point). The distributed conversion spills and distributes them so
# (lod/convert/distributed.py): every byte written goes into page cache that is new, which
# costs a host fault a page on a VM (docs/scale.md).


@njit(inline="always")
def _decoded(v, scale, offset):
    return v * scale + offset  # as io/las.py's _scaled_xyz: float64(int32) * scale + offset


@njit(cache=True)
def _encode_xyz(flat, scale, offset, out):
    """``flat``: x, y, z, x, ... (float64); False when a value does not come back exactly (no
    early exit: the loop stays vectorized, ~3 ns a point)."""
    ok = True
    inv0, inv1, inv2 = 1.0 / scale[0], 1.0 / scale[1], 1.0 / scale[2]
    for i in range(flat.shape[0] // 3):
        for a in range(3):
            inv = inv0 if a == 0 else (inv1 if a == 1 else inv2)
            x = flat[3 * i + a]
            q = min(max(np.rint((x - offset[a]) * inv), -2147483648.0), 2147483647.0)
            v = np.int32(q)
            d = _decoded(v, scale[a], offset[a])
            ok &= (d == x) & (math.copysign(1.0, d) == math.copysign(1.0, x))  # the sign too: -0.0
            out[3 * i + a] = v
    return ok


@njit(cache=True)
def _decode_xyz(flat, scale, offset, out):
    for i in range(flat.shape[0] // 3):
        for a in range(3):
            out[3 * i + a] = _decoded(flat[3 * i + a], scale[a], offset[a])


def las_xyz_code(path) -> np.ndarray | None:
    """A LAS/LAZ file's integer grid as ``encode_xyz`` takes it: [scale x, y, z, offset x, y, z]
    (from its header); None for a file of another format."""
    head = reader_for(path).header(path)
    if head.get("scale") is None or head.get("offset") is None:
        return None
    return np.array([*head["scale"], *head["offset"]], np.float64)


def encode_xyz(xyz: np.ndarray, code: np.ndarray) -> np.ndarray | None:
    """float64 positions (n, 3) as int32 under ``code`` ([scale x, y, z, offset x, y, z]), or
    None when one of them is not exactly ``int * scale + offset`` (decode_xyz would differ)."""
    out = np.empty(xyz.shape, np.int32)
    code = np.asarray(code, np.float64)
    if len(xyz) and not _encode_xyz(np.ascontiguousarray(xyz, np.float64).reshape(-1), code[:3], code[3:], out.reshape(-1)):
        return None
    return out


def decode_xyz(ints: np.ndarray, code: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """int32 positions (n, 3) under ``code`` back to float64 (into ``out``, C-contiguous, when given)."""
    out = np.empty(ints.shape, np.float64) if out is None else out
    if not out.flags.c_contiguous:
        raise ValueError("decode_xyz: out must be C-contiguous")
    code = np.asarray(code, np.float64)
    if len(ints):
        _decode_xyz(np.ascontiguousarray(ints, np.int32).reshape(-1), code[:3], code[3:], out.reshape(-1))
    return out


def one_value(values: np.ndarray):
    """The value every entry of 1-D ``values`` holds, bit for bit (-0.0 is not 0.0), as a numpy
    scalar of their dtype; None where they differ, are empty or NaN, or are not numbers."""
    if not len(values) or values.dtype.kind not in "biuf" or values.dtype.itemsize not in (1, 2, 4, 8):
        return None
    first = values[0]
    if values.dtype.kind == "f" and np.isnan(first):  # (a NaN's payload would not survive the state's JSON)
        return None
    bits = np.ascontiguousarray(values).view(f"u{values.dtype.itemsize}")
    return None if np.any(bits != bits[0]) else first


def save_raw_chunk(raw: Path, i: int, xyz: np.ndarray, rgba: np.ndarray, attributes: dict, xyz_code: np.ndarray | None = None) -> None:
    """Chunk ``i``'s valid points: xyz (n, 3), u32 RGBA and 1-D attributes, a file each. xyz:
    float64, or int32 under ``xyz_code`` (encode_xyz), saved beside it. An attribute given as a
    numpy scalar (its one value: read.spill_chunk finds them) is saved as that value alone
    (``const.<name>``): a LAS file's flags, its user_data, ... are ~7 bytes a point of zeros."""
    if xyz_code is not None:
        atomic_npy(_raw_path(raw, i, "xyzcode"), np.asarray(xyz_code, np.float64))
    atomic_npy(_raw_path(raw, i, "xyz"), xyz)
    atomic_npy(_raw_path(raw, i, "rgba"), rgba)
    for a, v in attributes.items():
        if np.ndim(v):
            atomic_npy(_raw_path(raw, i, "attr." + a), v)
        else:
            atomic_npy(_raw_path(raw, i, "const." + a), np.asarray(v).reshape(1))


def raw_xyz_code(raw: Path, i: int) -> np.ndarray | None:
    """Chunk ``i``'s position code (encode_xyz) when it was spilled as int32, else None."""
    path = _raw_path(raw, i, "xyzcode")
    return np.load(path) if path.exists() else None


def load_raw_chunk(raw: Path, i: int, attributes, decode: bool = True) -> dict:
    """Chunk ``i`` memory-mapped: {"xyz", "rgba", "attr.<name>" for each of ``attributes``};
    int32 positions decoded to float64 (``decode``: else as spilled, raw_xyz_code tells); an
    attribute saved as its value alone made again, a point at a time."""
    xyz = np.load(_raw_path(raw, i, "xyz"), mmap_mode="r")
    if decode and xyz.dtype != np.float64:
        xyz = decode_xyz(xyz, np.load(_raw_path(raw, i, "xyzcode")))
    d = {"xyz": xyz, "rgba": np.load(_raw_path(raw, i, "rgba"), mmap_mode="r")}
    for a in attributes:
        path = _raw_path(raw, i, "attr." + a)
        if path.exists():
            d["attr." + a] = np.load(path, mmap_mode="r")
        else:
            c = np.load(_raw_path(raw, i, "const." + a))
            d["attr." + a] = np.full(len(xyz), c[0], c.dtype)
    return d


def load_raw_chunks(raw: Path, chunks, attributes) -> dict:
    """Chunks ``chunks`` (load_raw_chunk's) one after the other, each mapped only while it is
    copied: a map holds its file open, and the chunks of 1 500 tiles mapped at once (a Dask
    worker's, one a tile, 3 to 10 files each) ran past the process's 1 024 open files."""
    sizes = [len(np.load(_raw_path(raw, i, "rgba"), mmap_mode="r")) for i in chunks]
    out: dict = {}
    at = 0
    for i, n in zip(chunks, sizes):
        for k, v in load_raw_chunk(raw, i, attributes).items():
            if k not in out:
                out[k] = np.empty((sum(sizes), *v.shape[1:]), v.dtype)
            elif np.result_type(out[k], v) != out[k].dtype:  # a later chunk's wider type, as np.concatenate gave
                out[k] = out[k].astype(np.result_type(out[k], v))
            out[k][at : at + n] = v
        at += n
    return out


def raw_chunk_files(raw: Path, chunks=None) -> list[Path]:
    """The files of chunk ``chunks`` (an index, or several; every chunk's when None), from one
    listing of the folder: a listing a chunk made deleting 2 000 small tiles' spills quadratic (2.7 s)."""
    files = raw.glob("c*.npy")
    if chunks is None:
        return list(files)
    wanted = {f"c{i:06d}" for i in ([chunks] if isinstance(chunks, int) else chunks)}
    return [f for f in files if f.name.split(".", 1)[0] in wanted]


def npy_data_offset(path: Path) -> int:
    """Where a .npy file's data starts (after its header)."""
    with open(path, "rb") as f:
        version = np.lib.format.read_magic(f)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        read_header(f)
        return f.tell()


_BLOCK = 64 << 20


def copy_range(src: Path, src_off: int, dst, dst_off: int, n: int) -> None:
    """Copy ``n`` bytes of ``src`` from ``src_off`` into the existing file ``dst`` (a path, or a
    descriptor open for writing) at ``dst_off``, in the kernel where it can (copy_file_range: no
    copy through this process; a reflink on file systems that share extents), else through a
    buffer. Copying the same bytes twice is harmless."""
    fi = os.open(src, os.O_RDONLY)
    try:
        fo = dst if isinstance(dst, int) else os.open(dst, os.O_WRONLY)
        try:
            done = 0
            fast = hasattr(os, "copy_file_range")
            while done < n:
                if fast:
                    try:
                        k = os.copy_file_range(fi, fo, min(n - done, 1 << 30), src_off + done, dst_off + done)
                    except OSError:  # not across these file systems, or not on this kernel
                        fast = False
                        continue
                else:
                    buf = os.pread(fi, min(n - done, _BLOCK), src_off + done)
                    k = os.pwrite(fo, buf, dst_off + done) if buf else 0
                if k <= 0:
                    raise OSError(f"{src}: ends before byte {src_off + n} (copying into {dst})")
                done += k
        finally:
            if fo is not dst:
                os.close(fo)
    finally:
        os.close(fi)
