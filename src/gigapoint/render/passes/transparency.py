"""Transparent points: hybrid transparency (Maule et al. 2013): each pixel's nearest fragments
depth-sorted and blended exactly, the rest by their mean; and the exactly sorted composite it is
measured against (docs/transparency.md says why this and not weighted blended OIT).

A frame is transparent when ``RenderSettings.opacity`` < 1 or its DrawList gives a batch an
``alpha`` < 1 (a live cloud's fade). Each point has an 8-bit alpha a = round(255 x opacity x
batch alpha) (params.batch_alphas). After the depth pass, every *fragment* (every footprint
pixel of every point in view: the pixels the depth pass wrote) goes into its pixel's

- k-buffer: the TR_LAYERS (8) smallest keys ``depth bits << 32 | point index`` (the depth pass's
  keys: nearer first, ties to the lower index), a set that does not depend on the order the
  fragments come in;
- integer sums over all of them: ``sum_a`` += a, ``sum_rgb`` += a x color, ``reveal`` +=
  (L(a) << 8) + 1 with L(a) = -log2(1 - a / 255) in 1/2^16 units (params.alpha_logs): the log
  of the product of all transmittances, nonzero wherever a fragment landed.

The resolve (``composite``), in 16-bit fixed point (T = 65536 is full transmittance): the kept
fragments front to back, each adding w = round(a x T / 255) of its color and leaving T - w;
then, if fragments were left out (their alpha sum is what the kept ones leave of ``sum_a``),
the tail: the light the whole pixel lets through, T_all = 2^-(reveal >> 8) / 2^16 from a
256-entry table (at most T), and the tail's mean color (its ``sum_rgb`` / ``sum_a``, shifted so
the divisor fits 16 bits, rounded) gets T - T_all; last the background gets what is left;
alpha likewise with points of alpha 255. Pixels no fragment reached keep ``fallback`` (the
resolve's: the background or a filled hole). With at most 8 fragments a pixel it is the exact
sorted composite (up to the fixed-point rounding); the tail matters only for what light the
8 nearest leave, so the error stays small (docs/transparency.md: measured).

``sorted_reference`` composites the same fragments exactly, front to back in float64 (what
Kraft 2019 gets by sorting the points by depth): the yardstick for the tests and
bench_transparency's error figures.
"""

from __future__ import annotations

import numpy as np

from ...errors import GigapointError
from ..params import TR_COUNT_BITS, TR_LAYERS, TR_REVEAL_BITS, batch_alphas, transmittance_table
from ..reference import footprint_pixels, projected_batches
from ..splats import ONE_PIXEL, point_sizes

_FULL = 65536  # transmittance 1 in 16-bit fixed point


def wants_transparency(settings, draw) -> bool:
    """True when the frame is composited as transparent (opacity below 1, or a batch alpha below 1)."""
    if settings.opacity < 1.0:
        return True
    alpha = draw.alpha
    return alpha is not None and len(alpha) > 0 and bool(np.min(alpha) < 1.0)


def frame_alphas(settings, draw) -> np.ndarray:
    """(k, 2) u32 per selected batch of ``draw``: 8-bit alpha and its revealage term."""
    alpha, k = draw.alpha, len(draw.selection.ids)
    if alpha is not None and np.shape(alpha) != (k,):
        raise GigapointError(f"{draw.points.name}: DrawList.alpha needs one value per selected batch ({k}), got shape {np.shape(alpha)}")
    if alpha is not None and not np.all(np.isfinite(alpha)):
        raise GigapointError(f"{draw.points.name}: DrawList.alpha must be finite (0..1)")
    return batch_alphas(alpha, settings.opacity, k)


def fragments(cloud, sel, width, height, near, far, splat=None, step: int = 1):
    """(pixel, float32 depth, point index, selected batch position) of every fragment, as arrays,
    in the projection and footprint of the depth pass (render/reference.py)."""
    footprint, size, atten = splat if splat is not None else ONE_PIXEL
    out = ([], [], [], [])
    for k, (first, idx, x0, y0, d) in enumerate(projected_batches(cloud, sel, width, height, near, far)):
        keep = idx % step == 0
        idx, x0, y0, d = idx[keep], x0[keep], y0[keep], d[keep]
        sizes = point_sizes(d, size, atten)
        for _, _, m, pix in footprint_pixels(x0, y0, sizes, footprint, width, height):
            out[0].append(pix)
            out[1].append(d[m])
            out[2].append(first + idx[m])
            out[3].append(np.full(len(pix), k, np.int64))
    if not out[0]:
        return np.zeros(0, np.int64), np.zeros(0, np.float32), np.zeros(0, np.int64), np.zeros(0, np.int64)
    return tuple(np.concatenate(a) for a in out)


def transmittance(reveal) -> np.ndarray:
    """16-bit fixed-point transmittance (int64) of revealage sums (u64)."""
    lg = np.asarray(reveal, np.uint64) >> np.uint64(TR_COUNT_BITS)
    e = (lg >> np.uint64(TR_REVEAL_BITS)).astype(np.int64)
    frac = ((lg >> np.uint64(TR_REVEAL_BITS - 8)) & np.uint64(255)).astype(np.int64)
    return np.where(e >= 16, 0, transmittance_table()[frac].astype(np.int64) >> np.minimum(e, 16))


def shifted_mean(sums, weight) -> np.ndarray:
    """round(sums / weight) per row (0 where weight is 0), both shifted right until the weight fits
    16 bits (u64 (n, c) and (n,) in, int64 out): what u32 arithmetic on a GPU can divide."""
    weight = np.asarray(weight, np.uint64)
    shift = np.zeros(len(weight), np.uint64)
    for t in range(48):  # bit length - 16, where above
        shift += (weight >> np.uint64(16 + t)) > 0
    w16 = (weight >> shift).astype(np.int64)
    c = (np.asarray(sums, np.uint64) >> shift[:, None]).astype(np.int64)
    return np.where(w16[:, None] > 0, (c + (w16 // 2)[:, None]) // np.maximum(w16, 1)[:, None], 0)


def hybrid_reference(
    cloud, sel, width, height, near, far, point_colors, alphas, fallback, background, splat=None, step: int = 1
) -> np.ndarray:
    """Plain numpy: the hybrid composite (module docstring) of the selected batches of ``cloud``;
    ``alphas`` (k, 2) from ``frame_alphas``; ``fallback`` (n,) u32, ``background`` RGBA."""
    n = width * height
    pix, depth, index, k = fragments(cloud, sel, width, height, near, far, splat, step)
    a = alphas[k, 0].astype(np.int64)
    rgb = point_colors.view(np.uint8).reshape(-1, 4)[index, :3].astype(np.int64)
    sum_a = np.zeros(n, np.uint64)
    np.add.at(sum_a, pix, a.astype(np.uint64))
    sum_rgb = np.zeros((n, 3), np.uint64)
    for c in range(3):
        np.add.at(sum_rgb[:, c], pix, (a * rgb[:, c]).astype(np.uint64))
    reveal = np.zeros(n, np.uint64)
    np.add.at(reveal, pix, (alphas[k, 1].astype(np.uint64) << np.uint64(TR_COUNT_BITS)) + np.uint64(1))
    # the k-buffer: each pixel's fragments by key, the first TR_LAYERS blended in turn
    key = (depth.view(np.uint32).astype(np.uint64) << np.uint64(32)) | index.astype(np.uint64)
    order = np.lexsort((key, pix))
    ps = pix[order]
    new = np.r_[True, ps[1:] != ps[:-1]] if len(ps) else np.zeros(0, bool)
    rank = np.arange(len(ps)) - np.flatnonzero(new)[np.cumsum(new) - 1] if len(ps) else np.zeros(0, np.int64)
    t = np.full(n, _FULL, np.int64)
    acc = np.zeros((n, 3), np.int64)
    kept_a = np.zeros(n, np.int64)
    kept_rgb = np.zeros((n, 3), np.int64)
    for r in range(TR_LAYERS):
        f = order[rank == r]  # one fragment per pixel: no repeated index below
        p, fa, fc = pix[f], a[f], rgb[f]
        w = (fa * t[p] + 127) // 255
        acc[p] += w[:, None] * fc
        t[p] -= w
        kept_a[p] += fa
        kept_rgb[p] += fa[:, None] * fc
    tail_a = sum_a.astype(np.int64) - kept_a
    tail = tail_a > 0
    t_all = np.minimum(transmittance(reveal), t)
    mean = shifted_mean(sum_rgb - kept_rgb.astype(np.uint64), tail_a.astype(np.uint64))
    acc[tail] += (t - t_all)[tail, None] * mean[tail]
    t = np.where(tail, t_all, t)
    return composite(acc, t, reveal, fallback, background)


def composite(acc, t, reveal, fallback, background) -> np.ndarray:
    """(n,) u32 RGBA: color sums ``acc`` (n, 3) in 1/65536 plus the background through transmittance
    ``t``, rounded; ``fallback`` where ``reveal`` is 0 (no fragment)."""
    bg = np.array(background, np.int64)
    rgb = (acc + bg[None, :3] * t[:, None] + 32768) >> 16
    alpha = (255 * (_FULL - t) + bg[3] * t + 32768) >> 16
    rgba = np.concatenate([rgb, alpha[:, None]], axis=1).astype(np.uint8)
    out = np.ascontiguousarray(fallback, np.uint32).reshape(-1).copy()
    hit = np.asarray(reveal) != 0
    out[hit] = rgba.view(np.uint32).reshape(-1)[hit]
    return out


def sorted_reference(
    cloud, sel, width, height, near, far, point_colors, alphas, fallback, background, splat=None, step: int = 1
) -> np.ndarray:
    """The exact composite: each pixel's fragments sorted by key (depth, then index), blended front
    to back in float64 (alpha a / 255) over the background; ``fallback`` where none landed."""
    pix, depth, index, k = fragments(cloud, sel, width, height, near, far, splat, step)
    out = np.ascontiguousarray(fallback, np.uint32).reshape(-1).copy()
    if len(pix) == 0:
        return out
    key = (depth.view(np.uint32).astype(np.uint64) << np.uint64(32)) | index.astype(np.uint64)
    order = np.lexsort((key, pix))
    pix, index, k = pix[order], index[order], k[order]
    a = np.minimum(alphas[k, 0].astype(np.float64) / 255.0, 1.0 - 1e-15)
    lg = np.log1p(-a)
    cum = np.cumsum(lg)
    starts = np.flatnonzero(np.r_[True, pix[1:] != pix[:-1]])
    group = np.cumsum(np.r_[True, pix[1:] != pix[:-1]]) - 1
    before = cum - lg - np.r_[0.0, cum][starts][group]  # log transmittance in front of each fragment
    contrib = a * np.exp(before)
    rgba = np.empty((len(pix), 4))
    rgba[:, :3] = point_colors.view(np.uint8).reshape(-1, 4)[index, :3]
    rgba[:, 3] = 255.0
    ends = np.r_[starts[1:], len(pix)]
    t = np.exp(cum[ends - 1] - np.r_[0.0, cum][starts])  # transmittance behind all of them
    color = np.add.reduceat(rgba * contrib[:, None], starts, axis=0) + np.array(background, np.float64)[None, :] * t[:, None]
    px = pix[starts]
    out[px] = np.clip(np.floor(color + 0.5), 0, 255).astype(np.uint8).view(np.uint32).reshape(-1)
    return out
