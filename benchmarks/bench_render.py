"""Brute-force render benchmark of the demo scene, with the GL_POINTS (Mesa llvmpipe) and naive-loop baselines.

    .venv/bin/python benchmarks/bench_render.py                       # 20 M and 100 M points, 1920x1080
    .venv/bin/python benchmarks/bench_render.py --points 2M --width 640 --height 360 --out /tmp/bench

Prints a table and writes the results as JSON (--json, else <out>/bench_render.json, else
./bench_render.json). Throughput = points in the cloud / median frame time, JIT warm-up excluded.
The work is done by gigapoint.bench.run_render_benchmark (also ``gigapoint bench``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rich.console import Console

from gigapoint.bench import one_line_errors, parse_counts, parse_threads, print_results, run_render_benchmark, write_results


@one_line_errors
def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", nargs="+", default=["20M", "100M"], help="point counts (e.g. 20M 100M)")
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--threads", nargs="+", default=["1", "all"], help="thread counts to measure ('all' = every core)")
    ap.add_argument("--repeats", type=int, default=5, help="timed frames per measurement (median reported)")
    ap.add_argument("--no-gl", action="store_true", help="skip the GL_POINTS baseline")
    ap.add_argument("--no-naive", action="store_true", help="skip the naive numba loop baseline")
    ap.add_argument("--out", type=Path, help="directory for the images (and the JSON)")
    ap.add_argument("--json", type=Path, help="where to write the JSON results")
    args = ap.parse_args(argv)
    err = Console(stderr=True)
    points = parse_counts(ap, *(("--points", p) for p in args.points))
    threads = [parse_threads(t) for t in args.threads]
    json_path = args.json or (args.out / "bench_render.json" if args.out else Path("bench_render.json"))
    results = run_render_benchmark(
        points=points,
        width=args.width,
        height=args.height,
        threads=threads,
        repeats=args.repeats,
        gl=not args.no_gl,
        naive=not args.no_naive,
        out=args.out,
        progress=lambda m: err.print(f"[dim]{m}[/dim]"),
    )
    print_results(results)
    err.print(f"results written to {write_results(results, json_path)}")


if __name__ == "__main__":
    sys.exit(main())
