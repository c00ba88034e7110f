"""The viewer's wire protocol: message validation, the settings schema, frame packing.

Client -> server: JSON text messages ``{"type": ..., ...}`` (at most MAX_MESSAGE bytes).
Server -> client: JSON text messages (hello, settings, pick, error, pong) and binary frames:
``b"GPF1" + u32 little-endian header length + JSON header + JPEG bytes``.

Every check here raises ProtocolError with a one-line message; the server answers it with
``{"type": "error", "message": ...}`` and keeps the connection.
"""

from __future__ import annotations

import dataclasses
import enum
import inspect
import json
import math
import re
import struct
import sys
import types
import typing

from ..errors import GigapointError
from ..render.camera import VIEWS
from ..render.settings import RenderSettings, parse_color

MAX_MESSAGE = 16_384  # bytes of one client message
MAX_VIEW_SIDE = 4096  # pixels of the live view
MAX_SHOT_SIDE = 8192  # pixels of a screenshot side
MAX_SHOT_PIXELS = 40_000_000
MAX_ABS_NUMBER = 1e9  # settings numbers beyond this are absurd (point budget 1e12...)
MAX_ABS_COORD = 1e13
FRAME_MAGIC = b"GPF1"


class ProtocolError(GigapointError):
    """A client message that is malformed, unknown or out of range."""


# --- primitive checks ----------------------------------------------------------------------
def number(msg: dict, key: str, lo: float, hi: float, default=None) -> float:
    v = msg.get(key, default)
    if v is None:
        raise ProtocolError(f"{msg.get('type')}: missing number {key!r}")
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ProtocolError(f"{msg.get('type')}: {key} must be a finite number, got {v!r}"[:200])
    if not lo <= v <= hi:
        raise ProtocolError(f"{msg.get('type')}: {key} must be in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


def integer(msg: dict, key: str, lo: int, hi: int, default=None) -> int:
    v = number(msg, key, lo, hi, default)
    if not float(v).is_integer():
        raise ProtocolError(f"{msg.get('type')}: {key} must be an integer, got {v!r}")
    return int(v)


def vec3(msg: dict, key: str) -> list[float]:
    v = msg.get(key)
    if not isinstance(v, list) or len(v) != 3:
        raise ProtocolError(f"{msg.get('type')}: {key} must be a list of three numbers")
    return [number({"type": msg.get("type"), key: c}, key, -MAX_ABS_COORD, MAX_ABS_COORD) for c in v]


def flag(msg: dict, key: str, default: bool = False) -> bool:
    v = msg.get(key, default)
    if not isinstance(v, bool):
        raise ProtocolError(f"{msg.get('type')}: {key} must be true or false, got {v!r}"[:200])
    return v


def parse_message(text) -> dict:
    """The JSON object of one client text message, with a known ``type``."""
    if not isinstance(text, str):
        raise ProtocolError("binary messages are not accepted; send JSON text")
    if len(text) > MAX_MESSAGE:
        raise ProtocolError(f"message of {len(text)} characters exceeds the limit of {MAX_MESSAGE}")
    try:
        msg = json.loads(text)
    except (ValueError, RecursionError):
        raise ProtocolError("message is not valid JSON") from None
    if not isinstance(msg, dict):
        raise ProtocolError("message must be a JSON object")
    kind = msg.get("type")
    if not isinstance(kind, str) or kind not in MESSAGE_TYPES:
        raise ProtocolError(f"unknown message type {str(kind)[:40]!r}; known: {', '.join(sorted(MESSAGE_TYPES))}")
    return msg


MESSAGE_TYPES = {
    "resize",  # width, height (device pixels)
    "orbit",  # dyaw, dpitch (degrees)
    "look",  # dyaw, dpitch (fly mode: turn around the eye)
    "pan",  # dx, dy (viewport heights)
    "zoom",  # factor, x, y (cursor, 0..1 of the viewport; optional)
    "move",  # forward, right, up (world units)
    "camera",  # target, yaw, pitch, distance, fov (any subset)
    "view",  # name: top | front | side | iso | ... ; or reset
    "reset",
    "fov",  # value (degrees)
    "pick",  # x, y (0..1), pivot (bool), id (echoed)
    "settings",  # values: {field: value}
    "quality",  # adaptive (bool), jpeg_quality (int)
    "ping",  # t (echoed)
    "refresh",  # render again
}
VIEW_NAMES = tuple(VIEWS)


# --- settings schema (introspected, so fields added to RenderSettings appear by themselves) -----------
def _field_comments(cls) -> dict[str, str]:
    try:
        src = inspect.getsource(cls)
    except (OSError, TypeError):
        return {}
    out = {}
    for m in re.finditer(r"^\s+(\w+)\s*:[^=\n]+=[^#\n]*#\s*(.+)$", src, re.MULTILINE):
        out[m.group(1)] = m.group(2).strip()
    return out


def _valid(cls, name: str, value) -> bool:
    try:
        dataclasses.replace(cls(), **{name: value})
    except Exception:  # noqa: BLE001 - any failure means "not a valid value"
        return False
    return True


def _str_choices(cls, name: str, comment: str) -> list[str] | None:
    """Choices of a str setting: from the validator's "must be one of" message, else comment words that validate."""
    try:
        dataclasses.replace(cls(), **{name: "\x00?"})
    except GigapointError as exc:
        m = re.search(r"must be one of (.+?), got", str(exc))
        if m:
            return [c.strip() for c in m.group(1).split(",")]
    except Exception:  # noqa: BLE001
        pass
    else:
        return None  # anything goes: free text
    words = list(dict.fromkeys(re.findall(r"[A-Za-z][\w-]*", comment)))
    good = [w for w in words if _valid(cls, name, w)]
    return good or None


def _strip_optional(tp):
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        nullable = len(args) < len(typing.get_args(tp))
        return (args[0] if len(args) == 1 else tp), nullable
    return tp, False


def _describe(cls, f: dataclasses.Field, tp, comment: str, current) -> dict | None:
    base, nullable = _strip_optional(tp)
    meta = dict(f.metadata or {})
    if meta.get("viewer") is False:
        return None
    d = {"name": f.name, "label": meta.get("label", f.name.replace("_", " ")), "help": meta.get("help", comment), "nullable": nullable}
    origin, args = typing.get_origin(base), typing.get_args(base)
    choices = meta.get("choices")
    if base is bool:
        d["kind"] = "bool"
    elif inspect.isclass(base) and issubclass(base, enum.Enum):
        d["kind"], choices = "enum", [m.value for m in base]
    elif origin is typing.Literal:
        d["kind"], choices = "enum", list(args)
    elif base is int or base is float:
        d["kind"] = "int" if base is int else "float"
        for k in ("min", "max", "step"):
            if k in meta:
                d[k] = meta[k]
    elif origin is tuple and (f.name == "background" or "color" in f.name) and len(args) in (3, 4):
        d["kind"] = "color"
    elif origin is tuple and len(args) == 2 and all(a in (int, float) for a in args):
        d["kind"] = "range"
    elif base is str:
        choices = choices or _str_choices(cls, f.name, comment)
        d["kind"] = "enum" if choices else "text"
    else:
        return None  # a type the panel cannot edit
    if choices:
        d["kind"] = "enum"
        d["choices"] = list(choices)
    d["default"] = to_json_value(f.default if f.default is not dataclasses.MISSING else current)
    return d


def _type_hints(cls) -> dict:
    """Field types; one annotation that cannot be resolved only loses that field's type."""
    try:
        return typing.get_type_hints(cls)
    except Exception:  # noqa: BLE001
        pass
    out = {}
    for klass in reversed(cls.__mro__):
        env = vars(sys.modules.get(klass.__module__, typing))
        for name, ann in vars(klass).get("__annotations__", {}).items():
            try:
                out[name] = eval(ann, dict(env)) if isinstance(ann, str) else ann
            except Exception:  # noqa: BLE001
                out.pop(name, None)
    return out


_SCHEMAS: dict[type, list[dict]] = {}


def settings_schema(cls: type = RenderSettings) -> list[dict]:
    """One entry per editable field of the settings dataclass: name, kind (bool|int|float|enum|color|range|text), choices...

    Introspected (types, defaults, trailing comments, the validator itself), so fields
    added to RenderSettings later show up in the viewer's panel without changes here.
    A field's ``metadata`` may refine it: choices, min, max, step, label, help, viewer=False.
    """
    if cls not in _SCHEMAS:
        hints = _type_hints(cls)
        comments = _field_comments(cls)
        defaults = cls()
        out = []
        for f in dataclasses.fields(cls):
            if not f.init:
                continue
            current = getattr(defaults, f.name)
            tp = hints.get(f.name, type(current))
            d = _describe(cls, f, tp, comments.get(f.name, ""), current)
            if d is not None:
                out.append(d)
        _SCHEMAS[cls] = out
    return _SCHEMAS[cls]


def to_json_value(v):
    if isinstance(v, enum.Enum):
        return v.value
    if isinstance(v, tuple):
        return [to_json_value(x) for x in v]
    return v


def settings_values(settings) -> dict:
    return {d["name"]: to_json_value(getattr(settings, d["name"])) for d in settings_schema(type(settings))}


def _coerce(d: dict, value):
    name, kind = d["name"], d["kind"]
    if value is None:
        if d.get("nullable"):
            return None
        raise ProtocolError(f"settings: {name} cannot be empty")
    probe = {"type": "settings", name: value}
    if kind == "bool":
        return flag(probe, name)
    if kind == "int":
        return integer(probe, name, -MAX_ABS_NUMBER, MAX_ABS_NUMBER)
    if kind == "float":
        return number(probe, name, -MAX_ABS_NUMBER, MAX_ABS_NUMBER)
    if kind == "enum":
        for c in d["choices"]:
            if value == c and type(value) is type(c):
                return c
        raise ProtocolError(f"settings: {name} must be one of {', '.join(map(str, d['choices']))}, got {str(value)[:40]!r}")
    if kind == "color":
        if isinstance(value, str) and len(value) > 40:
            raise ProtocolError(f"settings: {name} is not a color")
        try:
            return parse_color(value)
        except GigapointError as exc:
            raise ProtocolError(f"settings: {exc}") from None
    if kind == "range":
        if not isinstance(value, list) or len(value) != 2:
            raise ProtocolError(f"settings: {name} must be two numbers [low, high] or null")
        return tuple(number({"type": "settings", name: v}, name, -MAX_ABS_COORD, MAX_ABS_COORD) for v in value)
    if kind == "text":
        if not isinstance(value, str) or len(value) > 200:
            raise ProtocolError(f"settings: {name} must be a short string")
        return value
    raise ProtocolError(f"settings: {name} cannot be changed from the viewer")


def apply_settings(settings, values):
    """``settings`` with the client's ``values`` (validated, then checked by RenderSettings itself)."""
    if not isinstance(values, dict) or not values:
        raise ProtocolError("settings: values must be a non-empty object {field: value}")
    schema = {d["name"]: d for d in settings_schema(type(settings))}
    changes = {}
    for name, value in values.items():
        if name not in schema:
            raise ProtocolError(f"settings: unknown field {str(name)[:40]!r}")
        changes[name] = _coerce(schema[name], value)
    try:
        return dataclasses.replace(settings, **changes)
    except GigapointError as exc:
        raise ProtocolError(f"settings: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ProtocolError(f"settings: {exc}"[:300]) from None


# --- frames --------------------------------------------------------------------------------
def json_safe(v):
    """Plain JSON types; non-finite floats become strings ('nan', 'inf')."""
    if isinstance(v, dict):
        return {str(k): json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [json_safe(x) for x in v]
    if isinstance(v, float):
        return v if math.isfinite(v) else str(v)
    if isinstance(v, bytes):
        return v.hex()
    if hasattr(v, "item"):  # numpy scalar
        return json_safe(v.item())
    return v


def pack_frame(header: dict, jpeg: bytes) -> bytes:
    h = json.dumps(json_safe(header), separators=(",", ":")).encode()
    return FRAME_MAGIC + struct.pack("<I", len(h)) + h + jpeg


def unpack_frame(data: bytes) -> tuple[dict, bytes]:
    if data[:4] != FRAME_MAGIC:
        raise ProtocolError("not a gigapoint frame")
    (n,) = struct.unpack("<I", data[4:8])
    return json.loads(data[8 : 8 + n]), data[8 + n :]
