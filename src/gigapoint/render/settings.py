"""RenderSettings: every knob of a render, one frozen dataclass shared by API, CLI and viewer."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from ..errors import SettingsError

_NAMED_COLORS = {
    "black": (0, 0, 0),
    "white": (255, 255, 255),
    "gray": (128, 128, 128),
    "grey": (128, 128, 128),
    "darkgray": (32, 32, 32),
    "skyblue": (135, 206, 235),
    "potree": (79, 79, 79),
}


def parse_color(value) -> tuple[int, int, int, int]:
    """'black', '#rrggbb', '#rrggbbaa', 'r,g,b' or a tuple -> (r, g, b, a) in 0..255."""
    if isinstance(value, str):
        s = value.strip().lower()
        if s in _NAMED_COLORS:
            return (*_NAMED_COLORS[s], 255)
        if s.startswith("#") and len(s) in (7, 9):
            try:
                parts = [int(s[i : i + 2], 16) for i in range(1, len(s), 2)]
            except ValueError:
                raise SettingsError(f"background: cannot read color {value!r}") from None
            return tuple(parts + [255] * (4 - len(parts)))  # type: ignore[return-value]
        value = s.split(",")
    try:
        parts = [int(float(v)) for v in value]
    except (TypeError, ValueError):
        raise SettingsError(f"background: cannot read color {value!r} (use a name, #rrggbb or r,g,b)") from None
    if len(parts) not in (3, 4) or not all(0 <= p <= 255 for p in parts):
        raise SettingsError(f"background: color needs 3 or 4 values in 0..255, got {value!r}")
    return tuple(parts + [255] * (4 - len(parts)))  # type: ignore[return-value]


@dataclass(frozen=True)
class RenderSettings:
    background: tuple[int, int, int, int] = (0, 0, 0, 255)
    backend: str = "auto"  # auto | cpu | wgpu
    threads: int | None = None  # CPU threads; None = all cores
    precision_threshold_px: float = 500.0  # projected batch size below which 10 bits suffice
    adaptive_precision: bool = True  # False: always 30 bits (for comparisons)
    frustum_culling: bool = True
    # --- level of detail (octree clouds, gigapoint.lod) ---
    point_budget: int = 10_000_000  # most points an octree frame draws (largest projected nodes first)
    max_points: int = 0  # plain (unconverted) clouds: draw at most this many (every k-th point of each batch); 0 = all
    lod_threshold_px: float = 100.0  # octree nodes projected smaller than this are not drawn
    lod_foveation: float = 0.0  # > 0: the threshold grows to lod_threshold_px * (1 + lod_foveation) at the image corners
    # --- image quality (render/passes, render/colors.py) ---
    color_mode: str = "rgb"  # rgb | intensity | classification | elevation | return_number | point_source_id | batch | level | normal
    colormap: str = "viridis"  # elevation colormap: viridis | turbo | terrain | inferno | gray
    elevation_range: tuple[float, float] | None = None  # None: the cloud's z extent
    intensity_range: tuple[float, float] | None = None  # None: 2nd..98th percentile
    edl: bool = False  # eye-dome lighting
    edl_strength: float = 1.0
    edl_radius: float = 1.4  # pixels
    fill_holes: int = 0  # 0 off; 1, 2, 3 = depth-aware dilation in a 3x3, 5x5, 7x7 window
    fill_holes_foveated: bool = False  # window grows from 3x3 in the centre to the full size at the border
    hqs: bool = False  # high-quality shading: average the colors of all points near the closest depth
    hqs_depth_tolerance: float = 0.01  # relative depth range behind the closest point that blends
    point_size: int = 1  # pixels (side of the square / diameter of the disc)
    point_shape: str = "square"  # square | round
    size_mode: str = "fixed"  # fixed | attenuated (point_world_size metres, clamped to point_size px)
    point_world_size: float = 0.0  # world-space point size for size_mode='attenuated'
    splat_softness: float = 0.0  # Kraft's soft splats (eq. 3.1 falloff exponent) blended by HQS; 0 = hard
    supersample: int = 1  # 1, 2 or 4: render larger and box-filter down
    supersample_filter: str = "box"  # box (exact block mean) | lanczos (Pillow)
    stereo: str = "none"  # none | side-by-side | anaglyph
    ipd: float = 0.065  # eye distance, world units
    convergence: float | None = None  # zero-parallax distance; None: the camera's target distance
    lighting: bool = False  # Blinn-Phong headlight from the cloud's normals
    shininess: float = 32.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "background", parse_color(self.background))
        if self.backend not in ("auto", "cpu", "wgpu"):
            raise SettingsError(f"backend must be auto, cpu or wgpu, got {self.backend!r}")
        if self.threads is not None and not (isinstance(self.threads, int) and 1 <= self.threads <= 1024):
            raise SettingsError(f"threads must be a positive integer, got {self.threads!r}")
        t = self.precision_threshold_px
        if not (isinstance(t, (int, float)) and math.isfinite(t) and t > 0):
            raise SettingsError(f"precision_threshold_px must be > 0, got {t!r}")
        _number("point_budget", self.point_budget, 1, integer=True)
        _number("max_points", self.max_points, 0, integer=True)
        _number("lod_threshold_px", self.lod_threshold_px, 0.0)
        _number("lod_foveation", self.lod_foveation, 0.0)
        _validate_quality(self)

    def replace(self, **changes) -> RenderSettings:
        names = {f.name for f in fields(self)}
        unknown = set(changes) - names
        if unknown:
            raise SettingsError(f"unknown render setting(s): {', '.join(sorted(unknown))}")
        return replace(self, **changes)


def _number(name, value, lo=None, hi=None, integer=False, lo_open=False):
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and integer:
        ok = float(value).is_integer()
    if ok and lo is not None:
        ok = value > lo if lo_open else value >= lo
    if ok and hi is not None:
        ok = value <= hi
    if not ok:
        rng = f" in {'(' if lo_open else '['}{lo}, {hi}]" if hi is not None else (f" {'>' if lo_open else '>='} {lo}" if lo is not None else "")
        raise SettingsError(f"{name} must be a{'n integer' if integer else ' number'}{rng}, got {value!r}")


def _range(s, name) -> None:
    v = getattr(s, name)
    if v is None:
        return
    try:
        lo, hi = (float(x) for x in v)
    except (TypeError, ValueError):
        raise SettingsError(f"{name} must be two numbers (low, high), got {v!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise SettingsError(f"{name} must be finite with high > low, got {v!r}")
    object.__setattr__(s, name, (lo, hi))


def _choice(s, name, choices) -> None:
    if getattr(s, name) not in choices:
        raise SettingsError(f"{name} must be one of {', '.join(map(str, choices))}, got {getattr(s, name)!r}")


def _validate_quality(s: RenderSettings) -> None:
    from .colors import COLOR_MODES, COLORMAPS

    _choice(s, "color_mode", COLOR_MODES)
    _choice(s, "colormap", COLORMAPS)
    _range(s, "elevation_range")
    _range(s, "intensity_range")
    _number("edl_strength", s.edl_strength, 0.0)
    _number("edl_radius", s.edl_radius, 0.5, 16.0)
    _number("fill_holes", s.fill_holes, 0, 3, integer=True)
    _number("hqs_depth_tolerance", s.hqs_depth_tolerance, 0.0, 1.0)
    _number("point_size", s.point_size, 1, 64, integer=True)
    _choice(s, "point_shape", ("square", "round"))
    _choice(s, "size_mode", ("fixed", "attenuated"))
    _number("point_world_size", s.point_world_size, 0.0)
    _number("splat_softness", s.splat_softness, 0.0, 64.0)
    if s.splat_softness > 0 and not s.hqs:
        raise SettingsError("splat_softness needs hqs=True (soft splats are blended by high-quality shading)")
    if s.size_mode == "attenuated" and not s.point_world_size > 0:
        raise SettingsError("size_mode 'attenuated' needs point_world_size > 0 (metres)")
    _choice(s, "supersample", (1, 2, 4))
    _choice(s, "supersample_filter", ("box", "lanczos"))
    _choice(s, "stereo", ("none", "side-by-side", "anaglyph"))
    _number("ipd", s.ipd, 0.0)
    if s.convergence is not None:
        _number("convergence", s.convergence, 0.0, lo_open=True)
    _number("shininess", s.shininess, 0.0, 10_000.0)
    for name in ("edl", "hqs", "fill_holes_foveated", "lighting"):
        if not isinstance(getattr(s, name), (bool, int)):
            raise SettingsError(f"{name} must be true or false, got {getattr(s, name)!r}")
    object.__setattr__(s, "fill_holes", int(s.fill_holes))
    object.__setattr__(s, "point_size", int(s.point_size))
