"""Parameters every implementation of a pass shares: the CPU kernels, the WGSL shaders (their
constants are generated from here) and the numpy references in render/passes.

Only numbers, small tables and one inline numba function: nothing here draws. A pass's
behaviour is defined once, so the CPU, the GPU and the reference cannot drift apart.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

# --- eye-dome lighting (Boucheny 2009, as in Potree) -----------------------------------------
N_NEIGHBOURS = 8
EDL_EMPTY_RESPONSE = np.float32(100.0)  # what an empty pixel adds per neighbour: the dark outline
EDL_EXPONENT = -300.0  # shade = exp(EDL_EXPONENT * strength * mean response)

# fast float32 log2 / exp2 (plain IEEE float32 operations, so numpy and WGSL repeat them bit for bit):
# log2 = exponent + atanh series of the mantissa; 2^y = 2^floor(y) (bits) * Taylor polynomial of 2^frac
LOG2_C1 = np.float32(2.0 / math.log(2.0))
LOG2_C3 = np.float32(2.0 / math.log(2.0) / 3.0)
LOG2_C5 = np.float32(2.0 / math.log(2.0) / 5.0)
LOG2_C7 = np.float32(2.0 / math.log(2.0) / 7.0)
EXP2_C = tuple(np.float32(math.log(2.0) ** k / math.factorial(k)) for k in range(1, 7))


def neighbour_offsets(radius: float, n: int = N_NEIGHBOURS) -> np.ndarray:
    """(n, 2) int32 pixel offsets (dx, dy) of the samples on a circle (nearest pixel)."""
    a = 2.0 * math.pi * np.arange(n) / n
    return np.stack([np.rint(radius * np.cos(a)), np.rint(radius * np.sin(a))], axis=1).astype(np.int32)


def edl_scale(strength: float, n_offsets: int) -> np.float32:
    """The float32 factor y = response sum x scale of 2^y: exp(-300 s r / n) = 2^(r (-300 s / n / ln 2))."""
    return np.float32(EDL_EXPONENT * strength / n_offsets / math.log(2.0))


# --- hole filling ----------------------------------------------------------------------------
N_SECTORS = 16  # directions of the neighbours that close a hole, binned
DEPTH_GAP = 0.1  # a pixel this much (relative) behind its window's closest counts as a hole


def window(level: int):
    """offsets (k, 2) int32 (dx, dy), sector bit (k,) u32, Chebyshev ring (k,) int8 of a (2L+1)^2 window."""
    r = int(level)
    offs = sorted(
        ((dx, dy) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if (dx, dy) != (0, 0)), key=lambda o: max(abs(o[0]), abs(o[1]))
    )
    offsets = np.array(offs, np.int32).reshape(-1, 2)
    ang = np.arctan2(offsets[:, 1].astype(np.float64), offsets[:, 0].astype(np.float64))
    sector = np.floor((ang + math.pi) / (2 * math.pi) * N_SECTORS).astype(np.int64) % N_SECTORS
    bits = (np.uint32(1) << sector.astype(np.uint32)).astype(np.uint32)
    ring = np.maximum(np.abs(offsets[:, 0]), np.abs(offsets[:, 1])).astype(np.int8)
    return offsets, bits, ring


@functools.lru_cache(maxsize=8)
def radius_map(width: int, height: int, level: int, foveated: bool) -> np.ndarray:
    """(height, width) int8 window radius per pixel (foveated: 1 at the centre .. level at the corners)."""
    if not foveated or level <= 1:
        return np.full((height, width), level, np.int8)
    y, x = np.mgrid[0:height, 0:width]
    d = np.hypot((x + 0.5 - width / 2) / (width / 2), (y + 0.5 - height / 2) / (height / 2)) / math.sqrt(2.0)
    return np.minimum(level, 1 + np.floor(d * level)).astype(np.int8)


# --- Blinn-Phong headlight (Todoran 2019, ch. 4) ---------------------------------------------
AMBIENT, DIFFUSE, SPECULAR = 0.3, 0.7, 0.25


@functools.lru_cache(maxsize=4)
def view_directions(camera) -> np.ndarray:
    """(H*W, 3) float32 unit vectors from each pixel's centre towards the eye ((1, 3) if orthographic)."""
    right, up, back = camera.basis()
    if camera.projection != "perspective":
        return back.astype(np.float32)[None, :]
    t = np.tan(np.radians(camera.fov) / 2)
    nx = ((np.arange(camera.width) + 0.5) / camera.width * 2 - 1) * t * camera.aspect
    ny = (1 - (np.arange(camera.height) + 0.5) / camera.height * 2) * t
    d = back[None, None, :] - nx[None, :, None] * right[None, None, :] - ny[:, None, None] * up[None, None, :]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return d.reshape(-1, 3).astype(np.float32)


# --- soft splats (Kraft 2019) blended by high-quality shading ----------------------------------
@njit(inline="always")
def soft_weight(dx, dy, s, softness):
    """Kraft 2019 eq. 3.1 opacity 1 - (r / R)^x of a footprint pixel at (dx, dy) from the centre
    of a splat of diameter s (R = s / 2), quantised to 0..15 (1 for hard splats): integer
    weights keep the blended sums exact."""
    if softness == 0:
        return np.uint64(1)
    o = 1.0 - (math.sqrt(float(dx * dx + dy * dy)) / (0.5 * float(s))) ** softness
    return np.uint64(max(0.0, 15.0 * o + 0.5))



# --- transparency: hybrid transparency (Maule et al. 2013): the TR_LAYERS nearest fragments of a
# pixel depth-sorted and blended exactly, the rest by their mean (docs/transparency.md). All integer,
# so the numpy reference, the CPU kernel and the WGSL shader agree bit for bit, whatever the order
# the points come in.
TR_LAYERS = 8  # fragments a pixel keeps sorted (a k-buffer of u64 keys: 64 bytes a pixel)
TR_REVEAL_BITS = 16  # -log2(1 - alpha) in 1/2^16 units
TR_COUNT_BITS = 8  # each fragment adds (L << 8) + 1 to the revealage sum: nonzero where any point lands
TR_OPAQUE_LOG = 32 << TR_REVEAL_BITS  # alpha 255: transmittance 2^-32 (none)


def alpha_logs(a8: np.ndarray) -> np.ndarray:
    """-log2(1 - a8 / 255) in 1/2^TR_REVEAL_BITS units (u32) of 8-bit alphas; 255: TR_OPAQUE_LOG."""
    a = np.asarray(a8, np.int64)
    with np.errstate(divide="ignore"):
        lg = np.rint(-np.log2(1.0 - np.minimum(a, 254) / 255.0) * (1 << TR_REVEAL_BITS))
    return np.where(a >= 255, TR_OPAQUE_LOG, lg).astype(np.uint32)


@functools.cache
def transmittance_table() -> np.ndarray:
    """(256,) u32: round(2^16 * 2^(-f / 256)); transmittance = table[fraction byte] >> integer part."""
    return np.rint(65536.0 * np.exp2(-np.arange(256) / 256.0)).astype(np.uint32)


def batch_alphas(alpha, opacity: float, n: int) -> np.ndarray:
    """(n, 2) u32 per selected batch: 8-bit alpha round(255 * opacity * alpha) and its
    ``alpha_logs`` (the revealage term); ``alpha`` None: the opacity alone."""
    a = np.full(n, float(opacity)) if alpha is None else float(opacity) * np.clip(np.asarray(alpha, np.float64).reshape(-1), 0.0, 1.0)
    a8 = np.rint(a * 255.0).astype(np.int64)
    return np.ascontiguousarray(np.stack([a8, alpha_logs(a8)], axis=1), np.uint32)
