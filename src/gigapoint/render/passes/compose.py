"""Passes that combine whole renders: supersampling (anti-aliasing) and stereo pairs.

Supersampling renders at ``s`` times the size (point size and EDL radius scaled along) and
box-filters down with exact integer rounding; the frame's visibility buffer is the
closest key of each s x s block, so depth and picking stay meaningful.

Stereo uses parallel eyes ``ipd`` apart along the camera's right vector and a horizontal
image translation that puts zero parallax at ``convergence`` (default: the camera's
target distance): each eye's image moves by fx * ipd / (2 * convergence) pixels, the
uncovered columns show the background. The default ``ipd`` follows the stereographers'
1/30 rule, convergence / 30: a fixed 6.5 cm put the eyes of a 30 cm scan wider apart than
the object and gave a city no depth; scaled with the scene, a point at the convergence
distance is fx / 30 pixels apart in the two eyes whatever the units. A fov narrower than the
default 60 degrees shrinks it by tan(fov / 2) / tan(30°), keeping that disparity at what a
60 degree view has (``stereo_ipd``). ``side-by-side``
puts the eyes next to each other (2W x H); ``anaglyph`` takes red from the left eye and green and blue from the right.

Each whole render is ``render_one(cloud, camera, settings)`` (the renderer's render_frame,
handed in by it).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from ...core.layout import EMPTY_PIXEL
from ...core.selection import visible_and_size
from ...errors import GigapointWarning, SettingsError, warn
from ..backend import get_backend
from ..camera import MAX_IMAGE_SIDE, Camera
from ..frame import Frame, RenderStats, check_indexable
from . import finish_frame, splat_for


def box_downsample(image: np.ndarray, s: int) -> np.ndarray:
    """(H*s, W*s, C) uint8 -> (H, W, C): the rounded mean of each s x s block (numpy reference)."""
    hs, ws, c = image.shape
    blocks = image.reshape(hs // s, s, ws // s, s, c).astype(np.uint32)
    total = blocks.sum(axis=(1, 3))
    return ((total + (s * s) // 2) // (s * s)).astype(np.uint8)


def block_min(vis: np.ndarray, s: int) -> np.ndarray:
    hs, ws = vis.shape
    return vis.reshape(hs // s, s, ws // s, s).min(axis=(1, 3))


def _inner(settings, **changes):
    return replace(settings, **changes)  # dataclasses.replace: validated again by __post_init__


def supersampled_frame(cloud, camera, settings, render_one) -> Frame:
    s = settings.supersample
    if camera.width * s > MAX_IMAGE_SIDE or camera.height * s > MAX_IMAGE_SIDE:
        raise SettingsError(f"supersample {s}: a {camera.width * s}x{camera.height * s} render exceeds the {MAX_IMAGE_SIDE} pixel limit")
    inner = _inner(
        settings, supersample=1, stereo="none", point_size=min(64, settings.point_size * s), edl_radius=min(16.0, settings.edl_radius * s)
    )
    big = render_one(cloud, camera.with_size(camera.width * s, camera.height * s), inner)
    t0 = time.perf_counter()
    backend = get_backend(settings.backend)
    big_img = np.ascontiguousarray(big.image).reshape(-1, 4).view(np.uint32).reshape(-1)
    with backend.lock:
        vis, image = backend.passes.downsample(np.ascontiguousarray(big.visibility).reshape(-1), big_img, camera.width, camera.height, s)
    vis = vis.reshape(camera.height, camera.width)
    image = image.view(np.uint8).reshape(camera.height, camera.width, 4)
    if settings.supersample_filter == "lanczos":
        from PIL import Image

        image = np.asarray(
            Image.fromarray(np.ascontiguousarray(big.image)).resize((camera.width, camera.height), Image.Resampling.LANCZOS)
        ).copy()
    stats = replace(big.stats)
    stats.time_ms += (time.perf_counter() - t0) * 1000.0
    stats.visible_pixels = int((vis != EMPTY_PIXEL).sum())
    return Frame(vis, image, stats, big.points, big.generation)


def eye_cameras(camera, ipd: float):
    """(left, right) cameras: parallel, ipd apart along the camera's right vector."""
    right = camera.basis()[0] * (ipd / 2.0)
    left = replace(camera, eye=tuple(np.subtract(camera.eye, right)), target=tuple(np.subtract(camera.target, right)))
    rite = replace(camera, eye=tuple(np.add(camera.eye, right)), target=tuple(np.add(camera.target, right)))
    return left, rite


def convergence_distance(camera, convergence: float | None) -> float:
    """The zero-parallax distance: ``convergence``, else the camera's target distance."""
    return convergence if convergence is not None else float(np.linalg.norm(np.subtract(camera.target, camera.eye)))


#: the most pixels ``convergence_shift`` moves an eye's image (far beyond any image's width)
MAX_SHIFT_PX = 1e15

#: the camera's default fov (60 degrees): the normal lens the stereographers' 1/30 rule is for
NORMAL_FOV = Camera.fov


def stereo_ipd(camera, settings) -> float:
    """The eye distance drawn: ``settings.ipd``; when None (auto) the 1/30 rule, or 0 for an
    orthographic camera (its parallel rays see no parallax: moved eyes only double the image).
    A fov narrower than 60 degrees magnifies parallax by tan(30°) / tan(fov / 2): the auto ipd is
    that much smaller (as stereographers shorten the eye distance for a long lens), so each eye's
    image moves H / (120 tan 30°) px, 1.4 % of the height, at any fov up to 60. Without it the
    eyes' images moved fx / 60 px: a 5 degree pair's were 21 % of the width apart, and below
    half a degree both moved out of the picture (a blank pair)."""
    if settings.ipd is not None:
        return settings.ipd
    if camera.projection != "perspective":
        return 0.0
    narrowing = min(1.0, math.tan(math.radians(camera.fov) / 2) / math.tan(math.radians(NORMAL_FOV) / 2))
    return convergence_distance(camera, settings.convergence) / 30.0 * narrowing


def convergence_shift(camera, ipd: float, convergence: float | None) -> int:
    """Pixels each eye's image moves (left eye to the left, right eye to the right)."""
    if camera.projection != "perspective" or ipd == 0:
        return 0
    c = convergence_distance(camera, convergence)
    fx = (camera.width / 2.0) / (math.tan(math.radians(camera.fov) / 2.0) * camera.aspect)
    # a shift beyond the image moves it out of view all the same: capped (ipd 1e300 at convergence
    # 1e-300 was an internal OverflowError, and a 300-digit number of pixels in the warning)
    return round(min(fx * ipd / (2.0 * c), MAX_SHIFT_PX))


def shift_columns(a: np.ndarray, dx: int, fill, out: np.ndarray | None = None) -> np.ndarray:
    """Move an (H, W, ...) array dx columns to the right (left if negative), filling with ``fill``
    (into ``out`` when given; ``a`` itself when dx is 0 and no ``out``)."""
    if dx == 0 and out is None:
        return a
    if out is None:
        out = np.empty_like(a)
    w = a.shape[1]
    if abs(dx) >= w:
        out[...] = fill
    elif dx >= 0:
        out[:, dx:] = a[:, : w - dx]
        out[:, :dx] = fill
    else:
        out[:, : w + dx] = a[:, -dx:]
        out[:, w + dx :] = fill
    return out


def render_views(cloud, cameras, settings, backend, multi) -> list[Frame]:
    """Frames of several cameras of one size drawn in ONE pass over the batches (2022 paper,
    3.7: every point is written into both eyes' buffers), from the cloud's MultiViewDrawList
    ``multi``. Each view keeps its own batch selection, precision, near/far and passes, so each
    frame equals a separate render."""
    t0 = time.perf_counter()
    width, height = cameras[0].width, cameras[0].height
    views = [cam.view(cloud.bounds) for cam in cameras]
    check_indexable(multi.points)
    t1 = time.perf_counter()
    vis = backend.rasterize_views(
        multi.points, multi.ids, multi.bits, multi.matrices, width, height, [v.near for v in views], [v.far for v in views],
        settings.threads, splat_for(settings, cameras[0], multi.views[0], views[0].near),
    )  # fmt: skip
    t2 = time.perf_counter()
    frames = []
    for v, (cam, draw, view) in enumerate(zip(cameras, multi.views, views)):
        t3 = time.perf_counter()
        visibility, colors, _ = finish_frame(backend, draw, cam, vis[v], settings, view.near, view.far)
        counts = draw.points.batches["count"][draw.selection.ids].astype(np.int64)
        time_ms = (t2 - t0) * 1000.0 / len(cameras) + (time.perf_counter() - t3) * 1000.0  # the one pass shared, then this view's passes
        stats = RenderStats.of(draw, counts, cloud.n_points, time_ms, (t2 - t1) * 1000.0 / len(cameras), backend.name)
        visibility = visibility.reshape(height, width)
        stats.visible_pixels = int((visibility != EMPTY_PIXEL).sum())
        frames.append(Frame(visibility, colors.view(np.uint8).reshape(height, width, 4), stats, draw.points, draw.generation))
    return frames


def stereo_frame(cloud, camera, settings, render_one) -> Frame:
    """Render both eyes (one pass over the points where the cloud can) into one stereo Frame."""
    inner = _inner(settings, stereo="none")
    ipd = stereo_ipd(camera, settings)
    cams = eye_cameras(camera, ipd)
    with cloud.reading():
        multi = cloud.prepare_views([cam.view(cloud.bounds) for cam in cams], inner) if inner.supersample == 1 else None
        if multi is not None:
            frames = render_views(cloud, cams, inner, get_backend(inner.backend), multi)
    if multi is None:  # supersampled eyes, octrees (their nodes differ per eye): two renders
        frames = [render_one(cloud, cam, inner) for cam in cams]
    h = convergence_shift(camera, ipd, settings.convergence)
    bg = np.array(settings.background, np.uint8)
    stats = replace(frames[0].stats)
    for f in frames[1:]:
        stats.time_ms += f.stats.time_ms
        stats.raster_ms += f.stats.raster_ms
        stats.points_processed += f.stats.points_processed
    hgt, w = frames[0].visibility.shape
    if settings.stereo == "side-by-side":
        image = np.empty((hgt, 2 * w, 4), np.uint8)
        vis = np.empty((hgt, 2 * w), np.uint64)
        for k, (f, dx) in enumerate(zip(frames, (-h, h))):
            shift_columns(f.image, dx, bg, image[:, k * w : (k + 1) * w])
            shift_columns(f.visibility, dx, EMPTY_PIXEL, vis[:, k * w : (k + 1) * w])
    else:  # anaglyph: red from the left eye, green and blue from the right
        image = shift_columns(frames[1].image, h, bg).copy() if h == 0 else shift_columns(frames[1].image, h, bg)
        image[..., 0] = shift_columns(frames[0].image, -h, bg)[..., 0]
        vis = np.minimum(shift_columns(frames[0].visibility, -h, EMPTY_PIXEL), shift_columns(frames[1].visibility, h, EMPTY_PIXEL))
    stats.visible_pixels = int((vis != EMPTY_PIXEL).sum())
    # an empty pair was a background image without the plain frame's warning (one eye drawn by
    # render_one and empty has said it already)
    if stats.visible_pixels == 0 and (multi is not None or all(f.stats.visible_pixels for f in frames)):
        why = _why_no_eye_sees(cloud, camera, cams, settings, ipd, h, w)
        warn(f"{cloud.name}: no point is in view of the stereo camera{why}; the image shows only the background", GigapointWarning)
    # the buffers both eyes' indices name (point_info was None for every pixel); none where an
    # octree's arena was refilled between the eyes (the first eye's indices name other points now)
    left, right = frames
    same = left.points is right.points and left.generation == right.generation
    return Frame(vis, image, stats, right.points if same else None, right.generation if same else None)


def _why_no_eye_sees(cloud, camera, eyes, settings, ipd: float, shift: int, width: int) -> str:
    """Why a stereo pair shows no point, in brackets, where the eye distance is why ("" where it
    is not: a camera looking away). An explicit ipd can move each eye's image out of the picture
    (the auto one moves it 1.4 % of the height at most, stereo_ipd). Any ipd can put both eyes
    beside a cloud the camera itself sees: the auto one too, of a convergence far beyond the
    cloud (convergence 1e12: eyes 3.3e10 apart; a blank pair without a reason before)."""
    if settings.ipd is not None and abs(shift) >= width:
        moved = f"{abs(shift):,} px" if abs(shift) < MAX_SHIFT_PX else f"over {MAX_SHIFT_PX:g} px"
        return f" (each eye's image moves {moved} of {width}: ipd {ipd:g} world units is wide for this scene)"
    if not _sees_box(camera, cloud.bounds) or any(_sees_box(eye, cloud.bounds) for eye in eyes):
        return ""
    lo, hi = cloud.bounds
    span = float(np.max(hi - lo))
    if settings.ipd is not None:
        return f" (ipd {ipd:g} world units puts each eye beside the cloud, {span:.3g} across: give a smaller ipd)"
    convergence = convergence_distance(camera, settings.convergence)
    return (
        f" (the automatic ipd, {ipd:.2g} world units from convergence {convergence:g}, puts each eye beside the cloud, "
        f"{span:.3g} across: give a convergence near the cloud's distance, or an ipd)"
    )


def _sees_box(camera, bounds) -> bool:
    """Whether the box ``bounds`` is in ``camera``'s view (conservatively: out only with all its corners beyond one side)."""
    lo, hi = (np.asarray(b, np.float64).reshape(1, 3) for b in bounds)
    view = camera.view(bounds)
    visible, _ = visible_and_size(view.rows, lo, hi, view.width, view.height, view.near, view.far)
    return bool(visible[0])


def composite_frame(cloud, camera, settings, render_one) -> Frame:
    """Supersampling or stereo around whole renders made by ``render_one``."""
    if settings.stereo != "none":
        return stereo_frame(cloud, camera, settings, render_one)
    return supersampled_frame(cloud, camera, settings, render_one)
