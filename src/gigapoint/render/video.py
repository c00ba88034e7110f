"""Turntable and fly-through videos: one render per frame, written with imageio-ffmpeg.

``render_turntable(cloud, n_frames, path)`` orbits the camera once around the cloud's
centre; ``render_flythrough(cloud, cameras, path)`` renders any camera sequence (e.g.
``interpolate_cameras`` between key cameras). .mp4/.webm/.mkv/.avi go through ffmpeg,
.gif through Pillow. Frames are written as they are rendered (bounded memory) to a
temporary file that replaces ``path`` only when the video is complete.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..atomic import atomic_write, folders_for, output_file_refusal, refuse
from ..errors import GigapointError, check_switch, check_whole, is_real, number_text
from .camera import Camera, auto_view, image_side, sample_points
from .settings import RenderSettings

VIDEO_SUFFIXES = {".mp4", ".webm", ".mkv", ".avi", ".mov", ".gif"}
# how ffmpeg encodes them: H.264 (crf 10), but VP9 in WebM, which holds no H.264 (imageio's
# default codec, libx264, failed every .webm), at constant quality: crf 15 in realtime mode
# (the demo turntable: 42 dB against the H.264 frames, 0.24 s for 30 frames of 640x480;
# imageio's quality=8 gave VP8 at 22 dB)
_H264 = {"codec": "libx264", "quality": 8}
_WEBM = {"codec": "libvpx-vp9", "quality": None, "output_params": ["-deadline", "realtime", "-cpu-used", "8", "-crf", "15", "-b:v", "0", "-row-mt", "1"]}
#: a turntable frame may leave this share of the cloud's points out at each side (a still: camera.TRIM):
#: a frame's far corners often hold a few stray points (autzen_trim's river), which would shrink the rest
TURNTABLE_TRIM = 0.01
#: the adaptive orbit's pitches (degrees): each yaw looks down at the pitch, in 5-degree steps,
#: whose framed view fills most of the image (``fill_pitches``)
TURNTABLE_PITCHES = (25.0, 60.0)
#: yaws at which ``fill_pitches`` searches (a longer orbit interpolates between them)
PITCH_SEARCH_YAWS = 36
#: the most frames a turntable or fly-through takes: 55 minutes at 30 fps, framed one by one (~5 ms a frame)
MAX_TURNTABLE_FRAMES = 100_000
MAX_FPS = 1000  # a GIF's frames last 10 ms at least; a video's frame rate is a few hundred at most
#: a frame lasts 100 s at most: ffmpeg wrote no MP4 or MOV at 1e-6 fps (told once every frame was
#: drawn, as a full disk), and a GIF's frame lasts 655 s at most
MIN_FPS = 0.01


def turntable_cameras(
    cloud, n_frames: int, width=1280, height=720, pitch=None, fov=60.0, margin=1.05, start_yaw=None, projection="perspective"
):
    """n_frames cameras orbiting the cloud once (yaw steps of 360 / n_frames), starting at
    ``start_yaw`` (by default the ``auto`` view's: a long cloud across the image) at ``pitch``
    (by default adaptive: ``fill_pitches``, a flat cloud seen steeply side-on and lower across
    its diagonals, like a drone's orbit; pass a pitch for a level one).

    Each frame is framed like a still (``Camera.fit`` of the cloud's points, ``sample_points``:
    its data, not its box; ``TURNTABLE_TRIM`` of them may be cut at a side), so an elongated
    cloud fills the frame side-on and end-on alike (autzen_trim: 44 % of the frame on average
    and at least 36 %, against 35 % / 26 % at iso's pitch and 12 % at one distance around the
    box's centre); pitches, distances and targets are running means over an eighth of the
    orbit, so the camera glides instead of jumping."""
    from .renderer import check_renderable

    n_frames = check_whole("turntable", "number of frames", n_frames, 1, MAX_TURNTABLE_FRAMES)
    check_renderable(cloud)
    width, height = image_side("width", width), image_side("height", height)  # before width / height divides
    for name, v, lo, hi in (("pitch", pitch, -90, 90), ("start_yaw", start_yaw, -1e6, 1e6)):  # 100: over the top, upside down
        if v is not None and not (is_real(v) and lo <= v <= hi):
            raise GigapointError(f"turntable: {name} must be None or degrees in {lo}..{hi:g}, got {number_text(v)}")
    points = sample_points(cloud)
    start_yaw = auto_view(points, width / height)[0] if start_yaw is None else start_yaw
    yaws = start_yaw + 360.0 * np.arange(n_frames) / n_frames
    fit = {"width": width, "height": height, "fov": fov, "margin": margin, "projection": projection, "points": points, "trim": TURNTABLE_TRIM}
    half = n_frames // 16  # the window: 2 * half + 1 frames, about an eighth of the orbit

    if pitch is None:
        pitches = fill_pitches(cloud.bounds, yaws, fit)  # already gliding
    else:
        pitches = np.full(n_frames, float(pitch))
    fitted = [Camera.fit(cloud.bounds, view=(float(y), float(p)), **fit) for y, p in zip(yaws, pitches)]
    targets = circular_mean(np.array([c.target for c in fitted]), half)
    distances = circular_mean(np.array([float(np.linalg.norm(np.subtract(c.eye, c.target))) for c in fitted]), half)
    if projection == "orthographic":
        extra = {"projection": projection, "ortho_height": max(c.ortho_height for c in fitted)}
    else:
        extra = {}
    return [
        Camera.orbit(tuple(t), float(y), float(p), float(d), fov=fov, width=width, height=height, **extra)
        for y, p, t, d in zip(yaws, pitches, targets, distances)
    ]


def fill_pitches(bounds, yaws, fit: dict) -> np.ndarray:
    """For each of ``yaws`` (an orbit from ``yaws[0]``), a pitch in ``TURNTABLE_PITCHES`` whose
    framed view (``Camera.fit(bounds, **fit)``) fills much of the image with the points.

    The best pitch (``filled_share``, on a quarter of the points) is searched at
    ``PITCH_SEARCH_YAWS`` yaws around the orbit, whatever the number of frames, then averaged
    over an eighth of the orbit (so it glides) and interpolated around the circle."""
    search = float(yaws[0]) + 360.0 * np.arange(PITCH_SEARCH_YAWS) / PITCH_SEARCH_YAWS
    lo, hi = TURNTABLE_PITCHES
    candidates = np.arange(lo, hi + 1e-9, 5.0)
    few = dict(fit, points=fit["points"][::4])
    best = np.array(
        [max(candidates, key=lambda p: filled_share(Camera.fit(bounds, view=(float(y), float(p)), **few), few["points"])) for y in search]
    )
    smooth = circular_mean(best, PITCH_SEARCH_YAWS // 16)
    searched = 360.0 * np.arange(PITCH_SEARCH_YAWS) / PITCH_SEARCH_YAWS  # angles from yaws[0]
    return np.interp(np.remainder(np.asarray(yaws, np.float64) - search[0], 360.0), np.r_[searched, 360.0], np.r_[smooth, smooth[0]])


def circular_mean(values, half: int) -> np.ndarray:
    """Each row of ``values`` averaged with its ``half`` neighbours on either side, wrapping
    around (an orbit's frames), in time and memory linear in the rows: gathering each frame's
    window took n²/8 numbers (a 100 000-frame turntable: 10 GB, "out of memory")."""
    v = np.asarray(values, np.float64)
    centre = v.mean(axis=0)  # sums of offsets from it: UTM-sized targets keep their precision
    sums = np.cumsum(v[np.arange(-half, len(v) + half) % len(v)] - centre, axis=0)
    sums = np.concatenate([np.zeros((1, *v.shape[1:])), sums])
    window = 2 * half + 1
    return (sums[window:] - sums[:-window]) / window + centre


def filled_share(camera: Camera, points: np.ndarray, cols: int = 64) -> float:
    """The share of ``camera``'s image that ``points`` cover, counted on a grid of ``cols``
    columns (and as many rows as the aspect gives) closed over one-cell gaps."""
    rows = max(1, round(cols * camera.height / camera.width))
    p = np.c_[points, np.ones(len(points))] @ camera.screen_rows().T
    p = p[p[:, 2] > 0]
    gx = np.floor(p[:, 0] / p[:, 2] * (cols / camera.width)).astype(np.int64)
    gy = np.floor(p[:, 1] / p[:, 2] * (rows / camera.height)).astype(np.int64)
    inside = (gx >= 0) & (gx < cols) & (gy >= 0) & (gy < rows)
    grid = np.zeros((rows + 2, cols + 2), bool)  # a ring of empty cells around the image
    grid[gy[inside] + 1, gx[inside] + 1] = True
    closed = _spread(_spread(grid, np.logical_or), np.logical_and)  # a 3x3 closing: grow, then shrink
    return float(closed[1:-1, 1:-1].mean())


def _spread(grid: np.ndarray, combine) -> np.ndarray:
    """``grid`` combined with its eight one-cell shifts (``np.logical_or``: grown; ``np.logical_and``: shrunk)."""
    out = grid.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                combine(out, np.roll(grid, (dy, dx), axis=(0, 1)), out=out)
    return out


def interpolate_cameras(keys: list[Camera], n_frames: int) -> list[Camera]:
    """n_frames cameras moving linearly through the key cameras: eye, target, field of view and
    an orthographic camera's height; each keeps its segment's first key's up vector and clip
    planes, and the keys' projection and size (one of each)."""
    keys = list(keys)
    if len(keys) < 2:
        raise GigapointError(f"fly-through: needs at least 2 key cameras, got {len(keys)}")
    n_frames = check_whole("fly-through", "number of frames", n_frames, 2, MAX_TURNTABLE_FRAMES)
    _check_one_kind(keys, "fly-through: key cameras")
    if len({k.projection for k in keys}) > 1:
        raise GigapointError(f"fly-through: the key cameras must have one projection, got {sorted({k.projection for k in keys})}")
    ortho = keys[0].projection == "orthographic"
    stops = {name: np.array([getattr(k, name) for k in keys], np.float64) for name in ("eye", "target", "fov")}
    if ortho:
        stops["ortho_height"] = np.array([k.ortho_height for k in keys], np.float64)
    out = []
    for u in np.linspace(0, len(keys) - 1, n_frames):
        i = min(int(u), len(keys) - 2)
        f = u - i
        at = {name: v[i] * (1 - f) + v[i + 1] * f for name, v in stops.items()}
        k = keys[i]
        height = float(at["ortho_height"]) if ortho else None
        out.append(
            Camera(
                eye=tuple(at["eye"]), target=tuple(at["target"]), up=k.up, fov=float(at["fov"]), width=k.width, height=k.height,
                projection=k.projection, ortho_height=height, near=k.near, far=k.far,
            )
        )
    return out


def check_video_path(path, overwrite: bool = False) -> Path:
    """``path`` as a video's output: refused in one line before any frame (render --turntable asks too)."""
    check_switch("overwrite", overwrite, "video")
    path = Path(path)
    # before any frame (a path through a file: "Not a directory" came once every frame was drawn)
    refuse(path, output_file_refusal(path, overwrite, "a video file", VIDEO_SUFFIXES, "video"), GigapointError)
    return path


def _check_fps(fps) -> None:
    if not (is_real(fps) and MIN_FPS <= fps <= MAX_FPS):  # "a": a TypeError
        raise GigapointError(f"video fps must be a number in [{MIN_FPS:g}, {MAX_FPS:g}], got {number_text(fps)}")


def render_flythrough(
    cloud, cameras, path, settings: RenderSettings | None = None, fps: float = 30.0, progress=None, overwrite: bool = False,
    **setting_overrides,
) -> Path:
    """Render ``cameras`` one after another into the video ``path``; returns the path.

    An existing file at ``path`` is replaced only with ``overwrite=True``. ``progress(done,
    total)`` is called after each frame. Settings as ``render`` takes them: ``settings`` and/or
    keywords (``edl=True``)."""
    from .renderer import render

    path = check_video_path(path, overwrite)
    settings = RenderSettings.of(settings).given(**setting_overrides)  # (before any frame: a bad one is told at once)
    _check_fps(fps)
    cameras = list(cameras)
    if not cameras:
        raise GigapointError("video: no cameras to render")
    _check_cameras(cameras, path)  # before any frame: a later one of another size left ffmpeg's part-written file

    def write(tmp: Path) -> None:  # a temporary file that replaces ``path`` once the video is complete
        if path.suffix.lower() == ".gif":
            from PIL import Image

            frames = []
            for i, cam in enumerate(cameras):
                frames.append(Image.fromarray(render(cloud, cam, settings)[..., :3]))
                if progress is not None:
                    progress(i + 1, len(cameras))
            frames[0].save(tmp, save_all=True, append_images=frames[1:], duration=round(1000 / fps), loop=0)
        else:
            try:
                import imageio.v2 as imageio
            except ImportError:
                raise GigapointError("videos need imageio and imageio-ffmpeg (pip install 'gigapoint[quality]')") from None
            # even sizes for yuv420p; macro_block_size=1 keeps ours as they are; ffmpeg quiet: its
            # failures are told here in one line (_check_video), not in its many
            encoding = _WEBM if path.suffix.lower() == ".webm" else _H264
            try:
                with imageio.get_writer(str(tmp), fps=fps, macro_block_size=1, format="FFMPEG", ffmpeg_log_level="quiet", **encoding) as writer:
                    for i, cam in enumerate(cameras):
                        writer.append_data(np.ascontiguousarray(render(cloud, cam, settings)[..., :3]))
                        if progress is not None:
                            progress(i + 1, len(cameras))
            except OSError:  # ffmpeg stopped reading its frames (a broken pipe, told in many lines)
                pass
            _check_video(tmp, path, len(cameras))

    with folders_for(path):  # (those missing: check_video_path; removed if the video fails)
        atomic_write(path, write)
    return path


def _check_video(tmp: Path, path: Path, frames: int) -> None:
    """A one-line error unless ffmpeg's file ``tmp`` holds ``frames`` frames: imageio-ffmpeg
    does not look at ffmpeg's exit status, so a full disk left a video without its index
    ("moov atom not found") that was reported written. Its frames are counted by ffmpeg
    (a stream copy, nothing decoded: 0.06 s for 30 frames)."""
    import shutil

    import imageio_ffmpeg

    try:
        found, _ = imageio_ffmpeg.count_frames_and_secs(str(tmp))
    except (RuntimeError, OSError):  # not a video ffmpeg can read
        found = None
    if found != frames:
        held = "no readable video" if found is None else f"{found} of {frames} frames"
        free = shutil.disk_usage(tmp.parent).free
        raise GigapointError(f"{path}: ffmpeg could not write the video ({held}; {free:,} bytes free on its disk)")


def _check_one_kind(cameras: list, what: str) -> None:
    """One-line errors, starting ``what: ``, unless ``cameras`` are Cameras of one size."""
    for i, cam in enumerate(cameras):
        if not isinstance(cam, Camera):
            raise GigapointError(f"{what}: camera {i} must be a gigapoint.Camera, got {type(cam).__name__}")
        if (cam.width, cam.height) != (cameras[0].width, cameras[0].height):
            raise GigapointError(
                f"{what}: every camera must have one size: camera {i} is {cam.width}x{cam.height}, camera 0 {cameras[0].width}x{cameras[0].height}"
            )


def _check_cameras(cameras: list, path: Path) -> None:
    """One-line errors for what a video cannot hold: something not a Camera, frames of two
    sizes, odd sizes where ffmpeg encodes (yuv420p)."""
    _check_one_kind(cameras, "video")
    _check_even(path, cameras[0].width, cameras[0].height)


def _check_even(path: Path, width: int, height: int) -> None:
    """ffmpeg encodes yuv420p: even sizes but for a GIF."""
    if path.suffix.lower() != ".gif" and (width % 2 or height % 2):
        raise GigapointError(f"{path}: width and height must be even for video encoding, got {width}x{height}")


def check_turntable(path, n_frames, width, height, fps, overwrite: bool = False) -> None:
    """The one-line errors of a turntable that need no cloud: the path, the number of frames,
    the image size (even but for a GIF) and fps; `gigapoint render --turntable` asks before it
    reads its inputs (a bad --fps or an odd --width was told once a large file was read)."""
    path = check_video_path(path, overwrite)
    check_whole("turntable", "number of frames", n_frames, 1, MAX_TURNTABLE_FRAMES)
    width, height = image_side("width", width), image_side("height", height)
    _check_fps(fps)
    _check_even(path, width, height)


def render_turntable(
    cloud,
    n_frames: int,
    path,
    settings: RenderSettings | None = None,
    width=1280,
    height=720,
    pitch=None,
    fov=60.0,
    fps=30.0,
    progress=None,
    overwrite: bool = False,
    **setting_overrides,
) -> Path:
    """A video of the camera orbiting the cloud once in ``n_frames`` frames (``turntable_cameras``).
    An existing file at ``path`` is replaced only with ``overwrite=True``; sizes as
    ``render_flythrough`` takes them (even, but for a GIF); settings as ``render`` takes them."""
    check_turntable(path, n_frames, width, height, fps, overwrite)  # before any frame is rendered
    settings = RenderSettings.of(settings).given(**setting_overrides)
    cameras = turntable_cameras(cloud, n_frames, width, height, pitch, fov)
    return render_flythrough(cloud, cameras, path, settings, fps, progress, overwrite)
