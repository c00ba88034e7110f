"""The child process of io/laz_process.py: decodes LAZ points where a crash of lazrs cannot
take the caller with it, and without the caller's GIL.

Run as a script (``python -P _laz_child.py``), not as a module of the package: it imports the
standard library and lazrs only, so it is ready in a few tens of milliseconds (gigapoint's
own imports take ~0.3 s). Its first stdin line is the job, JSON with ``"mode"`` and
``"lazrs"`` (the folder the parent imported lazrs from). Messages go to its original stdout,
one JSON line each (fd 1 then points at stderr, so that nothing else written can break the
protocol); any failure of lazrs is ``{"error": "..."}``. It ends at EOF of stdin (the parent
is gone).

- ``"records"``: points ``start``..``stop`` of a LAZ file (``path``, ``offset`` of its point
  data, ``vlr``: the LASzip VLR's data in hex, ``parallel``) into ``slots`` slots of shared
  memory (``fd``, inherited; ``slot_bytes`` each, ``per_slot`` points), ``{"slot": k, "n": n}``
  a filled slot, then ``{"end": true}``. A slot that fails to decode: the points of it that
  decode LAZ chunk by chunk, ``{"slot": k, "n": m, "partial": true}``, then the error.
  ``cut``: the file ends at that byte, its chunk table gone with its tail: the sequential
  decoder reads the chunks before the cut (``_CutFile``), then a slot's points before it are
  ``partial`` and the error says where the file ends. It fills the first slot, waits until the parent has
  read it, then fills the slots in turn, reusing one only once the parent has written its
  number back on stdin.
- ``"blocks"``: requests on stdin, each a JSON line ``{"size", "skip", "vlr", "at", "out",
  "total", "parallel"}``: the first ``size`` bytes of the shared memory (``fd``, inherited;
  ``total`` bytes now: the parent grows it) hold a LAZ point block (the 8-byte offset of its
  chunk table, the chunks, the table) ``skip`` bytes in; its ``out`` bytes of records go to
  ``at`` there; the answer is ``{"ok": out}``.
"""

import io
import json
import mmap
import os
import signal
import sys


def _decoder(lazrs, source, vlr: bytes, parallel: bool):
    return (lazrs.ParLasZipDecompressor if parallel else lazrs.LasZipDecompressor)(source, vlr)


class _CutFile(io.RawIOBase):
    """A LAZ file cut off at byte ``cut`` as a decoder can read it: lazrs reads a chunk table
    before any point, and this one's is gone, so one is made up past the cut (its chunks' sizes
    unknown: the sequential decoder of chunks of a fixed size never reads them) and the offset
    at the start of the point data points there. ``high``: the furthest byte handed out; points
    are real only while it stays before the cut (the decoder of the chunk across it reads on
    into the made-up table)."""

    def __init__(self, path: str, offset: int, cut: int, table: bytes):
        self.file = open(path, "rb")  # noqa: SIM115 - closed with this one
        self.patches = [(offset, cut.to_bytes(8, "little", signed=True)), (cut, table)]
        self.end = cut + len(table)
        self.pos = self.high = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, pos: int, whence: int = 0) -> int:
        self.pos = pos if whence == 0 else self.pos + pos if whence == 1 else self.end + pos
        return self.pos

    def tell(self) -> int:
        return self.pos

    def readinto(self, b) -> int:
        n = max(0, min(len(b), self.end - self.pos))
        self.file.seek(self.pos)
        got = self.file.readinto(memoryview(b)[:n])
        for at, data in self.patches:  # the made-up bytes over the file's (past the cut: none)
            lo, hi = max(at, self.pos), min(at + len(data), self.pos + n)
            if lo < hi:
                memoryview(b)[lo - self.pos : hi - self.pos] = data[lo - at : hi - at]
                got = max(got, hi - self.pos)
        self.pos += got
        self.high = max(self.high, self.pos)
        return got

    def close(self) -> None:
        self.file.close()
        super().close()


CUT_STEP = 5_000  # points decoded a call in a file cut off: the most of them lost at the cut


def _records(lazrs, job: dict, inp, say) -> None:
    memory = mmap.mmap(job["fd"], job["slots"] * job["slot_bytes"])
    vlr = bytes.fromhex(job["vlr"])
    laz_vlr = lazrs.LazVlr(vlr)
    cut = job.get("cut")
    if cut is not None:
        table = io.BytesIO()
        lazrs.write_chunk_table(table, [(laz_vlr.chunk_size(), 1)] * (-(-job["stop"] // laz_vlr.chunk_size())), laz_vlr)
        source = _CutFile(job["path"], job["offset"], cut, table.getvalue())
    else:
        source = open(job["path"], "rb")  # noqa: SIM115 - open until the process ends
    source.seek(job["offset"])
    decoder = _decoder(lazrs, source, vlr, job["parallel"] and cut is None)
    if cut is not None:
        source.high = 0  # (the decoder read the made-up table first: points count from here)
    record = laz_vlr.item_size()
    if job["start"]:
        decoder.seek(job["start"])
    # the first slot alone until the parent has read it: decoding ahead would share the cores
    # with the parent's work on the first chunk (a first image; convert's first view 0.3 s later)
    free, spare = [0], list(range(1, job["slots"]))
    done, stop = job["start"], job["stop"]
    while done < stop:
        if not free:
            ack = inp.readline()
            if not ack:
                return  # the parent is gone
            free += [int(ack), *spare]
            spare = []
        slot = free.pop(0)
        n = min(job["per_slot"], stop - done)
        at = slot * job["slot_bytes"]
        if cut is not None:
            good = _before_cut(decoder, source, cut, memoryview(memory)[at : at + n * record], n, record)
            if good < n:
                if good:
                    say({"slot": slot, "n": good, "partial": True})
                raise EOFError(f"the file ends at byte {cut:,}, {done + good:,} points in")
            done += n
            say({"slot": slot, "n": n})
            continue
        try:
            decoder.decompress_many(memoryview(memory)[at : at + n * record])
        except BaseException as exc:  # lazrs's errors and panics: the slot's points before the bad LAZ chunk go first
            if isinstance(exc, (SystemExit, KeyboardInterrupt)):
                raise
            good = _salvage(lazrs, job, vlr, memoryview(memory)[at : at + n * record], done, n, record)
            if good:
                say({"slot": slot, "n": good, "partial": True})
            raise
        done += n
        say({"slot": slot, "n": n})
    say({"end": True})


def _before_cut(decoder, source: _CutFile, cut: int, out, n: int, record: int) -> int:
    """Up to ``n`` points into ``out``, CUT_STEP a call, while the decoder reads only bytes
    before the cut: how many."""
    good = 0
    while good < n:
        step = min(CUT_STEP, n - good)
        try:
            decoder.decompress_many(out[good * record : (good + step) * record])
        except BaseException as exc:  # the cut: lazrs's "failed to fill whole buffer" (or a panic on what lies past it)
            if isinstance(exc, (SystemExit, KeyboardInterrupt)):
                raise
            return good
        if source.high > cut:
            return good
        good += step
    return good


def _salvage(lazrs, job: dict, vlr: bytes, out, first: int, n: int, record: int) -> int:
    """Points first..first + n of the file decoded again into ``out``, a LAZ chunk at a time
    (its chunk table's) with a fresh decoder, up to the first chunk that fails and no further
    than the table's points: how many did. A slot that failed lost every point in it (a file of
    up to 250 000 points: all of them); a chunk is the most a bad one takes now. 0 where the
    table cannot be read, or where the whole slot decodes this time (nothing to trust then)."""
    good = 0
    try:
        with open(job["path"], "rb") as source:
            source.seek(job["offset"])
            table = lazrs.read_chunk_table(source, lazrs.LazVlr(vlr))  # [(points, bytes)] a chunk
            source.seek(job["offset"])
            decoder = _decoder(lazrs, source, vlr, True)  # (the parallel one gives a chunk its own bytes only: a bad one fails, the
            decoder.seek(first)  # sequential one read on into the next chunk's and gave garbage points without a word)
            end = 0
            for points, _ in table:
                end += points
                step = min(end, first + n) - (first + good)
                if step <= 0:
                    continue
                decoder.decompress_many(out[good * record : (good + step) * record])
                good += step
                if good == n:
                    break
    except BaseException as exc:
        if isinstance(exc, (SystemExit, KeyboardInterrupt)):
            raise
    return good if good < n else 0


def _blocks(lazrs, job: dict, inp, say) -> None:
    memory = None
    while True:
        line = inp.readline()
        if not line:
            return  # the parent is gone
        ask = json.loads(line)
        if memory is None or len(memory) != ask["total"]:  # the parent grew the memfd
            if memory is not None:
                memory.close()
            memory = mmap.mmap(job["fd"], ask["total"])
        try:
            source = io.BytesIO(memory[: ask["size"]])
            source.seek(ask["skip"])
            at = ask["at"]
            _decoder(lazrs, source, bytes.fromhex(ask["vlr"]), ask["parallel"]).decompress_many(memoryview(memory)[at : at + ask["out"]])
        except BaseException as exc:  # lazrs's errors and panics (pyo3's PanicException is a BaseException)
            if isinstance(exc, (SystemExit, KeyboardInterrupt)):
                raise
            say({"error": _one_line(exc)})
            continue
        say({"ok": ask["out"]})


def _one_line(exc: BaseException) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())


def main() -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C reaches both processes: the parent decides
    out = os.fdopen(os.dup(1), "wb", buffering=0)
    os.dup2(2, 1)
    inp = sys.stdin.buffer

    def say(message: dict) -> None:
        out.write(json.dumps(message).encode() + b"\n")

    line = inp.readline()
    if not line:
        return 0
    job = json.loads(line)
    try:
        if job.get("lazrs"):
            sys.path.insert(0, job["lazrs"])  # the parent's lazrs, wherever its sys.path found it
        import lazrs

        if job["mode"] == "blocks":
            _blocks(lazrs, job, inp, say)
        else:
            _records(lazrs, job, inp, say)
    except BrokenPipeError:
        return 0
    except BaseException as exc:  # lazrs's and the OS's errors (and panics), said in one line to the parent
        if isinstance(exc, (SystemExit, KeyboardInterrupt)):
            raise
        say({"error": _one_line(exc)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
