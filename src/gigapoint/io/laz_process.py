"""LAZ point records decoded in a child process (``_laz_child.py``), for ``LasReader.read_chunks``.

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
inherits) that the child filled. It fills ``SLOTS`` slots in turn and reuses one only once
this process has said (on the child's stdin) that the records there were read. The child
imports only the standard library and lazrs, so it is ready in ~40 ms. Where a child cannot
be had (no ``os.memfd_create``: not Linux; a ``sys.executable`` that is not a Python, in an
application that embeds one; ``GIGAPOINT_LAZ_PROCESS=0``)
``usable`` says no and the records are decoded in this process as before: the same bytes.
"""

from __future__ import annotations

import contextlib
import json
import mmap
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

SLOTS = 3  # the chunk being read here, and two decoded ahead meanwhile
ENV_SWITCH = "GIGAPOINT_LAZ_PROCESS"  # "0": decode LAZ in this process
_CHILD = Path(__file__).with_name("_laz_child.py")


def usable(decompressor) -> bool:
    """Whether records that ``decompressor`` (laspy's lazrs decompressor of the file) would
    decode can be decoded by a child instead."""
    return (
        decompressor is not None
        and hasattr(os, "memfd_create")
        and Path(sys.executable or "").name.startswith(("python", "pypy"))  # not an app embedding Python
        and os.environ.get(ENV_SWITCH, "1") != "0"
    )


class ChildRecords:
    """Records ``start``..``stop`` of a LAZ file decoded by a child, ``per_read`` at a time."""

    def __init__(self, path, offset: int, vlr: bytes, start: int, stop: int, per_read: int, point_format, parallel: bool):
        import laspy
        import lazrs

        self.record = laspy.PackedPointRecord
        self.point_format = point_format
        self.dtype = point_format.dtype()
        self.size = point_format.size
        self.slot_bytes = -(-per_read * self.size // mmap.PAGESIZE) * mmap.PAGESIZE
        self.child = None
        self.log = tempfile.TemporaryFile()  # noqa: SIM115 - the child's stderr, closed by close()
        self._read_slot: int | None = None  # the slot the last read's records are in
        fd = os.memfd_create("gigapoint-laz")
        try:
            os.ftruncate(fd, SLOTS * self.slot_bytes)
            self.memory = mmap.mmap(fd, SLOTS * self.slot_bytes)
            self.child = subprocess.Popen(
                [sys.executable, "-P", str(_CHILD)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log, pass_fds=(fd,)
            )
            job = {"path": str(path), "offset": int(offset), "vlr": bytes(vlr).hex(), "start": int(start), "stop": int(stop),
                   "parallel": bool(parallel), "fd": fd, "slots": SLOTS, "slot_bytes": self.slot_bytes, "per_slot": int(per_read),
                   "lazrs": str(Path(lazrs.__file__).resolve().parent.parent)}  # fmt: skip
            self._send(json.dumps(job))
        except BaseException:
            self.close()
            raise
        finally:
            os.close(fd)  # the child has its own, the map stays

    def read(self, n: int):
        """The next ``n`` records (what the child decoded next: the reader asks for the same
        counts), as a laspy PackedPointRecord over the slot they are in."""
        if self._read_slot is not None:  # the last read's records are done with: the child may reuse the slot
            self._send(str(self._read_slot))
            self._read_slot = None
        line = self.child.stdout.readline()
        if not line:
            raise RuntimeError(self._ended())
        msg = json.loads(line)
        if "error" in msg:
            raise RuntimeError(msg["error"])
        if msg.get("end"):
            return self.record(np.empty(0, self.dtype), self.point_format)
        got = msg["n"]
        if got != n:
            raise RuntimeError(f"the LAZ decoding process gave {got:,} records where {n:,} were asked for")
        self._read_slot = msg["slot"]
        return self.record(np.frombuffer(self.memory, self.dtype, count=got, offset=msg["slot"] * self.slot_bytes), self.point_format)

    def _send(self, line: str) -> None:
        try:
            self.child.stdin.write(line.encode() + b"\n")
            self.child.stdin.flush()
        except BrokenPipeError:  # the child ended: the next read says why
            pass

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

    def close(self) -> None:
        """Stop the child (if it still runs) and free the shared memory (once no records of it are held)."""
        if self.child is not None:
            if self.child.poll() is None:
                self.child.kill()
            self.child.wait()
            for f in (self.child.stdin, self.child.stdout):
                with contextlib.suppress(OSError):
                    f.close()
            self.child = None
        self.log.close()
        memory = getattr(self, "memory", None)
        if memory is not None:
            with contextlib.suppress(BufferError):  # records still held: freed with the last of them
                memory.close()
