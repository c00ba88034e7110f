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

    def __post_init__(self) -> None:
        object.__setattr__(self, "background", parse_color(self.background))
        if self.backend not in ("auto", "cpu", "wgpu"):
            raise SettingsError(f"backend must be auto, cpu or wgpu, got {self.backend!r}")
        if self.threads is not None and not (isinstance(self.threads, int) and 1 <= self.threads <= 1024):
            raise SettingsError(f"threads must be a positive integer, got {self.threads!r}")
        t = self.precision_threshold_px
        if not (isinstance(t, (int, float)) and math.isfinite(t) and t > 0):
            raise SettingsError(f"precision_threshold_px must be > 0, got {t!r}")

    def replace(self, **changes) -> RenderSettings:
        names = {f.name for f in fields(self)}
        unknown = set(changes) - names
        if unknown:
            raise SettingsError(f"unknown render setting(s): {', '.join(sorted(unknown))}")
        return replace(self, **changes)
