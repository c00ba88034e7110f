"""Organised depth images -> points with normals (Kraft 2019, 3.2: a Kinect's 512x424 frames).

``depth_to_points`` back-projects every pixel with a valid depth through the pinhole
intrinsics (OpenCV convention: x right, y down, z forward), takes its normal from its image
neighbours (the cross product of the horizontal and vertical differences: the right/lower
neighbour where it is valid, else the left/upper one; oriented towards the sensor), and
applies the sensor's pose, all in one compiled pass over the rows (or, for the live cloud, over
16x16 tiles in the image's Z order: its batches are cut from the points as they come, no sort).
``depth_to_points_reference`` is the same in plain numpy (the tests compare them).

A pixel is valid when its depth is finite, > 0 and (with ``max_depth``) not beyond it: zeros
and NaNs are a sensor's holes, skipped; a frame with no valid pixel is refused. An integer image
with a negative depth is refused: no sensor marks holes so (they write 0), and it is what
uint16 millimetres read as int16 show beyond 32.767 m (they were dropped without a word).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit, prange

from ..errors import InputError, is_real

#: depth units of integer images when no ``depth_scale`` is given: millimetres (Kinect, RealSense, TUM uses 1/5000)
DEFAULT_INTEGER_SCALE = 0.001

#: the most pixels one depth frame may have: 8192 x 4096, beyond every depth sensor (a 4K
#: one has 8.3 M); each pixel costs ~60 bytes while it becomes a point with its normal
MAX_DEPTH_PIXELS = 8192 * 4096


def parse_intrinsics(intrinsics, name: str = "push_depth") -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) from a 3x3 camera matrix or a 4-sequence; a one-line InputError otherwise."""
    if intrinsics is None:
        raise InputError(f"{name}: intrinsics are missing: give a 3x3 camera matrix or (fx, fy, cx, cy)")
    try:
        k = np.asarray(intrinsics)
        listed = () if isinstance(intrinsics, np.ndarray) else np.asarray(intrinsics, object).ravel()
        if k.dtype.kind not in "iuf" or any(isinstance(v, (bool, np.bool_)) for v in listed):
            raise TypeError  # ((True, True, 1, 1) was fx = fy = 1: numpy made them numbers)
        k = k.astype(np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name}: intrinsics must be a 3x3 matrix or (fx, fy, cx, cy), got {type(intrinsics).__name__}") from None
    if k.shape == (3, 3):
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    elif k.shape == (4,):
        fx, fy, cx, cy = k
    else:
        raise InputError(f"{name}: intrinsics must be a 3x3 matrix or (fx, fy, cx, cy), got shape {k.shape}")
    if not (np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0):
        raise InputError(f"{name}: intrinsics need finite fx, fy > 0 and finite cx, cy, got {(float(fx), float(fy), float(cx), float(cy))}")
    return float(fx), float(fy), float(cx), float(cy)


def parse_pose(pose, name: str = "push") -> np.ndarray:
    """A float64 4x4 rigid/affine pose (sensor -> world); identity for None."""
    if pose is None:
        return np.eye(4)
    try:
        p = np.asarray(pose, np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name}: pose must be a 4x4 matrix, got {type(pose).__name__}") from None
    if p.shape == (3, 4):
        p = np.vstack([p, [0.0, 0.0, 0.0, 1.0]])
    if p.shape != (4, 4):
        raise InputError(f"{name}: pose must be a 4x4 matrix, got shape {p.shape}")
    if not np.isfinite(p).all():
        raise InputError(f"{name}: pose holds NaN or inf")
    if not np.allclose(p[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError(f"{name}: pose's last row must be (0, 0, 0, 1), got {p[3].tolist()}")
    r = p[:3, :3]  # a singular one (zeros, a repeated axis) flattened the frame onto a plane or a point, without a word
    if not abs(np.linalg.det(r)) > 1e-9 * np.prod(np.linalg.norm(r, axis=0)):
        raise InputError(f"{name}: pose's 3x3 rotation part is singular (it would flatten the frame): {np.round(r, 6).tolist()}")
    return np.ascontiguousarray(p)


def normal_matrix(pose: np.ndarray) -> tuple[np.ndarray, bool]:
    """(3x3 taking sensor normals to world normals under ``pose``, whether they must be made unit
    again after it). Normals move by the inverse transpose of the pose's 3x3 part, not by it: a
    pose in millimetres -> metres made every normal 0.001 long, and a non-uniform scale tilted
    them off their surfaces. A rotation times a uniform scale keeps them unit once divided by
    that scale; any other (a non-uniform scale, a shear) needs ``unit_rows`` after it."""
    r = pose[:3, :3]
    gram = r.T @ r
    scale2 = float(np.trace(gram)) / 3.0
    if np.allclose(gram, scale2 * np.eye(3), rtol=0.0, atol=1e-9 * scale2):  # a rotation times a uniform scale
        return np.ascontiguousarray(r / np.sqrt(scale2)), False
    return np.ascontiguousarray(np.linalg.inv(r).T), True


def unit_rows(v: np.ndarray) -> None:
    """Scale each non-zero row of ``v`` to length 1, in place (zero rows: unknown normals, kept)."""
    length = np.linalg.norm(v, axis=1)
    known = length > 0
    v[known] /= length[known, None].astype(v.dtype)


def check_depth(depth, depth_scale, name: str = "push_depth") -> tuple[np.ndarray, float]:
    """The depth image as a 2-D array and its scale to metres."""
    try:
        d = np.asarray(depth)
    except (TypeError, ValueError):  # a ragged list: numpy's "inhomogeneous shape" traceback
        raise InputError(f"{name}: depth must be an (H, W) image of numbers, got a ragged {type(depth).__name__}") from None
    if d.ndim == 3 and d.shape[2] == 1:
        d = d[:, :, 0]
    if d.ndim != 2 or d.shape[0] < 1 or d.shape[1] < 1:
        raise InputError(f"{name}: depth must be an (H, W) image, got shape {d.shape}")
    if d.size > MAX_DEPTH_PIXELS:  # 20000 x 20000 ran the machine out of memory (~60 bytes a pixel)
        raise InputError(f"{name}: a {d.shape[1]}x{d.shape[0]} depth image is more than a sensor's {MAX_DEPTH_PIXELS:,} pixels; push it in tiles")
    if d.dtype.kind not in "uif":
        raise InputError(f"{name}: depth must hold numbers (uint16 millimetres or float metres), got dtype {d.dtype}")
    if d.dtype.kind == "i" and d.min() < 0:  # (float images: -inf is a sensor's "too close", a hole)
        r, c = np.unravel_index(d.argmin(), d.shape)
        raise InputError(f"{name}: depth holds negative values (e.g. {d[r, c]} at row {r}, column {c}): integer depths must be >= 0 "
                         f"(0 marks a hole); was an unsigned image read as {d.dtype}?")  # fmt: skip
    if depth_scale is None:
        depth_scale = DEFAULT_INTEGER_SCALE if d.dtype.kind in "ui" else 1.0
    if not (is_real(depth_scale) and depth_scale > 0):  # "a" was float()'s ValueError traceback, True taken as 1
        raise InputError(f"{name}: depth_scale must be a positive number, got {depth_scale!r}")
    depth_scale = float(depth_scale)
    if d.dtype not in (np.uint16, np.float32, np.float64):
        d = d.astype(np.float64)
    return np.ascontiguousarray(d), depth_scale


@njit(inline="always")
def _metres(depth, v, u, scale, max_depth):
    """Depth of pixel (v, u) in metres, or 0 where invalid (hole, NaN, beyond max_depth)."""
    z = float(depth[v, u]) * scale
    if not (0.0 < z < np.inf) or z > max_depth:  # NaN compares False
        return 0.0
    return z


@njit(parallel=True, cache=True)
def depth_kernel(depth, scale, max_depth, fx, fy, cx, cy, pose, normal_to_world, rgb, tiles, th, tw, z, xyz, nrm, rgba, pix, counts):
    """Points of the valid pixels of ``depth``, tile by tile in the order of ``tiles`` ((row,
    column) of each ``th`` x ``tw`` tile: whole rows in order, or ``tile_order``'s Z order),
    row-major inside a tile: world xyz (pose applied), normal (world: ``normal_to_world``, from
    normal_matrix, applied; 0 where no neighbour pair exists), rgba (from ``rgb`` (H*W, 3|4) u8, alpha 255 for 3 channels, or left alone
    when it has no rows) and pixel index. Scratch: ``z`` (H, W) float64 metres (0: invalid),
    ``counts`` (tiles + 1) the tiles' offsets. Returns the number of points."""
    h, w = depth.shape
    n_tiles = tiles.shape[0]
    counts[0] = 0
    for v in prange(h):  # pass 1: metres, 0 where invalid (whole rows: ~0.25 ms a frame faster than by tiles)
        for u in range(w):
            z[v, u] = _metres(depth, v, u, scale, max_depth)
    for t in prange(n_tiles):  # the valid pixels of each tile
        v0, u0 = tiles[t, 0] * th, tiles[t, 1] * tw
        c = 0
        for v in range(v0, min(v0 + th, h)):
            for u in range(u0, min(u0 + tw, w)):
                c += z[v, u] > 0.0
        counts[t + 1] = c
    for t in range(n_tiles):
        counts[t + 1] += counts[t]
    has_rgb = rgb.shape[0] > 0
    nc = rgb.shape[1]
    ifx = 1.0 / fx
    ify = 1.0 / fy
    for t in prange(n_tiles):  # pass 2: positions, normals, colors of the valid pixels, in tile order
        k = counts[t]
        v0, u0 = tiles[t, 0] * th, tiles[t, 1] * tw
        for v in range(v0, min(v0 + th, h)):
            ry = (v - cy) * ify
            for u in range(u0, min(u0 + tw, w)):
                zc = z[v, u]
                if zc == 0.0:
                    continue
                rx = (u - cx) * ifx
                x = rx * zc
                y = ry * zc
                # horizontal difference: to the right neighbour, else from the left one
                hx = hy = hz = 0.0
                ok_h = False
                if u + 1 < w and z[v, u + 1] > 0.0:
                    z1 = z[v, u + 1]
                    hx, hy, hz, ok_h = (u + 1 - cx) * ifx * z1 - x, ry * z1 - y, z1 - zc, True
                elif u > 0 and z[v, u - 1] > 0.0:
                    z1 = z[v, u - 1]
                    hx, hy, hz, ok_h = x - (u - 1 - cx) * ifx * z1, y - ry * z1, zc - z1, True
                vx = vy = vz = 0.0
                ok_v = False
                if v + 1 < h and z[v + 1, u] > 0.0:
                    z1 = z[v + 1, u]
                    vx, vy, vz, ok_v = rx * z1 - x, (v + 1 - cy) * ify * z1 - y, z1 - zc, True
                elif v > 0 and z[v - 1, u] > 0.0:
                    z1 = z[v - 1, u]
                    vx, vy, vz, ok_v = x - rx * z1, y - (v - 1 - cy) * ify * z1, zc - z1, True
                nx = ny = nz = 0.0
                if ok_h and ok_v:
                    nx = hy * vz - hz * vy
                    ny = hz * vx - hx * vz
                    nz = hx * vy - hy * vx
                    length = np.sqrt(nx * nx + ny * ny + nz * nz)
                    if length > 0.0:
                        if nx * x + ny * y + nz * zc > 0.0:  # towards the sensor (at the origin)
                            length = -length
                        nx /= length
                        ny /= length
                        nz /= length
                    else:
                        nx = ny = nz = 0.0
                for a in range(3):
                    xyz[k, a] = pose[a, 0] * x + pose[a, 1] * y + pose[a, 2] * zc + pose[a, 3]
                    nrm[k, a] = np.float32(normal_to_world[a, 0] * nx + normal_to_world[a, 1] * ny + normal_to_world[a, 2] * nz)
                if has_rgb:
                    for c in range(nc):
                        rgba[k, c] = rgb[v * w + u, c]
                    if nc == 3:
                        rgba[k, 3] = 255
                pix[k] = v * w + u
                k += 1
    return counts[n_tiles]


TILE = 16  # pixels on a side of the tiles of the Z order: a frame's batch (10 240 points) is ~40 of them


@lru_cache(maxsize=8)
def tile_order(h: int, w: int, z_order: bool) -> tuple[np.ndarray, int, int]:
    """(tiles (n, 2) int64 (row, column) in visiting order, tile height, tile width) of an (h, w)
    image: its rows one by one, or with ``z_order`` TILE x TILE tiles in Z (Morton) order, each
    aligned power-of-two square of tiles whole before the next. Computed once per shape."""
    th, tw = (TILE, TILE) if z_order else (1, w)
    rows, cols = -(-h // th), -(-w // tw)
    r, c = np.divmod(np.arange(rows * cols, dtype=np.int64), cols)
    code = np.zeros(rows * cols, np.int64)
    for b in range(max(rows, cols).bit_length()):
        code |= ((c >> b) & 1) << (2 * b) | ((r >> b) & 1) << (2 * b + 1)
    order = np.argsort(code, kind="stable")
    tiles = np.stack([r[order], c[order]], axis=1)
    tiles.flags.writeable = False  # shared by every frame of this shape
    return tiles, th, tw


def depth_to_points(depth, intrinsics, pose=None, rgb=None, depth_scale=None, max_depth=None, name: str = "push_depth", z_order: bool = False,
                    scratch: dict | None = None, scalers: dict | None = None):  # fmt: skip
    """(xyz float64 (N, 3) world, normals float32 (N, 3) world, rgba uint8 (N, 4) or None,
    pixel index int64 (N,)) of the valid pixels of an (H, W) depth image, in row-major order, or
    with ``z_order`` tile by tile in the image's Z order (``tile_order``): consecutive points are
    neighbours in the image, so the live cloud cuts a frame's batches from them as they come,
    about as compact as a sort by 3-D Morton code makes them (the image is the sensor's
    projection of the scene: only depth edges stretch a batch along the view rays), without the sort.

    ``scratch``: a dict that keeps the positions, pixel indices and the kernel's metres from one
    call to the next (LiveCloud.push_depth: one per producer thread): the xyz and pixel index
    returned are then views of its arrays, valid until the next call with it. ``scalers``: the
    stream's colour range (``colors_for``'s), decided on its first frame with colours
    (LiveCloud.push_depth: the cloud's, as push's; None: this frame's alone). Made anew for
    every frame they are ~7 MB of fresh pages while the caller still holds the last frame's:
    1.6 ms a frame on the Intel Xeon VM, as long as the kernel (docs/benchmarks.md)."""
    d, scale = check_depth(depth, depth_scale, name)
    fx, fy, cx, cy = parse_intrinsics(intrinsics, name)
    p = parse_pose(pose, name)
    h, w = d.shape
    scratch = {} if scratch is None else scratch
    if max_depth is not None and not (is_real(max_depth) and max_depth > 0 or max_depth == np.inf):  # -1: "no valid pixel"; before the colours, whose range a refused frame must not decide
        raise InputError(f"{name}: max_depth must be a positive number of metres or None, got {max_depth!r}")
    rgb8 = np.empty((0, 4), np.uint8)
    if rgb is not None:
        from ..core.chunk import colors_for

        try:
            c = np.asarray(rgb)
        except (TypeError, ValueError):  # a ragged list
            c = np.empty(0)
        if c.shape[:2] != (h, w) or c.ndim != 3 or c.shape[2] not in (3, 4):
            raise InputError(f"{name}: rgb must be an ({h}, {w}, 3|4) image matching the depth, got shape {c.shape}")
        if c.dtype.kind not in "biuf":  # strings were int()'s ValueError traceback, complex a ComplexWarning
            raise InputError(f"{name}: rgb must hold numbers (uint8, uint16 or float colors), got dtype {c.dtype}")
        rgb8 = c.reshape(h * w, c.shape[2])
        # 8-bit RGB(A) read as it is; others judged as push's colours (to_rgba8 took every float
        # as 0..1: a float image of 0..255 was all white, NaN and -3 black without a word), their
        # range once per stream: judged per frame, one overshooting 1.0 a little flashed black
        if rgb8.dtype != np.uint8:
            rgb8 = colors_for(rgb8, h * w, name, scalers)
        rgb8 = np.ascontiguousarray(rgb8)
    limit = np.inf if max_depth is None else float(max_depth)
    n = h * w

    def reused(key, shape, dtype):
        a = scratch.get(key)
        if not (isinstance(a, np.ndarray) and a.shape == shape and a.dtype == dtype and a.flags.c_contiguous and a.flags.writeable):
            a = scratch[key] = np.empty(shape, dtype)
        return a

    xyz = reused("xyz", (n, 3), np.float64)
    nrm = np.empty((n, 3), np.float32)  # kept by the frame (its normals): new each call
    rgba = np.empty((n if rgb is not None else 0, 4), np.uint8)  # likewise its colours
    pix = reused("pix", (n,), np.int64)
    tiles, th, tw = tile_order(h, w, bool(z_order))
    counts = np.empty(len(tiles) + 1, np.int64)
    to_world, renormalize = normal_matrix(p)
    k = depth_kernel(d, scale, limit, fx, fy, cx, cy, p, to_world, rgb8, tiles, th, tw, reused("z", (h, w), np.float64), xyz, nrm, rgba, pix, counts)
    if k == 0:
        raise InputError(f"{name}: the {w}x{h} depth image has no valid pixel (all zero, NaN or beyond max_depth)")
    if renormalize:
        unit_rows(nrm[:k])
    return xyz[:k], nrm[:k], (rgba[:k] if rgb is not None else None), pix[:k]


def depth_to_points_reference(depth, intrinsics, pose=None, depth_scale=None, max_depth=None):
    """``depth_to_points`` in plain numpy (xyz, normals, pixel index): the tests' reference."""
    d, scale = check_depth(depth, depth_scale)
    fx, fy, cx, cy = parse_intrinsics(intrinsics)
    p = parse_pose(pose)
    h, w = d.shape
    z = d.astype(np.float64) * scale
    limit = np.inf if max_depth is None else float(max_depth)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(z) & (z > 0) & (z <= limit)
    z = np.where(valid, z, 0.0)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    cam = np.stack([(u - cx) * (1.0 / fx) * z, (v - cy) * (1.0 / fy) * z, z], axis=-1)  # the kernel's operation order

    def diff(axis):
        fwd = np.zeros_like(cam)
        bwd = np.zeros_like(cam)
        ok_f = np.zeros((h, w), bool)
        ok_b = np.zeros((h, w), bool)
        if axis == 1:
            fwd[:, :-1] = cam[:, 1:] - cam[:, :-1]
            ok_f[:, :-1] = valid[:, 1:]
            bwd[:, 1:] = cam[:, 1:] - cam[:, :-1]
            ok_b[:, 1:] = valid[:, :-1]
        else:
            fwd[:-1] = cam[1:] - cam[:-1]
            ok_f[:-1] = valid[1:]
            bwd[1:] = cam[1:] - cam[:-1]
            ok_b[1:] = valid[:-1]
        out = np.where(ok_f[..., None], fwd, np.where(ok_b[..., None], bwd, 0.0))
        return out, ok_f | ok_b

    dh, ok_h = diff(1)
    dv, ok_v = diff(0)
    n = np.cross(dh, dv)
    length = np.linalg.norm(n, axis=-1)
    good = ok_h & ok_v & (length > 0)
    flip = np.sum(n * cam, axis=-1) > 0
    length = np.where(flip, -length, length)
    n = np.where(good[..., None], n / np.where(good, length, 1.0)[..., None], 0.0)
    idx = np.flatnonzero(valid.reshape(-1))
    pts = cam.reshape(-1, 3)[idx]
    nrm = n.reshape(-1, 3)[idx]
    world = pts @ p[:3, :3].T + p[:3, 3]
    world_normals = nrm @ np.linalg.inv(p[:3, :3])  # (the inverse transpose, applied to rows)
    length = np.linalg.norm(world_normals, axis=1, keepdims=True)
    return world, (world_normals / np.where(length > 0, length, 1.0)).astype(np.float32), idx
