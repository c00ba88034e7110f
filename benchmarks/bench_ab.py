"""A/B of the renderer against an earlier revision, in one process: same images, and speed.

    .venv/bin/python benchmarks/bench_ab.py --base de52ae0                       # 20 M brute force + 5 M LOD
    .venv/bin/python benchmarks/bench_ab.py --base HEAD~3 --points 2M --lod-points 1M --rounds 3
    .venv/bin/python benchmarks/bench_ab.py --base HEAD~1 --points 8M --cap 1M --speed cap --lod-points 200k

The base revision's ``src/gigapoint`` is exported (``git archive``) into a temporary folder as
the package ``gigapoint_base`` (its imports are relative, so it runs beside ``gigapoint``). Both
draw the same point arrays (the base's PointCloud wraps this revision's arrays), so any
difference is the renderer's:

1. **images**: a matrix of settings (every pass, splats, supersampling, stereo, color modes,
   a point cap) on a small demo scene and on a converted octree; visibility buffers and
   images must be identical bit for bit (exit status 1 otherwise);
2. **speed**: frames of the brute-force overview and close-up (1 thread and all) and of the
   octree at a point budget, and HQS and transparency of the brute-force scene under a point
   cap ``--cap`` (``--speed cap``: those alone), base and new interleaved frame by frame (the host drifts:
   compare the ratio, not absolute times). JIT warm-up is excluded. Reported: median ms
   and the ratio base / new (> 1: the new code is faster).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import io
import re
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

import gigapoint as gp
from gigapoint.core.palette import PaletteColors

ROOT = Path(__file__).resolve().parents[1]

#: Settings whose images must agree (a small scene: each takes a fraction of a second).
IMAGE_SETTINGS = [
    {},
    {"edl": True, "edl_strength": 0.7},
    {"fill_holes": 2, "fill_holes_foveated": True},
    {"hqs": True},
    {"point_size": 3, "point_shape": "round", "hqs": True, "splat_softness": 2.0},
    {"point_size": 4, "size_mode": "attenuated", "point_world_size": 0.5},
    {"supersample": 2},
    {"stereo": "side-by-side"},
    {"stereo": "anaglyph", "point_size": 2},
    {"color_mode": "elevation", "colormap": "turbo"},
    {"color_mode": "classification", "edl": True, "fill_holes": 1},
    {"max_points": 50_000},
    {"max_points": 50_000, "hqs": True},
    {"max_points": 25_000, "hqs": True, "point_size": 3, "point_shape": "round", "splat_softness": 2.0},
    {"max_points": 40_000, "opacity": 0.5},
    {"max_points": 25_000, "opacity": 0.5, "point_size": 3},
    {"adaptive_precision": False, "background": "white"},
]


def load_base(rev: str, into: Path):
    """The package ``gigapoint_base``: src/gigapoint of ``rev``."""
    data = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", rev, "src/gigapoint"], check=True, capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(into, filter="data")
    (into / "src" / "gigapoint").rename(into / "gigapoint_base")
    # its imports are relative, but the names it imports on first use (``_LAZY``, lazy_names) and
    # a few absolute imports name the package: left so, base.render_frame was this revision's
    for path in (into / "gigapoint_base").rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        moved = re.sub(r"""(["'])gigapoint\.""", r"\1gigapoint_base.", text)
        moved = re.sub(r"^(\s*)(from|import) gigapoint\b(?!_)", r"\1\2 gigapoint_base", moved, flags=re.MULTILINE)
        if moved != text:
            path.write_text(moved, encoding="utf-8")
    sys.path.insert(0, str(into))
    return importlib.import_module("gigapoint_base")


def base_cloud(base, cloud):
    """The base revision's PointCloud over this revision's arrays: every field both revisions'
    PointCloud takes (the compact layout's ``ext``/``packing`` too, which a base from before #22 lacks)."""
    known = {f.name for f in dataclasses.fields(base.PointCloud) if f.init}
    fields = {f.name: getattr(cloud, f.name) for f in dataclasses.fields(cloud) if f.init and f.name in known}
    if isinstance(cloud.color, PaletteColors):  # in the base's own class, or it takes them for an array
        palettes = importlib.import_module("gigapoint_base.core.palette").PaletteColors
        fields["color"] = palettes(**{f.name: getattr(cloud.color, f.name) for f in dataclasses.fields(cloud.color) if f.init})
    return base.PointCloud(**fields)


def compare_images(base, cloud, octree_path) -> list[str]:
    """Frames of every IMAGE_SETTINGS entry by both revisions; the differences found."""
    failures = []
    bcloud = base_cloud(base, cloud)
    boct, noct = base.open(str(octree_path)), gp.open(octree_path)
    for label, (b, n) in {"plain": (bcloud, cloud), "octree": (boct, noct)}.items():
        for view in ("iso", "top"):
            cam = gp.Camera.fit(n.bounds, view=view, width=320, height=200)
            bcam = base.Camera.fit(n.bounds, view=view, width=320, height=200)
            for kw in IMAGE_SETTINGS:
                if label == "octree" and "max_points" in kw:
                    kw = {k: v for k, v in kw.items() if k != "max_points"} | {"point_budget": kw["max_points"]}
                s = {"backend": "cpu", "size_mode": "fixed", **kw}  # the exact sizes (the base may know no other)
                fb = base.render_frame(b, bcam, base.RenderSettings(**s))
                fn = gp.render_frame(n, cam, gp.RenderSettings(**s))
                same = np.array_equal(fb.visibility, fn.visibility) and np.array_equal(fb.image, fn.image)
                print(f"  {label:6} {view:4} {kw}: {'identical' if same else 'DIFFERENT'}")
                if not same:
                    failures.append(f"{label} {view} {kw}")
    return failures


def interleaved(frames: list, rounds: int) -> list[list[float]]:
    """Seconds of each (render_frame, cloud, camera, settings) in ``frames``, drawn in turn
    ``rounds`` times after one untimed frame each (JIT, scratch buffers). The order flips
    every round (ABBA...), so coming second in a pair favours neither."""
    for draw, *args in frames:
        draw(*args)
    times: list[list[float]] = [[] for _ in frames]
    for r in range(rounds):
        order = range(len(frames)) if r % 2 == 0 else reversed(range(len(frames)))
        for k in order:
            draw, *args = frames[k]
            t = time.perf_counter()
            draw(*args)
            times[k].append(time.perf_counter() - t)
    return times


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="git revision to compare with (e.g. a commit before a refactor)")
    ap.add_argument("--points", default="20M", help="brute-force scene size")
    ap.add_argument("--lod-points", default="5M", help="points of the converted octree")
    ap.add_argument("--rounds", type=int, default=7, help="timed frames of each, interleaved")
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--cap", default="1M", help="max_points of the HQS and transparency frames")
    ap.add_argument("--speed", choices=("all", "cap"), default="all", help="cap: only the frames under a point cap")
    args = ap.parse_args(argv)
    from gigapoint.bench import benchmark_cameras, cpu_model, parse_counts

    n, n_lod, cap = parse_counts(ap, ("--points", args.points), ("--lod-points", args.lod_points), ("--cap", args.cap))
    if cap >= n:  # step 1: every point drawn, the capped frames time nothing new
        ap.error(f"--cap {args.cap} must be below --points {args.points} (a cap of {cap:,} leaves all {n:,} points drawn)")
    cpu = cpu_model()
    print(f"A/B: {args.base} (base) against the working tree (new); {cpu}")
    with tempfile.TemporaryDirectory() as tmp:
        base = load_base(args.base, Path(tmp) / "base")
        octree = Path(tmp) / "octree"
        # the base's converter writes it: this tree reads every older octree format, the base may
        # not read this tree's (format 2, #22)
        # (of the base's own PointChunks: it refuses another package's)
        importlib.import_module("gigapoint_base.lod").convert(importlib.import_module("gigapoint_base.io").demo_chunks(n_lod), octree, name="ab")
        print("1. images (320x200, CPU backend)")
        failures = compare_images(base, gp.demo(200_000), octree)

        print(f"2. speed ({args.width}x{args.height}, median of {args.rounds} interleaved frames)")
        cloud = gp.demo(n)
        bcloud = base_cloud(base, cloud)
        rows = []
        for view, cam in benchmark_cameras(cloud.bounds, args.width, args.height).items():
            bcam = base.Camera(**{f: getattr(cam, f) for f in ("eye", "target", "up", "fov", "width", "height", "projection", "ortho_height", "near", "far")})
            cases = [] if args.speed == "cap" else [(f"{n / 1e6:g} M brute force", {"threads": t}) for t in (1, None)]
            for name, kw in [(f"HQS, max_points {cap / 1e6:g} M", {"hqs": True}), (f"opacity 0.5, max_points {cap / 1e6:g} M", {"opacity": 0.5})]:
                cases.append((name, {"max_points": cap, **kw}))
            for scene, kw in cases:
                s = {"backend": "cpu", "size_mode": "fixed", **kw}
                bs, ns = base.RenderSettings(**s), gp.RenderSettings(**s)
                tb, tn = interleaved([(base.render_frame, bcloud, bcam, bs), (gp.render_frame, cloud, cam, ns)], args.rounds)
                rows.append((scene, view, kw.get("threads") or "all", tb, tn))
        del cloud, bcloud
        boct, noct = base.open(str(octree)), gp.open(octree)
        for view in ("iso", "top") if args.speed == "all" else ():
            cam = gp.Camera.fit(noct.bounds, view=view, width=args.width, height=args.height)
            bcam = base.Camera.fit(noct.bounds, view=view, width=args.width, height=args.height)
            s = {"backend": "cpu", "point_budget": 2_000_000, "size_mode": "fixed"}
            bs, ns = base.RenderSettings(**s), gp.RenderSettings(**s)
            tb, tn = interleaved([(base.render_frame, boct, bcam, bs), (gp.render_frame, noct, cam, ns)], args.rounds)
            rows.append((f"{n_lod / 1e6:g} M octree, 2 M budget", view, "all", tb, tn))
        print(f"  {'scene':34} {'view':9} {'thr':>4} {'base ms':>9} {'new ms':>9} {'base/new':>9}")
        for scene, view, threads, tb, tn in rows:
            mb, mn = statistics.median(tb) * 1e3, statistics.median(tn) * 1e3
            print(f"  {scene:34} {view:9} {threads!s:>4} {mb:9.1f} {mn:9.1f} {mb / mn:9.3f}")
    if failures:
        print(f"DIFFERENT images: {failures}")
        return 1
    print("all images identical")
    return 0


if __name__ == "__main__":
    sys.exit(main())
