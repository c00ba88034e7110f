"""A LAS/LAZ file read to the end by ``gigapoint.io.read_chunks`` and loaded progressively
(``gigapoint.open(..., progressive=True)`` then ``wait()``), in one process, JIT warm-up excluded
(a first chunk read, a small file loaded progressively first). Compare two trees by running it
with each on ``PYTHONPATH``, alternately:

    PYTHONPATH=<tree>/src .venv/bin/python benchmarks/bench_las_read.py FILE
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gigapoint as gp
from gigapoint.io import read_chunks

SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "autzen_trim.laz"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("file")
    ap.add_argument("--chunk", type=int, default=2_000_000)
    args = ap.parse_args(argv)
    next(iter(read_chunks(args.file, args.chunk)))  # the decoding kernels compiled
    if SAMPLE.exists():
        gp.open(SAMPLE, progressive=True).wait()  # the octree's kernels compiled
    t = time.perf_counter()
    n, attrs = 0, []
    for chunk in read_chunks(args.file, args.chunk):
        n += len(chunk)
        attrs = sorted(chunk.attributes)
    read = time.perf_counter() - t
    t = time.perf_counter()
    cloud = gp.open(args.file, progressive=True)
    cloud.wait()
    load = time.perf_counter() - t
    print(f"{n:,} points: read_chunks {read:.2f} s ({n / read / 1e6:.1f} M points/s), progressive load {load:.2f} s; {len(attrs)} attributes: {', '.join(attrs)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
