"""Coordinates' rules every reader and cloud shares (numba-free: ``gigapoint info`` reads a
header without importing numba): the validity limit, the decimals a stored coordinate shows."""

from __future__ import annotations

import math

import numpy as np

#: Coordinates beyond this magnitude are not of this planet in any CRS: skipped as invalid.
MAX_ABS_COORDINATE = 1e12
#: the span points can have, the bound of distances and sizes said in world units
MAX_SPAN = 2 * MAX_ABS_COORDINATE

#: arrays up to this many points are scanned and gathered by numpy (milliseconds): a small
#: cloud's first run does not wait for the parallel kernels to compile
NUMPY_MAX = 1 << 20


def value_decimals(value: float, scale: float) -> int:
    """Decimals that show ``value``, a coordinate stored at resolution ``scale``: the scale's
    (scale_decimals), more where the value lies off that decimal grid by over 1e-4 of a
    step: its file's offset does (PDAL's offset 'auto', 637000.123456 at scale 0.001 was shown
    rounded to 3 decimals, up to half a step from the file's value). Within a few float64 steps
    of the grid is on it: at scale 1e-7 a value near 2e5 (float64 steps of 3e-11) showed 11
    decimals of rounding noise (193898.87588702643)."""
    scale = abs(scale)
    d = scale_decimals(scale)
    tolerance = max(1e-4 * scale, 4 * math.ulp(value))  # (positions held compact are the source's, to float64 rounding)
    while d < 12 and abs(round(value, d) - value) > tolerance:
        d += 1
    return d


def scale_decimals(scale: float) -> int:
    """Decimals that show a coordinate stored at resolution ``scale`` (0.01 -> 2, 0.001 -> 3, 0.5 -> 1)."""
    if not (math.isfinite(scale) and scale > 0):
        return 6
    return max(0, min(12, math.ceil(-math.log10(scale) - 1e-9)))


def valid_mask(xyz: np.ndarray) -> np.ndarray:
    """The rule of cloud.py's ``_scan_blocks``: |x| <= the limit on every axis (False for NaN and inf)."""
    return np.all(np.abs(xyz) <= MAX_ABS_COORDINATE, axis=1)
