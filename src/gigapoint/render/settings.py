"""RenderSettings: every knob of a render, one frozen dataclass shared by API, CLI and viewer.

The dataclass is the one schema. A field's type says which values it takes (``Literal``
choices, ``X | None``, a ``(low, high)`` range, a color) and its metadata, written by
``setting(...)``, says the rest: range, help text, CLI option name, group. Validation
(``__post_init__``), the options of ``gigapoint render`` (``cli/settings_opts.py``) and the
viewer's settings panel (``viewer/protocol.py``) are all generated from ``settings_fields``,
so a new setting is one field here and nothing else.
"""

from __future__ import annotations

import enum
import math
import numbers
import re
import sys
import types
import typing
from dataclasses import MISSING, dataclass, field, fields, replace
from typing import Literal, get_args

import numpy as np

from ..core.classes import parse_classes
from ..core.coords import MAX_SPAN
from ..errors import SettingsError, number_text

# --- the choices (render/colors.py derives COLOR_MODES and COLORMAPS from these) ----------------------
Backend = Literal["auto", "cpu", "wgpu"]
ColorMode = Literal["rgb", "intensity", "classification", "elevation", "return_number", "point_source_id", "attribute", "batch", "level", "normal"]
Colormap = Literal["viridis", "turbo", "terrain", "inferno", "gray"]
PointShape = Literal["square", "round"]
SizeMode = Literal["auto", "adaptive", "fixed", "attenuated"]
Supersample = Literal[1, 2, 4]
SupersampleFilter = Literal["box", "lanczos"]
Stereo = Literal["none", "side-by-side", "anaglyph"]
Color = tuple[int, int, int, int]  # r, g, b, a in 0..255
Range = tuple[float, float]  # low, high
Classes = tuple[int, ...]  # LAS classification codes, 0..255

#: the most world units a distance (the stereo eyes', their convergence) can be: the span points
#: can have (convergence 1e300 put the auto eyes 3e298 apart: a blank image)

COLOR_MODES: tuple[str, ...] = get_args(ColorMode)
COLORMAPS: tuple[str, ...] = get_args(Colormap)
GROUPS = ("execution", "lod", "appearance")  # CLI help panels (in this order); the viewer may use them

_NAMED_COLORS = {
    "black": (0, 0, 0),
    "white": (255, 255, 255),
    "gray": (128, 128, 128),
    "grey": (128, 128, 128),
    "darkgray": (32, 32, 32),
    "skyblue": (135, 206, 235),
    "potree": (79, 79, 79),
}


def parse_color(value, name: str = "background") -> tuple[int, int, int, int]:
    """'black', '#rrggbb', '#rrggbbaa', '#rgb', '#rgba', 'r,g,b' or a tuple -> (r, g, b, a) in 0..255.
    Channels are whole numbers in 0..255; floats that all lie in 0..1 (not all 0) are refused, as
    0..1 channels would be misread (255.0 is taken as 255)."""
    text = value
    spellings = f"use {', '.join(_NAMED_COLORS)}, #rrggbb, #rgb or r,g,b"  # ('red' did not say which names there are)
    if isinstance(value, str):
        s = value.strip().lower()
        if s in _NAMED_COLORS:
            return (*_NAMED_COLORS[s], 255)
        if s.startswith("#") and len(s) in (4, 5, 7, 9):
            digits = s[1:] if len(s) > 5 else "".join(c * 2 for c in s[1:])  # CSS's #fff is #ffffff ('cannot read color')
            try:
                parts = [int(digits[i : i + 2], 16) for i in range(0, len(digits), 2)]
            except ValueError:
                raise SettingsError(f"{name}: cannot read color {value!r} ({spellings})") from None
            return tuple(parts + [255] * (4 - len(parts)))  # type: ignore[return-value]
        value = s.split(",")
    try:
        numbers = [float(v) for v in value]
    except (TypeError, ValueError):
        raise SettingsError(f"{name}: cannot read color {text!r} ({spellings})") from None
    # whole numbers only: 'inf' was an internal OverflowError, '0.5,0.5,0.5' black without a word;
    # floats within 0..1 are refused too, whole or not: (1.0, 1.0, 1.0) meant white, not (1, 1, 1)
    fractions = len(numbers) in (3, 4) and all(0 <= p <= 1 for p in numbers) and any(numbers) and any(map(_written_as_float, value))
    if fractions or len(numbers) not in (3, 4) or not all(0 <= p <= 255 and p == int(p) for p in numbers):
        hint = ""
        if fractions:
            scaled = [round(p * 255) for p in numbers]
            hint = f" (0..1 channels: give {tuple(scaled)} or {format_color(scaled)!r})"
        raise SettingsError(f"{name}: color needs 3 or 4 whole numbers in 0..255, got {text!r}{hint}")
    return tuple(int(p) for p in numbers) + (255,) * (4 - len(numbers))  # type: ignore[return-value]


def _written_as_float(value) -> bool:
    """A colour channel given as a float (1.0, np.float32, '1.0'), not as a whole number (1, '1')."""
    if isinstance(value, str):
        return not value.strip().lstrip("+-").isdigit()
    return isinstance(value, (float, np.floating))


def format_color(rgba) -> str:
    """The text ``parse_color`` reads back: a name where one fits, else '#rrggbb' or '#rrggbbaa'."""
    rgba = parse_color(rgba)
    if rgba[3] == 255:
        for name, rgb in _NAMED_COLORS.items():
            if rgb == rgba[:3]:
                return name
    return "#" + "".join(f"{c:02x}" for c in (rgba if rgba[3] != 255 else rgba[:3]))


def setting(
    default,
    help: str,
    *,
    min: float | None = None,
    max: float | None = None,
    exclusive_min: bool = False,
    option: str | None = None,
    group: str = "appearance",
    viewer: bool = True,
    kind: str | None = None,
    label: str | None = None,
    step: float | None = None,
    implies: dict | None = None,
    needs: tuple | None = None,
):
    """A settings field: its default and the metadata that CLI, viewer and validation read.

    ``min``/``max`` bound numbers (``exclusive_min``: strictly above ``min``); ``option`` is the
    CLI option where it is not ``--kebab-case`` of the field; ``group`` one of GROUPS;
    ``viewer=False`` hides it from the viewer's panel; ``kind="color"`` marks a color tuple;
    ``implies`` {field: value}: giving this field's CLI option also sets those fields, unless
    their own options are given too; ``needs`` (field, values): the field this one is read only
    at (those values of it), so the CLI refuses its option given without that.
    """
    meta = {"help": help, "group": group}
    extra = {"min": min, "max": max, "option": option, "kind": kind, "label": label, "step": step, "implies": implies, "needs": needs}
    meta.update({k: v for k, v in extra.items() if v is not None})
    if exclusive_min:
        meta["exclusive_min"] = True
    if not viewer:
        meta["viewer"] = False
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class RenderSettings:
    background: Color = setting((0, 0, 0, 255), "Background color: name, #rrggbb or r,g,b.", kind="color")
    # --- execution ---
    backend: Backend = setting("auto", "Rasterizer: auto (the GPU when wgpu finds one), cpu or wgpu.", group="execution")
    threads: int | None = setting(None, "CPU threads (default: all cores).", min=1, max=1024, group="execution")
    # --- precision and culling, level of detail (octree clouds, gigapoint.lod) ---
    precision_threshold_px: float = setting(
        500.0, "Batches projected smaller than this many pixels use 10-bit coordinates.", min=0, exclusive_min=True, group="lod"
    )
    adaptive_precision: bool = setting(True, "Choose 10, 20 or 30-bit coordinates per batch (off: always 30 bits).", group="lod")
    frustum_culling: bool = setting(True, "Skip the batches outside the view.", group="lod")
    # what a frame draws, not what is read (io/filters.py's --drop-classes re-reads the files): a
    # changed set costs a plain cloud one filtering pass, an octree reloading its nodes, a
    # progressive octree filtering the chunks it draws again
    hidden_classes: Classes = setting(
        (), "LAS classes not drawn, e.g. '7,18' (noise); changing them re-reads nothing.", kind="classes"
    )  # (the viewer edits it in its Classes panel, not among the settings: viewer/classes.py)
    point_budget: int = setting(
        10_000_000, "Converted octrees: most points a frame draws (largest projected nodes first).", min=1, group="lod"
    )
    max_points: int = setting(
        0, "Plain clouds: draw at most this many points, every k-th of each batch, at least one of each (a quick preview); 0 = all.", min=0, group="lod"
    )
    lod_threshold_px: float = setting(
        100.0, "Converted octrees: nodes projected smaller than this many pixels are not drawn.", min=0.0, group="lod"
    )
    lod_foveation: float = setting(
        0.0, "Above 0 the LOD threshold grows to threshold * (1 + this) at the image corners.", min=0.0, group="lod"
    )
    # --- image quality (render/passes, render/colors.py) ---
    color_mode: ColorMode = setting("rgb", "Point colors: the cloud's own, an attribute, the elevation or a debug view.")
    color_attribute: str | None = setting(
        None,
        "The attribute color mode's attribute: any the cloud holds (a LAS file's extra bytes too), mapped through the colormap "
        "(given on the command line or as a keyword of render, it also means color_mode attribute).",
        implies={"color_mode": "attribute"},
        needs=("color_mode", ("attribute",)),
    )
    colormap: Colormap = setting("viridis", "Colormap of the elevation and attribute color modes.", needs=("color_mode", ("elevation", "attribute")))
    elevation_range: Range | None = setting(
        None, "'low,high' elevations mapped onto the colormap (default: the cloud's z extent).", needs=("color_mode", ("elevation",))
    )
    intensity_range: Range | None = setting(
        None, "'low,high' intensity contrast range (default: 2nd..98th percentile).", needs=("color_mode", ("intensity",))
    )
    attribute_range: Range | None = setting(
        None, "'low,high' values of color_attribute mapped onto the colormap (default: 2nd..98th percentile).", needs=("color_mode", ("attribute",))
    )
    edl: bool = setting(False, "Eye-dome lighting.")
    # float32 in the kernels: 1e39 was inf
    edl_strength: float = setting(1.0, "Eye-dome lighting strength.", min=0.0, max=10_000.0, needs=("edl", (True,)))
    edl_radius: float = setting(1.4, "Eye-dome lighting radius in pixels.", min=0.5, max=16.0, needs=("edl", (True,)))
    fill_holes: int = setting(0, "Depth-aware hole filling: 0 off, 1/2/3 = 3x3/5x5/7x7 window.", min=0, max=3)
    fill_holes_foveated: bool = setting(
        False, "Hole filling window grows from 3x3 in the centre to the full size at the border.", option="--foveated",
        needs=("fill_holes", (1, 2, 3)),
    )
    hqs: bool = setting(False, "High-quality shading: blend the colors of all points near the front.")
    hqs_depth_tolerance: float = setting(
        0.01, "High-quality shading blends the points at most this fraction behind the closest.", min=0.0, max=1.0,
        needs=("hqs", (True,)),
    )
    point_size: int = setting(1, "Point size in pixels (attenuated: the largest size; adaptive: a multiple of the size).", min=1, max=64)
    point_shape: PointShape = setting("square", "Point footprint shape.")
    size_mode: SizeMode = setting(
        "auto",
        "adaptive: as large as the cloud's point spacing seen at the point's depth, so surfaces look solid (Potree's default); "
        "fixed: point_size pixels (with point_size 1: the exact one-pixel render); attenuated: point_world_size, at most point_size "
        "pixels; auto: attenuated with a point_world_size, fixed with a point_size above 1, else adaptive.",
    )
    point_world_size: float = setting(
        0.0,
        "Attenuated points: size in world units (given on the command line or as a keyword of render, it also means size_mode "
        "attenuated, point_size 16).",
        min=0.0,
        implies={"size_mode": "attenuated", "point_size": 16},
        needs=("size_mode", ("auto", "attenuated")),  # (fixed and adaptive sizes ignore it)
    )
    splat_softness: float = setting(
        0.0, "Soft splats (Kraft's falloff exponent, e.g. 2) blended by high-quality shading; 0 = hard.", min=0.0, max=64.0
    )
    opacity: float = setting(
        1.0,
        "Point opacity 0..1; below 1 the points are composited as transparent splats, nearest first (each pixel's 8 nearest "
        "depth-sorted, the rest by their mean; docs/transparency.md); it replaces high-quality shading. 1 = opaque.",
        min=0.0,
        max=1.0,
        step=0.05,
    )
    supersample: Supersample = setting(1, "Anti-aliasing: render 1, 2 or 4 times larger and filter down.")
    supersample_filter: SupersampleFilter = setting(
        "box", "Supersampling filter: box (exact block mean) or lanczos (Pillow).", needs=("supersample", (2, 4))
    )
    stereo: Stereo = setting("none", "Stereo pair: none, side-by-side or anaglyph.")
    ipd: float | None = setting(
        None,
        "Stereo eye distance in world units (default: auto, the zero-parallax distance / 30, the stereographers' 1/30 rule, "
        "so a 30 cm object and a city both show depth; smaller by tan(fov/2) / tan(30°) for a fov under 60 degrees; "
        "0 for an orthographic camera; 0 = both eyes alike).",
        min=0.0,
        max=MAX_SPAN,
        needs=("stereo", ("side-by-side", "anaglyph")),
    )
    convergence: float | None = setting(
        None,
        "Stereo zero-parallax distance in world units (default: the camera's target distance).",
        min=0.0,
        exclusive_min=True,
        max=MAX_SPAN,
        needs=("stereo", ("side-by-side", "anaglyph")),
    )
    lighting: bool = setting(False, "Blinn-Phong headlight from the cloud's normals (the CLI estimates them when missing).")
    shininess: float = setting(32.0, "Lighting specular exponent.", min=0.0, max=10_000.0, needs=("lighting", (True,)))

    def __post_init__(self) -> None:
        for spec in settings_fields(type(self)):
            value = getattr(self, spec.name)
            checked = spec.check(value)
            if checked is not value:
                object.__setattr__(self, spec.name, checked)
        # the few rules between fields
        if self.splat_softness > 0 and not self.hqs:
            raise SettingsError("splat_softness needs hqs=True (soft splats are blended by high-quality shading)")
        if self.hqs and self.opacity < 1:  # (passes.finish_frame composites transparent points instead: hqs was dropped without a word)
            raise SettingsError(f"hqs: high-quality shading is not drawn at opacity {number_text(self.opacity)}, whose transparent points replace it; turn hqs off or set opacity to 1")
        if self.size_mode == "attenuated" and not self.point_world_size > 0:
            raise SettingsError("size_mode 'attenuated' needs point_world_size > 0 (metres)")

    @property
    def point_sizing(self) -> str:
        """The size mode drawn: ``size_mode``, with 'auto' resolved (attenuated when a
        point_world_size is set, fixed when a point_size above 1 is, else adaptive)."""
        if self.size_mode != "auto":
            return self.size_mode
        if self.point_world_size > 0:
            return "attenuated"
        return "fixed" if self.point_size > 1 else "adaptive"

    @classmethod
    def of(cls, settings) -> RenderSettings:
        """``settings`` itself, the defaults for None, else a one-line SettingsError (a dict
        failed later as an AttributeError)."""
        if settings is None:
            return cls()
        if not isinstance(settings, cls):
            raise SettingsError(
                f"settings must be a gigapoint.RenderSettings, got {type(settings).__name__} "
                "(RenderSettings(point_size=3), or the fields as keywords of gigapoint.render)"
            )
        return settings

    def replace(self, **changes) -> RenderSettings:
        names = {f.name for f in fields(self)}
        unknown = set(changes) - names
        if unknown:
            raise SettingsError(f"unknown render setting(s): {', '.join(sorted(unknown))}")
        return replace(self, **changes)

    def given(self, **changes) -> RenderSettings:
        """``replace`` as render's keywords give settings: as on the command line, a field given
        also sets the fields it implies (``color_attribute`` means ``color_mode='attribute'``,
        ``point_world_size`` attenuated points of at most 16 px; ``implied_fields``), unless they
        are given too or already set away from their defaults."""
        implying = {spec.name: spec.default for spec in settings_fields(type(self)) if spec.implies}
        named = {n for n, v in changes.items() if n in implying and v is not None and v != implying[n]}  # (given its default: nothing)
        implied = implied_fields(type(self), named, self)
        return self.replace(**{target: value for target, (value, _) in implied.items() if target not in changes}, **changes)


# --- the schema, read from types and metadata ----------------------------------------------------


@dataclass(frozen=True)
class SettingSpec:
    """One field of a settings dataclass as CLI, viewer and validation see it.

    kind: bool | int | float | enum (``choices``) | color | range (low, high) | classes (LAS
    classes: ``parse_classes``) | text | other
    (a type none of them can edit; it is not validated either).
    """

    name: str
    kind: str
    default: object  # dataclasses.MISSING for a field without one
    nullable: bool = False
    choices: tuple = ()
    enum: type | None = None  # the Enum class whose values ``choices`` are
    min: float | None = None
    max: float | None = None
    exclusive_min: bool = False
    help: str = ""
    option: str = ""  # the CLI option, '--kebab-case' of the name unless the metadata names one
    group: str = "appearance"
    viewer: bool = True
    label: str = ""
    step: float | None = None
    size: int = 0  # values of a color tuple (3 or 4)
    implies: tuple = ()  # ((field, value), ...) its CLI option also sets
    needs: tuple = ()  # (field, values): the field's values at which this one is read (none: always)

    def check(self, value):
        """``value`` validated (and normalised: ints, the matching choice, (low, high) floats, RGBA)."""
        if value is None and self.nullable:
            return None
        name, kind = self.name, self.kind
        if kind == "bool":  # numpy's too (a mask's value); an int (edl=2) or a string ("no") is refused
            if not isinstance(value, (bool, np.bool_)):
                raise SettingsError(f"{name} must be true or false, got {value!r}")
            return bool(value)
        if kind in ("int", "float"):
            _number(name, value, self.min, self.max, integer=kind == "int", lo_open=self.exclusive_min)
            return value if kind == "float" or type(value) is int else int(value)
        if kind == "enum":
            if self.enum is not None:
                try:
                    return self.enum(value)
                except (ValueError, TypeError):
                    pass
            else:
                for c in self.choices:
                    if value == c:
                        return c
            raise SettingsError(f"{name} must be one of {', '.join(map(str, self.choices))}, got {value!r}")
        if kind == "color":
            rgba = parse_color(value, name)
            return rgba if self.size == 4 else rgba[: self.size]
        if kind == "range":
            return _range(name, value)
        if kind == "classes":
            return parse_classes(value, name)
        if kind == "text" and not isinstance(value, str):
            raise SettingsError(f"{name} must be a string, got {value!r}")
        return value


def _number(name, value, lo=None, hi=None, integer=False, lo_open=False):
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
    if ok and integer:
        ok = float(value).is_integer()
    if ok and lo is not None:
        ok = value > lo if lo_open else value >= lo
    if ok and hi is not None:
        ok = value <= hi
    if not ok:
        rng = (
            f" in {'(' if lo_open else '['}{number_text(lo)}, {number_text(hi)}]"
            if hi is not None
            else (f" {'>' if lo_open else '>='} {number_text(lo)}" if lo is not None else "")
        )
        raise SettingsError(f"{name} must be a{'n integer' if integer else ' number'}{rng}, got {number_text(value)}")


def _range(name, v) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in v)
    except (TypeError, ValueError):
        raise SettingsError(f"{name} must be two numbers (low, high), got {v!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise SettingsError(f"{name} must be finite with high > low, got {v!r}")
    return (lo, hi)


def field_types(cls) -> dict[str, object]:
    """The resolved type of each field (``typing.get_type_hints``); when one annotation cannot be
    resolved (a class local to a function), only that field goes without (it falls back to its default's type)."""
    try:
        return typing.get_type_hints(cls)
    except (NameError, TypeError, AttributeError, SyntaxError):
        pass
    out: dict[str, object] = {}
    for klass in reversed(cls.__mro__):
        module = sys.modules.get(klass.__module__)
        globalns = dict(vars(module)) if module is not None else {}
        for name, ann in vars(klass).get("__annotations__", {}).items():
            try:
                out[name] = typing.get_type_hints(types.SimpleNamespace(__annotations__={name: ann}), globalns=globalns)[name]
            except (NameError, TypeError, AttributeError, SyntaxError):
                out.pop(name, None)
    return out


def _strip_optional(tp) -> tuple[object, bool]:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in get_args(tp) if a is not type(None)]
        nullable = len(args) < len(get_args(tp))
        return (args[0] if len(args) == 1 else tp), nullable
    return tp, False


def _spec(f, tp) -> SettingSpec:
    meta = dict(f.metadata or {})
    default = f.default if f.default is not MISSING else (f.default_factory() if f.default_factory is not MISSING else MISSING)
    if tp is None:
        tp = type(default) if default not in (MISSING, None) else object
    base, nullable = _strip_optional(tp)
    origin, args = typing.get_origin(base), get_args(base)
    choices, enum_cls, size = tuple(meta.get("choices", ())), None, 0
    kind = meta.get("kind")
    if kind == "color" or (
        kind is None
        and origin is tuple
        and len(args) in (3, 4)
        and (f.name == "background" or "color" in f.name)
        and all(a is int for a in args)
    ):
        kind, size = "color", len(args) if len(args) in (3, 4) else 4
    elif kind is not None:
        pass
    elif base is bool:
        kind = "bool"
    elif isinstance(base, type) and issubclass(base, enum.Enum):
        kind, enum_cls, choices = "enum", base, tuple(m.value for m in base)
    elif origin is Literal:
        kind, choices = "enum", args
    elif choices:
        kind = "enum"
    elif base is int or base is float:
        kind = base.__name__
    elif origin is tuple and len(args) == 2 and all(a in (int, float) for a in args):
        kind = "range"
    elif base is str:
        kind = "text"
    else:
        kind = "other"
    return SettingSpec(
        name=f.name,
        kind=kind,
        default=default,
        nullable=nullable,
        choices=choices,
        enum=enum_cls,
        min=meta.get("min"),
        max=meta.get("max"),
        exclusive_min=bool(meta.get("exclusive_min", False)),
        help=meta.get("help", ""),
        option=meta.get("option") or "--" + f.name.replace("_", "-"),
        group=meta.get("group", "appearance"),
        viewer=meta.get("viewer", True) is not False,
        label=meta.get("label") or f.name.replace("_", " "),
        step=meta.get("step"),
        size=size,
        implies=tuple(dict(meta.get("implies") or {}).items()),
        needs=tuple(meta.get("needs") or ()),
    )


_SPECS: dict[type, tuple[SettingSpec, ...]] = {}


def implied_fields(cls: type, given, current=None) -> dict[str, tuple[object, str]]:
    """{field: (value, the given field implying it)} of the fields that the fields named in
    ``given`` imply (their metadata's ``implies``), leaving out those given too and, with
    ``current`` (settings), those it holds away from their defaults."""
    specs = {spec.name: spec for spec in settings_fields(cls)}
    out = {}
    for name in (n for n in specs if n in given):
        for target, value in specs[name].implies:
            if target in specs and target not in given and (current is None or getattr(current, target) == specs[target].default):
                out[target] = (value, name)
    return out


def help_text(cls: type, spec: SettingSpec, name) -> str:
    """``spec.help`` with the other fields it names (``point_size``) told as ``name(their spec)``:
    the CLI shows its option (--point-size), the viewer its label. Only names with an underscore
    are taken for fields (plain words like lighting or colormap stay words)."""
    specs = {s.name: s for s in settings_fields(cls)}
    return re.sub(r"\b[a-z]+(?:_[a-z]+)+\b", lambda m: name(specs[m[0]]) if m[0] in specs else m[0], spec.help)


def settings_fields(cls: type = RenderSettings) -> tuple[SettingSpec, ...]:
    """The schema of a settings dataclass (RenderSettings or one extending it): one SettingSpec per init field, in order."""
    specs = _SPECS.get(cls)
    if specs is None:
        hints = field_types(cls)
        specs = tuple(_spec(f, hints.get(f.name)) for f in fields(cls) if f.init)
        _SPECS[cls] = specs
    return specs
