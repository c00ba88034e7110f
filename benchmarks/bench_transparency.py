"""Transparent points (issue #19): frame rate opaque vs transparent, and the error of the
composite against the exactly depth-sorted one, with the alternatives measured beside it.

    .venv/bin/python benchmarks/bench_transparency.py [--points 2000000] [--repeat 7] [--wgpu] [--error]

1. **speed**: the demo scene at 1280x720 (overview and close-up, the default adaptive point
   size and one-pixel points), opaque and at opacity 0.5 drawn interleaved frame by frame (the
   host is shared: the ratio of each pair is what counts), after a warm-up frame each (no JIT
   time). Reported: median ms, frames/s, points drawn per second, and the median of the
   per-pair ratios transparent / opaque. ``--wgpu``: the same on the wgpu backend where an
   adapter exists (lavapipe is a CPU emulation: its figures say little about a GPU).
2. **error** (``--error``): a small scene (150 000 points, 320x180) composited by (a) this
   renderer's hybrid transparency (``hybrid_reference``: 8 depth-sorted fragments a pixel +
   the tail's mean), (b) the same k-buffer without the tail, K = 4, 8, 16, (c) weighted
   blended OIT (McGuire & Bavoil 2013) with the paper's depth weight (eq. 7) and with a
   weight on the depth relative to the pixel's front, tuned here to its best, against the
   exact front-to-back composite of the sorted fragments (``sorted_reference``). Reported: mean
   and 99th percentile of the absolute error per channel (0..255) over the covered pixels, PSNR.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import numpy as np

import gigapoint as gp
from gigapoint.core.compact import rgba32
from gigapoint.render.params import batch_alphas
from gigapoint.render.passes.transparency import fragments, hybrid_reference, sorted_reference

WIDTH, HEIGHT = 1280, 720


def _camera(cloud, view: str, width: int, height: int) -> gp.Camera:
    if view == "overview":
        return gp.Camera.fit(cloud.bounds, view=(-70.0, 30.0), width=width, height=height, fov=40.0)
    lo, hi = cloud.bounds
    c = (lo + hi) / 2
    return gp.Camera.look_at((c[0] - 120, c[1] - 120, c[2] + 40.0), (c[0], c[1], c[2]), fov=60, width=width, height=height)


def speed(points: int, repeat: int, backend: str, threads: int | None) -> None:
    cloud = gp.demo(points, seed=1)
    print(f"speed: {points:,} demo points, {WIDTH}x{HEIGHT}, backend {backend}, median of {repeat} interleaved frames")
    print(f"  {'view':<9} {'size':<9} {'opaque ms':>9} {'fps':>6} {'transp. ms':>10} {'fps':>6} {'Mpts/s op/tr':>13} {'tr/op':>6}")
    for view in ("overview", "closeup"):
        cam = _camera(cloud, view, WIDTH, HEIGHT)
        for size in ("adaptive", "fixed"):
            base = gp.RenderSettings(backend=backend, size_mode=size, threads=threads)
            settings = (base, base.replace(opacity=0.5))
            frames = [gp.render_frame(cloud, cam, s) for s in settings]  # warm-up (JIT, buffers)
            drawn = frames[0].stats.points_processed
            times: list[list[float]] = [[], []]
            for _ in range(repeat):
                for i, s in enumerate(settings):
                    t = time.perf_counter()
                    gp.render_frame(cloud, cam, s)
                    times[i].append((time.perf_counter() - t) * 1000.0)
            op, tr = (statistics.median(t) for t in times)
            ratio = statistics.median(b / a for a, b in zip(*times))
            print(
                f"  {view:<9} {size:<9} {op:9.1f} {1000 / op:6.1f} {tr:10.1f} {1000 / tr:6.1f} "
                f"{drawn / op / 1e3:6.0f}/{drawn / tr / 1e3:<6.0f} {ratio:6.2f}"
            )


# --- the error of the alternatives ----------------------------------------------------------------
def _wboit(pix, rgb, a8, weight, n, reveal_t, fallback, background):
    """Weighted blended OIT: sum(w a c) / sum(w a) x (1 - T) + background x T, T = prod(1 - a) exact."""
    wa = weight * a8 / 255.0
    sw = np.bincount(pix, wa, n)
    out = np.ascontiguousarray(fallback).copy()
    hit = np.bincount(pix, minlength=n) > 0
    mean = np.stack([np.bincount(pix, wa * rgb[:, c], n) for c in range(3)], axis=1) / np.maximum(sw, 1e-300)[:, None]
    col = mean * (1 - reveal_t)[:, None] + np.array(background[:3], float)[None, :] * reveal_t[:, None]
    u8 = out.view(np.uint8).reshape(-1, 4)
    u8[hit, :3] = np.clip(np.floor(col[hit] + 0.5), 0, 255)
    u8[hit, 3] = 255
    return out


def _kbuffer(pix, key, rgb, a8, n, k, fallback, background):
    """The k nearest fragments of each pixel blended exactly, the rest dropped."""
    order = np.lexsort((key, pix))
    ps = pix[order]
    new = np.r_[True, ps[1:] != ps[:-1]]
    rank = np.arange(len(ps)) - np.flatnonzero(new)[np.cumsum(new) - 1]
    t = np.ones(n)
    acc = np.zeros((n, 3))
    for r in range(k):
        f = order[rank == r]
        p, a = pix[f], a8[f] / 255.0
        acc[p] += (a * t[p])[:, None] * rgb[f]
        t[p] *= 1 - a
    out = np.ascontiguousarray(fallback).copy()
    hit = np.bincount(pix, minlength=n) > 0
    u8 = out.view(np.uint8).reshape(-1, 4)
    u8[hit, :3] = np.clip(np.floor(acc[hit] + np.array(background[:3])[None, :] * t[hit, None] + 0.5), 0, 255)
    return out


def error(points: int = 150_000, width: int = 320, height: int = 180) -> None:
    cloud = gp.demo(points, seed=1)
    # u32 RGBA8 whatever the cloud holds (the demo's colours are per-block palettes since #22)
    colors = rgba32(cloud.color)
    bg = (0, 0, 0, 255)
    for view in ("overview", "closeup"):
        cam = _camera(cloud, view, width, height)
        s = gp.RenderSettings(backend="cpu", size_mode="fixed", background=bg)
        v = cam.view(cloud.bounds)
        sel = cloud.prepare(v, s).selection
        opaque = gp.render_frame(cloud, cam, s)
        fallback = np.ascontiguousarray(opaque.image).reshape(-1, 4).view(np.uint32).reshape(-1)
        n = width * height
        pix, depth, index, k = fragments(cloud, sel, width, height, v.near, v.far)
        cover = np.bincount(pix, minlength=n)
        hit = cover > 0
        print(
            f"error: {points:,} points, {width}x{height}, {view}: fragments per covered pixel mean {cover[hit].mean():.1f}, median {np.median(cover[hit]):.0f}"
        )
        rgb = colors.view(np.uint8).reshape(-1, 4)[index, :3].astype(float)
        key = (depth.view(np.uint32).astype(np.uint64) << np.uint64(32)) | index.astype(np.uint64)
        front = (opaque.visibility.reshape(-1) >> np.uint64(32)).astype(np.int64)
        rel = depth.astype(np.float64) / np.maximum((front[pix].astype(np.uint32).view(np.float32)).astype(np.float64), 1e-30)
        for opacity in (0.25, 0.5, 0.8):
            alphas = batch_alphas(None, opacity, len(sel.ids))
            a8 = alphas[k, 0].astype(float)
            args = (cloud, sel, width, height, v.near, v.far, colors, alphas, fallback, bg)
            exact = sorted_reference(*args).view(np.uint8).reshape(-1, 4)[hit, :3].astype(int)
            reveal_t = np.exp(np.bincount(pix, np.log1p(-np.minimum(a8 / 255.0, 1 - 1e-15)), n))

            images = {"hybrid: 8 sorted + tail mean (this renderer)": hybrid_reference(*args)}
            for kk in (4, 8, 16):
                images[f"k-buffer K={kk}, tail dropped"] = _kbuffer(pix, key, rgb, a8, n, kk, fallback, bg)
            z = depth.astype(np.float64)
            mcguire = np.clip(10.0 / (1e-5 + (z / 5.0) ** 2 + (z / 200.0) ** 6), 1e-2, 3e3)
            images["WBOIT, McGuire-Bavoil eq. 7 weight"] = _wboit(pix, rgb, a8, mcguire, n, reveal_t, fallback, bg)
            for steep in (0.0, 30.0, 300.0):
                name = "WBOIT, equal weights" if steep == 0 else f"WBOIT, weight 2^-({steep:g} (d/d_front - 1))"
                images[name] = _wboit(pix, rgb, a8, np.exp2(-steep * (rel - 1.0)), n, reveal_t, fallback, bg)
            for name, img in images.items():
                d = np.abs(img.view(np.uint8).reshape(-1, 4)[hit, :3].astype(int) - exact)
                psnr = 10 * np.log10(255.0**2 / max(float((d.astype(float) ** 2).mean()), 1e-12))
                print(f"  opacity {opacity:<4} {name:<44} mean {d.mean():6.2f}  p99 {np.percentile(d, 99):4.0f}  PSNR {psnr:5.1f} dB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=2_000_000)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--wgpu", action="store_true", help="also time the wgpu backend")
    ap.add_argument("--error", action="store_true", help="also measure the error against the sorted composite")
    ap.add_argument("--error-points", type=int, default=150_000, help="points of the error scene")
    ap.add_argument("--no-speed", action="store_true", help="skip the frame rates")
    args = ap.parse_args()
    print(f"host: {platform.processor() or platform.machine()}, {platform.python_version()}")
    if not args.no_speed:
        speed(args.points, args.repeat, "cpu", args.threads)
    if args.wgpu and not args.no_speed:
        speed(args.points, args.repeat, "wgpu", None)
    if args.error:
        error(args.error_points)


if __name__ == "__main__":
    main()
