"""Spill files: the read phase's raw input chunks (``OctreeDir.raw``) and the gathering appends
that fill the partitions' files."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ...atomic import atomic_npy

_IOV_MAX = min(1024, os.sysconf("SC_IOV_MAX")) if hasattr(os, "sysconf") else 16  # buffers per writev


def _raw_path(raw: Path, i: int, key: str) -> Path:
    return raw / f"c{i:06d}.{key}.npy"


def save_raw_chunk(raw: Path, i: int, xyz: np.ndarray, rgba: np.ndarray, attributes: dict) -> None:
    """Chunk ``i``'s valid points: float64 xyz (n, 3), u32 RGBA and 1-D attributes, a file each."""
    atomic_npy(_raw_path(raw, i, "xyz"), xyz)
    atomic_npy(_raw_path(raw, i, "rgba"), rgba)
    for a, v in attributes.items():
        atomic_npy(_raw_path(raw, i, "attr." + a), v)


def load_raw_chunk(raw: Path, i: int, attributes) -> dict:
    """Chunk ``i`` memory-mapped: {"xyz", "rgba", "attr.<name>" for each of ``attributes``}."""
    d = {"xyz": np.load(_raw_path(raw, i, "xyz"), mmap_mode="r"), "rgba": np.load(_raw_path(raw, i, "rgba"), mmap_mode="r")}
    for a in attributes:
        d["attr." + a] = np.load(_raw_path(raw, i, "attr." + a), mmap_mode="r")
    return d


def raw_chunk_files(raw: Path, i: int | None = None) -> list[Path]:
    """The files of chunk ``i`` (of every chunk when None)."""
    return list(raw.glob("c*.npy" if i is None else f"c{i:06d}.*"))


def append_file(path: Path, arrays: list) -> None:
    """Append contiguous arrays to ``path`` with gathering writes (writev): one open and, per
    1 024 arrays, one system call; no concatenated copy."""
    views = [memoryview(a).cast("B") for a in arrays if a.nbytes]
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
    try:
        while views:
            batch = views[:_IOV_MAX]
            written = os.writev(fd, batch)
            for v in batch:  # a short write (a signal, a nearly full disk) resumes where it stopped
                if written >= len(v):
                    written -= len(v)
                    views.pop(0)
                else:
                    views[0] = v[written:]
                    break
    finally:
        os.close(fd)


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
