"""`gigapoint render` and `gigapoint demo`."""

from __future__ import annotations

import math
import re
import time
from pathlib import Path
from typing import Optional

import typer

from ..errors import GigapointError
from ..render import VIEWS, Camera, RenderSettings
from . import app
from .output import check_output, save_array, save_image
from .quality_opts import apply_quality, prepare_cloud

_CAMERA_KEYS = {"eye": 3, "target": 3, "up": 3, "yaw": 1, "pitch": 1, "distance": 1, "fov": 1}


def parse_camera(text: str) -> dict:
    """'eye=x,y,z target=x,y,z [up=...]' or 'yaw=.. pitch=.. distance=.. [target=..]' (';' or spaces)."""
    values: dict = {}
    for part in filter(None, re.split(r"[;\s]+", text.strip())):
        key, sep, raw = part.partition("=")
        key = key.strip().lower()
        if not sep or key not in _CAMERA_KEYS:
            raise GigapointError(f"--camera: cannot read {part!r}; expected key=value with keys {', '.join(_CAMERA_KEYS)}")
        try:
            nums = [float(v) for v in raw.split(",")]
        except ValueError:
            raise GigapointError(f"--camera: {key} needs numbers, got {raw!r}") from None
        if len(nums) != _CAMERA_KEYS[key] or not all(math.isfinite(v) for v in nums):
            raise GigapointError(f"--camera: {key} needs {_CAMERA_KEYS[key]} finite number(s), got {raw!r}")
        values[key] = nums if len(nums) > 1 else nums[0]
    look_at = "eye" in values
    orbit = any(k in values for k in ("yaw", "pitch", "distance"))
    if look_at and orbit:
        raise GigapointError("--camera: give either eye/target/up or yaw/pitch/distance, not both")
    if look_at and "target" not in values:
        raise GigapointError("--camera: eye needs a target (eye=x,y,z target=x,y,z)")
    if orbit and not {"yaw", "pitch"} <= set(values):
        raise GigapointError("--camera: orbit needs yaw and pitch (distance and target are optional)")
    if not values:
        raise GigapointError("--camera: empty camera description")
    return values


def make_camera(cloud, width, height, view, camera_text, projection, fov) -> Camera:
    bounds = cloud.bounds
    if camera_text is None:
        return Camera.fit(bounds, view=view, width=width, height=height, fov=fov, projection=projection)
    c = parse_camera(camera_text)
    fov = c.get("fov", fov)
    if "eye" in c:
        return Camera.look_at(c["eye"], c["target"], up=c.get("up", (0, 0, 1)), fov=fov, width=width, height=height)
    fitted = Camera.fit(bounds, view=(c["yaw"], c["pitch"]), width=width, height=height, fov=fov, projection=projection)
    import numpy as np

    target = c.get("target", fitted.target)
    distance = c.get("distance", float(np.linalg.norm(np.subtract(fitted.eye, fitted.target))))
    extra = {"projection": projection, "ortho_height": fitted.ortho_height} if projection == "orthographic" else {}
    return Camera.orbit(target, c["yaw"], c["pitch"], distance, fov=fov, width=width, height=height, **extra)


def print_stats(stats, console=None) -> None:
    from rich.console import Console

    console = console or Console(stderr=True)
    h = stats.precision_histogram
    console.print(
        f"{stats.points_processed:,} of {stats.points_total:,} points, "
        f"{stats.batches_rendered:,} batches drawn, {stats.batches_culled:,} culled, "
        f"precision 10/20/30 bit: {h[10]:,}/{h[20]:,}/{h[30]:,} points, "
        f"{stats.visible_pixels:,} pixels covered, {stats.time_ms:.1f} ms "
        f"({stats.points_processed / max(stats.time_ms, 1e-9) / 1e3:,.1f} M points/s) on {stats.backend}",
        highlight=False,
    )


@app.command()
def render(
    inputs: list[Path] = typer.Argument(..., help="Point cloud files, directories or converted octrees (merged into one scene)."),
    output: Path = typer.Option(..., "-o", "--output", help="Image to write (.png, .jpg, .webp, .tif)."),
    width: int = typer.Option(1920, "--width", "-W"),
    height: int = typer.Option(1080, "--height", "-H"),
    view: str = typer.Option("iso", help=f"Named view: {', '.join(VIEWS)}."),
    camera: Optional[str] = typer.Option(None, help="'eye=x,y,z target=x,y,z [up=x,y,z]' or 'yaw=deg pitch=deg [distance=m] [target=x,y,z]'."),
    projection: str = typer.Option("perspective", help="perspective or orthographic."),
    fov: float = typer.Option(60.0, help="Vertical field of view in degrees."),
    background: str = typer.Option("black", help="Background color: name, #rrggbb or r,g,b."),
    backend: str = typer.Option("auto", help="auto, cpu or wgpu."),
    threads: Optional[int] = typer.Option(None, help="CPU threads (default: all cores)."),
    max_points: int = typer.Option(0, help="Plain clouds: draw at most this many points, every k-th of each batch (a quick preview); 0 = all."),
    point_budget: int = typer.Option(10_000_000, help="Converted octrees: most points a frame draws (largest projected nodes first)."),
    depth_out: Optional[Path] = typer.Option(None, help="Also write the depth buffer (.npy, float32, inf = empty)."),
    index_out: Optional[Path] = typer.Option(None, help="Also write the point index buffer (.npy, int64, -1 = empty)."),
    stats: bool = typer.Option(False, "--stats", help="Print render statistics."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace existing output files."),
    color_mode: str = typer.Option("rgb", "--color-mode", help="rgb, intensity, classification, elevation, return_number, point_source_id, batch, level, normal."),
    colormap: str = typer.Option("viridis", help="Elevation colormap: viridis, turbo, terrain, inferno, gray."),
    elevation_range: Optional[str] = typer.Option(None, help="'low,high' elevations mapped onto the colormap (default: the cloud's z extent)."),
    intensity_range: Optional[str] = typer.Option(None, help="'low,high' intensity contrast range (default: 2nd..98th percentile)."),
    edl: bool = typer.Option(False, "--edl", help="Eye-dome lighting."),
    edl_strength: float = typer.Option(1.0, help="Eye-dome lighting strength."),
    edl_radius: float = typer.Option(1.4, help="Eye-dome lighting radius in pixels."),
    fill_holes: int = typer.Option(0, help="Depth-aware hole filling: 0 off, 1/2/3 = 3x3/5x5/7x7 window."),
    foveated: bool = typer.Option(False, "--foveated", help="Hole filling window grows from 3x3 in the centre to the full size at the border."),
    hqs: bool = typer.Option(False, "--hqs", help="High-quality shading: blend the colors of all points near the front."),
    hqs_depth_tolerance: float = typer.Option(0.01, help="--hqs blends the points at most this fraction behind the closest (0..1)."),
    point_size: int = typer.Option(1, help="Point size in pixels."),
    point_shape: str = typer.Option("square", help="square or round."),
    point_world_size: Optional[float] = typer.Option(None, help="Attenuated points: size in world units, at most --point-size pixels (16 unless given)."),
    splat_softness: float = typer.Option(0.0, help="Soft splats (Kraft's falloff exponent, e.g. 2) blended by --hqs; 0 = hard."),
    supersample: int = typer.Option(1, help="Anti-aliasing: render 1, 2 or 4 times larger and filter down."),
    supersample_filter: str = typer.Option("box", help="--supersample filter: box (exact block mean) or lanczos."),
    stereo: str = typer.Option("none", help="none, side-by-side or anaglyph."),
    ipd: float = typer.Option(0.065, help="Stereo eye distance in world units."),
    convergence: Optional[float] = typer.Option(None, help="Stereo zero-parallax distance in world units (default: the camera's target distance)."),
    lighting: bool = typer.Option(False, "--lighting", help="Blinn-Phong headlight (estimates normals when the cloud has none)."),
    shininess: float = typer.Option(32.0, help="--lighting specular exponent."),
    turntable: Optional[int] = typer.Option(None, help="Write a video of N frames orbiting the cloud instead of an image (-o out.mp4)."),
    fps: float = typer.Option(30.0, help="Frames per second of --turntable videos."),
) -> None:
    """Render point clouds to an image (or a turntable video)."""
    import gigapoint as gp

    if turntable is not None:
        from ..render.video import VIDEO_SUFFIXES

        check_output(output, overwrite, suffixes=VIDEO_SUFFIXES)
    else:
        check_output(output, overwrite)
    for extra in (depth_out, index_out):
        if extra is not None:
            check_output(extra, overwrite, suffixes={".npy"})
    settings = RenderSettings(background=background, backend=backend, threads=threads, max_points=max_points, point_budget=point_budget)
    settings = apply_quality(
        settings, color_mode=color_mode, colormap=colormap, elevation_range=elevation_range, intensity_range=intensity_range, edl=edl,
        edl_strength=edl_strength, edl_radius=edl_radius, fill_holes=fill_holes, foveated=foveated, hqs=hqs, hqs_depth_tolerance=hqs_depth_tolerance,
        point_size=point_size, point_shape=point_shape, point_world_size=point_world_size, splat_softness=splat_softness, supersample=supersample,
        supersample_filter=supersample_filter, stereo=stereo, ipd=ipd, convergence=convergence, lighting=lighting, shininess=shininess,
    )  # fmt: skip
    if projection not in ("perspective", "orthographic"):
        raise GigapointError(f"--projection must be perspective or orthographic, got {projection!r}")
    if view not in VIEWS:
        raise GigapointError(f"--view: unknown view {view!r}; choose one of {', '.join(VIEWS)}")
    # validate the image size before reading anything
    Camera.look_at((0, 0, 1), (0, 0, 0), up=(0, 1, 0), width=width, height=height, fov=fov)
    cloud = gp.open(*inputs)
    prepare_cloud(cloud, settings)
    if turntable is not None:
        from ..render.video import render_turntable

        render_turntable(cloud, turntable, output, settings, width=width, height=height, fov=fov, fps=fps)
        typer.echo(f"wrote {output} ({turntable} frames, {width}x{height}, {cloud.n_points:,} points)")
        return
    cam = make_camera(cloud, width, height, view, camera, projection, fov)
    frame = gp.render_frame(cloud, cam, settings)
    save_image(frame.image, output)
    if depth_out is not None:
        save_array(frame.depth, depth_out)
    if index_out is not None:
        save_array(frame.index, index_out)
    if stats:
        print_stats(frame.stats)
    typer.echo(f"wrote {output} ({width}x{height}, {cloud.n_points:,} points)")


@app.command()
def demo(
    points: int = typer.Option(20_000_000, "--points", "-n", help="Points in the procedural demo scene."),
    output: Path = typer.Option(Path("demo.png"), "-o", "--output"),
    width: int = typer.Option(1920, "--width", "-W"),
    height: int = typer.Option(1080, "--height", "-H"),
    view: str = typer.Option("iso"),
    threads: Optional[int] = typer.Option(None),
    seed: int = typer.Option(0),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing output file."),
) -> None:
    """Generate the procedural demo scene, render it and report how fast each step was."""
    from rich.console import Console

    from ..core import build_cloud, demo_arrays
    from ..core.chunk import PointChunk
    from ..render import render_frame

    console = Console()
    if not 1 <= points <= 4_000_000_000:
        raise GigapointError(f"--points must be between 1 and 4e9, got {points}")
    check_output(output, overwrite)
    Camera.look_at((0, 0, 1), (0, 0, 0), up=(0, 1, 0), width=width, height=height)
    t0 = time.perf_counter()
    xyz, rgba, attrs = demo_arrays(points, seed)
    t1 = time.perf_counter()
    cloud = build_cloud([PointChunk(xyz, rgba, attrs)], name=f"demo({points:,})")
    del xyz, rgba, attrs
    t2 = time.perf_counter()
    cam = Camera.fit(cloud.bounds, view=view, width=width, height=height)
    settings = RenderSettings(threads=threads)
    first = render_frame(cloud, cam, settings)
    times = []
    for _ in range(7):  # the median of 7: this kind of shared host swings 1.5x within seconds
        frame = render_frame(cloud, cam, settings)
        times.append(frame.stats.time_ms)
    median = sorted(times)[3]
    save_image(frame.image, output)
    console.print("(the first run after installing also compiles the numba kernels: later runs are faster)", style="dim", highlight=False)
    console.print(f"demo scene: {points:,} points generated in {t1 - t0:.2f} s ({points / (t1 - t0) / 1e6:.1f} M points/s)", highlight=False)
    console.print(f"Morton sort + batching: {t2 - t1:.2f} s ({points / (t2 - t1) / 1e6:.1f} M points/s), {len(cloud.batches):,} batches", highlight=False)
    console.print(f"first render (JIT compile included): {first.stats.time_ms:.0f} ms", highlight=False)
    console.print(
        f"render {width}x{height} '{view}': {median:.1f} ms per frame (median of 7) = {cloud.n_points / median / 1e3:,.0f} M points/s "
        f"({frame.stats.visible_pixels:,} pixels covered)",
        highlight=False,
    )
    console.print(f"wrote {output}", highlight=False)
