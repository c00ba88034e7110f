"""LAZ point records decoded in a child process (``_laz_child.py``): ``LasReader.read_chunks``'s
(``ChildRecords``), and COPC's and EPT's nodes' (``decode_block``).

Why a second process:

- **Crashes.** lazrs decodes some corrupt files by recursing until the stack overflows (its
  GPS-time decoder, on a LAZ with 20 kB of 0xFF in its middle): the process dies of SIGSEGV,
  however Python is called. In a child that is one line of error naming the file, and the
  points before it stay loaded.
- **The GIL.** lazrs holds it for each decoding call (~60-80 ms for 250 k points): every
  other thread of the process stalled that long, once a chunk (a frame being drawn while a
  progressive octree loads, the viewer's server). The child decodes while this process only
  waits on a pipe.

``ChildRecords`` stands in for ``las._Records``: ``read(n)`` gives the next ``n`` records,
valid until the next ``read``, here as a view of a slot of shared memory (a memfd the child
inherits) that the child filled. It fills ``SLOTS`` slots in turn (two where they are large)
and reuses one only once this process has said (on the child's stdin) that the records there
were read. The child imports only the standard library and lazrs, so it is ready in ~40 ms.
Where a child cannot be had (no ``os.memfd_create``: not Linux; a ``sys.executable`` that is
not a Python, in an application that embeds one; ``GIGAPOINT_LAZ_PROCESS=0``) ``usable`` says
no and the records are decoded in this process as before: the same bytes (also where starting
the child fails).

``decode_block`` does the same for the LAZ point blocks of COPC and EPT nodes, through one
child per process that takes requests one at a time.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import mmap
import os
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np

SLOTS = 3  # the chunk being read here, and two decoded ahead meanwhile
#: slots larger than this come two at a time (one being read, one decoded ahead): convert's
#: 2 M-point chunks are 68-134 MB of records a slot, which a third slot would add to its memory
BIG_SLOT = 16 << 20
#: a LAZ file up to this size (and its records too) is decoded whole by the child all files share
#: (``decode_file``): a child of its own costs 50-120 ms to start, a tile of 2 000 points 1 ms to decode
SHARED_MAX = BIG_SLOT
ENV_SWITCH = "GIGAPOINT_LAZ_PROCESS"  # "0": decode LAZ in this process
_CHILD = Path(__file__).with_name("_laz_child.py")


def bad_data(exc: BaseException) -> bool:
    """Whether ``exc`` is laspy's or lazrs's failure on bad data: any Exception, and a panic of
    lazrs's Rust code, which pyo3 raises as a PanicException, a BaseException that ``except
    Exception`` lets through (a corrupt chunk table: a traceback where one line was due)."""
    return isinstance(exc, Exception) or type(exc).__name__ == "PanicException"


def _wanted() -> bool:
    """Whether a child may decode here at all (a Python to start it with, and not switched off)."""
    return Path(sys.executable or "").name.startswith(("python", "pypy")) and os.environ.get(ENV_SWITCH, "1") != "0"


def available() -> bool:
    """Whether a child can decode here (``ChildRecords``: it needs a memfd)."""
    return hasattr(os, "memfd_create") and _wanted()


def usable(decompressor) -> bool:
    """Whether records that ``decompressor`` (laspy's lazrs decompressor of the file) would
    decode can be decoded by a child instead."""
    return decompressor is not None and available()


class _Child:
    """A started ``_laz_child.py`` with ``job``; its stderr goes to a temporary file, for the
    one line that says why it ended where it ends without a message."""

    def __init__(self, job: dict, pass_fds=()):
        import lazrs

        self.log = tempfile.TemporaryFile()  # noqa: SIM115 - the child's stderr, closed by close()
        self.child = None
        try:
            self.child = subprocess.Popen(
                [sys.executable, "-P", str(_CHILD)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log, pass_fds=pass_fds
            )
            self.send(json.dumps({**job, "lazrs": str(Path(lazrs.__file__).resolve().parent.parent)}).encode())
        except BaseException:
            self.close()
            raise

    def send(self, line: bytes, data: bytes = b"") -> None:
        try:
            self.child.stdin.write(line + b"\n")
            if data:
                self.child.stdin.write(data)
            self.child.stdin.flush()
        except BrokenPipeError:  # the child ended: the next message read says why
            pass

    def message(self) -> dict:
        """The child's next message; a RuntimeError where it is an error, or where the child ended."""
        line = self.child.stdout.readline()
        if not line:
            raise RuntimeError(self._ended())
        msg = json.loads(line)
        if "error" in msg:
            raise RuntimeError(msg["error"])
        return msg

    def _ended(self) -> str:
        """Why the child ended without a message (a crash of the decoder, most likely)."""
        code = self.child.wait()
        self.log.seek(0)
        lines = [ln.strip() for ln in self.log.read().decode(errors="replace").splitlines() if ln.strip()]
        if code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            why = f"the LAZ decoder crashed with {name}"
        else:
            why = f"the LAZ decoding process ended with status {code}"
        return why + (f": {lines[-1]}" if lines else "")

    def alive(self) -> bool:
        return self.child is not None and self.child.poll() is None

    def close(self) -> None:
        """Stop the child, if it still runs."""
        if self.child is not None:
            if self.child.poll() is None:
                self.child.kill()
            self.child.wait()
            for f in (self.child.stdin, self.child.stdout):
                with contextlib.suppress(OSError):
                    f.close()
            self.child = None
        self.log.close()


class ChildRecords(_Child):
    """Records ``start``..``stop`` of a LAZ file decoded by a child, ``per_read`` at a time
    (``cut``: the file ends there, its chunk table gone: the child decodes the points before it,
    then says where they end, _laz_child.py)."""

    def __init__(self, path, offset: int, vlr: bytes, start: int, stop: int, per_read: int, point_format, parallel: bool, cut: int | None = None):
        import laspy

        self.record = laspy.PackedPointRecord
        self.point_format = point_format
        self.dtype = point_format.dtype()
        self.size = point_format.size
        self.slot_bytes = _pages(per_read * self.size)
        self.memory = None
        self._read_slot: int | None = None  # the slot the last read's records are in
        fd = os.memfd_create("gigapoint-laz")
        try:
            slots = SLOTS if self.slot_bytes <= BIG_SLOT else 2
            os.ftruncate(fd, slots * self.slot_bytes)
            self.memory = mmap.mmap(fd, slots * self.slot_bytes)
            job = {"mode": "records", "path": str(path), "offset": int(offset), "vlr": bytes(vlr).hex(), "start": int(start),
                   "stop": int(stop), "parallel": bool(parallel), "fd": fd, "slots": slots, "slot_bytes": self.slot_bytes,
                   "per_slot": int(per_read), "cut": cut}  # fmt: skip
            super().__init__(job, pass_fds=(fd,))
        except BaseException:
            self.close()
            raise
        finally:
            os.close(fd)  # the child has its own, the map stays

    def read(self, n: int):
        """The next ``n`` records (what the child decoded next: the reader asks for the same
        counts), as a laspy PackedPointRecord over the slot they are in."""
        if self._read_slot is not None:  # the last read's records are done with: the child may reuse the slot
            self.send(str(self._read_slot).encode())
            self._read_slot = None
        msg = self.message()
        if msg.get("end"):
            return self.record(np.empty(0, self.dtype), self.point_format)
        got = msg["n"]
        if got != n and not (msg.get("partial") and got < n):  # (partial: the points before a bad chunk; the error comes next)
            raise RuntimeError(f"the LAZ decoding process gave {got:,} records where {n:,} were asked for")
        self._read_slot = msg["slot"]
        return self.record(np.frombuffer(self.memory, self.dtype, count=got, offset=msg["slot"] * self.slot_bytes), self.point_format)

    def close(self) -> None:
        """Stop the child and free the shared memory (once no records of it are held)."""
        if getattr(self, "log", None) is not None:
            super().close()
        if self.memory is not None:
            with contextlib.suppress(BufferError):  # records still held: freed with the last of them
                self.memory.close()


class _BlockDecoder(_Child):
    """A child that decodes LAZ point blocks on request (``decode_block``), through a memfd it
    inherits: the block, then the records, each from a page boundary (through a pipe, the
    records of a 1.2 M-point COPC frame took 0.1 s more)."""

    def __init__(self):
        self.fd = os.memfd_create("gigapoint-laz-blocks")
        self.memory = None
        try:
            super().__init__({"mode": "blocks", "fd": self.fd}, pass_fds=(self.fd,))
        except BaseException:
            os.close(self.fd)
            raise

    def decode(self, block: bytes, skip: int, vlr: bytes, out_bytes: int, parallel: bool) -> np.ndarray:
        at = _pages(len(block))  # where the records go
        total = at + _pages(out_bytes)
        if self.memory is None or len(self.memory) < total:  # grown (the file, then this side's map; the child maps it anew)
            os.ftruncate(self.fd, total)
            if self.memory is not None:
                self.memory.close()
            self.memory = mmap.mmap(self.fd, total)
        self.memory[: len(block)] = block
        ask = {"size": len(block), "skip": int(skip), "vlr": bytes(vlr).hex(), "at": at, "out": int(out_bytes),
               "total": len(self.memory), "parallel": bool(parallel)}  # fmt: skip
        self.send(json.dumps(ask).encode())
        try:
            self.message()
            return np.frombuffer(self.memory, np.uint8, count=out_bytes, offset=at).copy()  # the map is the next request's
        finally:
            if total > BIG_SLOT and hasattr(mmap, "MADV_REMOVE"):  # a large request's pages go back (the file keeps its
                self.memory.madvise(mmap.MADV_REMOVE, 0, total)  # size): held for the process's life otherwise

    def close(self) -> None:
        super().close()
        if self.memory is not None:
            self.memory.close()
            self.memory = None
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


class DecodedRecords:
    """``ChildRecords``' stand-in for a small LAZ file decoded whole (``decode_file``)."""

    def __init__(self, records: np.ndarray, point_format):
        import laspy

        self.records, self.point_format, self.at = records, point_format, 0
        self.record = laspy.PackedPointRecord

    def read(self, n: int):
        out = self.records[self.at : self.at + n]
        self.at += len(out)
        return self.record(out, self.point_format)

    def close(self) -> None:
        pass


def decode_file(path, size: int, offset: int, vlr: bytes, count: int, point_format, parallel: bool) -> DecodedRecords | None:
    """The ``count`` records of a LAZ file of ``size`` bytes up to SHARED_MAX, decoded whole by
    the child that ``decode_block`` shares: a child started for each file (``ChildRecords``) cost
    50-120 ms, 40 times the decoding of a 2 000-point tile (a folder of 1 500 tiles: 3 minutes).
    None for a larger file, or where it fails: its own child then salvages what it can."""
    if max(size, count * point_format.size) > SHARED_MAX:
        return None
    try:
        with open(path, "rb") as f:
            block = f.read()
        raw = decode_block(block, vlr, count * point_format.size, skip=offset, parallel=parallel)
    except BaseException as exc:  # damage, said by the file's own child (a crash too)
        if not bad_data(exc):
            raise
        return None
    return DecodedRecords(raw.view(point_format.dtype()), point_format)


def _pages(n: int) -> int:
    return -(-int(n) // mmap.PAGESIZE) * mmap.PAGESIZE


_blocks: _BlockDecoder | None = None
_blocks_lock = threading.Lock()


def _forget_after_fork() -> None:
    """In a forked process: the parent's decoder is not this process's to talk to (their
    messages would mix on the pipes); its copies of the pipes and the memfd are closed, so the
    parent's child still ends when the parent does, and this process starts its own. The lock
    is new: a thread of the parent may have held it at the fork, and would never release it here."""
    global _blocks, _blocks_lock
    if _blocks is not None and _blocks.child is not None:
        for f in (_blocks.child.stdin, _blocks.child.stdout):
            with contextlib.suppress(OSError):
                f.close()
        with contextlib.suppress(OSError):
            os.close(_blocks.fd)
    _blocks = None
    _blocks_lock = threading.Lock()


def _close_blocks() -> None:
    """At exit: the decoder's child stopped, its pipes and memory closed (else they are left to
    the interpreter's teardown, which warns about each)."""
    global _blocks
    if _blocks is not None:
        _blocks.close()
        _blocks = None


atexit.register(_close_blocks)
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_after_fork)


def decode_block(block: bytes, vlr: bytes, out_bytes: int, skip: int = 0, parallel: bool = True) -> np.ndarray:
    """``out_bytes`` of point records (uint8) of the LAZ point block ``block[skip:]`` (its chunk
    table's 8-byte offset, counted from ``block``'s start, its chunks, the table), LASzip VLR
    data ``vlr``: decoded by one child process this process shares (started on first use,
    again after a crash), or here where no child can be had or started. Any failure of the decoder, a
    crash included, is a RuntimeError with its reason in one line (``usable``'s conditions,
    but for the file's decompressor)."""
    global _blocks
    if not (_wanted() and hasattr(os, "memfd_create")):
        return _decode_here(block, skip, vlr, out_bytes, parallel)
    with _blocks_lock:  # one request at a time on the pipes
        if _blocks is None or not _blocks.alive():
            if _blocks is not None:
                _blocks.close()
                _blocks = None
            try:
                _blocks = _BlockDecoder()
            except OSError:  # no process or memfd to be had (a process limit, a sandbox): decoded here
                return _decode_here(block, skip, vlr, out_bytes, parallel)
        return _blocks.decode(block, skip, vlr, out_bytes, parallel)


def _decode_here(block: bytes, skip: int, vlr: bytes, out_bytes: int, parallel: bool) -> np.ndarray:
    import io

    import lazrs

    source = io.BytesIO(block)
    source.seek(skip)
    records = np.empty(out_bytes, np.uint8)
    (lazrs.ParLasZipDecompressor if parallel else lazrs.LasZipDecompressor)(source, bytes(vlr)).decompress_many(records)
    return records
