"""Color modes: per-point u32 RGBA colors from attributes, elevation, batches or normals.

``point_colors(cloud, settings)`` returns the (N,) u32 RGBA array the resolve step
fetches from (the cloud's own ``color`` for ``rgb``). Attribute-derived arrays are
computed once per (mode, parameters) and kept in the RenderCache (cache.py), so a frame
only pays a dictionary lookup. Everything here is vectorised numpy over the cloud's point order
(attributes are stored in that order) except the elevation decode, a small numba kernel.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..core.compact import full_words, rgba32
from ..core.layout import COORD_BITS
from ..core.renderable import held_points
from ..errors import SettingsError
from .cache import render_cache
from .settings import COLOR_MODES, COLORMAPS  # the Literal choices of RenderSettings.color_mode and .colormap

# --- colormaps: small tables of evenly spaced control points, interpolated to 256 entries --------
_CONTROL = {
    "viridis": ["440154", "482878", "3e4989", "31688e", "26828e", "1f9e89", "35b779", "6ece58", "b5de2b", "fde725"],
    "gray": ["000000", "ffffff"],
    "inferno": ["000004", "1b0c41", "4a0c6b", "781c6d", "a52c60", "cf4446", "ed6925", "fb9b06", "f7d13d", "fcffa4"],
    # ColorBrewer's diverging RdBu, white in the middle: the change preview's (survey/change.py), not a
    # points' colormap (RenderSettings.colormap's choices are settings.Colormap)
    "rdbu": ["67001f", "b2182b", "d6604d", "f4a582", "fddbc7", "f7f7f7", "d1e5f0", "92c5de", "4393c3", "2166ac", "053061"],
}
# matplotlib's "terrain": (position, rgb 0..1) segments
_TERRAIN = [
    (0.00, (0.2, 0.2, 0.6)),
    (0.15, (0.0, 0.6, 1.0)),
    (0.25, (0.0, 0.8, 0.4)),
    (0.50, (1.0, 1.0, 0.6)),
    (0.75, (0.5, 0.36, 0.33)),
    (1.00, (1.0, 1.0, 1.0)),
]
# Google's polynomial fit of Turbo (r, g, b coefficients of x^0..x^5)
_TURBO = np.array(
    [
        [0.13572138, 4.61539260, -42.66032258, 132.13108234, -152.94239396, 59.28637943],
        [0.09140261, 2.19418839, 4.84296658, -14.18503333, 4.27729857, 2.82956604],
        [0.10667330, 12.64194608, -60.58204836, 110.36276771, -89.90310912, 27.34824973],
    ]
)


def colormap_table(name: str) -> np.ndarray:
    """(256, 4) uint8 RGBA lookup table of a named colormap."""
    x = np.linspace(0.0, 1.0, 256)
    if name == "turbo":
        rgb = np.stack([np.polyval(c[::-1], x) for c in _TURBO], axis=1)
    elif name == "terrain":
        pos = np.array([p for p, _ in _TERRAIN])
        cols = np.array([c for _, c in _TERRAIN])
        rgb = np.stack([np.interp(x, pos, cols[:, k]) for k in range(3)], axis=1)
    elif name in _CONTROL:
        cols = np.array([[int(h[i : i + 2], 16) for i in (0, 2, 4)] for h in _CONTROL[name]], np.float64) / 255.0
        pos = np.linspace(0.0, 1.0, len(cols))
        rgb = np.stack([np.interp(x, pos, cols[:, k]) for k in range(3)], axis=1)
    else:
        raise SettingsError(f"colormap: unknown colormap {name!r}; choose one of {', '.join(COLORMAPS)}")
    out = np.empty((256, 4), np.uint8)
    out[:, :3] = np.clip(np.rint(rgb * 255.0), 0, 255)
    out[:, 3] = 255
    return out


# --- ASPRS LAS 1.4 classes: colors (Potree's scheme where it has one; their names: io/las_fields.py) --------


_CLASS_COLORS = {
    0: (128, 128, 128),
    1: (160, 160, 160),
    2: (160, 82, 45),
    3: (0, 255, 0),
    4: (0, 204, 0),
    5: (0, 153, 0),
    6: (255, 168, 0),
    7: (255, 0, 255),
    8: (255, 0, 0),
    9: (0, 0, 255),
    10: (200, 200, 50),
    11: (90, 90, 90),
    12: (255, 255, 0),
    13: (255, 220, 160),
    14: (255, 240, 90),
    15: (220, 100, 255),
    16: (180, 120, 40),
    17: (120, 120, 200),
    18: (255, 80, 80),
}
_CLASS_DEFAULT = (77, 153, 153)


def classification_table() -> np.ndarray:
    """(256, 4) uint8 RGBA color per ASPRS class (unknown classes a teal grey)."""
    t = np.empty((256, 4), np.uint8)
    t[:, :3] = _CLASS_DEFAULT
    for c, rgb in _CLASS_COLORS.items():
        t[c, :3] = rgb
    t[:, 3] = 255
    return t


_RETURN_COLORS = [(255, 255, 0), (255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 0, 255), (0, 255, 255), (255, 128, 0), (128, 0, 255)]

# attribute names a color mode reads, first found wins
_ATTRIBUTE_NAMES = {
    "intensity": ("intensity", "Intensity"),
    "classification": ("classification", "Classification", "class"),
    "return_number": ("return_number", "ReturnNumber", "return_num"),
    "point_source_id": ("point_source_id", "PointSourceId", "source_id"),
}


def _attribute(cloud, mode: str) -> np.ndarray:
    for name in _ATTRIBUTE_NAMES[mode]:
        if name in cloud.attributes:
            return np.asarray(cloud.attributes[name])
    have = ", ".join(sorted(cloud.attributes)) or "none"
    raise SettingsError(f"color_mode {mode!r}: {cloud.name} has no {mode} attribute (attributes: {have})")


def missing_attribute(cloud_name: str, name: str, have) -> SettingsError:
    """The error of a color_attribute the cloud lacks (also told from the files' headers, before
    they are read: cli/quality_opts.check_color_attribute)."""
    return SettingsError(f"color_attribute: {cloud_name} has no attribute {name!r} (attributes: {', '.join(sorted(have)) or 'none'})")


def _named_attribute(cloud, name: str | None) -> np.ndarray:
    """The values of attribute ``name`` (color_mode 'attribute'); naming none, or one the cloud
    lacks, is a one-line SettingsError listing the attributes it has."""
    have = ", ".join(sorted(cloud.attributes)) or "none"
    if not name:
        raise SettingsError(f"color_mode 'attribute': name the attribute with color_attribute (--color-attribute); {cloud.name} has: {have}")
    if name not in cloud.attributes:
        raise missing_attribute(cloud.name, name, cloud.attributes)
    values = np.asarray(cloud.attributes[name])
    if values.ndim != 1:  # an NPZ's normal (N, 3): numba's TypingError in the resolve
        raise SettingsError(
            f"color_attribute: {name!r} of {cloud.name} holds {int(np.prod(values.shape[1:]))} values a point; "
            f"colour by an attribute of one value a point (normals: color_mode 'normal')"
        )
    return values


def normals_of(cloud) -> np.ndarray | None:
    """(N, 3) float32 unit normals if the cloud carries them (nx/ny/nz or 'normal'), else None."""
    a = cloud.attributes
    if "normal" in a:
        return np.asarray(a["normal"], np.float32).reshape(-1, 3)
    if "normals" in a:
        return np.asarray(a["normals"], np.float32).reshape(-1, 3)
    if all(k in a for k in ("nx", "ny", "nz")):
        return np.stack([np.asarray(a[k], np.float32) for k in ("nx", "ny", "nz")], axis=1)
    return None


def _hash_colors(ids: np.ndarray) -> np.ndarray:
    """Distinct, stable colors for integer ids (golden-ratio hue, varied lightness)."""
    ids = np.asarray(ids, np.int64)
    h = (ids * 0.6180339887498949) % 1.0
    v = 0.65 + 0.35 * ((ids * 0.3819660112501051 * 7) % 1.0)
    return _hsv_to_rgba(h, np.full_like(h, 0.75), v)


def _hsv_to_rgba(h, s, v) -> np.ndarray:
    i = np.floor(h * 6.0).astype(np.int64) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    r = np.choose(i, [v, q, p, p, t, v])
    g = np.choose(i, [t, v, v, q, p, p])
    b = np.choose(i, [p, p, t, v, v, q])
    out = np.empty((len(h), 4), np.uint8)
    out[:, 0], out[:, 1], out[:, 2] = (np.clip(np.rint(c * 255), 0, 255) for c in (r, g, b))
    out[:, 3] = 255
    return out


NO_VALUE = (128, 128, 128, 255)  # a point whose attribute is NaN (no value): grey, not the colormap's low end


def ramp(values: np.ndarray, lo: float, hi: float, table: np.ndarray) -> np.ndarray:
    """u32 colors of values mapped linearly from [lo, hi] onto a (256, 4) table (clamped);
    NaN values get ``NO_VALUE`` (their cast to an index was an IndexError)."""
    scale = 255.0 / (hi - lo) if hi > lo else 0.0
    x = (np.asarray(values, np.float64) - lo) * scale
    missing = np.isnan(x)
    i = np.clip(np.rint(np.where(missing, 0.0, x)), 0, 255).astype(np.intp)
    colors = table.view(np.uint32).reshape(-1)[i]
    if missing.any():
        colors[missing] = np.array(NO_VALUE, np.uint8).view(np.uint32)[0]
    return colors


def ramp_image(values: np.ndarray, lo: float, hi: float, colormap: str) -> np.ndarray:
    """(H, W, 4) uint8 image of the (H, W) raster ``values`` (a height difference, a height above
    a base) on ``colormap`` from ``lo`` to ``hi`` (clamped); transparent where a value is NaN
    (no data): a map product's preview (survey/change.py, survey/volume.py)."""
    image = ramp(values, lo, hi, colormap_table(colormap)).view(np.uint8).reshape(*np.shape(values), 4)
    image[np.isnan(values)] = 0
    return image


@njit(parallel=True, cache=True)
def _decode_z(firsts, counts, zmin, zsize, low, med, high, out):
    """float64 world z (30-bit cell centres) of every point, batch by batch."""
    inv = 1.0 / float(1 << COORD_BITS)
    for b in prange(firsts.shape[0]):
        step = zsize[b] * inv
        for i in range(firsts[b], firsts[b] + counts[b]):
            q = ((low[i] >> np.uint32(20)) & np.uint32(1023)) << np.uint32(20)
            q |= ((med[i] >> np.uint32(20)) & np.uint32(1023)) << np.uint32(10)
            q |= (high[i] >> np.uint32(20)) & np.uint32(1023)
            out[i] = zmin[b] + (float(q) + 0.5) * step


def elevations(cloud) -> np.ndarray:
    """float64 (N,) world z of every point in cloud order, decoded once (RenderCache)."""
    cache = render_cache.arrays(cloud)
    z = cache.get("__z__")
    if z is None:
        b = cloud.batches
        z = np.zeros(cloud.n_points, np.float64)  # zeros: an LOD arena has slots no batch covers
        zmin = np.ascontiguousarray(b["bbox_min"][:, 2])
        zsize = np.ascontiguousarray(b["bbox_max"][:, 2] - b["bbox_min"][:, 2])
        med, high = full_words(cloud)  # decoded for this once where the layout is compact
        _decode_z(b["first"].astype(np.int64), b["count"].astype(np.int64), zmin, zsize, cloud.low, med, high, z)
        cache["__z__"] = z
    return z


_AUTO_RANGE_SAMPLE = 1_000_000  # values an automatic range is taken over, at most ~twice that


def _auto_range(values: np.ndarray) -> tuple[float, float]:
    """2nd..98th percentile (robust to a few outliers), on a subsample for big clouds, of the
    finite values (a NaN or inf made the range NaN); (0, 1) where none is finite."""
    v = values if len(values) <= _AUTO_RANGE_SAMPLE else values[:: len(values) // _AUTO_RANGE_SAMPLE]
    v = v.astype(np.float64)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return 0.0, 1.0
    lo, hi = np.percentile(v, [2.0, 98.0])
    if not hi > lo:
        lo, hi = float(v.min()), float(v.max())
    return float(lo), float(hi)


def held_values(cloud, values: np.ndarray) -> np.ndarray:
    """``values`` of the points the cloud's batches hold (``first`` .. ``first + count``), a
    sample where they are many (``_auto_range`` reads ~1 M): all of a PointCloud's; an LOD
    arena's or pool's slots beyond them (never filled, or a partial slot's tail) read 0 in one
    layout and the attribute's low end in another, which an automatic range taken over them
    started at 0 or differed by layout."""
    if int(cloud.batches["count"].sum(dtype=np.int64)) == len(values):  # (a PointCloud: its batches hold every point)
        return values
    return values[held_points(cloud.batches, most=_AUTO_RANGE_SAMPLE)]


def _compute(cloud, mode: str, settings) -> np.ndarray:
    n = cloud.n_points
    if mode == "intensity":
        v = _attribute(cloud, mode)
        lo, hi = settings.intensity_range or _auto_range(held_values(cloud, v))
        return ramp(v, lo, hi, colormap_table("gray"))
    if mode == "attribute":
        v = _named_attribute(cloud, settings.color_attribute)
        lo, hi = settings.attribute_range or _auto_range(held_values(cloud, v))
        return ramp(v, lo, hi, colormap_table(settings.colormap))
    if mode == "classification":
        v = _attribute(cloud, mode).astype(np.int64) & 0xFF
        return classification_table().view(np.uint32).reshape(-1)[v]
    if mode == "elevation":
        z = elevations(cloud)
        lo, hi = settings.elevation_range or (float(cloud.bounds[0][2]), float(cloud.bounds[1][2]))
        return ramp(z, lo, hi, colormap_table(settings.colormap))
    if mode == "return_number":
        v = _attribute(cloud, mode).astype(np.int64)
        table = np.array([(*c, 255) for c in _RETURN_COLORS], np.uint8)
        return table.view(np.uint32).reshape(-1)[np.clip(v - 1, 0, len(_RETURN_COLORS) - 1)]
    if mode == "point_source_id":
        v = _attribute(cloud, mode).astype(np.int64)
        ids, inverse = np.unique(v, return_inverse=True)
        return _hash_colors(ids).view(np.uint32).reshape(-1)[inverse]
    if mode in ("batch", "level"):
        b = cloud.batches
        per_batch = np.arange(len(b)) if mode == "batch" else b["level"].astype(np.int64)
        colors = _hash_colors(per_batch + (0 if mode == "batch" else 3)).view(np.uint32).reshape(-1)
        order = np.argsort(b["first"], kind="stable")  # batches by position (an LOD arena's slots need not be in order)
        owner = np.searchsorted(b["first"][order].astype(np.int64), np.arange(n), side="right") - 1
        return colors[order[np.maximum(owner, 0)]]
    if mode == "normal":
        nrm = normals_of(cloud)
        if nrm is None:
            raise SettingsError(
                f"color_mode 'normal': {cloud.name} has no normals (attributes nx, ny, nz); estimate them with gigapoint.estimate_normals(cloud) "
                f"on a cloud held in memory (gigapoint.open(path))"
            )
        out = np.empty((n, 4), np.uint8)
        out[:, :3] = np.clip(np.rint((nrm * 0.5 + 0.5) * 255.0), 0, 255)
        out[:, 3] = 255
        return out.view(np.uint32).reshape(-1)
    raise SettingsError(f"color_mode: unknown mode {mode!r}; choose one of {', '.join(COLOR_MODES)}")


def point_colors(cloud, settings) -> np.ndarray:
    """(N,) u32 RGBA color of every point under ``settings.color_mode`` (cached per parameters)."""
    mode = settings.color_mode
    if mode == "rgb":
        return cloud.color
    if cloud.n_points == 0:  # a progressive cloud before its first points: none to color, its attributes not known yet
        return np.zeros(0, np.uint32)
    key = (
        mode,
        settings.colormap if mode == "elevation" else None,
        settings.elevation_range if mode == "elevation" else None,
        settings.intensity_range if mode == "intensity" else None,
        (settings.color_attribute, settings.attribute_range, settings.colormap) if mode == "attribute" else None,
    )
    cache = render_cache.arrays(cloud)
    colors = cache.get(key)
    if colors is None:
        colors = np.ascontiguousarray(_compute(cloud, mode, settings), np.uint32)
        for k in [k for k in cache if isinstance(k, tuple)]:  # keep one color array at a time (not "__z__", "__normals__"...)
            del cache[k]
        cache[key] = colors
    return colors


def rgba_point_colors(cloud, settings) -> np.ndarray:
    """``point_colors`` as u32 RGBA8 for the passes that blend colors (HQS, transparency): decoded
    once from a compact cloud's 16-bit colors or palettes (kept in the RenderCache while they are drawn)."""
    colors = point_colors(cloud, settings)
    if isinstance(colors, np.ndarray) and colors.dtype == np.uint32:
        return colors
    cache = render_cache.arrays(cloud)
    out = cache.get("__rgba32__")
    if out is None:
        out = cache["__rgba32__"] = rgba32(colors)
    return out

