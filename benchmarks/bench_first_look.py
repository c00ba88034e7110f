"""What a new user meets (issue #17): the default picture of real data, and compiling on first use.

    .venv/bin/python benchmarks/bench_first_look.py                 # coverage and frame time, autzen_trim at 1920x1080
    .venv/bin/python benchmarks/bench_first_look.py --compile       # cold compile time per entry point (empty numba caches)

Coverage: the data's *footprint* is the lit area closed over small gaps (a binary closing with
a disc of ``--radius`` pixels, 8 by default: the issue's definition, which gives today's 19 % of
the frame and 23 % covered); reported: lit pixels, footprint (share of the frame) and the share
of the footprint covered, for the exact one-pixel render at the iso view (before #17) and the
default render (adaptive point size, the 'auto' view). Frame times are render_frame calls of
the two interleaved (the host drifts), median and best; the ratio is default / exact; with
``--threads 1`` the whole process is single-threaded and the clock is its CPU time. The
turntable row is the mean footprint over the frames of ``turntable_cameras``.

Compile: each command runs once in a fresh process on an empty NUMBA_CACHE_DIR (``render``),
or on a copy of the cache the plain render left (``--hqs``, ``--fill-holes 1``, ``--edl``:
what each adds), and ``gigapoint compile`` on an empty one. Wall and CPU (user + system)
seconds of the whole process: compiling is single-threaded, so on a busy host the CPU time
is the better guess of a quiet host's wall time.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
AUTZEN = ROOT.parent / "shared" / "data" / "autzen_trim.laz"


def footprint(lit: np.ndarray, radius: int) -> np.ndarray:
    from scipy import ndimage

    y, x = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    pad = radius + 1
    return ndimage.binary_closing(np.pad(lit, pad), structure=x * x + y * y <= radius * radius)[pad:-pad, pad:-pad]


def coverage(args) -> None:
    import gigapoint as gp
    from gigapoint.render.video import turntable_cameras

    cloud = gp.open(args.file)
    w, h = args.width, args.height
    threads = args.threads
    # one thread: the process's CPU time, steady on a busy host (main() made numba single-threaded,
    # so every kernel of the frame, the parallel passes too, runs on this thread); else wall time
    clock = time.process_time if threads == 1 else time.perf_counter
    cases = {
        "exact, iso (before #17)": (gp.Camera.fit(cloud.bounds, view="iso", width=w, height=h), gp.RenderSettings(size_mode="fixed", threads=threads)),
        "default (adaptive, auto)": (gp.Camera.fit_cloud(cloud, width=w, height=h), gp.RenderSettings(threads=threads)),
        "adaptive, iso": (gp.Camera.fit(cloud.bounds, view="iso", width=w, height=h), gp.RenderSettings(threads=threads)),
    }
    times: dict[str, list[float]] = {k: [] for k in cases}
    frames = {k: gp.render_frame(cloud, cam, s) for k, (cam, s) in cases.items()}  # warm-up
    for _ in range(args.rounds):
        for k, (cam, s) in cases.items():
            t = clock()
            gp.render_frame(cloud, cam, s)
            times[k].append(clock() - t)
    print(f"{args.file.name}, {w}x{h}, footprint = lit pixels closed by a disc of {args.radius} px, {args.rounds} interleaved frames, "
          f"{threads or 'all'} thread(s){' (CPU time)' if threads == 1 else ''}; {cpu_model()}")  # fmt: skip
    print(f"  {'render':28} {'lit':>6} {'footprint':>10} {'covered':>8} {'median ms':>10} {'best ms':>8}")
    for k, f in frames.items():
        lit = ~f.empty
        fp = footprint(lit, args.radius)
        covered = (lit & fp).sum() / max(fp.sum(), 1)
        print(f"  {k:28} {lit.mean():6.1%} {fp.mean():10.1%} {covered:8.1%} {statistics.median(times[k]) * 1e3:10.2f} {min(times[k]) * 1e3:8.2f}")
    a, b = (times[k] for k in list(cases)[:2])
    print(f"  frame time default / exact: median {statistics.median(b) / statistics.median(a):.2f}, best {min(b) / min(a):.2f}")
    cams = turntable_cameras(cloud, args.turntable, 1280, 720)
    shares = [footprint(~gp.render_frame(cloud, c).empty, args.radius).mean() for c in cams]
    print(f"  turntable ({args.turntable} frames, 1280x720): footprint mean {np.mean(shares):.1%}, min {np.min(shares):.1%}")


def bands_ab(args) -> None:
    """2-thread splat frames: the row bands of ``band_plan`` against the batch split with
    per-thread buffers and a merge (what splat frames used before), alternated frame by frame
    in this process, for the default view and a close-up."""
    import gigapoint as gp
    from gigapoint.backends.numba_cpu import backend

    banded = backend.band_plan

    def batch_split(matrices, firsts, counts, low, width, height, splat, n_parts):
        return backend.split_by_points(counts, n_parts), np.arange(len(counts), dtype=np.int64), backend._NO_BANDS

    cloud = gp.open(args.file) if args.demo is None else gp.demo(args.demo)
    lo, hi = (np.asarray(b, np.float64) for b in cloud.bounds)
    cams = {
        "default view": gp.Camera.fit_cloud(cloud, width=args.width, height=args.height),
        "close-up": gp.Camera.orbit(tuple((lo + hi) / 2), -60.0, 30.0, float(np.linalg.norm(hi - lo)) * 0.25, width=args.width, height=args.height),
    }
    settings = gp.RenderSettings(threads=2)
    print(f"{cloud.name}, {args.width}x{args.height}, default (adaptive) size, 2 threads, {args.rounds} alternated frames; {cpu_model()}, load {os.getloadavg()[0]:.1f}")
    for name, cam in cams.items():
        times = {"bands": [], "batch split": []}
        frames = {}
        for mode, plan in (("bands", banded), ("batch split", batch_split)):
            backend.band_plan = plan
            frames[mode] = gp.render_frame(cloud, cam, settings).visibility  # warm-up
        assert np.array_equal(frames["bands"], frames["batch split"])
        for _ in range(args.rounds):
            for mode, plan in (("bands", banded), ("batch split", batch_split)):
                backend.band_plan = plan
                t = time.perf_counter()
                gp.render_frame(cloud, cam, settings)
                times[mode].append(time.perf_counter() - t)
        backend.band_plan = banded
        b, s = (statistics.median(times[m]) for m in times)
        print(f"  {name:13} bands {b * 1e3:6.2f} ms  batch split {s * 1e3:6.2f} ms (medians)  bands / split {b / s:.3f}  (best {min(times['bands']) / min(times['batch split']):.3f})")


def _run(cmd, cache: Path) -> tuple[float, float]:
    """(wall, CPU) seconds of a command: CPU = user + system of the process (compiling is
    single-threaded, so on a busy host its CPU time is what the wall time would be on a quiet one)."""
    import resource

    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def compile_times(args) -> None:
    exe = str(Path(sys.executable).with_name("gigapoint"))
    with tempfile.TemporaryDirectory(prefix="bench_first_look_") as tmp:
        tmp = Path(tmp)
        out = str(tmp / "a.png")
        render = [exe, "render", str(args.file), "-o", out, "--overwrite"]
        rows = []
        plain = tmp / "plain"
        plain.mkdir()
        rows.append((f"gigapoint render {args.file.name}", "empty", _run(render, plain)))
        rows.append(("  again (warm)", "warm", _run(render, plain)))
        for extra in (["--hqs"], ["--fill-holes", "1"], ["--edl"]):
            cache = tmp / ("c" + "".join(extra))
            shutil.copytree(plain, cache)
            rows.append((f"  ... {' '.join(extra)}", "the plain render's", _run(render + extra, cache)))
        empty = tmp / "compile"
        empty.mkdir()
        rows.append(("gigapoint compile", "empty", _run([exe, "compile"], empty)))
    print(f"cold compile: seconds of the whole process (Python {platform.python_version()}, {cpu_model()}, load {os.getloadavg()[0]:.1f})")
    print(f"  {'command':40} {'numba cache':>20} {'wall s':>7} {'CPU s':>7}")
    for name, cache, (wall, cpu) in rows:
        print(f"  {name:40} {cache:>20} {wall:7.1f} {cpu:7.1f}")


def cpu_model() -> str:
    from gigapoint.bench import cpu_model

    return cpu_model()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--file", type=Path, default=AUTZEN)
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--radius", type=int, default=8, help="footprint: closing disc radius in pixels")
    ap.add_argument("--rounds", type=int, default=30)
    ap.add_argument("--threads", type=int, default=None, help="render threads (default: all; 1 is steadier on a busy host)")
    ap.add_argument("--turntable", type=int, default=36, help="turntable frames measured")
    ap.add_argument("--compile", action="store_true", help="measure cold compile times instead")
    ap.add_argument("--bands-ab", action="store_true", help="2-thread splat frames: row bands against the batch split (same process)")
    ap.add_argument("--demo", default=None, help="with --bands-ab: a demo town of this many points instead of --file")
    args = ap.parse_args(argv)
    if args.demo is not None:
        from gigapoint.bench import parse_counts

        (args.demo,) = parse_counts(ap, ("--demo", args.demo))
    if not args.file.exists():
        print(f"error: {args.file} not found", file=sys.stderr)
        return 1
    if args.bands_ab:
        bands_ab(args)
        return 0
    if args.threads == 1 and not args.compile:
        # before numba loads: with more threads its parallel passes (clear, resolve) would run
        # partly on others, whose time one thread's clock misses (the Xeon's figures before
        # 2026-12-02 afternoon did: time.thread_time with numba's default threads)
        os.environ["NUMBA_NUM_THREADS"] = "1"
    compile_times(args) if args.compile else coverage(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
