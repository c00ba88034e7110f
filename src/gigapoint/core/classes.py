"""LAS classes as users give them ('7,18', 7, [7, 18]): read into whole numbers 0..255, without
numba or numpy (``--help`` and the settings' schema need it: cli startup imports no kernel)."""

from __future__ import annotations

import numbers

from ..errors import SettingsError


def parse_classes(value, name: str = "hidden_classes") -> tuple[int, ...]:
    """'7,18', one class or several (ints) -> the sorted distinct LAS classes, each a whole number
    in 0..255, or a one-line SettingsError naming ``name`` (RenderSettings.hidden_classes,
    PointCloud.without_classes)."""
    parts = [p for p in value.replace(" ", "").split(",") if p] if isinstance(value, str) else value
    if isinstance(parts, numbers.Real):  # one class: 7
        parts = [parts]
    try:
        classes = [float(c) for c in parts]
    except (TypeError, ValueError):
        raise SettingsError(f"{name} must be LAS classes (whole numbers in 0..255, e.g. 7,18), got {value!r}") from None
    bad = [c for c in classes if not (0 <= c <= 255 and c == int(c))]  # (NaN fails both)
    if bad:
        raise SettingsError(f"{name}: {bad[0]:g} is not a LAS class (whole numbers in 0..255), got {value!r}")
    return tuple(sorted({int(c) for c in classes}))
