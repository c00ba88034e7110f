"""Turntable and fly-through videos: one render per frame, written with imageio-ffmpeg.

``render_turntable(cloud, n_frames, path)`` orbits the camera once around the cloud's
centre; ``render_flythrough(cloud, cameras, path)`` renders any camera sequence (e.g.
``interpolate_cameras`` between key cameras). .mp4/.webm/.mkv/.avi go through ffmpeg,
.gif through Pillow. Frames are written as they are rendered (bounded memory) to a
temporary file that replaces ``path`` only when the video is complete.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..errors import GigapointError
from .camera import Camera
from .settings import RenderSettings

VIDEO_SUFFIXES = {".mp4", ".webm", ".mkv", ".avi", ".mov", ".gif"}


def turntable_cameras(
    cloud, n_frames: int, width=1280, height=720, pitch=30.0, fov=60.0, margin=1.05, start_yaw=-90.0, projection="perspective"
):
    """n_frames cameras orbiting the cloud's centre once (yaw steps of 360 / n_frames), all at one
    distance: the largest that ``Camera.fit`` needs over the orbit, so nothing leaves the frame."""
    if not (isinstance(n_frames, (int, np.integer)) and n_frames >= 1):
        raise GigapointError(f"turntable: number of frames must be a positive integer, got {n_frames!r}")
    views = [(start_yaw + 360.0 * i / n_frames, pitch) for i in range(n_frames)]
    fitted = [Camera.fit(cloud.bounds, view=v, width=width, height=height, fov=fov, margin=margin, projection=projection, recenter=False) for v in views]
    lo, hi = (np.asarray(b, np.float64) for b in cloud.bounds)
    center = tuple((lo + hi) / 2)
    distance = max(float(np.linalg.norm(np.subtract(c.eye, c.target))) for c in fitted)
    extra = {"projection": projection, "ortho_height": max(c.ortho_height for c in fitted)} if projection == "orthographic" else {}
    return [Camera.orbit(center, v[0], v[1], distance, fov=fov, width=width, height=height, **extra) for v in views]


def interpolate_cameras(keys: list[Camera], n_frames: int) -> list[Camera]:
    """n_frames cameras moving linearly (eye and target) through the key cameras."""
    if len(keys) < 2 or n_frames < 2:
        raise GigapointError("fly-through: needs at least 2 key cameras and 2 frames")
    eyes = np.array([k.eye for k in keys])
    targets = np.array([k.target for k in keys])
    t = np.linspace(0, len(keys) - 1, n_frames)
    out = []
    for u in t:
        i = min(int(u), len(keys) - 2)
        f = u - i
        eye = eyes[i] * (1 - f) + eyes[i + 1] * f
        target = targets[i] * (1 - f) + targets[i + 1] * f
        out.append(Camera.look_at(tuple(eye), tuple(target), up=keys[i].up, fov=keys[i].fov, width=keys[0].width, height=keys[0].height))
    return out


def _check_path(path) -> Path:
    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise GigapointError(f"{path}: unsupported video type {path.suffix or '(none)'!r}; use one of {', '.join(sorted(VIDEO_SUFFIXES))}")
    if not path.parent.exists():
        raise GigapointError(f"{path}: directory {path.parent} does not exist")
    return path


def render_flythrough(cloud, cameras, path, settings: RenderSettings | None = None, fps: float = 30.0, progress=None) -> Path:
    """Render ``cameras`` one after another into the video ``path``; returns the path."""
    from .renderer import render

    path = _check_path(path)
    settings = settings or RenderSettings()
    if not (math.isfinite(fps) and fps > 0):
        raise GigapointError(f"video fps must be > 0, got {fps!r}")
    cameras = list(cameras)
    if not cameras:
        raise GigapointError("video: no cameras to render")

    def write(tmp: Path) -> None:  # a temporary file that replaces ``path`` once the video is complete
        if path.suffix.lower() == ".gif":
            from PIL import Image

            frames = [Image.fromarray(render(cloud, cam, settings)[..., :3]) for cam in cameras]
            frames[0].save(tmp, save_all=True, append_images=frames[1:], duration=round(1000 / fps), loop=0)
        else:
            try:
                import imageio.v2 as imageio
            except ImportError:
                raise GigapointError("videos need imageio and imageio-ffmpeg (pip install 'gigapoint[quality]')") from None
            # even sizes for yuv420p; macro_block_size=1 keeps ours as they are
            with imageio.get_writer(
                str(tmp), fps=fps, codec=None if path.suffix.lower() != ".mp4" else "libx264", quality=8, macro_block_size=1, format="FFMPEG"
            ) as writer:
                for i, cam in enumerate(cameras):
                    writer.append_data(np.ascontiguousarray(render(cloud, cam, settings)[..., :3]))
                    if progress is not None:
                        progress(i + 1, len(cameras))

    atomic_write(path, write)
    return path


def render_turntable(
    cloud,
    n_frames: int,
    path,
    settings: RenderSettings | None = None,
    width=1280,
    height=720,
    pitch=30.0,
    fov=60.0,
    fps=30.0,
    progress=None,
) -> Path:
    """A video of the camera orbiting the cloud once in ``n_frames`` frames."""
    if width % 2 or height % 2:
        raise GigapointError(f"turntable: width and height must be even for video encoding, got {width}x{height}")
    return render_flythrough(cloud, turntable_cameras(cloud, n_frames, width, height, pitch, fov), path, settings, fps, progress)
