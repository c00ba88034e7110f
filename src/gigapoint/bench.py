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

import math
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
from numba import njit, prange

from .backends.numba_cpu.backend import _KERNEL_LOCK
from .backends.numba_cpu.raster import EMPTY, TILE_SHIFT, fill_empty, merge, resolve_colors
from .core import cloud_from_points, demo_arrays
from .core.quantize import dequantize
from .errors import GigapointError
from .render import Camera, RenderSettings, render_frame

THROUGHPUT_DEFINITION = "points/s = points in the cloud / median wall-clock frame time (JIT warm-up excluded)"
VIEWS = ("overview", "closeup")
#: How far the GL image's coverage may differ from gigapoint's (fraction of the image).
COVERAGE_TOLERANCE = 0.03
_GL_UPLOAD_CHUNK = 4_000_000  # points dequantized and uploaded at a time
_MESA_EGL_VENDOR = "/usr/share/glvnd/egl_vendor.d/50_mesa.json"


# --- the scene ------------------------------------------------------------------------
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


# --- gigapoint ------------------------------------------------------------------------
def _time_gigapoint(cloud, camera: Camera, settings: RenderSettings, repeats: int):
    frame = render_frame(cloud, camera, settings)  # warm-up: JIT, scratch buffers
    times, raster = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        frame = render_frame(cloud, camera, settings)
        times.append(time.perf_counter() - t0)
        raster.append(frame.stats.raster_ms)
    return frame, times, raster


# --- the OpenGL baseline --------------------------------------------------------------
_VERTEX_SHADER = """
#version 330
uniform mat4 mvp;
in vec3 in_pos;
in vec4 in_color;
out vec4 v_color;
void main() {
    gl_Position = mvp * vec4(in_pos, 1.0);
    v_color = in_color;
}
"""
_FRAGMENT_SHADER = """
#version 330
in vec4 v_color;
out vec4 f_color;
void main() {
    f_color = v_color;
}
"""


def gl_matrix(camera: Camera, near: float, far: float, center) -> np.ndarray:
    """float64 4x4 clip matrix for points given relative to ``center``, matching gigapoint's projection.

    Window x, y equal gigapoint's pixel coordinates (x'/w, y'/w, row 0 first in memory),
    so a framebuffer read back needs no flip; depth maps [near, far] to [-1, 1].
    """
    rows = camera.screen_rows()
    e4 = np.array([0.0, 0.0, 0.0, 1.0])
    w_row, depth = rows[2], rows[3]
    if camera.projection == "perspective":  # w == depth
        z_row = (far + near) / (far - near) * depth - 2.0 * far * near / (far - near) * e4
    else:  # w == 1
        z_row = 2.0 / (far - near) * depth - (far + near) / (far - near) * e4
    clip = np.stack([2.0 / camera.width * rows[0] - w_row, 2.0 / camera.height * rows[1] - w_row, z_row, w_row])
    to_world = np.eye(4)
    to_world[:3, 3] = center
    return clip @ to_world


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


class GLBaseline:
    """GL_POINTS of one cloud through moderngl on an offscreen EGL context (Mesa llvmpipe)."""

    def __init__(self, width: int, height: int, software: bool = True):
        try:
            import moderngl
        except ImportError as exc:
            raise GigapointError(f"GL baseline needs moderngl ({exc}); install with: pip install 'gigapoint[bench]'") from None
        self.mgl = moderngl
        # software: Mesa's llvmpipe even where a GPU driver exists (the baseline is GL on the CPU);
        # the variables only steer driver selection, so they are restored once the context exists.
        steer = {"LIBGL_ALWAYS_SOFTWARE": "1"}
        if Path(_MESA_EGL_VENDOR).is_file():
            steer["__EGL_VENDOR_LIBRARY_FILENAMES"] = _MESA_EGL_VENDOR
        saved = {k: os.environ.get(k) for k in steer} if software else {}
        try:
            if software:
                os.environ.update({k: os.environ.get(k, v) for k, v in steer.items()})
            self.ctx = moderngl.create_standalone_context(backend="egl", require=330)
        except Exception as exc:  # noqa: BLE001 - no libEGL, no driver, no display: say why in one line
            raise GigapointError(f"GL baseline: no EGL/OpenGL 3.3 context ({_first_line(exc)})") from None
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        self.renderer = f"{self.ctx.info.get('GL_RENDERER', '?')} / {self.ctx.info.get('GL_VERSION', '?')}"
        self.prog = self.ctx.program(vertex_shader=_VERTEX_SHADER, fragment_shader=_FRAGMENT_SHADER)
        self.width, self.height = width, height
        self.fbo = self.ctx.framebuffer(
            color_attachments=[self.ctx.renderbuffer((width, height), 4)],
            depth_attachment=self.ctx.depth_renderbuffer((width, height)),
        )
        self.vao = None
        self._buffers: list = []

    def upload(self, cloud, center) -> None:
        """Float32 positions relative to ``center`` and u8 colors of every point, in cloud order."""
        self._release_buffers()
        n = cloud.n_points
        pos = self.ctx.buffer(reserve=n * 12)
        for first, chunk in relative_chunks(cloud, center):
            pos.write(chunk.tobytes(), offset=first * 12)
        col = self.ctx.buffer(cloud.color)
        self._buffers = [pos, col]
        self.vao = self.ctx.vertex_array(self.prog, [(pos, "3f", "in_pos"), (col, "4f1", "in_color")])
        self.n_points = n

    def draw(self, matrix: np.ndarray, background=(0, 0, 0, 255)) -> float:
        """One frame (clear + draw + glFinish); its wall-clock seconds."""
        ctx = self.ctx
        t0 = time.perf_counter()
        self.fbo.use()
        ctx.enable(self.mgl.DEPTH_TEST)
        ctx.point_size = 1.0
        self.prog["mvp"].write(matrix.T.astype("f4").tobytes())  # GL reads column-major
        self.fbo.clear(*(c / 255.0 for c in background), depth=1.0)
        self.vao.render(self.mgl.POINTS)
        ctx.finish()
        return time.perf_counter() - t0

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """(H, W, 4) uint8 image (row 0 = gigapoint's top row) and (H, W) bool coverage."""
        img = np.frombuffer(self.fbo.read(components=4, alignment=1), np.uint8).reshape(self.height, self.width, 4)
        depth = np.frombuffer(self.fbo.read(components=1, attachment=-1, dtype="f4", alignment=1), np.float32).reshape(
            self.height, self.width
        )
        return img.copy(), depth < 1.0

    def _release_buffers(self) -> None:
        if self.vao is not None:
            self.vao.release()
            self.vao = None
        for b in self._buffers:
            b.release()
        self._buffers = []

    def release(self) -> None:
        self._release_buffers()
        self.fbo.release()
        self.prog.release()
        self.ctx.release()


# --- the naive baseline ---------------------------------------------------------------
@njit(parallel=True, cache=True, error_model="numpy")  # numpy's model: no zero-division branch on x'/w
def naive_raster(xyz, m, width, height, near, far, bufs):
    """The first loop one writes: point i of ``xyz`` (float32 (N, 3)) through ``m`` (float32
    4x4, rows x', y', w, depth), depth-tested into thread t's buffer ``bufs[t]`` (EMPTY on
    entry) with the key (depth bits << 32 | i). Thread t takes the t-th contiguous share of
    the points; no batches, no culling, no quantization, no vectorised phases."""
    n = xyz.shape[0]
    n_threads = bufs.shape[0]
    for t in prange(n_threads):
        buf = bufs[t]
        depth = np.empty(1, np.float32)
        depth_bits = depth.view(np.uint32)
        for i in range(t * n // n_threads, (t + 1) * n // n_threads):
            x, y, z = xyz[i, 0], xyz[i, 1], xyz[i, 2]
            sx = m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3]
            sy = m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3]
            sw = m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3]
            sd = m[3, 0] * x + m[3, 1] * y + m[3, 2] * z + m[3, 3]
            if sw <= 0 or sd <= near or sd >= far:
                continue
            px = sx / sw
            py = sy / sw
            if px < 0 or px >= width or py < 0 or py >= height:
                continue
            p = np.int64(py) * width + np.int64(px)
            depth[0] = sd
            key = (np.uint64(depth_bits[0]) << np.uint64(32)) | np.uint64(i)
            if key < buf[p]:
                buf[p] = key


def naive_matrix(camera: Camera, center) -> np.ndarray:
    """float32 rows (x', y', w, depth) of ``camera`` for points given relative to ``center``."""
    to_world = np.eye(4)
    to_world[:3, 3] = center
    return (camera.screen_rows() @ to_world).astype(np.float32)


def naive_frame(xyz, color, camera: Camera, near: float, far: float, n_threads: int, background=(0, 0, 0, 255), center=(0.0, 0.0, 0.0)):
    """(visibility (H*W,) u64, colors (H*W,) u32, seconds in ``naive_raster``) of one naive frame:
    clear the per-thread buffers, the loop, the merge, and gigapoint's own colour resolve."""
    import numba

    n_pixels = camera.width * camera.height
    with _KERNEL_LOCK:  # numba's parallel kernels: one caller at a time (backends/numba_cpu/backend.py)
        previous = numba.get_num_threads()
        numba.set_num_threads(n_threads)
        try:
            bufs = np.empty((n_threads, n_pixels), np.uint64)
            for b in bufs:
                fill_empty(b)
            t0 = time.perf_counter()
            naive_raster(xyz, naive_matrix(camera, center), camera.width, camera.height, np.float32(near), np.float32(far), bufs)
            t1 = time.perf_counter()
            frame = bufs[0]
            if n_threads > 1:  # gigapoint's merge with every tile flagged: the naive loop keeps no flags
                merge(frame, bufs[1:], np.ones((n_threads, (n_pixels >> TILE_SHIFT) + 1), np.uint8))
            colors = np.empty(n_pixels, np.uint32)
            resolve_colors(frame, color, np.array(background, np.uint8).view(np.uint32)[0], colors)
        finally:
            numba.set_num_threads(previous)
    return frame, colors, t1 - t0


def coverage_iou(covered: np.ndarray, reference: np.ndarray) -> float:
    """Intersection over union of two covered-pixel masks (1 when both are empty)."""
    union = int((covered | reference).sum())
    return int((covered & reference).sum()) / union if union else 1.0


def _measure_naive(row: dict, xyz, cloud, camera: Camera, center, background, repeats: int, best) -> np.ndarray:
    """Time the naive loop's frame for one view with gigapoint's best thread count, fill ``row``,
    return its image."""
    near, far = camera.clip_range(cloud.bounds)
    gp_row, gp_frame = best
    n_threads = gp_row["threads"]
    naive_frame(xyz, cloud.color, camera, near, far, n_threads, background, center)  # warm-up: JIT cache, page faults
    times, kernel = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        vis, colors, k = naive_frame(xyz, cloud.color, camera, near, far, n_threads, background, center)
        times.append(time.perf_counter() - t0)
        kernel.append(k)
    covered = (vis != EMPTY).reshape(camera.height, camera.width)
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


# --- the benchmark --------------------------------------------------------------------
def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


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
    out_dir = None
    if out is not None:
        out_dir = Path(out)
        if out_dir.exists() and not out_dir.is_dir():
            raise GigapointError(f"{out_dir}: benchmark output must be a directory")
        out_dir.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda message: None)
    # Validate settings and image size before any work.
    settings_for = {t: RenderSettings(threads=t, backend="cpu") for t in threads}
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
                    n_reason = f"GL could not take {n:,} points ({_first_line(exc)})"
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
                        gl_row.update(skipped=True, reason=f"GL draw failed ({_first_line(exc)})")
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


# --- argument parsing and output ------------------------------------------------------
_SUFFIXES = {"k": 10**3, "m": 10**6, "g": 10**9, "b": 10**9}


def parse_count(text) -> int:
    """'20M', '100_000_000', '1e6', '200k' -> a positive int."""
    s = str(text).strip().lower().replace("_", "").replace(",", "")
    mult = 1
    if s and s[-1] in _SUFFIXES:
        s, mult = s[:-1], _SUFFIXES[s[-1]]
    try:
        value = float(s) * mult
    except ValueError:
        raise GigapointError(f"--points: cannot read {text!r} (use e.g. 20M, 200k, 1e6 or 5000000)") from None
    if not (math.isfinite(value) and value >= 1 and value == int(value)):
        raise GigapointError(f"--points: need a positive whole number of points, got {text!r}")
    return int(value)


def parse_threads(text) -> int | None:
    """'all' -> None (every core), else a positive int."""
    s = str(text).strip().lower()
    if s in ("all", "none", "0"):
        return None
    try:
        value = int(s)
    except ValueError:
        raise GigapointError(f"--threads: need a positive integer or 'all', got {text!r}") from None
    if value < 1:
        raise GigapointError(f"--threads: need a positive integer or 'all', got {text!r}")
    return value


def write_results(results: list[dict], path) -> Path:
    """Write the results as JSON (atomically) and return the path."""
    import json

    path = Path(path)
    if not path.parent.is_dir():
        raise GigapointError(f"{path}: directory {path.parent} does not exist")
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_text(json.dumps(results, indent=2) + "\n")
    os.replace(tmp, path)
    return path


# --- presentation ---------------------------------------------------------------------
def _mps(v: float) -> str:
    return f"{v / 1e6:,.1f} M" if math.isfinite(v) else "-"


def _short(n: int) -> str:
    """1234567 -> '1.23M', 4096 -> '4.1k'."""
    for div, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if n >= div:
            return f"{n / div:.3g}{unit}"
    return str(n)


def _render_row(table, r: dict, step: str, threads: str, note: str, culled: str = "", bits: str = "") -> None:
    """One timed frame's row: gigapoint, the naive loop or GL_POINTS."""
    table.add_row(_short(r["points"]), step, r["view"], threads, f"{r['frame_ms']:,.1f}", _mps(r["points_per_second"]), culled, bits, f"{r['coverage']:.1%}", note)


def results_table(results: list[dict]):
    """A rich Table of ``run_render_benchmark`` results."""
    from rich.table import Table

    env = next((r for r in results if r["kind"] == "environment"), {})
    table = Table(title="gigapoint brute-force render benchmark", caption=THROUGHPUT_DEFINITION)
    for col in ("points", "step", "view", "threads", "ms", "points/s", "culled", "10/20/30 bit", "coverage", "note"):
        table.add_column(col, justify="left" if col in ("step", "view", "note") else "right")
    for r in results:
        if r["kind"] in ("generate", "build"):
            if r["kind"] == "build":
                step, note = "build", f"Morton sort + batching, {r['batches']:,} batches"
            else:
                step, note = "generate", f"demo scene, median of {len(r['seconds_runs'])} after a warm-up run"
            table.add_row(_short(r["points"]), step, "", "", f"{r['seconds'] * 1e3:,.0f}", _mps(r["points_per_second"]), "", "", "", note)
        elif r["kind"] == "render" and r["renderer"] == "gigapoint":
            h = r["precision_histogram"]
            culled = f"{r['batches_culled']:,}/{r['batches_total']:,}"
            bits = "/".join(_short(h[b]) for b in ("10", "20", "30"))
            _render_row(table, r, "gigapoint", str(r["threads"]), f"raster {r['raster_ms']:,.1f} ms", culled, bits)
        elif r["kind"] == "render" and r["renderer"] == "naive":
            note = f"loop {r['raster_ms']:,.1f} ms; gigapoint / naive = {r['gigapoint_over_naive']:.2f}x; IoU {r['coverage_iou']:.2f}"
            _render_row(table, r, "naive loop", str(r["threads"]), note)
        elif r["kind"] == "render" and r["renderer"] == "gl":
            if r.get("skipped"):
                table.add_row(_short(r["points"]), "GL_POINTS", r["view"], "", "", "", "", "", "", f"skipped: {r['reason']}")
                continue
            ok = "ok" if r["coverage_matches"] else "MISMATCH"
            note = f"gigapoint ({r['gigapoint_threads']} thr) / GL = {r['gigapoint_over_gl']:.1f}x; coverage {ok}, IoU {r['coverage_iou']:.2f}"
            _render_row(table, r, "GL_POINTS", str(env.get("gl_threads", "all")), note)
    if env.get("gl_renderer"):
        table.caption += f"\nGL: {env['gl_renderer']}; CPU: {env['cpu_count']} cores, numba {env['numba']}"
    return table


def print_results(results: list[dict], console=None) -> None:
    """Print the results table (wide enough to stay readable when stdout is not a terminal)."""
    import sys

    from rich.console import Console

    if console is None:
        console = Console() if sys.stdout.isatty() else Console(width=200)
    console.print(results_table(results))


__all__ = [
    "COVERAGE_TOLERANCE",
    "GLBaseline",
    "benchmark_cameras",
    "demo_cloud",
    "gl_matrix",
    "naive_frame",
    "naive_raster",
    "parse_count",
    "parse_threads",
    "print_results",
    "results_table",
    "run_render_benchmark",
    "write_results",
]
