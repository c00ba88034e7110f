"""A conversion's time and peak resident memory per phase (RSS sampled every 20 ms).

    .venv/bin/python benchmarks/bench_convert_memory.py INPUT.las [--memory-limit 2G] [--partition-points N]

One conversion of INPUT into a temporary folder, in this process (numba's cache warm: run it
twice, or after ``gigapoint compile``). Prints the phases' seconds, each phase's peak RSS and
whether the points were held in memory (lod/convert/in_memory.py) or spilled. What found the
malloc-arena cost of reading chunks in a thread (docs/benchmarks.md, "Third session of
2026-12-03"): try it again with ``MALLOC_ARENA_MAX=1`` when a phase holds more than it should.
"""

from __future__ import annotations

import argparse
import importlib
import tempfile
import threading
import time
from pathlib import Path

from gigapoint.lod import convert

PHASES = ("read", "count", "distribute", "build", "group", "upper", "write")


def _rss() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("input")
    ap.add_argument("--memory-limit", default=None)
    ap.add_argument("--partition-points", type=int, default=None)
    args = ap.parse_args(argv)
    converter = importlib.import_module("gigapoint.lod.convert.converter")
    now, peaks = ["start"], {}

    def entering(name, method):
        def phase(self, *a, **k):
            now[0] = name
            return method(self, *a, **k)

        return phase

    for cls in (converter._Converter, converter._InMemoryConverter):  # the classes a local conversion runs
        for name in PHASES:
            setattr(cls, name, entering(name, getattr(cls, name)))

    def sample():
        while now[0] != "done":
            peaks[now[0]] = max(peaks.get(now[0], 0), _rss())
            time.sleep(0.02)

    threading.Thread(target=sample, daemon=True).start()
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        res = convert([args.input], Path(tmp) / "octree", memory_limit=args.memory_limit, partition_points=args.partition_points)
        seconds = time.perf_counter() - t
    now[0] = "done"
    print(f"{res.points:,} points in {seconds:.2f} s, {'held in memory' if res.in_memory else 'spilled'}")
    for name in PHASES:
        if name in peaks:
            print(f"  {name:10s} {res.phase_seconds.get(name, 0):6.2f} s, peak RSS {peaks[name] / 2**20:7.0f} MiB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
