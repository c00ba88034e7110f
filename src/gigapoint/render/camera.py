"""Camera: perspective or orthographic, built by look-at, orbit or fit-to-bounds.

Conventions: right-handed world, z up by default; the camera looks down its -z axis;
image row 0 is the top. ``fov`` is the vertical field of view in degrees. Orbit angles:
yaw around the up axis measured from +x, pitch above the horizon (positive looks down).
"""

from __future__ import annotations

import functools
import inspect
import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ..core.coords import MAX_SPAN
from ..errors import CameraError, count_or_inf, count_text, is_real, number_text, numbers_text

if TYPE_CHECKING:
    from ..core.selection import View

MAX_IMAGE_SIDE = 16_384
DEFAULT_SIZE = (1920, 1080)  # a fitted camera's image (16:9)
VIEWS = {
    # name: (yaw, pitch) in degrees
    "top": (-90.0, 90.0),
    "front": (-90.0, 0.0),
    "back": (90.0, 0.0),
    "side": (0.0, 0.0),
    "left": (180.0, 0.0),
    "right": (0.0, 0.0),
    "iso": (-135.0, 35.264),
    "auto": (None, None),  # iso, or turned so a long cloud runs across the image (``auto_view``)
}
#: how far (pixels) inside a ``top_down`` image every edge of its box lies: more than the
#: rasterizer's error in px and py (float32 rounding, ~1e-3 px in a 16,384 px image)
EDGE_MARGIN_PX = 1 / 64
#: the largest gsd: a pixel as wide as the span points can have (1e100 drew a blank image, 1e200
#: numpy's warnings and a refused world file)
MAX_GSD = MAX_SPAN
TRIM = 1e-4  # framing sample points: this share at each side may fall outside the frame (a few stray points)
#: the largest coordinate of a camera's vectors, its orbit distance and ortho_height: far beyond any
#: framing of points (within ±1e12), far below where float64 squares overflow (an eye at 1e200 gave
#: numpy's overflow warnings and a blank image)
MAX_CAMERA_COORDINATE = 1e30
#: the keywords look_at and orbit pass on to Camera, and those fit passes on (its projection sets ortho_height)
CAMERA_KEYWORDS = ("projection", "ortho_height", "near", "far")
FIT_KEYWORDS = ("up", "near", "far")


def _check_keywords(method: str, kw: dict, passed_on) -> None:
    """A one-line CameraError naming ``Camera.method`` and a keyword it does not take, with those
    it does (Python's said "Camera.__init__() got an unexpected keyword argument 'foo'")."""
    unknown = [k for k in kw if k not in passed_on]
    if unknown:
        named = [p for p in inspect.signature(getattr(Camera, method)).parameters if p != "kw"]
        raise CameraError(f"Camera.{method}: unknown keyword {', '.join(unknown)} (it takes {', '.join(dict.fromkeys([*named, *passed_on]))})")


def _vec3(value, what: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(c) for c in value)
    except (TypeError, ValueError):
        raise CameraError(f"camera {what} must be three numbers, got {number_text(value)}") from None
    if len(v) != 3:
        raise CameraError(f"camera {what} must be three numbers, got {len(v)}")
    if not all(math.isfinite(c) for c in v):
        raise CameraError(f"camera {what} must be finite, got {numbers_text(v)}")
    if max(map(abs, v)) > MAX_CAMERA_COORDINATE:
        raise CameraError(f"camera {what} must lie within ±{MAX_CAMERA_COORDINATE:g}, got {numbers_text(v)}")
    return v


AUTO_MAX_PITCH = 55.0  # the steepest 'auto' view (a long, flat cloud seen side-on)


def auto_view(points, aspect: float = 16 / 9) -> tuple[float, float]:
    """(yaw, pitch) of the 'auto' view of ``points`` for an image of ``aspect``: iso's for a
    cloud whose plan is about as long as wide (less than 1.3 : 1); else turned so the long
    horizontal axis (the principal axis of the points' xy) runs across the image, seen from
    the side of -y, and looking down more steeply (up to ``AUTO_MAX_PITCH``) where a flat,
    long cloud would fill only a band of the image at iso's pitch."""
    iso_yaw, iso_pitch = VIEWS["iso"]
    p = np.asarray(points, np.float64)
    if len(p) < 3:
        return iso_yaw, iso_pitch
    xy = p[:, :2] - p[:, :2].mean(axis=0)
    evals, evecs = np.linalg.eigh(np.cov(xy.T))
    if not evals[1] > 1.69 * max(evals[0], 0.0):  # the axes' spreads' ratio, squared
        return iso_yaw, iso_pitch
    axis = math.degrees(math.atan2(evecs[1, 1], evecs[0, 1]))
    yaws = [math.remainder(axis + 90.0, 360.0), math.remainder(axis - 90.0, 360.0)]
    yaw = min(yaws, key=lambda y: math.sin(math.radians(y)))  # the eye south of the cloud
    # extents along the long axis, across it and up (less TRIM at each side)
    long_, across = (np.quantile(xy @ evecs[:, k], 1 - TRIM) - np.quantile(xy @ evecs[:, k], TRIM) for k in (1, 0))
    up = np.quantile(p[:, 2], 1 - TRIM) - np.quantile(p[:, 2], TRIM)
    pitch = iso_pitch
    while pitch < AUTO_MAX_PITCH:  # steeper until the side view's height / width reaches the image's
        r = math.radians(pitch)
        if (across * math.sin(r) + up * math.cos(r)) * aspect >= long_:
            break
        pitch = min(AUTO_MAX_PITCH, pitch + 2.5)
    return yaw, pitch


def auto_yaw(points) -> float:
    """The yaw of the 'auto' view of ``points`` (``auto_view``)."""
    return auto_view(points)[0]


def sample_points(cloud, n: int = 20_000) -> np.ndarray:
    """About ``n`` float64 world positions spread over ``cloud`` (any Renderable): every k-th
    point of the batches (octree nodes) that a view of its whole box draws. What framing a
    cloud looks at, rather than its bounding box (whose corners may hold no point at all)."""
    from ..core.compact import point_words
    from ..core.quantize import dequantize
    from .settings import RenderSettings

    bounds = cloud.bounds
    probe = Camera.fit(bounds, view="iso", width=256, height=256)
    with cloud.reading():
        draw = cloud.prepare(probe.view(bounds), RenderSettings())
        rec = draw.points.batches[draw.selection.ids]
        step = max(1, int(rec["count"].sum()) // max(n, 1))
        parts = []
        for b, r in zip(draw.selection.ids.tolist(), rec):
            first, count = int(r["first"]), int(r["count"])
            if count:
                low, med, high = point_words(draw.points, b, first, first + count)  # any layout
                parts.append(dequantize(low[::step], med[::step], high[::step], r["bbox_min"], r["bbox_max"], 30))
    if not parts:
        lo, hi = (np.asarray(b, np.float64) for b in bounds)
        return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return np.concatenate(parts)


def _yaw_pitch(view) -> tuple[float, float]:
    """A view given as (yaw, pitch) degrees: two finite numbers, else a one-line CameraError
    ((1,) was a ValueError of the unpacking, NaN a camera eye that "must be finite")."""
    try:
        yaw, pitch = view
    except (TypeError, ValueError):
        yaw = pitch = None
    if not (is_real(yaw) and is_real(pitch)):
        raise CameraError(f"camera view must be one of {', '.join(VIEWS)} or (yaw, pitch) degrees, got {view!r}")
    return float(yaw), float(pitch)


def _box(bounds) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) float64 corners of ``bounds``, else a one-line CameraError."""
    try:
        lo, hi = bounds  # ((0, 0, 0),) was an IndexError
    except (TypeError, ValueError):
        raise CameraError(f"camera bounds must be (min, max), two points of three numbers, got {bounds!r}") from None
    return np.asarray(_vec3(lo, "bounds min")), np.asarray(_vec3(hi, "bounds max"))


def _corners(lo, hi) -> np.ndarray:
    """(8, 3) the corners of the box from ``lo`` to ``hi``."""
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _round_up(v: float) -> float:
    """``v`` rounded up to three significant digits (a suggested gsd that still fits)."""
    step = 10.0 ** (math.floor(math.log10(v)) - 2)
    return math.ceil(v / step - 1e-9) * step


def image_side(name: str, v) -> int:
    """An image's width or height (``name``) as an int in 1..MAX_IMAGE_SIDE (960.0 taken as 960),
    else a one-line CameraError."""
    if isinstance(v, (float, np.floating)) and v.is_integer():  # (np.float32(960) too)
        v = int(v)
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_IMAGE_SIDE:  # True was 1 pixel
        raise CameraError(f"image {name} must be an integer in 1..{MAX_IMAGE_SIDE}, got {v!r}")
    return int(v)


def image_size(width, height, like: tuple[int, int] = DEFAULT_SIZE) -> tuple[int, int]:
    """(width, height) of an image asked for by either side or both (None: not given); the side not
    given follows ``like``'s aspect (a camera's, by default 16:9), to the nearest pixel, at least 1
    (width=33 was 33x1080). Each side checked as ``image_side`` does; neither given: ``like``."""
    if width is None and height is None:
        return like
    if width is not None:
        width = image_side("width", width)
    if height is not None:
        height = image_side("height", height)
    if height is None:
        return width, _following("height", width * like[1] / like[0], f"width {width}", like)
    if width is None:
        return _following("width", height * like[0] / like[1], f"height {height}", like), height
    return width, height


def _following(name: str, exact: float, given: str, like: tuple[int, int]) -> int:
    """The side of ``image_size`` that follows the aspect (half a pixel rounds up)."""
    side = max(1, math.floor(exact + 0.5))
    if side > MAX_IMAGE_SIDE:
        raise CameraError(f"image {name} would be {side} ({given} at {like[0]}x{like[1]}'s aspect), over {MAX_IMAGE_SIDE}: give both sides")
    return side


@dataclass(frozen=True)
class Camera:
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov: float = 60.0
    width: int = 1920
    height: int = 1080
    projection: str = "perspective"
    ortho_height: float | None = None  # world units seen vertically (orthographic only)
    near: float | None = None  # None: chosen from the scene bounds at render time
    far: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "eye", _vec3(self.eye, "eye"))
        object.__setattr__(self, "target", _vec3(self.target, "target"))
        object.__setattr__(self, "up", _vec3(self.up, "up"))
        for name in ("width", "height"):
            object.__setattr__(self, name, image_side(name, getattr(self, name)))
        if self.projection not in ("perspective", "orthographic"):
            raise CameraError(f"camera projection must be 'perspective' or 'orthographic', got {self.projection!r}")
        if not (is_real(self.fov) and 0.01 <= self.fov <= 179.0):  # (True was a 1 degree view)
            raise CameraError(f"camera fov must be between 0.01 and 179 degrees, got {number_text(self.fov)}")
        if self.projection == "perspective" and self.ortho_height is not None:  # (it was ignored: fov sets the view)
            raise CameraError(f"camera ortho_height is for projection='orthographic'; a perspective camera's view is set by fov, got ortho_height {number_text(self.ortho_height)}")
        d = np.subtract(self.target, self.eye)
        if not np.linalg.norm(d) > 0:
            raise CameraError("camera eye and target are the same point")
        if self.projection == "orthographic":
            h = self.ortho_height
            if not (is_real(h) and h > 0):  # ("10" was math's TypeError)
                raise CameraError(f"orthographic camera needs ortho_height > 0, got {number_text(h)}")
            if h > MAX_CAMERA_COORDINATE:  # (1e308: numpy's warnings in ray)
                raise CameraError(f"orthographic camera needs ortho_height at most {MAX_CAMERA_COORDINATE:g}, got {number_text(h)}")
        if np.linalg.norm(self.up) == 0:
            raise CameraError("camera up vector is zero")
        for name in ("near", "far"):
            v = getattr(self, name)
            if v is not None and not (is_real(v) and v > 0):
                raise CameraError(f"camera {name} must be > 0, got {number_text(v)}")
        if self.near is not None and self.far is not None and self.near >= self.far:
            raise CameraError(f"camera near ({number_text(self.near)}) must be less than far ({number_text(self.far)})")

    # --- constructors -------------------------------------------------------------
    @classmethod
    def look_at(cls, eye, target, up=(0, 0, 1), fov=60.0, width=1920, height=1080, **kw) -> Camera:
        _check_keywords("look_at", kw, CAMERA_KEYWORDS)
        return cls(eye=eye, target=target, up=up, fov=fov, width=width, height=height, **kw)

    @classmethod
    def orbit(cls, target, yaw, pitch, distance, up=(0, 0, 1), fov=60.0, width=1920, height=1080, **kw) -> Camera:
        """Camera at ``distance`` from ``target``, at (yaw, pitch) degrees (z-up world)."""
        _check_keywords("orbit", kw, CAMERA_KEYWORDS)
        for name, v in (("yaw", yaw), ("pitch", pitch), ("distance", distance)):
            if not is_real(v):  # 'a' was math's TypeError, a NaN yaw an eye that "must be finite"
                raise CameraError(f"orbit {name} must be a finite number, got {number_text(v)}")
        if not distance > 0:
            raise CameraError(f"orbit distance must be > 0, got {number_text(distance)}")
        if distance > MAX_CAMERA_COORDINATE:  # (named here, not as the eye it would place)
            raise CameraError(f"orbit distance must be at most {MAX_CAMERA_COORDINATE:g}, got {number_text(distance)}")
        target = np.asarray(_vec3(target, "target"))
        yaw_r, pitch_r = math.radians(yaw), math.radians(pitch)
        direction = np.array([math.cos(pitch_r) * math.cos(yaw_r), math.cos(pitch_r) * math.sin(yaw_r), math.sin(pitch_r)])
        eye = target + distance * direction
        if abs(pitch) >= 89.999:  # straight down or up: keep the image's up along the yaw direction
            up = (-math.cos(yaw_r), -math.sin(yaw_r), 0.0) if pitch > 0 else (math.cos(yaw_r), math.sin(yaw_r), 0.0)
        return cls(eye=tuple(eye), target=tuple(target), up=up, fov=fov, width=width, height=height, **kw)

    @classmethod
    def fit(
        cls, bounds, view="iso", width=1920, height=1080, fov=60.0, projection="perspective", margin=1.05, recenter=True, points=None,
        trim=None, **kw,
    ) -> Camera:  # fmt: skip
        """Camera that frames the box ``bounds = (min, max)`` from a named view or (yaw, pitch).

        ``recenter``: move the target so the box's image is centred (perspective pushes it off
        centre); False keeps the target at the box centre (an orbit around it, a turntable).
        ``points``: (k, 3) positions to frame instead of the box's corners (``sample_points``;
        ``trim`` (default ``TRIM``) of them at each side may fall outside): the data, not its box, fills the frame.
        ``view='auto'``: the (yaw, pitch) ``auto_view`` gives (of ``points``, else the box)."""
        _check_keywords("fit", kw, FIT_KEYWORDS)
        width, height = image_side("width", width), image_side("height", height)  # before width / height divides
        lo, hi = _box(bounds)
        box = _corners(lo, hi)
        if points is not None:
            points = np.asarray(points, np.float64).reshape(-1, 3)
            points = points[np.all(np.isfinite(points), axis=1)]
            # a sample far smaller than the box (PDAL's bcbf EPT: one point at 1, 1, 999 in a 2 km
            # cube) frames the box: framed at the sample, the eye came nearer than the box's near plane
            if len(points) == 0 or np.ptp(points, axis=0).max() < 1e-5 * np.ptp(box, axis=0).max():
                points = None
        if isinstance(view, str):
            if view not in VIEWS:
                raise CameraError(f"unknown view {view!r}; choose one of {', '.join(VIEWS)}")
            yaw, pitch = VIEWS[view]
            if yaw is None:
                yaw, pitch = auto_view(points if points is not None else box, width / height)
        else:
            yaw, pitch = _yaw_pitch(view)
        if not (is_real(margin) and 0 < margin <= 1000):  # 0 or -1 were framed as if 1.05 (the nearest the eye could be)
            raise CameraError(f"camera margin must be a number in (0, 1000] (1: the data touches the frame), got {number_text(margin)}")
        if trim is not None and not (is_real(trim) and 0 <= trim < 0.5):  # 5: numpy's "Quantiles must be in the range [0, 1]"
            raise CameraError(f"camera trim must be a share of the points in [0, 0.5), got {number_text(trim)}")
        trim = (TRIM if trim is None else float(trim)) if points is not None and len(points) > 8 else 0.0
        if points is not None:
            lo, hi = np.quantile(points, trim, axis=0), np.quantile(points, 1.0 - trim, axis=0)
        center = (lo + hi) / 2
        # a cloud more than 1e-14 of its coordinates' size across (~45 float64 steps) is framed by
        # its own size (a floor of 1e-6 of the coordinates framed 0.1 m at 1e9 from 1 km away, a few
        # pixels), at least 1 µm
        size = max(1.0, float(np.abs(center).max()))
        half = float(np.linalg.norm(hi - lo)) / 2
        radius = max(half, 1e-6)
        if half <= 1e-14 * size:
            # a single point (or identical ones): framed as a cube 1 unit (1e-6 of the coordinates'
            # size, at least) from its centre to its corners, the point at the target: the image's
            # centre. A box of 1e-6 of the coordinates was finer than a batch's float32 grid
            # resolves: a blank image
            radius = max(1.0, 1e-6 * size)
            box, points, trim, recenter = _corners(center - radius / math.sqrt(3), center + radius / math.sqrt(3)), None, 0.0, False
        aspect = width / height
        # orientation first (distance 1), then the distance at which every corner fits
        probe = cls.orbit(center, yaw, pitch, 1.0, fov=fov, width=width, height=height)
        right, up, back = probe.basis()
        corners = (points if points is not None else box) - center
        cx, cy, cz = corners @ right, corners @ up, corners @ back

        def extreme(a, side=1.0):
            """The largest of ``a`` (side 1) or its smallest (side -1), less the trimmed share."""
            if trim == 0.0:
                return float(a.max() if side > 0 else a.min())
            return float(np.quantile(a, 1.0 - trim if side > 0 else trim))

        if projection == "orthographic":
            extent_v = max(extreme(np.abs(cy)), extreme(np.abs(cx)) / aspect, radius * 1e-6, 1e-14 * size)
            return cls.orbit(
                center, yaw, pitch, radius * 3, fov=fov, width=width, height=height, projection=projection, ortho_height=2 * extent_v * margin, **kw
            )
        tan_v = math.tan(math.radians(fov) / 2)
        tan_h = tan_v * aspect
        # A corner at (x, y, z) in the camera basis, with the camera `distance` behind the target,
        # is at depth distance - z and fits when |x| <= tan_h * depth (and likewise y). Then the
        # target moves so the box's projection is centred (perspective pushes it down otherwise),
        # and the distance is solved again: two rounds settle it.
        def fitting_distance():
            d = extreme(np.maximum(cz + np.abs(cx) * margin / tan_h, cz + np.abs(cy) * margin / tan_v))
            return max(d, float(cz.max()) + 0.05 * radius)  # every corner well in front of the eye

        distance = fitting_distance()
        for _ in range(2 if recenter else 0):
            depth = distance - cz
            sx, sy = cx / depth / tan_h, cy / depth / tan_v  # -1..1 across the image
            shift_x = (extreme(sx) + extreme(sx, -1)) / 2 * tan_h * distance
            shift_y = (extreme(sy) + extreme(sy, -1)) / 2 * tan_v * distance
            center = center + right * shift_x + up * shift_y
            cx, cy = cx - shift_x, cy - shift_y
            distance = fitting_distance()
        return cls.orbit(center, yaw, pitch, distance, fov=fov, width=width, height=height, projection=projection, **kw)

    @classmethod
    def top_down(cls, bounds, gsd) -> Camera:
        """An orthographic camera looking straight down on the box ``bounds = (min, max)``, north
        up (+y up the image, +x to the right), each pixel ``gsd`` (ground sample distance: the
        cloud's units) a side: an orthophoto or a surface model that a GIS places on its map
        (``world_file``, ``heights``). Pixel edges lie on whole multiples of ``gsd`` (tiles drawn
        alike line up), and the image holds every point of the box, those on its edges too, with
        EDGE_MARGIN_PX to spare: columns floor(min_x / gsd - m) .. floor(max_x / gsd + m) (m the
        margin), rows likewise from y (a box whose max y lies on the grid gets a row above it).
        An image over MAX_IMAGE_SIDE a side is a one-line CameraError naming the finest gsd that fits."""
        lo, hi = _box(bounds)
        if not (is_real(gsd) and 0 < gsd <= MAX_GSD):
            raise CameraError(f"gsd (ground sample distance) must be a number > 0 and at most {MAX_GSD:g}, got {number_text(gsd)}")
        gsd = float(gsd)
        # the rasterizer puts a point into column floor(px) and row floor(py) (px = (x - left) / gsd,
        # py = (top - y) / gsd): column 0 holds x in [left, left + gsd), row 0 y in (top - gsd, top].
        # Its px and py are not exact: decoded positions lie off the true ones (a LAS cloud's ~5e-9
        # above them, an octree's up to half a 30-bit cell either way) and float32 rounds them. A
        # point of the box on an image edge (a max y on the grid: py = -5e-9) fell outside, so each
        # edge of the box lies at least EDGE_MARGIN_PX inside the image (a row or column more there).
        margin = EDGE_MARGIN_PX
        width = count_or_inf(lambda: math.floor(hi[0] / gsd + margin) - math.floor(lo[0] / gsd - margin) + 1)
        height = count_or_inf(lambda: math.ceil(hi[1] / gsd + margin) - math.ceil(lo[1] / gsd - margin) + 1)
        if max(width, height) > MAX_IMAGE_SIDE:
            # (a side of extent / gsd pixels takes at most that + 2: the margins' rows may add one)
            fits = _round_up(float(np.max(hi[:2] - lo[:2])) / (MAX_IMAGE_SIDE - 2))
            raise CameraError(f"gsd {number_text(gsd)} makes a {count_text(width)}x{count_text(height)} image, over {MAX_IMAGE_SIDE:,} pixels a side: a gsd of {fits:g} or more fits")
        left, top = math.floor(lo[0] / gsd - margin) * gsd, math.ceil(hi[1] / gsd + margin) * gsd
        # the eye just above the highest point: depths then span little more than the cloud's
        # heights, so float32 depths give heights (``heights``) as finely as they can
        eye_z = hi[2] + max(hi[2] - lo[2], gsd)
        centre = (left + width * gsd / 2, top - height * gsd / 2)
        return cls(
            eye=(*centre, eye_z), target=(*centre, lo[2]), up=(0.0, 1.0, 0.0), width=width, height=height,
            projection="orthographic", ortho_height=height * gsd,
        )  # fmt: skip

    @classmethod
    def section(cls, line, corridor_width, pixel_size, left: float, top: float, width: int, height: int) -> Camera:
        """An orthographic camera looking horizontally across the corridor ``corridor_width`` wide
        along ``line`` = (x1, y1, x2, y2): a cross-section, the line's start on the left, +z up,
        each pixel ``pixel_size`` a side on both axes (a section must not distort heights). It
        looks from the line's right (looking from its start to its end) towards its left.

        Image column ``floor((distance - left) / pixel_size)`` of its ``width`` holds the points
        ``distance`` along the line from its start, row ``floor((top - z) / pixel_size)`` of its
        ``height`` those at height ``z`` (``gigapoint.Section.camera`` chooses them to frame a
        section's points)."""
        x1, y1, x2, y2 = (float(v) for v in line)
        length = math.dist((x1, y1), (x2, y2))
        for name, v in (("pixel size", pixel_size), ("corridor width", corridor_width), ("line's length", length)):
            if not (is_real(v) and v > 0):
                raise CameraError(f"section: the {name} must be a number > 0, got {number_text(v)}")
        along = np.array([x2 - x1, y2 - y1, 0.0]) / length
        right_of_line = np.array([along[1], -along[0], 0.0])
        centre = np.array([x1, y1, top - height * pixel_size / 2]) + along * (left + width * pixel_size / 2)
        # the eye ``distance`` from the line, at least half a corridor outside its right edge: every
        # point lies between depths distance -+ width / 2, inside near and far whatever the cloud's
        # (axis-aligned) box. The rasterizer's float32 depths are ~1e-7 of the section's size off:
        # a corridor far thinner than that (1e-9 wide) had every point outside near or far.
        distance = max(corridor_width, 1e-4 * max(width, height) * pixel_size)
        eye = centre + right_of_line * distance
        return cls(
            eye=tuple(eye), target=tuple(centre), up=(0.0, 0.0, 1.0), width=width, height=height, projection="orthographic",
            ortho_height=height * pixel_size, near=distance / 4, far=2 * distance,
        )  # fmt: skip

    def _check_top_down(self, what: str) -> None:
        right, up, _ = self.basis()
        if self.projection != "orthographic" or not (np.allclose(right, (1, 0, 0), rtol=0, atol=1e-12) and np.allclose(up, (0, 1, 0), rtol=0, atol=1e-12)):
            raise CameraError(f"{what} needs an orthographic camera looking straight down, north up (Camera.top_down)")

    def world_file(self) -> tuple[float, float, float, float, float, float]:
        """The six numbers of an ESRI world file for this camera's image (``top_down``): pixel
        width, 0, 0, minus pixel height, then x and y of the centre of the upper-left pixel (the
        rasterizer's pixel (0, 0) holds x in [left, left + size), y in (top - size, top])."""
        self._check_top_down("a world file")
        size = self.ortho_height / self.height
        left, top = self.eye[0] - self.width * size / 2, self.eye[1] + self.height * size / 2
        return (size, 0.0, 0.0, -size, left + size / 2, top - size / 2)

    def heights(self, depth: np.ndarray) -> np.ndarray:
        """float32 heights (z) of the points a ``top_down`` camera drew at each pixel from their
        depths (``Frame.depth``): the eye's height less the depth; NaN where no point is (inf depth)."""
        self._check_top_down("heights from depths")
        depth = np.asarray(depth, np.float64)
        return np.where(np.isfinite(depth), self.eye[2] - depth, np.nan).astype(np.float32)

    @classmethod
    def fit_cloud(cls, cloud, view="auto", **kw) -> Camera:
        """``fit`` for a cloud (any Renderable): the 'auto' view frames its points (``sample_points``),
        so its data, not its bounding box, fills the frame; other views frame its box."""
        _check_keywords("fit_cloud", kw, FIT_CLOUD_KEYWORDS)
        auto = isinstance(view, str) and view == "auto"  # (a numpy pair compared element-wise: "ambiguous truth value")
        return cls.fit(cloud.bounds, view=view, points=sample_points(cloud) if auto else None, **kw)

    def with_size(self, width: int, height: int) -> Camera:
        return replace(self, width=width, height=height)

    # --- matrices -----------------------------------------------------------------
    @property
    def aspect(self) -> float:
        return self.width / self.height

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera right, up and backward unit vectors (float64)."""
        eye = np.asarray(self.eye)
        back = eye - np.asarray(self.target)
        back /= np.linalg.norm(back)
        up = np.asarray(self.up, np.float64)
        right = np.cross(up, back)
        if np.linalg.norm(right) < 1e-9 * np.linalg.norm(up):  # up parallel to the view: pick another
            alt = np.array([0.0, 1.0, 0.0]) if abs(back[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
            right = np.cross(alt, back)
        right /= np.linalg.norm(right)
        true_up = np.cross(back, right)
        return right, true_up, back

    def view_matrix(self) -> np.ndarray:
        """float64 world -> camera matrix (camera looks down -z)."""
        return self._view_matrix.copy()

    def screen_rows(self) -> np.ndarray:
        """float64 4x4 rows mapping world points to (x', y', w, depth).

        Pixel coordinates are x'/w and y'/w (0..width, 0..height, row 0 at the top);
        depth is the distance along the view direction (positive in front).
        """
        return self._screen_rows.copy()

    # A frame asks for these a dozen times (selection, clip range, passes): the camera is
    # immutable, so they are computed once per camera (~1 ms a frame in numpy's small-array calls).
    @functools.cached_property
    def _view_matrix(self) -> np.ndarray:
        right, up, back = self.basis()
        eye = np.asarray(self.eye)
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = right, up, back
        m[:3, 3] = -m[:3, :3] @ eye
        return m

    @functools.cached_property
    def _screen_rows(self) -> np.ndarray:
        v = self._view_matrix
        forward = -v[2]  # distance along the view direction
        half_w, half_h = self.width / 2.0, self.height / 2.0
        rows = np.zeros((4, 4))
        if self.projection == "perspective":
            t = math.tan(math.radians(self.fov) / 2)
            w_row = forward
            rows[0] = half_w / (t * self.aspect) * v[0] + half_w * w_row
            rows[1] = -half_h / t * v[1] + half_h * w_row
        else:
            extent_v = self.ortho_height / 2
            extent_h = extent_v * self.aspect
            w_row = np.array([0.0, 0.0, 0.0, 1.0])
            rows[0] = half_w / extent_h * v[0] + half_w * w_row
            rows[1] = -half_h / extent_v * v[1] + half_h * w_row
        rows[2] = w_row
        rows[3] = forward
        return rows

    def clip_range(self, bounds) -> tuple[float, float]:
        """(near, far) depths: the camera's own, else chosen to enclose ``bounds``."""
        lo, hi = np.asarray(bounds[0], np.float64), np.asarray(bounds[1], np.float64)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        forward = -self.view_matrix()[2]
        depths = corners @ forward[:3] + forward[3]
        far = self.far if self.far is not None else max(float(depths.max()) * 1.001 + 1e-9, 1e-6)
        if self.near is not None:
            near = self.near
        else:
            extent = float(np.linalg.norm(hi - lo))
            near = max(float(depths.min()) * 0.999, far * 1e-6, extent * 1e-9, 1e-9)
        return near, max(far, near * 1.000001)

    def view(self, bounds) -> View:
        """What selecting batches needs of this camera looking at ``bounds``: its screen rows,
        image size and the clip range that encloses them."""
        from ..core.selection import View  # (numba's kernels beside it: not for the CLI's --view check)

        near, far = self.clip_range(bounds)
        return View(self.screen_rows(), self.width, self.height, near, far)

    def ray(self, px: float, py: float) -> tuple[np.ndarray, np.ndarray]:
        """World-space origin and unit direction through pixel coordinates (px, py)."""
        if not (is_real(px) and is_real(py)):  # (NaN gave a NaN ray, "a" a TypeError)
            raise CameraError(f"ray: pixel coordinates must be finite numbers, got {numbers_text((px, py))}")
        right, up, back = self.basis()
        nx = (px / self.width) * 2 - 1
        ny = 1 - (py / self.height) * 2
        if self.projection == "perspective":
            t = math.tan(math.radians(self.fov) / 2)
            d = -back + nx * t * self.aspect * right + ny * t * up
            return np.asarray(self.eye), d / np.linalg.norm(d)
        ev = self.ortho_height / 2
        origin = np.asarray(self.eye) + nx * ev * self.aspect * right + ny * ev * up
        return origin, -back


# what fit_cloud passes on to fit: fit's parameters but those it sets itself, and fit's keywords (read once, not each call)
FIT_CLOUD_KEYWORDS = (*(p for p in inspect.signature(Camera.fit).parameters if p not in ("bounds", "view", "points", "kw")), *FIT_KEYWORDS)
