"""The brute-force render benchmark and its OpenGL baseline (GL_POINTS on Mesa llvmpipe).

``run_render_benchmark`` measures, on the procedural demo scene (``gigapoint.demo(n)``):

- demo-scene generation speed (points/s of ``demo_arrays``; median of up to 3 runs after
  an untimed first run, so first-touch allocation and JIT cache loading are excluded),
- the cloud build (Morton sort + batching + quantization) time,
- brute-force render throughput for an overview view (``Camera.fit(bounds, 'iso')``) and a
  close-up view (45 m from a building, looking across the town, near plane 1 m, so frustum
  culling and 20/30-bit precision matter), with 1 thread and
  with all threads, JIT warm-up excluded (one frame first, then the median of ``repeats``),
- in the same run the same points drawn as GL_POINTS through moderngl on an EGL standalone
  context (float32 positions relative to the scene centre, u8 colors, the same view and
  clip range, an offscreen framebuffer with a depth test, timed to ``glFinish``), and the
  ratio gigapoint / GL. Its image coverage is compared with gigapoint's so the baseline is
  known to draw the same thing. Without a usable GL the baseline rows say ``skipped``.
- in the same run a *naive numba loop* (``naive_raster``: every point of a float32 array
  through the 4x4 matrix, depth-tested into a per-thread 64-bit buffer, no batches,
  culling or quantization) with gigapoint's colour resolve after it, and the ratio
  gigapoint / naive. Issue #2 calibrated its target against such a loop (~290 M points/s
  on its machine); this host's speed drifts 1.5x within minutes, and the ratio does not.

Throughput is always *points in the cloud / wall-clock frame time* (the whole
``render_frame`` call: selection, rasterization, merge and color resolve), whatever
frustum culling left out.
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from ..core.compact import rgba32
from ..core.layout import EMPTY_PIXEL
from ..errors import GigapointError
from ..render import Camera, RenderSettings, render_frame
from .gl_baseline import GLBaseline, first_line, gl_matrix
from .naive import naive_frame
from .scene import THROUGHPUT_DEFINITION, VIEWS, benchmark_cameras, coverage_iou, demo_cloud, relative_cloud

#: How far the GL image's coverage may differ from gigapoint's (fraction of the image).
COVERAGE_TOLERANCE = 0.03


def _time_gigapoint(cloud, camera: Camera, settings: RenderSettings, repeats: int):
    frame = render_frame(cloud, camera, settings)  # warm-up: JIT, scratch buffers
    times, raster = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        frame = render_frame(cloud, camera, settings)
        times.append(time.perf_counter() - t0)
        raster.append(frame.stats.raster_ms)
    return frame, times, raster


def _measure_naive(row: dict, xyz, cloud, camera: Camera, center, background, repeats: int, best) -> np.ndarray:
    """Time the naive loop's frame for one view with gigapoint's best thread count, fill ``row``,
    return its image."""
    near, far = camera.clip_range(cloud.bounds)
    gp_row, gp_frame = best
    n_threads = gp_row["threads"]
    color = rgba32(cloud.color)  # u32 RGBA8 (decoded once from a compact cloud's)
    naive_frame(xyz, color, camera, near, far, n_threads, background, center)  # warm-up: JIT cache, page faults
    times, kernel = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        vis, colors, k = naive_frame(xyz, color, camera, near, far, n_threads, background, center)
        times.append(time.perf_counter() - t0)
        kernel.append(k)
    covered = (vis != EMPTY_PIXEL).reshape(camera.height, camera.width)
    median = statistics.median(times)
    row.update(
        threads=n_threads,
        frame_ms=median * 1e3,
        frame_ms_runs=[x * 1e3 for x in times],
        raster_ms=statistics.median(kernel) * 1e3,
        points_per_second=row["points"] / median,
        coverage=float(covered.mean()),
        coverage_iou=coverage_iou(covered, ~gp_frame.empty),
        gigapoint_threads=n_threads,
        gigapoint_over_naive=gp_row["points_per_second"] / (row["points"] / median),
    )
    return colors.view(np.uint8).reshape(camera.height, camera.width, 4)


def _measure_gl(baseline: GLBaseline, row: dict, camera: Camera, cloud, center, background, repeats: int, best) -> np.ndarray:
    """Time GL_POINTS for one view, fill ``row``, return the GL image."""
    near, far = camera.clip_range(cloud.bounds)  # the same clip range gigapoint uses
    matrix = gl_matrix(camera, near, far, center)
    baseline.draw(matrix, background)  # warm-up: shader compile, buffer residency
    times = [baseline.draw(matrix, background) for _ in range(repeats)]
    image, covered = baseline.read()
    median = statistics.median(times)
    gp_row, gp_frame = best
    gp_mask = ~gp_frame.empty
    coverage, gp_coverage = float(covered.mean()), float(gp_mask.mean())
    row.update(
        skipped=False,
        gl_renderer=baseline.renderer,
        frame_ms=median * 1e3,
        frame_ms_runs=[x * 1e3 for x in times],
        points_per_second=row["points"] / median,
        coverage=coverage,
        coverage_gigapoint=gp_coverage,
        coverage_difference=abs(coverage - gp_coverage),
        coverage_iou=coverage_iou(covered, gp_mask),
        coverage_matches=abs(coverage - gp_coverage) <= COVERAGE_TOLERANCE,
        gigapoint_threads=gp_row["threads"],
        gigapoint_over_gl=gp_row["points_per_second"] / (row["points"] / median),
    )
    return image


def _save_png(path: Path, image: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(np.ascontiguousarray(image)).save(path)


def _environment(gl_info: str | None, gl_reason: str | None) -> dict:
    import numba

    return {
        "kind": "environment",
        "machine": platform.machine(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "numba_threads": numba.config.NUMBA_NUM_THREADS,
        "numba": numba.__version__,
        "numpy": np.__version__,
        "gl_renderer": gl_info,
        "gl_threads": int(os.environ.get("LP_NUM_THREADS", os.cpu_count() or 1)),  # llvmpipe's rasterizer threads
        "gl_skipped_reason": gl_reason,
        "definition": THROUGHPUT_DEFINITION,
    }


def run_render_benchmark(
    points=(20_000_000, 100_000_000),
    width: int = 1920,
    height: int = 1080,
    threads=(1, None),
    repeats: int = 5,
    gl: bool = True,
    out=None,
    views=VIEWS,
    naive: bool = True,
    seed: int = 0,
    progress=None,
) -> list[dict]:
    """Measure brute-force rendering of the demo scene; one dict per measurement.

    Rows (``kind``): ``environment`` (once), then per point count ``generate``, ``build``,
    and per view one ``render`` row per thread count (``renderer='gigapoint'``) and one GL
    baseline row (``renderer='gl'``; ``skipped`` with a ``reason`` when GL is unavailable),
    after a ``renderer='naive'`` row (the naive numba loop, with gigapoint's largest thread
    count) unless ``naive`` is False.
    ``out`` (a directory) receives the PNG of each gigapoint, naive and GL frame.
    ``progress`` (callable taking a string) is told what is being measured.
    """
    import numba

    if isinstance(points, int):
        points = (points,)
    if not points or any(not isinstance(n, (int, np.integer)) or n < 1 for n in points):
        raise GigapointError(f"benchmark points must be positive integers, got {points!r}")
    if not isinstance(repeats, int) or repeats < 1:
        raise GigapointError(f"benchmark repeats must be >= 1, got {repeats!r}")
    unknown = [v for v in views if v not in VIEWS]
    if unknown:
        raise GigapointError(f"benchmark views: unknown {unknown}; choose from {', '.join(VIEWS)}")
    if threads is None or isinstance(threads, int):
        threads = (threads,)
    from ..core.chunked import IN_MEMORY_BYTES_MIN, check_room

    for n in points:  # before any scene is made: 10^10 points ran out of memory minutes into the run
        check_room(f"benchmark of {n:,} points", n, IN_MEMORY_BYTES_MIN, instead=": measure fewer --points")
    out_dir = None
    if out is not None:
        out_dir = Path(out)
        if out_dir.exists() and not out_dir.is_dir():
            raise GigapointError(f"{out_dir}: benchmark output must be a directory")
        out_dir.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda message: None)
    # Validate settings and image size before any work.
    # the exact one-pixel render (the baselines draw one pixel a point, the throughput is the rasterizer's)
    settings_for = {t: RenderSettings(threads=t, backend="cpu", size_mode="fixed") for t in threads}
    Camera.look_at((0, 0, 1), (0, 0, 0), width=width, height=height)

    baseline, gl_reason = None, None
    if not gl:
        gl_reason = "disabled (--no-gl)"
    else:
        try:
            baseline = GLBaseline(width, height)
        except GigapointError as exc:
            gl_reason = str(exc)
    results = [_environment(baseline.renderer if baseline else None, gl_reason)]
    try:
        for n in points:
            n = int(n)
            say(f"{n:,} points: generating the demo scene and building the cloud")
            timings: dict = {}
            cloud = demo_cloud(n, seed, timings, runs=min(repeats, 3))
            results.append(
                {
                    "kind": "generate",
                    "points": n,
                    "seconds": timings["generate_s"],
                    "seconds_runs": timings["generate_runs_s"],
                    "points_per_second": n / timings["generate_s"],
                }
            )
            results.append(
                {
                    "kind": "build",
                    "points": n,
                    "seconds": timings["build_s"],
                    "points_per_second": n / timings["build_s"],
                    "batches": len(cloud.batches),
                }
            )
            cameras = benchmark_cameras(cloud.bounds, width, height)
            lo, hi = cloud.bounds
            center = (lo + hi) / 2
            n_reason = gl_reason
            xyz = None  # the naive loop's float32 copy of the points, made when first needed
            if baseline is not None:
                say(f"{n:,} points: uploading to GL")
                try:
                    baseline.upload(cloud, center)
                except Exception as exc:  # noqa: BLE001 - out of memory in the driver, buffer limits: skip, keep measuring
                    n_reason = f"GL could not take {n:,} points ({first_line(exc)})"
            for view in views:
                camera = cameras[view]
                best = None  # the row (and frame) with the most threads: what GL (all cores) is compared with
                for t in threads:
                    eff = max(1, min(int(t or numba.get_num_threads()), numba.config.NUMBA_NUM_THREADS))  # as the backend clamps
                    say(f"{n:,} points, {view}, {eff} thread(s): gigapoint")
                    frame, times, raster = _time_gigapoint(cloud, camera, settings_for[t], repeats)
                    s = frame.stats
                    median = statistics.median(times)
                    row = {
                        "kind": "render",
                        "renderer": "gigapoint",
                        "points": n,
                        "view": view,
                        "threads": eff,
                        "width": width,
                        "height": height,
                        "frame_ms": median * 1e3,
                        "frame_ms_runs": [x * 1e3 for x in times],
                        "raster_ms": statistics.median(raster),
                        "points_per_second": n / median,
                        "batches_total": s.batches_total,
                        "batches_culled": s.batches_culled,
                        "batches_rendered": s.batches_rendered,
                        "points_processed": s.points_processed,
                        "precision_histogram": {str(k): v for k, v in s.precision_histogram.items()},
                        "coverage": s.visible_pixels / (width * height),
                    }
                    results.append(row)
                    if best is None or eff >= best[0]["threads"]:
                        best = (row, frame)
                if out_dir is not None:
                    _save_png(out_dir / f"gigapoint_{n}_{view}.png", best[1].image)
                if naive:
                    say(f"{n:,} points, {view}: the naive numba loop")
                    if xyz is None:
                        xyz = relative_cloud(cloud, center)
                    naive_row = {"kind": "render", "renderer": "naive", "points": n, "view": view, "width": width, "height": height}
                    image = _measure_naive(naive_row, xyz, cloud, camera, center, settings_for[threads[0]].background, repeats, best)
                    results.append(naive_row)
                    if out_dir is not None:
                        _save_png(out_dir / f"naive_{n}_{view}.png", image)
                gl_row = {"kind": "render", "renderer": "gl", "points": n, "view": view, "width": width, "height": height}
                if n_reason is None:
                    say(f"{n:,} points, {view}: GL_POINTS baseline")
                    try:
                        image = _measure_gl(baseline, gl_row, camera, cloud, center, settings_for[threads[0]].background, repeats, best)
                    except Exception as exc:  # noqa: BLE001 - a driver failure must not lose the gigapoint figures
                        gl_row.update(skipped=True, reason=f"GL draw failed ({first_line(exc)})")
                    else:
                        if out_dir is not None:
                            _save_png(out_dir / f"gl_{n}_{view}.png", image)
                else:
                    gl_row.update(skipped=True, reason=n_reason)
                results.append(gl_row)
            del cloud, xyz
    finally:
        if baseline is not None:
            baseline.release()
    return results


