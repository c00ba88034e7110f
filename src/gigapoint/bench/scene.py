"""The benchmark scene: the demo town, its two views, and its points as float32 for baselines."""

from __future__ import annotations

import statistics
import time

import numpy as np

from ..core import cloud_from_points
from ..core.quantize import dequantize
from ..io.demo import demo_arrays
from ..render import Camera

THROUGHPUT_DEFINITION = "points/s = points in the cloud / median wall-clock frame time (JIT warm-up excluded)"
VIEWS = ("overview", "closeup")
_GL_UPLOAD_CHUNK = 4_000_000  # points dequantized at a time


def demo_cloud(n_points: int, seed: int = 0, timings: dict | None = None, runs: int = 1):
    """``gigapoint.demo(n_points, seed)`` built from one ``demo_arrays`` call, timing both steps.

    The points are the same as ``gigapoint.demo`` (every demo point is a pure function of
    its index, so one call equals the concatenated chunks). With ``timings`` the scene is
    generated once untimed (page faults, JIT cache loading), then ``runs`` times timed;
    ``timings`` receives ``generate_s`` (the median of those runs), ``generate_runs_s`` and
    ``build_s`` (Morton sort + batching + quantization).
    """
    times = []
    if timings is not None:
        demo_arrays(n_points, seed)
    for _ in range(max(1, runs) if timings is not None else 1):
        xyz = rgba = attrs = None  # let the previous run's arrays go first
        t0 = time.perf_counter()
        xyz, rgba, attrs = demo_arrays(n_points, seed)
        times.append(time.perf_counter() - t0)
    t1 = time.perf_counter()
    cloud = cloud_from_points(xyz, rgba, attrs, name=f"demo({n_points:,})")
    t2 = time.perf_counter()
    if timings is not None:
        timings["generate_s"] = statistics.median(times)
        timings["generate_runs_s"] = times
        timings["build_s"] = t2 - t1
    return cloud


def benchmark_cameras(bounds, width: int, height: int) -> dict[str, Camera]:
    """The two benchmark views of a demo-like scene with ``bounds``."""
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    size = hi - lo
    overview = Camera.fit((lo, hi), view="iso", width=width, height=height)
    # 45 m from a 23 m tall building near the south edge of the town (lot 5,1 of the demo
    # scene), slightly above its roof line, looking north-east across the town: nearby
    # batches project large (20/30 bits) and everything behind the camera is culled.
    target = (lo[0] + 0.55 * size[0], lo[1] + 0.15 * size[1], lo[2] + 0.35 * size[2])
    closeup = Camera.orbit(target, yaw=-120.0, pitch=12.0, distance=45.0, width=width, height=height, fov=60.0, near=1.0)
    return {"overview": overview, "closeup": closeup}


def comparison_cameras(cloud) -> dict[str, Camera]:
    """Five small frames of a demo-like ``cloud`` that the GPU tier draws with both backends
    (tests/unit/test_wgpu_backend.py, benchmarks/gpu_exactness.py): the fitted iso view, from
    above, from inside the town, a close-up of a surface point (30-bit batches) and orthographic."""
    lo, hi = cloud.bounds
    c = (lo + hi) / 2
    p = cloud.positions([cloud.n_points // 2])[0]  # a surface point for the close-up
    return {
        "iso": Camera.fit(cloud.bounds, width=320, height=240),
        "top": Camera.fit(cloud.bounds, view="top", width=256, height=256),
        "inside": Camera.look_at((c[0], c[1], lo[2] + 20), (c[0] + 300, c[1] + 50, lo[2] + 10), width=320, height=200),
        "closeup": Camera.look_at(tuple(p + [0.4, 0.3, 0.8]), tuple(p), fov=40, width=240, height=180),
        "ortho": Camera.fit(cloud.bounds, view="front", width=300, height=200, projection="orthographic"),
    }


def relative_positions(cloud, center, batch_ids) -> np.ndarray:
    """float32 (k, 3) positions (30-bit decode) minus ``center`` of the points of consecutive batches."""
    b = cloud.batches[batch_ids]
    counts = b["count"].astype(np.int64)
    lo = np.repeat(b["bbox_min"] - center, counts, axis=0)
    hi = np.repeat(b["bbox_max"] - center, counts, axis=0)
    s = slice(int(b["first"][0]), int(b["first"][-1]) + int(counts[-1]))
    return dequantize(cloud.low[s], cloud.med[s], cloud.high[s], lo, hi, 30).astype(np.float32)


def relative_chunks(cloud, center):
    """(first point, float32 positions minus ``center``) of the whole cloud, a few million points at a time."""
    per_chunk = max(1, _GL_UPLOAD_CHUNK // max(1, int(cloud.batches["count"].max())))
    for k in range(0, len(cloud.batches), per_chunk):
        ids = np.arange(k, min(k + per_chunk, len(cloud.batches)))
        yield int(cloud.batches["first"][k]), relative_positions(cloud, center, ids)


def relative_cloud(cloud, center) -> np.ndarray:
    """float32 (N, 3) positions minus ``center`` of every point, in cloud order (the naive loop's input)."""
    xyz = np.empty((cloud.n_points, 3), np.float32)
    for first, chunk in relative_chunks(cloud, center):
        xyz[first : first + len(chunk)] = chunk
    return xyz


def coverage_iou(covered: np.ndarray, reference: np.ndarray) -> float:
    """Intersection over union of two covered-pixel masks (1 when both are empty)."""
    union = int((covered | reference).sum())
    return int((covered & reference).sum()) / union if union else 1.0


