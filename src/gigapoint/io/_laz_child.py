"""The child process of io/laz_process.py: decodes LAZ point records into shared memory.

Run as a script (``python -P _laz_child.py``), not as a module of the package: it imports the
standard library and lazrs only, so it is ready in a few tens of milliseconds (gigapoint's
own imports take ~0.3 s). It reads one JSON line, the job, from stdin:

    {"path", "offset" (of the point data), "vlr" (the LASzip VLR's data, hex), "start", "stop",
     "parallel", "fd" (of the shared memory, inherited), "slots", "slot_bytes", "per_slot",
     "lazrs" (the folder the parent imported lazrs from)}

and writes one JSON line a decoded slot, ``{"slot": k, "n": n}``, then ``{"end": true}``,
or ``{"error": "..."}`` where lazrs fails, to its original stdout (fd 1 then points at
stderr, so that nothing else written can break the protocol). It fills the first slot, waits
until the parent has read it, then fills the slots in turn, reusing one only once the parent
has written its number back on stdin. It ends at EOF of stdin (the parent is gone) or of its
points.
"""

import json
import mmap
import os
import signal
import sys


def main() -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C reaches both processes: the parent decides
    out = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    line = sys.stdin.readline()
    if not line:
        return 0
    job = json.loads(line)
    try:
        if job.get("lazrs"):
            sys.path.insert(0, job["lazrs"])  # the parent's lazrs, wherever its sys.path found it
        import lazrs

        memory = mmap.mmap(job["fd"], job["slots"] * job["slot_bytes"])
        source = open(job["path"], "rb")  # noqa: SIM115 - open until the process ends
        source.seek(job["offset"])
        vlr = bytes.fromhex(job["vlr"])
        decoder = (lazrs.ParLasZipDecompressor if job["parallel"] else lazrs.LasZipDecompressor)(source, vlr)
        record = lazrs.LazVlr(vlr).item_size()
        if job["start"]:
            decoder.seek(job["start"])
        # the first slot alone until the parent has read it: decoding ahead would share the cores
        # with the parent's work on the first chunk (a first image; convert's first view 0.3 s later)
        free, spare = [0], list(range(1, job["slots"]))
        done, stop = job["start"], job["stop"]
        while done < stop:
            if not free:
                ack = sys.stdin.readline()
                if not ack:
                    return 0  # the parent is gone
                free += [int(ack), *spare]
                spare = []
            slot = free.pop(0)
            n = min(job["per_slot"], stop - done)
            at = slot * job["slot_bytes"]
            decoder.decompress_many(memoryview(memory)[at : at + n * record])
            done += n
            out.write(json.dumps({"slot": slot, "n": n}) + "\n")
        out.write('{"end": true}\n')
    except BrokenPipeError:
        return 0
    except Exception as exc:  # noqa: BLE001 - lazrs's and the OS's errors, said in one line to the parent
        out.write(json.dumps({"error": " ".join(f"{type(exc).__name__}: {exc}".split())}) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
