"""The viewer's wire protocol: message validation, the settings schema, frame packing.

Client -> server: JSON text messages ``{"type": ..., ...}`` (at most MAX_MESSAGE bytes).
Server -> client: JSON text messages (hello, settings, classes, pick, measure, volume, volume_result,
section, section_result, error, pong) and binary frames:
``b"GPF1" + u32 little-endian header length + JSON header + JPEG bytes``; a frame's header
has ``cloud`` (hello's cloud line) again when that changed since the tab last got it.
Hello's ``cloud`` (ViewerCore.cloud_info): name, points, batches, bounds, attributes,
load_progress, and units: the length units of its CRS, what measured lengths are in (see "measure").

Every check here raises ProtocolError with a one-line message; the server answers it with
``{"type": "error", "message": ...}`` and keeps the connection.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import struct

from ..errors import GigapointError, number_text
from ..render.camera import VIEWS
from ..render.settings import RenderSettings, SettingSpec, help_text, parse_color, settings_fields

MAX_MESSAGE = 16_384  # bytes of one client message
MAX_VIEW_SIDE = 4096  # pixels of the live view
MAX_SHOT_SIDE = 8192  # pixels of a screenshot side
MAX_SHOT_PIXELS = 40_000_000  # rendered for a screenshot, supersampling counted; a tab's frame lowers its supersample to fit
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
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (isinstance(v, float) and not math.isfinite(v)):
        raise ProtocolError(f"{msg.get('type')}: {key} must be a finite number, got {v!r}"[:200])
    if not lo <= v <= hi:  # ints compared exactly: math.isfinite(10**400), a JSON integer, raised OverflowError
        raise ProtocolError(f"{msg.get('type')}: {key} must be in [{lo:g}, {hi:g}], got {number_text(v)}"[:200])
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
    # action: add (x, y: the point picked there joins the measurement) | restore (points: world
    # [x, y, z] lists appended: what a page that reconnected had measured) | undo (drops the last) |
    # clear; id echoed. Reply {"type": "measure", "id", "added", "points", "segments": [{length,
    # horizontal, vertical}], "total": {the same, summed}, "units"} in the cloud's units, which
    # "units" names (as hello's cloud: io.crs_units, {"horizontal": U, "vertical": U,
    # "vertical_assumed"}, U {name, symbol, metres} or null: unknown; a geographic CRS's horizontal
    # U has metres null and length and horizontal are null: degrees are no length); the 3D length
    # counts heights in the horizontal unit (viewer/measure.py). A click on no point adds nothing:
    # added false and a "message". Frames draw the polyline. close (3 points or more) | open: the
    # polyline closed into a polygon (its last segment back to the first point; restore's
    # "closed": true closes what it restores), or open again (an undo below 3 points opens it);
    # every reply has "closed", "area" (the polygon's horizontal area, in the horizontal unit
    # squared) and "perimeter" (its horizontal length), both null where open or in degrees, and
    # "crossing": null, or for a polygon crossing itself the line saying which edges (area null).
    "measure",
    # the stockpile volume inside the closed measurement (viewer/volume_tool.py, gp.volume of the
    # cloud shown, but the classes hidden): base ("plane", the default | "lowest" | an elevation),
    # gsd (> 0; by default the polygon's larger side / 500, to 2 digits; at most 4096 pixels
    # across); id echoed. Reply {"type": "volume", "id", "job", "computing": true, "gsd", "base"},
    # then, computed off the render loop, {"type": "volume_result", "id": job, gp.volume's pile
    # figures (fill, cut, net, area, polygon_area, highest, height, base: {type, z, slope,
    # boundary_rms}, filled, empty, pixels), "gsd", "gsd_note", "note" (thinned points: a box of
    # over volume_tool.MAX_POINTS read every k-th, the gsd then no finer than their spacing; ""
    # none), "warnings": [one line each] (gp.volume's: a toe beyond the data; shown in the panel,
    # not printed by the server), "units": {length, area, volume} symbols} or {"type": "volume_result", "id", "error":
    # one line}. A polygon crossing itself is refused (an error). A change of the measurement
    # drops what is on its way.
    "volume",
    # the section tool (viewer/section_tool.py): action: add (x, y: the point picked there, as
    # measure's, is the line's next end; a third starts a new line) | set (any of points: two world
    # [x, y, z] with different x, y; width: the corridor's, > 0, in the cloud's units; size: [w, h]
    # pixels of the panel's image, 8..2048) | clear; id echoed. Reply {"type": "section", "id",
    # "points", "width", "computing"} ("message" where a click found no point); with two points
    # the section is computed off the render loop and sent as {"type": "section_result", "id": a
    # number that grows with each change, "count", "length", "width", "line": [x1, y1, x2, y2],
    # "distance": [min, max], "z": [min, max], "units" (as measure's), "image": a PNG data URL
    # (Section.render at size: equal scale, +z up), "message": "" or what was left out (over
    # section_tool.MAX_POINTS points: every k-th)} or {"type": "section_result", "id", "error": one
    # line (an octree without source files, an empty corridor)}. GET section.csv?session=ID: its
    # rows (Section.write_csv). Frames draw the line.
    "section",
    # values: {field: value}; hidden_classes: a list of LAS classes (whole numbers 0..255), what
    # the Classes panel leaves unticked, refused in one line where the panel is disabled
    "settings",
    # the Classes panel's list (viewer/classes.py): reply {"type": "classes", "enabled", "reason":
    # "" or why not (no classification; a live cloud's refusal), "source": cloud (the
    # classes a cloud in memory holds) | metadata (those an octree's files list: class counts, metadata) | standard
    # (ASPRS 0..18, within a range its metadata gives, and the classes seen and hidden), "complete"
    # (false: the list may grow as nodes load; ask again), "classes": [{code, name, color: "#rrggbb"}]};
    # hello carries the first
    "classes",
    "quality",  # adaptive (bool), jpeg_quality (int)
    "ping",  # t (echoed)
    "refresh",  # render again
}
VIEW_NAMES = tuple(VIEWS)


# --- settings schema (generated from RenderSettings' types and field metadata) -------------------------
_SCHEMAS: dict[type, list[dict]] = {}


def _describe(cls: type, spec: SettingSpec) -> dict | None:
    if not spec.viewer or spec.kind == "other" or spec.default is dataclasses.MISSING:
        return None  # hidden, or a type the panel cannot edit
    helped = help_text(cls, spec, lambda other: other.label)  # the fields it names as the panel shows them
    d = {"name": spec.name, "label": spec.label, "help": helped, "nullable": spec.nullable, "kind": spec.kind}
    if spec.kind == "enum":
        d["choices"] = list(spec.choices)
    elif spec.kind in ("int", "float"):
        for k in ("min", "max", "step"):
            if getattr(spec, k) is not None:
                d[k] = getattr(spec, k)
    d["default"] = to_json_value(spec.default)
    return d


def settings_schema(cls: type = RenderSettings) -> list[dict]:
    """One entry per editable field of the settings dataclass: name, label, help, nullable,
    kind (bool|int|float|enum|color|range|classes|text), choices, min, max, step, default
    (classes: the Classes panel edits it, not the settings panel).

    Generated from ``render.settings.settings_fields`` (the fields' types and metadata), so a
    field added to RenderSettings, or to a class extending it, shows up in the viewer's panel
    without changes here; ``viewer=False`` in its metadata hides it.
    """
    if cls not in _SCHEMAS:
        _SCHEMAS[cls] = [d for d in (_describe(cls, spec) for spec in settings_fields(cls)) if d is not None]
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
    if kind == "classes":  # the Classes panel's unticked classes; RenderSettings sorts them
        if not isinstance(value, list) or len(value) > 256:
            raise ProtocolError(f"settings: {name} must be a list of LAS classes (whole numbers in 0..255)")
        return tuple(integer({"type": "settings", name: c}, name, 0, 255) for c in value)
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
