"""The compact layout (core/compact.py) against three u32 words a point: bytes and speed.

    .venv/bin/python benchmarks/bench_compact.py                       # autzen_trim + a 5 M demo town
    .venv/bin/python benchmarks/bench_compact.py --points 20M --rounds 5 --width 1920 --height 1080

For each scene the same points are built twice, in the compact layout and in the three-word
layout of the *same boxes* (``PointCloud.expanded``), so the images must be identical bit
for bit and any speed difference is the layout's:

1. **bytes a point** per component (positions, color, attributes, batch records) of both;
2. **exactness**: every decoded position against the source at the source's scale;
3. **speed**: brute-force frames (CPU backend, every point, fixed size) of the benchmark
   cameras, the two layouts interleaved frame by frame (ABBA), median ms and the ratio
   words / compact (> 1: compact is faster). JIT warm-up excluded.

``--octree`` measures the compact octree on disk instead (lod/compact_octree.py, format version
2, against version 1: ``convert(layout="words")``), for autzen_trim and the demo town written as
a LAS file at ``--scale``: bytes of the output folder, conversion time (the two layouts
alternated, ``--rounds`` each, medians; JIT warmed up first) and LOD frame times of the two
octrees (the first frame from a cold arena, which reads and decodes every node it draws, then
warm frames interleaved ABBA) with the share of identical pixels (the boxes differ: version 1's
are tight, version 2's on the source grid) and the arenas' bytes a point (version 2's holds the
compact layout)::

    .venv/bin/python benchmarks/bench_compact.py --octree --points 5M --rounds 3

``--colors`` measures the colour formats of the compact layout instead (issue #22): RGB565
against per-block palettes (core/palette.py, ``colors="palette"``), for autzen_trim and the demo
town (``gp.demo(n, scale=0.01)``): bytes a point by component, PSNR / largest error against the
exact colours, the quantizer's speed, and brute-force frames of the two interleaved (ABBA)::

    .venv/bin/python benchmarks/bench_compact.py --colors --points 20M --rounds 7

``--bitmaps`` compares the thesis's two encodings at the source's precision (lossless): bricks
of N³ grid cells stored as occupancy bitmaps (N³ bits each non-empty brick) against the same
bricks holding relative offsets (3·log2 N bits a point), bytes a point, and the points a bitmap
would lose (two in one cell)::

    .venv/bin/python benchmarks/bench_compact.py --bitmaps --points 5M

``--default`` measures what ``gp.open`` / ``gp.demo(n, scale=0.01)`` hold by default
(``colors="auto"``: the palette where its PSNR is at least RGB565's, else RGB565): which one
each scene gets, bytes a point, the cost of the choice in the build (``encode_colors`` "auto"
against "rgb565" on the same colours, interleaved; autzen_trim's whole ``gp.open`` both ways),
and brute-force frames of the default cloud interleaved (ABBA) with the 16-byte layout (three
words, u32 colours: ``colors="rgba"`` expanded) and with RGB565::

    .venv/bin/python benchmarks/bench_compact.py --default --points 20M --rounds 11

The demo town has no source scale of its own (its points are floats): it is stored at 1 cm
here, as a LAS export of it would be (``--scale``). Peak RSS is reported at the end; the
1 B point figure in docs/benchmarks.md is extrapolated from the bytes a point measured here.
"""

from __future__ import annotations

import argparse
import dataclasses
import resource
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import gigapoint as gp
from gigapoint.core import PointChunk, build_cloud
from gigapoint.core.compact import rgba32
from gigapoint.io import demo_chunks  # scale=: rounded to a survey's grid, the chunks saying so

AUTZEN = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "autzen_trim.laz"


def bytes_row(cloud) -> str:
    n = max(cloud.n_points, 1)
    mem = cloud.memory()
    pc = (mem["positions"] + mem["color"]) / n
    return f"{cloud.layout:8} " + " ".join(f"{v / n:10.2f}" for v in mem.values()) + f" {sum(mem.values()) / n:10.2f} {pc:14.2f}"


def interleaved(frames: list, rounds: int) -> tuple[list[list[float]], list[list[float]]]:
    """(wall, CPU) seconds of each (cloud, camera, settings) drawn in turn, ABBA, after one untimed
    frame each. The CPU time (the process's, all threads) is the steadier on a shared host."""
    for args in frames:
        gp.render_frame(*args)
    wall: list[list[float]] = [[] for _ in frames]
    cpu: list[list[float]] = [[] for _ in frames]
    for r in range(rounds):
        for k in range(len(frames)) if r % 2 == 0 else reversed(range(len(frames))):
            t, c = time.perf_counter(), time.process_time()
            gp.render_frame(*frames[k])
            wall[k].append(time.perf_counter() - t)
            cpu[k].append(time.process_time() - c)
    return wall, cpu


def check_exact(cloud, reference_xyz, scale) -> str:
    """'exact' when the decoded positions are the source's points at the source's scale."""
    s = np.asarray(scale, np.float64)
    origin = reference_xyz.min(axis=0)
    got = np.round((cloud.positions() - origin) / s).astype(np.int64)
    want = np.round((reference_xyz - origin) / s).astype(np.int64)
    same = np.array_equal(got[np.lexsort(got.T)], want[np.lexsort(want.T)])
    dev = float(np.abs((cloud.positions() - origin) / s - got).max())
    return f"{'exact' if same else 'NOT EXACT'} (largest distance from the source grid point: {dev:.1e} steps)"


def scene(name: str, cloud, reference_xyz, args) -> bool:
    print(f"\n{name}: {cloud.n_points:,} points, {len(cloud.batches):,} batches, source scale {cloud.source_scale}")
    words = cloud.expanded()
    mem = cloud.memory()
    print(f"  {'layout':8} {'positions':>10} {'color':>10} {'attributes':>10} {'batches':>10} {'total':>10} {'pos+color B/pt':>14}")
    print("  " + bytes_row(words))
    print("  " + bytes_row(cloud))
    bits = np.bincount(
        ((cloud.packing["code"] & 0xFF) + ((cloud.packing["code"] >> 8) & 0xFF) + ((cloud.packing["code"] >> 16) & 0xFF)).astype(np.int64)
    )
    print("  extension bits a point per batch: " + ", ".join(f"{b}: {c} batches" for b, c in enumerate(bits) if c))
    print(
        f"  positions {mem['positions'] / cloud.n_points:.2f} B/pt (three words: 12): "
        + (check_exact(cloud, reference_xyz, cloud.source_scale) if reference_xyz is not None else "not checked")
    )
    from gigapoint.bench import benchmark_cameras

    ok = True
    # the compact positions with 32-bit colors: what each half of the layout costs
    positions_only = dataclasses.replace(cloud, color=rgba32(cloud.color))
    print(f"  speed ({args.width}x{args.height}, CPU backend, {args.rounds} interleaved frames; medians in ms, ratios words / compact)")
    print(f"  {'view':9} {'thr':>3} {'clock':5} {'words':>7} {'compact':>8} {'ratio':>6} {'pos.only':>9} {'ratio':>6}  images")
    for view, cam in benchmark_cameras(cloud.bounds, args.width, args.height).items():
        for threads in (1, None):
            s = gp.RenderSettings(backend="cpu", size_mode="fixed", threads=threads)
            same = np.array_equal(gp.render_frame(cloud, cam, s).image, gp.render_frame(words, cam, s).image)
            ok &= same
            for clock, (tw, tc, tp) in zip(
                ("wall", "cpu"), interleaved([(words, cam, s), (cloud, cam, s), (positions_only, cam, s)], args.rounds)
            ):
                mw, mc, mp = (statistics.median(t) * 1e3 for t in (tw, tc, tp))
                print(
                    f"  {view:9} {threads or 'all'!s:>3} {clock:5} {mw:7.1f} {mc:8.1f} {mw / mc:6.3f} {mp:9.1f} {mw / mp:6.3f}  "
                    f"{'identical' if same else 'DIFFERENT'}"
                )
    return ok


def write_town_las(path: Path, n: int, scale: float) -> Path:
    """The demo town as a LAS 1.2 file (point format 3) at ``scale`` metres: bench_convert's writer."""
    from bench_convert import write_las  # a sibling script: its folder is sys.path[0]

    return write_las(path, n, scale)


def folder_bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())


def arena_bytes(arena) -> float:
    """Bytes a point of an LOD arena's positions and colours (three words, or the compact layout)."""
    arrays = [arena.low, arena.color, *((arena.med, arena.high) if arena.med is not None else (arena.ext,))]
    return sum(a.nbytes for a in arrays) / arena.n_points


def octree_scene(name: str, src: Path, work: Path, args) -> None:
    """Version 1 against version 2 of one input: bytes, conversion time, LOD frames."""
    from gigapoint.lod import convert, open_octree

    layouts = {"v1 words": {"layout": "words"}, "v2 compact": {"layout": "compact"}, "v2 rgb565": {"layout": "compact", "colors": "rgb565"}}
    secs: dict[str, list[float]] = {k: [] for k in layouts}
    for _ in range(args.rounds):
        for k, opts in layouts.items():
            t = time.perf_counter()
            r = convert([src], work / k.replace(" ", "_"), overwrite=True, **opts)
            secs[k].append(time.perf_counter() - t)
    n = r.points
    print(f"\n{name}: {n:,} points, {r.nodes:,} nodes; conversion medians of {args.rounds}")
    print(f"{'layout':12} {'bytes':>12} {'B/point':>8} {'v1/this':>8} {'convert s':>10} {'this/v1':>8}")
    b1, t1 = folder_bytes(work / "v1_words"), statistics.median(secs["v1 words"])
    for k in layouts:
        b, t = folder_bytes(work / k.replace(" ", "_")), statistics.median(secs[k])
        print(f"{k:12} {b:12,} {b / n:8.2f} {b1 / b:8.2f} {t:10.2f} {t / t1:8.2f}")
    cam = gp.Camera.fit(open_octree(work / "v1_words").bounds, view="iso", width=args.width, height=args.height)
    settings = gp.RenderSettings(backend="cpu", size_mode="fixed")
    cold = {}
    for k in ("v1 words", "v2 compact"):
        oc = open_octree(work / k.replace(" ", "_"))
        t = time.perf_counter()
        gp.render_frame(oc, cam, settings)
        cold[k] = time.perf_counter() - t
    clouds = [open_octree(work / k.replace(" ", "_")) for k in ("v1 words", "v2 compact")]
    images = [gp.render_frame(c, cam, settings) for c in clouds]
    same = float(np.all(images[0].image == images[1].image, axis=2).mean())
    wall, cpu = interleaved([(c, cam, settings) for c in clouds], args.rounds * 2)
    w = [statistics.median(x) * 1e3 for x in wall]
    c = [statistics.median(x) * 1e3 for x in cpu]
    print(
        f"LOD frame {args.width}x{args.height}, default budget, {images[0].stats.points_processed:,} points: "
        f"cold (node reads + decoding) v1 {cold['v1 words'] * 1e3:.1f} ms, v2 {cold['v2 compact'] * 1e3:.1f} ms "
        f"(v2/v1 {cold['v2 compact'] / cold['v1 words']:.2f}); warm wall v1 {w[0]:.1f} / v2 {w[1]:.1f} ms (v2/v1 {w[1] / w[0]:.2f}), "
        f"CPU {c[0]:.1f} / {c[1]:.1f} ms; identical pixels {same:.4f}; arena bytes a point for positions and colour "
        f"v1 {arena_bytes(clouds[0].arena):.2f}, v2 {arena_bytes(clouds[1].arena):.2f}"
    )


def octree_part(args) -> None:
    import tempfile

    from gigapoint.lod import convert, open_octree

    with tempfile.TemporaryDirectory(prefix="bench_compact_octree_") as tmp:
        work = Path(tmp)
        for layout in ("words", "compact"):  # JIT: conversion, node decoding, the frame
            warm = [PointChunk(np.round(np.random.default_rng(0).random((5_000, 3)) * 100, 2), scale=(0.01,) * 3)]
            convert(warm, work / f"warm_{layout}", max_leaf=1_000, layout=layout)
            oc = open_octree(work / f"warm_{layout}")
            gp.render_frame(oc, gp.Camera.fit(oc.bounds, width=64, height=64), gp.RenderSettings(backend="cpu", size_mode="fixed"))
        if not args.skip_autzen and AUTZEN.exists():
            octree_scene("autzen_trim", AUTZEN, work / "autzen", args)
        n = args.points
        t = time.perf_counter()
        src = write_town_las(work / "town.las", n, args.scale)
        print(f"\n(demo town LAS written in {time.perf_counter() - t:.1f} s, {src.stat().st_size / n:.1f} B/point)")
        octree_scene(f"demo town at {args.scale:g} m", src, work / "town", args)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(f"\npeak RSS {rss / 2**30:.2f} GiB")


def color_stats(exact: np.ndarray, got: np.ndarray) -> str:
    """PSNR (RGB), largest and mean absolute error per channel of ``got`` against ``exact`` (u32 RGBA8)."""
    a = exact.view(np.uint8).reshape(-1, 4)[:, :3].astype(np.float32)
    b = got.view(np.uint8).reshape(-1, 4)[:, :3].astype(np.float32)
    d = np.abs(a - b)
    mse = float(np.mean(d.astype(np.float64) ** 2))
    psnr = float("inf") if mse == 0 else 10 * np.log10(255**2 / mse)
    return f"PSNR {psnr:5.1f} dB, max error {d.max():3.0f}/255, mean {d.mean():.3f}/255"


def colors_scene(name: str, exact, args) -> None:
    """RGB565 against per-block palettes for one cloud built with exact (u32) colours."""
    from gigapoint.bench import benchmark_cameras
    from gigapoint.core.compact import pack_rgb565
    from gigapoint.core.palette import PALETTE_SHIFT, quantize_palettes

    n = exact.n_points
    color = exact.color
    quantize_palettes(color[: 2 << PALETTE_SHIFT])  # JIT
    secs = []
    for _ in range(args.rounds):
        t = time.perf_counter()
        pal = quantize_palettes(color)
        secs.append(time.perf_counter() - t)
    q = statistics.median(secs)
    t = time.perf_counter()
    short = pack_rgb565(color)
    t565 = time.perf_counter() - t
    clouds = {"rgb565": dataclasses.replace(exact, color=short), "palette": dataclasses.replace(exact, color=pal)}
    print(f"\n{name}: {n:,} points, {len(exact.batches):,} batches, palettes of {pal.block:,} points")
    print(f"  {'colors':8} {'positions':>10} {'color':>8} {'(index':>7} {'palette)':>9} {'batches':>8} {'pos+col+batch':>14}   quality against the exact colours")
    for k, c in (("rgba", exact), *clouds.items()):
        mem = c.memory()
        idx, pt = (pal.words.nbytes / n, pal.palette.nbytes / n) if k == "palette" else (mem["color"] / n, 0.0)
        total = (mem["positions"] + mem["color"] + mem["batches"]) / n
        quality = "exact" if k == "rgba" else color_stats(color, rgba32(c.color))
        print(f"  {k:8} {mem['positions'] / n:10.3f} {mem['color'] / n:8.3f} {idx:7.3f} {pt:9.3f} {mem['batches'] / n:8.3f} {total:14.3f}   {quality}")
    print(
        f"  quantizer: {q * 1e3:.1f} ms ({n / q / 1e6:.1f} M points/s, median of {args.rounds}, numba threads {gp.RenderSettings().threads or 'all'}); "
        f"RGB565 packing {t565 * 1e3:.1f} ms"
    )
    print(f"  brute-force frames ({args.width}x{args.height}, CPU backend, every point, {args.rounds} interleaved; medians in ms, ratio rgb565 / palette)")
    decoded = dataclasses.replace(exact, color=rgba32(pal))
    resolve_rows = []
    for view, cam in benchmark_cameras(exact.bounds, args.width, args.height).items():
        s = gp.RenderSettings(backend="cpu", size_mode="fixed")
        frame = gp.render_frame(clouds["palette"], cam, s)
        same = np.array_equal(frame.image, gp.render_frame(decoded, cam, s).image)
        resolve_rows.append((view, resolve_times(frame.visibility, (short, pal, color), 10 * args.rounds), int(frame.stats.visible_pixels)))
        wall, cpu = interleaved([(clouds["rgb565"], cam, s), (clouds["palette"], cam, s)], args.rounds)
        w = [statistics.median(x) * 1e3 for x in wall]
        c = [statistics.median(x) * 1e3 for x in cpu]
        print(
            f"  {view:9} wall {w[0]:7.1f} / {w[1]:7.1f} ({w[0] / w[1]:.3f})   CPU {c[0]:7.1f} / {c[1]:7.1f} ({c[0] / c[1]:.3f})   "
            f"palette image {'= its decoded colours' if same else 'DIFFERS from its decoded colours'}"
        )
    print("  the resolve pass alone (CPU, one thread, the frame's visibility buffer; medians of interleaved runs in ms: rgb565 / palette / u32)")
    for view, (t565, tpal, t32), covered in resolve_rows:
        print(f"  {view:9} {t565:6.2f} / {tpal:6.2f} / {t32:6.2f}   ratio rgb565 / palette {t565 / tpal:.3f}   ({covered:,} covered pixels)")


def resolve_times(vis, colors, rounds: int) -> list[float]:
    """Median ms of the CPU resolve of ``vis`` with each colour array, one thread, interleaved ABBA."""
    import numba

    from gigapoint.backends.numba_cpu.passes import resolve

    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        for c in colors:
            resolve(vis, c, (0, 0, 0, 255))
        times: list[list[float]] = [[] for _ in colors]
        for r in range(rounds):
            for k in range(len(colors)) if r % 2 == 0 else reversed(range(len(colors))):
                t = time.perf_counter()
                resolve(vis, colors[k], (0, 0, 0, 255))
                times[k].append(time.perf_counter() - t)
    finally:
        numba.set_num_threads(previous)
    return [statistics.median(t) * 1e3 for t in times]


def colors_part(args) -> None:
    if not args.skip_autzen and AUTZEN.exists():
        colors_scene("autzen_trim", gp.open(AUTZEN, colors="rgba"), args)
    n = args.points
    t = time.perf_counter()
    town = gp.demo(n, scale=args.scale, colors="rgba")
    print(f"\n(demo town built in {time.perf_counter() - t:.1f} s)")
    colors_scene(f"demo town ({n:,}) at {args.scale:g} m", town, args)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(f"\npeak RSS {rss / 2**30:.2f} GiB")


def timed_pair(calls: dict, rounds: int) -> dict[str, float]:
    """Median seconds of each callable, run in turn (ABBA) after one untimed call each."""
    for f in calls.values():
        f()
    times: dict[str, list[float]] = {k: [] for k in calls}
    keys = list(calls)
    for r in range(rounds):
        for k in keys if r % 2 == 0 else reversed(keys):
            t = time.perf_counter()
            calls[k]()
            times[k].append(time.perf_counter() - t)
    return {k: statistics.median(v) for k, v in times.items()}


def default_scene(name: str, default, exact, args, open_calls: dict | None = None) -> None:
    """The default cloud (``colors="auto"``) against the 16-byte layout and RGB565: bytes, the
    choice's build cost, brute-force frames interleaved."""
    from gigapoint.bench import benchmark_cameras
    from gigapoint.core.cloud import encode_colors
    from gigapoint.core.compact import pack_rgb565

    n = default.n_points
    color = exact.color
    full = exact.expanded()  # three u32 words and a u32 colour a point: 16 bytes
    short = dataclasses.replace(exact, color=pack_rgb565(color))
    chosen = "palette" if not isinstance(default.color, np.ndarray) else {2: "rgb565", 4: "rgba"}[default.color.itemsize]
    print(f"\n{name}: {n:,} points; colors='auto' chose {chosen}")
    print(f"  {'cloud':10} {'positions':>10} {'color':>8} {'batches':>8} {'pos+col':>8} {'pos+col+batch':>14}   colours against the exact ones")
    for k, c in (("16-byte", full), ("rgb565", short), ("default", default)):
        mem = c.memory()
        quality = "exact" if c is full else color_stats(color, rgba32(c.color))
        pc = (mem["positions"] + mem["color"]) / n
        print(f"  {k:10} {mem['positions'] / n:10.3f} {mem['color'] / n:8.3f} {mem['batches'] / n:8.3f} {pc:8.3f} {pc + mem['batches'] / n:14.3f}   {quality}")
    enc = timed_pair({"auto": lambda: encode_colors(color, "auto"), "rgb565": lambda: encode_colors(color, "rgb565")}, args.rounds)
    print(
        f"  colour encoding, median of {args.rounds} interleaved: auto {enc['auto'] * 1e3:.1f} ms ({n / enc['auto'] / 1e6:.1f} M points/s), "
        f"rgb565 {enc['rgb565'] * 1e3:.1f} ms"
    )
    if open_calls:
        t = timed_pair(open_calls, args.rounds)
        print("  whole build, median of interleaved: " + ", ".join(f"{k} {v * 1e3:.1f} ms" for k, v in t.items()))
    print(f"  brute-force frames ({args.width}x{args.height}, CPU backend, every point, fixed size, {args.rounds} interleaved ABBA; medians in ms)")
    print(f"  {'view':9} {'clock':5} {'16-byte':>8} {'rgb565':>8} {'default':>8}  {'16-byte/default':>15} {'rgb565/default':>14}")
    for view, cam in benchmark_cameras(default.bounds, args.width, args.height).items():
        s = gp.RenderSettings(backend="cpu", size_mode="fixed")
        for clock, times in zip(("wall", "cpu"), interleaved([(full, cam, s), (short, cam, s), (default, cam, s)], args.rounds)):
            a, b, c = (statistics.median(t) * 1e3 for t in times)
            print(f"  {view:9} {clock:5} {a:8.2f} {b:8.2f} {c:8.2f}  {a / c:15.3f} {b / c:14.3f}")


def default_part(args) -> None:
    if not args.skip_autzen and AUTZEN.exists():
        opens = {"auto": lambda: gp.open(AUTZEN), "rgb565": lambda: gp.open(AUTZEN, colors="rgb565")}
        default_scene("autzen_trim", gp.open(AUTZEN), gp.open(AUTZEN, colors="rgba"), args, opens)
    n = args.points
    t = time.perf_counter()
    town = gp.demo(n, scale=args.scale)
    print(f"\n(default demo town built in {time.perf_counter() - t:.1f} s)")
    default_scene(f"demo town ({n:,}) at {args.scale:g} m", town, gp.demo(n, scale=args.scale, colors="rgba"), args)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(f"\npeak RSS {rss / 2**30:.2f} GiB")


def bitmap_rows(name: str, q: np.ndarray, cloud) -> None:
    """Todoran's comparison (seed 004, 4.1) at the source's precision: bricks of N³ grid cells, each
    non-empty one a bitmap of N³ bits, against the same bricks holding 3·log2(N) bits a point; both
    with a brick record of 12 bytes (its corner); and what the compact layout holds now."""
    n = len(q)
    mem = cloud.memory()
    print(f"\n{name}: {n:,} points, grid {(q.max(axis=0) + 1).tolist()} cells; the compact layout holds positions in {mem['positions'] / n:.2f} bytes a point")
    print(f"  {'N':>4} {'bricks':>10} {'points/brick':>13} {'occupancy':>10} {'bitmap B/pt':>12} {'offsets B/pt':>13} {'bitmap/offsets':>15} {'points a bitmap loses':>22}")
    for side in (4, 8, 16, 32, 64, 128):
        brick = q // side
        keys = (brick[:, 0] << 42) | (brick[:, 1] << 21) | brick[:, 2]
        cell = ((q[:, 0] % side) * side + q[:, 1] % side) * side + q[:, 2] % side
        bricks = len(np.unique(keys))
        distinct = len(np.unique(np.stack([keys, cell], axis=1).view("i8,i8")))
        bitmap = bricks * (side**3 / 8 + 12) / n
        offsets = (n * 3 * np.log2(side) / 8 + bricks * 12) / n
        print(
            f"  {side:4} {bricks:10,} {n / bricks:13.1f} {distinct / (bricks * side**3):10.2e} {bitmap:12.2f} {offsets:13.2f} {bitmap / offsets:15.1f} "
            f"{n - distinct:12,} ({(n - distinct) / n:.1%})"
        )


def bitmaps_part(args) -> None:
    """Bitmaps against relative offsets (issue #22's "measure both"), lossless at the source's grid."""
    if not args.skip_autzen and AUTZEN.exists():
        import laspy

        las = laspy.read(str(AUTZEN))
        xyz = np.stack([las.X, las.Y, las.Z], axis=1).astype(np.int64)  # the file's integers: its grid
        bitmap_rows("autzen_trim (0.01 m)", xyz - xyz.min(axis=0), gp.open(AUTZEN))
    n = args.points
    town = gp.demo(n, scale=args.scale)
    q = np.round(town.positions() / args.scale).astype(np.int64)
    bitmap_rows(f"demo town ({n:,}) at {args.scale:g} m", q - q.min(axis=0), town)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", default="5M", help="demo town size")
    ap.add_argument("--scale", type=float, default=0.01, help="grid the demo town is stored at (metres)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--skip-autzen", action="store_true")
    ap.add_argument("--octree", action="store_true", help="the compact octree on disk (format 2) against format 1 instead")
    ap.add_argument("--colors", action="store_true", help="RGB565 against per-block palettes (issue #22) instead")
    ap.add_argument("--default", action="store_true", help="the default colours (colors='auto') against the 16-byte layout and RGB565")
    ap.add_argument("--bitmaps", action="store_true", help="occupancy bitmaps against relative offsets per brick (Todoran 4.1) instead")
    args = ap.parse_args(argv)
    from gigapoint.bench import cpu_model, parse_counts

    (args.points,) = parse_counts(ap, ("--points", args.points))  # (a number from here on, checked before any work)

    cpu = cpu_model()
    print(f"compact layout vs three words; {cpu}, numba threads {gp.RenderSettings().threads or 'all'}")
    if args.octree:
        octree_part(args)
        return 0
    if args.colors:
        colors_part(args)
        return 0
    if args.default:
        default_part(args)
        return 0
    if args.bitmaps:
        bitmaps_part(args)
        return 0
    ok = True
    if not args.skip_autzen and AUTZEN.exists():
        import laspy

        las = laspy.read(str(AUTZEN))
        xyz = np.stack([las.x, las.y, las.z], axis=1)
        ok &= scene("autzen_trim", gp.open(AUTZEN), xyz, args)
        del las, xyz
    n = args.points
    t = time.perf_counter()
    cloud = build_cloud(demo_chunks(n, scale=args.scale), name="demo", layout="compact")
    print(f"\n(demo town built in {time.perf_counter() - t:.1f} s)")
    # the reference points only for small towns (the check holds a second copy)
    ref = np.concatenate([c.xyz for c in demo_chunks(n, scale=args.scale)]) if n <= 5_000_000 else None
    ok &= scene(f"demo town at {args.scale:g} m", cloud, ref, args)
    del ref
    mem = cloud.memory()
    per_point = sum(mem.values()) / cloud.n_points
    pos_color = (mem["positions"] + mem["color"]) / cloud.n_points
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(f"\npeak RSS {rss / 2**30:.2f} GiB (both layouts of the town and the build's temporaries)")
    print(
        f"1 B points of this town at this density would hold {per_point:.2f} GB ({pos_color:.2f} GB positions + color) in the compact layout"
    )
    print("all images identical" if ok else "DIFFERENT images")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
