"""Eye-dome lighting (Boucheny 2009, as in Potree): screen-space shading from log-depth.

For every pixel, each of 8 neighbours at ``radius`` pixels adds max(0, log2 d - log2 d_n)
(100 if this pixel is empty: the dark outline around silhouettes); the color is scaled by
exp(-300 * strength * sum / 8). Needs only the visibility buffer's depth. The backends run
it (their Passes.eye_dome_lighting); this is its plain-numpy reference, with the same
float32 arithmetic, and the parameters all three share are in render/params.py.
"""

from __future__ import annotations

import numpy as np

from ...core.layout import EMPTY_PIXEL
from ..params import EDL_EMPTY_RESPONSE, EXP2_C, LOG2_C1, LOG2_C3, LOG2_C5, LOG2_C7, N_NEIGHBOURS, edl_scale, neighbour_offsets


def log2_approx(bits: np.ndarray) -> np.ndarray:
    """float32 log2 of positive float32s given as u32 bits: exponent + atanh series of the mantissa."""
    e = ((bits >> np.uint32(23)).astype(np.int32) - np.int32(127)).astype(np.float32)
    m = ((bits & np.uint32(0x007FFFFF)) | np.uint32(0x3F800000)).view(np.float32)
    t = (m - np.float32(1)) / (m + np.float32(1))
    t2 = t * t
    return e + t * (LOG2_C1 + t2 * (LOG2_C3 + t2 * (LOG2_C5 + t2 * LOG2_C7)))


def exp2_approx(y: np.ndarray) -> np.ndarray:
    """float32 2^y for y <= 0: 2^floor(y) from bits times a degree-6 Taylor polynomial of 2^frac."""
    y = np.maximum(y.astype(np.float32), np.float32(-126.0))
    fl = np.floor(y)
    f = y - fl
    c1, c2, c3, c4, c5, c6 = EXP2_C
    poly = np.float32(1) + f * (c1 + f * (c2 + f * (c3 + f * (c4 + f * (c5 + f * c6)))))
    scale = ((fl.astype(np.int32) + np.int32(127)) << np.int32(23)).view(np.float32)
    return poly * scale


def edl_reference(vis: np.ndarray, colors: np.ndarray, width: int, height: int, strength: float = 1.0, radius: float = 1.4) -> np.ndarray:
    """Plain-numpy eye-dome lighting, same float32 arithmetic as the kernels."""
    vis = vis.reshape(height, width)
    empty = vis == EMPTY_PIXEL
    logd = np.where(empty, np.float32(0), log2_approx((vis >> np.uint64(32)).astype(np.uint32))).astype(np.float32)
    e = empty.astype(np.float32)
    acc = np.zeros((height, width), np.float32)
    for dx, dy in neighbour_offsets(radius):
        # neighbour values shifted into place; outside the image counts as empty
        nl = np.zeros_like(logd)
        ne = np.ones_like(e)
        ys, yd = slice(max(dy, 0), height + min(dy, 0)), slice(max(-dy, 0), height + min(-dy, 0))
        xs, xd = slice(max(dx, 0), width + min(dx, 0)), slice(max(-dx, 0), width + min(-dx, 0))
        nl[yd, xd] = logd[ys, xs]
        ne[yd, xd] = e[ys, xs]
        r = e * EDL_EMPTY_RESPONSE + (np.float32(1) - e) * np.maximum(np.float32(0), logd - nl)
        acc += (np.float32(1) - ne) * r
    shade = exp2_approx(acc * edl_scale(strength, N_NEIGHBOURS))
    rgba = colors.reshape(height, width).view(np.uint8).reshape(height, width, 4)
    out = rgba.copy()
    out[..., :3] = (rgba[..., :3].astype(np.float32) * shade[..., None] + np.float32(0.5)).astype(np.uint8)
    return out.view(np.uint32).reshape(-1)
