"""LiveCloud: point frames streamed in by producer threads, the last ``keep`` of them drawn
(Kraft 2019: a depth sensor's frames replaced every frame, pose-tagged snapshots accumulated).

A frame (``push``: points in sensor or world coordinates with a 4x4 pose; ``push_depth``: an
organised depth image turned into points and normals by depth.py's kernel) is put in world
coordinates, Morton-ordered (a depth frame: in its image's Z order, no sort) and cut into
batches on arrival by core's own path (core/morton.py, core/quantize.py: Morton codes, sort,
batches, 30-bit words), outside any lock;
then its batches are copied into free chunks of the ring (ring.py) under a frames-first lock,
so a frame appears whole or not at all (no torn frames) and culling and adaptive precision work
on it unchanged. A frame of at most half a chunk (PACK_LIMIT) is kept as it came instead and
packed after the frames before it into a shared chunk (``_pack``): a chunk each made frames of
50 points hold 6 712 bytes of ring arrays a point. A frame pushed while another is being drawn
waits, batched, in a queue and is copied in when the drawing lets go of the lock: producers
never wait for the renderer. At most ``keep`` frames wait: an older one would leave the ring as
soon as it was copied in, never drawn, so it is dropped (``stats.frames_dropped``, a warning
once) and the queue holds no more than a full ring. Frames beyond ``keep`` (or ``decay``
seconds old) leave the ring and their chunks are reused: memory stays flat over a long stream.

``snapshot()`` freezes the frames in the ring into a ProgressiveOctree (lod.progressive, its
public ``add``); the octree's pool is mirrored into the same buffers, so one DrawList draws the
ring (every chunk in view) and the octree's selection (its LOD within ``point_budget``).

Per point, ``frame_time`` (float32) holds the seconds since the cloud's start at which its
frame arrived (NaN for snapshot points). With ``decay``, frames ``decay`` seconds old
leave the ring, and until then fade: ``prepare`` gives each drawn batch an ``alpha`` (1 for a
new frame, falling linearly to 0 at ``decay``; ``fade_alpha``) that the transparency pass
(render/passes/transparency.py) composites; ``fade=False`` drops them without fading.
"""

from __future__ import annotations

import copy
import heapq
import numbers
import os
import threading
import time as _time
from collections import Counter, deque
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.bounds import valid_bounds
from ..core.chunk import colors_for, points_for
from ..core.cloud import MAX_ABS_COORDINATE, PointCloud, take
from ..core.layout import BATCH_SIZE
from ..core.morton import argsort_codes, cube_of, morton_codes
from ..core.quantize import make_batches, quantize
from ..core.renderable import DrawList, refuse_hidden_classes
from ..core.selection import Selection, View, select_view, subsample_step
from ..core.threads import threads_for
from ..errors import GigapointError, GigapointWarning, InputError, KeptWarnings, check_switch, check_timeout, check_whole, is_real, warn
from ..lod.progressive import CHUNK as SNAPSHOT_CHUNK  # the snapshot octree's chunk: the mirror's
from ..render.splats import point_spacing
from .depth import depth_to_points, normal_matrix, parse_pose, unit_rows
from .ring import BASE_ATTRIBUTES, NORMAL_PARTS, LiveBuffers, LiveLock, Runs, attribute_dtype

_INITIAL_CHUNKS = 32
PACK_LIMIT = 0.5  # frames of at most this share of a chunk are packed into shared chunks (LiveCloud._pack)
PACK_FILL = BATCH_SIZE  # points packed into one chunk at most (LiveCloud._pack_fill)
PACK_SPAN = 32  # with fading, small frames packed into one chunk arrived within decay / PACK_SPAN (its alpha is its first's)
PACK_GROWTH, PACK_NEAR = 2.0, 16.0  # packed frames lie near each other: LiveCloud._near
PACK_OPEN = 8  # chunks open to small frames at once (sensors whose packets interleave: one each)
_LATENCIES = 512  # push-to-pixels latencies kept for the median / p99
SNAPSHOT_BATCH = 1 << 20  # points a snapshot adds to the octree at a time
SNAPSHOT_SAMPLE_STEP = 32  # every 32nd point shapes the tree first (ProgressiveOctree.expect): ~1 500 for a full leaf


@dataclass
class FrameInfo:
    """One frame in the ring."""

    seq: int  # 0, 1, 2... in arrival order
    chunks: list[int]  # the ring chunks holding its points (a small frame shares one with others: _pack)
    n_points: int
    time: float  # the sensor's time stamp (seconds), or the arrival clock's
    arrived: float  # seconds since the cloud's start (the frame_time of its points)
    pose: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    pushed_at: float = 0.0  # perf_counter when push was called (latency)
    firsts: list[int] = field(default_factory=list)  # per chunk, the buffer entry of its first point there
    counts: list[int] = field(default_factory=list)  # per chunk, its points there
    colored: bool = True  # pushed with colours (False: drawn in the grey it was filled with, saved without RGB)


@dataclass
class SmallFrame:
    """A frame of at most half a chunk, kept as it came (world positions, colours as u32 words,
    per-point attributes, copies): packed into the ring's open chunk with the frames before it."""

    xyz: np.ndarray
    color: np.ndarray
    attributes: dict


@dataclass
class OpenChunk:
    """The ring chunk small frames are packed into (``_pack``): the world positions of every
    point written to it (its words are quantized afresh from them when a frame widens its box),
    how many, and the arrival of its first frame (its fade)."""

    slot: int
    xyz: np.ndarray
    written: int
    opened: float
    lo: np.ndarray  # the box of its frames
    hi: np.ndarray
    widest: float  # the largest edge of one of its frames' boxes


@dataclass
class LiveStats:
    frames_in: int = 0  # frames copied into the ring
    frames_rejected: int = 0
    frames_dropped: int = 0  # frames accepted but dropped unseen: more than ``keep`` waited for the lock
    points_in: int = 0
    last_error: str | None = None
    clock: Callable[[], float] = _time.monotonic  # the cloud's (a test's fake): arrivals and frames_per_second's now
    arrivals: deque = field(default_factory=lambda: deque(maxlen=120))  # clock() of recent arrivals
    latencies: deque = field(default_factory=lambda: deque(maxlen=_LATENCIES))  # seconds, push -> drawn

    def frames_per_second(self) -> float:
        """Frames in a second over the last 2 s of arrivals (from the last earlier arrival for a
        slower stream); 0 once no frame came for twice that interval (at least 2 s): the stream
        stopped, and 0 while every arrival came at one clock reading (no rate to tell).
        (Over the last 120 arrivals, a 30 -> 1 frames/s stream still read 8.7 after 10 s, and a
        steady 0.4 frames/s one read 0 two seconds after each frame; two arrivals at one reading
        of a frozen or coarse clock read 1e9 frames/s.)"""
        a = list(self.arrivals)
        if len(a) < 2:
            return 0.0
        recent = [t for t in a if t >= a[-1] - 2.0]
        if recent[-1] <= recent[0]:  # arrivals at one instant tell no rate: back to the last one before them
            recent = [t for t in a if t < recent[-1]][-1:] + recent
        span = recent[-1] - recent[0]
        if span <= 0:
            return 0.0
        interval = span / (len(recent) - 1)
        if self.clock() - a[-1] > max(2.0, 2.0 * interval):  # the stream stopped
            return 0.0
        return 1.0 / interval

    def latency_ms(self, q: float = 50.0) -> float | None:
        lat = list(self.latencies)
        return float(np.percentile(lat, q) * 1000.0) if lat else None


MAX_CHUNK = 1 << 20  # the most points a ring chunk (a drawn batch) may hold


def _array(values, where: str) -> np.ndarray:
    """``values`` as an array; a ragged list (numpy's "inhomogeneous shape" ValueError) is a one-line InputError."""
    try:
        return np.asarray(values)
    except (TypeError, ValueError):
        raise InputError(f"{where} must be an array of numbers, got a ragged {type(values).__name__}") from None


def batch_frame(pts: np.ndarray, rgba: np.ndarray, attributes: dict, lo, hi, chunk: int, ordered: bool = False) -> PointCloud:
    """One frame in core's layout: Morton codes in its bounding cube, batches of ``chunk``
    points, 30-bit words (core/morton.py, core/quantize.py). The order is numpy's faster sort on
    this CPU (morton.argsort_codes): 3-5 ms for a
    512x424 frame (ties are the same point: their order does not matter). ``ordered``: the
    points come in an order batches can be cut from as they are (a depth frame's image Z order,
    depth.tile_order): no sort and no gathers."""
    batches = make_batches(len(pts), chunk)
    color = np.ascontiguousarray(rgba, np.uint8).view(np.uint32).reshape(-1)
    if ordered:
        low, med, high = quantize(pts, np.arange(len(pts)), batches)
        return PointCloud(batches, low, med, high, color, {a: np.asarray(v) for a, v in attributes.items()}, name="frame")
    origin, edge = cube_of(lo, hi)
    order = argsort_codes(morton_codes(pts, origin, edge))
    low, med, high = quantize(pts, order, batches)
    # gathered in parallel: numpy's fancy indexing of the (N, 3) normals alone took ~3 ms a frame
    return PointCloud(batches, low, med, high, take(color, order), {a: take(np.asarray(v), order) for a, v in attributes.items()}, name="frame")


def _misfits(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Which of ``values`` lose their value in ``dtype`` (integers: not exact; floats: finite
    turned infinite)."""
    with np.errstate(all="ignore"):
        held = values.astype(dtype)
        if dtype.kind == "f":
            return np.isfinite(held) != np.isfinite(values)
        return held.astype(values.dtype) != values


class LiveCloud:
    """A cloud fed frame by frame (``push``, ``push_depth``), drawn at any moment (a Renderable)."""

    KIND = "a live cloud"  # what refusals call it (hidden_classes)

    def __init__(self, keep: int = 100, decay: float | None = None, name: str = "live", chunk: int = BATCH_SIZE, clock: Callable[[], float] | None = None,
                 bounds=None, fade: bool = True):  # fmt: skip
        """``keep``: frames drawn (a ring: the oldest leaves when a new one arrives); ``decay``:
        seconds after which a frame leaves the ring whatever ``keep`` says (None: never);
        ``clock``: seconds (monotonic) for decay and frame times (tests pass a fake);
        ``bounds``: (min, max) of the region the stream will cover, if known (the viewer frames
        it from the start; the clip range covers it); ``fade``: with ``decay``, frames fade out
        as they age (each drawn batch's ``alpha`` in the DrawList, for the transparency pass)."""
        if not isinstance(name, str):  # the name every message and file of the cloud starts with
            raise InputError(f"live: name must be a string, got {name!r}")
        keep = check_whole(name, "keep", keep, 1)  # True was taken as 1
        check_switch("fade", fade, name)  # "no" was taken as true
        self.fade = bool(fade)
        if decay is not None and not (isinstance(decay, numbers.Real) and not isinstance(decay, bool) and decay > 0):  # "abc": a ValueError
            raise InputError(f"{name}: decay must be a positive number of seconds or None, got {decay!r}")
        self.name = name
        self.keep = keep
        self.decay = None if decay is None else float(decay)
        self.chunk = check_whole(name, "chunk", chunk, 1, MAX_CHUNK, " points")  # 0 divided by zero, 10**12 asked numpy for 116 TiB
        self.clock = clock or _time.monotonic
        self.expected_bounds = None if bounds is None else self._check_bounds(bounds)
        self.started = self.clock() if callable(self.clock) else None
        if not is_real(self.started):  # 5 was "'int' object is not callable"; NaN seconds never decayed a frame
            raise InputError(f"{name}: clock must be a function giving seconds (a finite number), got {clock!r:.80}")
        self.lock = LiveLock(released=self._commit_pending)
        self._pending: deque = deque()  # (frame in core's layout, FrameInfo) batched, not yet in the ring
        self._pending_lock = threading.Lock()
        self._depth_scratch = threading.local()  # push_depth's reused arrays, one set per producer thread
        self._push_colors: dict = {}  # the stream's colour range (colors_for's scalers): decided by its first accepted frame with colours, as a file's
        self._attr_dtypes: dict | None = None  # fixed by the first frame (as the octree's attributes)
        self.buffers_: LiveBuffers | None = None
        self._free: list[int] = []
        self._open: list[OpenChunk] = []  # the chunks small frames are packed into, newest first (_pack)
        self._seen = None  # (min, max) of every small frame's box so far (_near)
        self._pins: Counter = Counter()  # ring chunks snapshots are reading: not reused meanwhile
        self._held: list[int] = []  # chunks of frames gone, freed when no snapshot reads them
        self.frames: deque[FrameInfo] = deque()
        self._seq = 0
        self._spacing = None  # ((buffers id, step, snapshot points), push count when measured, spacing): _kept_spacing
        self.points = 0  # points in the ring
        self.stats = LiveStats(clock=self.clock)  # (stamped by the real clock beside a fake one, frames/s disagreed with frame times and decay)
        self.snapshots = None  # the ProgressiveOctree of snapshots (created by the first snapshot)
        self.snapshots_colored = False  # a frame snapshotted had colours: save writes RGB (else the grey is made up)
        self.closed = False  # close(): frames and snapshots freed, pushes refused
        self._mirror_pool = None
        self._mirror_version = -1
        self._version_pushed: dict[int, float] = {}  # buffers version -> perf_counter of the newest push it holds
        self._counted_versions: deque = deque(maxlen=64)
        self._changed = threading.Condition()
        self.changes = 0  # frames accepted, snapshots, clears (wait_frame)
        self._chunk_time = np.empty(0, np.float32)  # per ring chunk: its frame's arrival (frame_time), NaN when free
        self._listeners: list[Callable[[], None]] = []
        self.recorder = None
        self.player = None  # a source feeding it (sources.Player), if any
        self.warnings = KeptWarnings()  # its player's thread's warnings, for snapshot, save, close (or player.join) to issue

    def _check_bounds(self, bounds) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) as two float64 (3,) arrays; NaN or min > max failed only at the first
        snapshot (the octree's cube), a wrong shape with numpy's ValueError."""
        try:
            lo, hi = (np.asarray(b, np.float64).reshape(3) for b in bounds)
            ok = bool(np.isfinite(lo).all() and np.isfinite(hi).all() and (lo <= hi).all())
        except (TypeError, ValueError, OverflowError):
            ok = False
        if not ok:
            raise InputError(f"{self.name}: bounds must be (min, max): two (x, y, z) of finite numbers with min <= max, got {bounds!r}"[:300])
        return lo, hi

    # ------------------------------------------------------------------ facts (Renderable)
    load_progress = 1.0

    @contextmanager
    def _as_drawn_now(self, reading: bool = False):
        """The lock held, frames past their ``decay`` gone: what a frame drawn now would show. (Decay
        drops frames only at a push, a drawn frame or here: a paused stream's count, bounds and
        HUD held a frame that had faded out until the next of them.) The plain lock, which counts
        no frame: the facts (n_points, bounds, repr, the HUD) are asked by every rendered frame
        and the viewer's watcher up to 120 times a second, and as frames they made writers wait
        for a frame's turn and ``_commit_pending`` stop early. ``reading``: the frame's lock, for
        what reads the ring's points as a frame does (snapshot, frame_points)."""
        with self.lock.reading() if reading else self.lock:
            self._drop_decayed()
            yield

    @property
    def n_points(self) -> int:
        with self._as_drawn_now():
            return self.points + (self.snapshots.n_points if self.snapshots is not None else 0)

    @property
    def n_frames(self) -> int:
        with self._as_drawn_now():
            return len(self.frames)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        with self._as_drawn_now():
            return self._bounds()

    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The box of the frames in the ring, the snapshots and the expected ``bounds`` (lock held)."""
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for f in self.frames:
            lo, hi = np.minimum(lo, f.lo), np.maximum(hi, f.hi)
        if self.snapshots is not None and self.snapshots.n_points:
            slo, shi = self.snapshots.bounds
            # the octree draws far nodes with 10-bit positions in node cubes: up to half a cell
            # (root edge / 2048) off, so a clip range fitted to the exact bounds of a flat scene
            # seen edge-on or from above would cut them away
            pad = self.snapshots.edge / 2048.0
            lo, hi = np.minimum(lo, slo - pad), np.maximum(hi, shi + pad)
        if self.expected_bounds is not None:
            lo, hi = np.minimum(lo, self.expected_bounds[0]), np.maximum(hi, self.expected_bounds[1])
        if not np.isfinite(lo).all():
            return np.zeros(3), np.ones(3)  # nothing yet: a unit box to look at
        return lo, hi

    @property
    def attributes(self) -> dict:
        return self.buffers_.attributes if self.buffers_ is not None else {}

    @property
    def attribute_names(self) -> list[str]:
        return list(self.attributes)

    @property
    def batches(self) -> np.ndarray:
        return self.buffers_.batches if self.buffers_ is not None else np.empty(0)

    def buffers(self) -> LiveBuffers | None:
        """The point buffers frames are drawn from (None before the first frame)."""
        return self.buffers_

    def __len__(self) -> int:
        return self.n_points

    def __repr__(self) -> str:
        snap = f", {self.snapshots.n_points:,} snapshot points" if self.snapshots is not None else ""
        closed = ", closed" if self.closed else ""  # (as ProgressiveOctree's: the empty cloud said nothing of why)
        with self._as_drawn_now():
            return f"LiveCloud({self.name!r}, {len(self.frames)} of {self.keep} frames, {self.points:,} live points{snap}{closed})"

    def now(self) -> float:
        """Seconds since the cloud started (the clock of ``frame_time``)."""
        return self.clock() - self.started

    def fade_alpha(self, frame_time: np.ndarray, now: float | None = None) -> np.ndarray:
        """float32 opacity factor per point for fading old frames: 1 for a new frame falling
        linearly to 0 at ``decay`` seconds (1 everywhere without decay; 1 for snapshot points, NaN)."""
        t = np.asarray(frame_time, np.float32)
        if self.decay is None:
            return np.ones(t.shape, np.float32)
        age = np.float32(self.now() if now is None else now) - t
        alpha = np.clip(1.0 - age / np.float32(self.decay), 0.0, 1.0).astype(np.float32)
        return np.where(np.isnan(t), np.float32(1.0), alpha)

    # ------------------------------------------------------------------ events
    def add_listener(self, fn: Callable[[], None]) -> None:
        """``fn()`` is called (from the producer's thread) after every accepted frame or snapshot."""
        self._listeners.append(fn)

    def remove_listener(self, fn) -> None:
        if fn in self._listeners:
            self._listeners.remove(fn)

    def wait_frame(self, seen: int, timeout: float | None = None) -> int:
        """Wait until the cloud changed (a frame accepted, a snapshot, a clear) more than ``seen``
        times, or ``timeout`` passes; returns the count of changes."""
        check_whole(f"{self.name}: wait_frame", "seen", seen)  # 'a' was a TypeError inside the wait
        timeout = check_timeout(f"{self.name}: wait_frame", timeout)  # NaN waited forever
        with self._changed:
            self._changed.wait_for(lambda: self.changes > seen, timeout)
            return self.changes

    def _notify(self) -> None:
        with self._changed:
            self.changes += 1
            self._changed.notify_all()
        for fn in list(self._listeners):
            fn()

    def refused(self, error) -> None:
        """Count a frame refused before it reached ``push`` (a malformed pushed message, an
        unreadable file): the HUD shows the last such error."""
        self.stats.frames_rejected += 1
        self.stats.last_error = str(error)

    # ------------------------------------------------------------------ pushing frames
    def push(self, xyz, rgb=None, pose=None, time: float | None = None, normals=None, **attributes) -> int:
        """Add a frame: xyz (N, 3) in sensor coordinates (``pose``: 4x4 sensor -> world; None:
        world coordinates), colors (N, 3|4) uint8/uint16/float (their range decided on the first
        frame with colours, as a file's: ``colors_for``), optional (N, 3) normals in sensor
        coordinates and 1-D attributes of length N. Points with NaN/inf coordinates are dropped.
        Returns the frame's sequence number. A bad frame raises a one-line InputError and leaves
        the ring as it was."""
        pushed_at = _time.perf_counter()
        try:
            return self._push(xyz, rgb, pose, time, normals, attributes, pushed_at)[0]
        except GigapointError as exc:
            self.refused(exc)
            raise

    def push_depth(self, depth, intrinsics, pose=None, rgb=None, depth_scale: float | None = None, time: float | None = None,
                   max_depth: float | None = None) -> int:  # fmt: skip
        """Add a frame from an organised (H, W) depth image (uint16 in ``depth_scale`` metres, by
        default millimetres; float in metres, or times ``depth_scale``) and its pinhole
        ``intrinsics`` (3x3 matrix or (fx, fy, cx, cy)); ``rgb`` an aligned (H, W, 3|4) image.
        Zero and NaN depths are holes (skipped); points get normals from their image neighbours."""
        pushed_at = _time.perf_counter()
        try:
            where = f"{self.name}: push_depth"  # (several clouds: which one refused, as push says)
            self._check_open("push_depth")  # (before the kernel: a closed cloud's refusal named push)
            p = parse_pose(pose, where)
            scratch = self._depth_scratch.__dict__  # this producer thread's (the frame keeps no view of its arrays)
            scalers = self._trial_colors()  # (the cloud's range, as push's: a replay, one thread, colours as live)
            xyz, nrm, rgba, _ = depth_to_points(depth, intrinsics, p, rgb, depth_scale, max_depth, where, z_order=True, scratch=scratch, scalers=scalers)
            seq, t = self._push(xyz, rgba, None, time, None, {}, pushed_at, world_normals=nrm, pose_tag=p, ordered=True, scalers=scalers)
        except GigapointError as exc:
            self.refused(exc)
            raise
        if self.recorder is not None:
            self.recorder.write_depth(seq, depth, intrinsics, p, rgb, depth_scale, max_depth, t)
        return seq

    def _push(self, xyz, rgb, pose, time, normals, attributes, pushed_at, world_normals=None, pose_tag=None, ordered=False,
              scalers=None) -> tuple[int, float]:  # fmt: skip
        """The frame's sequence number and time stamp (for a depth frame's recording: the cloud's
        last time stamp was another producer's frame's when one pushed meanwhile). ``ordered``: a
        depth frame's points in its image's Z order, batched as they come (batch_frame); other
        frames are sorted by Morton code. ``scalers``: the colour range the frame's colours were
        judged with (push_depth's ``_trial_colors``), kept if it is accepted."""
        name = self.name
        self._check_open("push")
        xyz_in = points_for(xyz, f"{name}: push")
        n = len(xyz_in)
        if n == 0:
            raise InputError(f"{name}: push: the frame has no points")
        with threads_for(n):  # a small frame on this thread alone: waking the others costs more (core/threads.py)
            return self._push_points(xyz_in, rgb, pose, time, normals, attributes, pushed_at, world_normals, pose_tag, ordered, scalers)

    def _push_points(self, xyz_in, rgb, pose, time, normals, attributes, pushed_at, world_normals, pose_tag, ordered, scalers) -> tuple[int, float]:
        name, n = self.name, len(xyz_in)
        p = parse_pose(pose, f"{name}: push") if pose_tag is None else pose_tag
        scalers = self._trial_colors() if scalers is None else scalers
        rgba = colors_for(rgb, n, f"{name}: push", scalers) if rgb is not None else None
        attrs = {}
        for a, v in attributes.items():
            v = _array(v, f"{name}: push: attribute {a!r}")
            if v.ndim != 1 or len(v) != n or v.dtype.kind not in "biuf":
                raise InputError(f"{name}: push: attribute {a!r} must be 1-D numbers of length {n}, got shape {v.shape} dtype {v.dtype}")
            if a in BASE_ATTRIBUTES or a in NORMAL_PARTS:
                raise InputError(f"{name}: push: attribute name {a!r} is reserved (give normals=...)")
            attrs[a] = v
        if normals is not None:
            nrm = _array(normals, f"{name}: push: normals")
            if nrm.shape != (n, 3) or nrm.dtype.kind not in "if":
                raise InputError(f"{name}: push: normals must be ({n}, 3) floats or signed integers, got shape {nrm.shape} dtype {nrm.dtype}")
            to_world, renormalize = normal_matrix(p)  # (a scaled pose moves normals otherwise than points)
            with np.errstate(invalid="ignore"):  # (inf times 0)
                world_normals = (nrm.astype(np.float64) @ to_world.T).astype(np.float32)
            # a NaN or inf normal is an unknown one: 0 (as the module doc says); lighting and
            # color_mode="normal" drew a point with NaN in it black
            world_normals[~np.isfinite(world_normals).all(axis=1)] = 0.0
            if renormalize:
                unit_rows(world_normals)
        pts = np.asarray(xyz_in, np.float64)  # no copy of float64 points (nothing writes into them)
        if pose_tag is None and pose is not None:  # sensor -> world (push_depth's kernel applied it already)
            pts = pts @ p[:3, :3].T + p[:3, 3]
        valid, lo, hi = valid_bounds(pts, MAX_ABS_COORDINATE)  # one parallel pass (the octree's)
        if not valid.all():
            if not valid.any():
                raise InputError(f"{name}: push: none of the frame's {n} points is valid (NaN, inf or beyond ±{MAX_ABS_COORDINATE:g})")
            pts = pts[valid]
            rgba = rgba[valid] if rgba is not None else None
            world_normals = world_normals[valid] if world_normals is not None else None
            attrs = {a: v[valid] for a, v in attrs.items()}
        m = len(pts)
        colored = rgba is not None  # (before the grey fill: saved without RGB, not as grey)
        if rgba is None:
            rgba = np.empty((m, 4), np.uint8)
            rgba[:] = (200, 200, 200, 255)
        if world_normals is None:
            world_normals = np.zeros((m, 3), np.float32)
        arrived = self.now()
        if time is not None and not is_real(time):  # (NaN and inf; "a" was float()'s ValueError)
            raise InputError(f"{name}: push: time must be a finite number of seconds, got {time!r}")
        t = float(time) if time is not None else self.clock()
        per_point = {"normal": world_normals, "frame_time": np.full(m, arrived, np.float32)}
        per_point.update(attrs)
        if m <= PACK_LIMIT * self._pack_fill:  # copies: push_depth's arrays are its thread's scratch, reused by its next frame
            color = np.ascontiguousarray(rgba, np.uint8).view(np.uint32).reshape(-1)
            frame = SmallFrame(np.array(pts, np.float64), color.copy(), {a: np.array(v) for a, v in per_point.items()})
        else:
            frame = batch_frame(pts, rgba, per_point, lo, hi, self.chunk, ordered)
        with self._pending_lock:
            self._attribute_set(attrs)  # in push order: the first frame's set, which later ones keep to
            self._keep_colors(scalers)  # (the frame is accepted: its colours may decide the range)
            seq = self._seq
            self._seq += 1
            self._pending.append((frame, FrameInfo(seq, [], m, t, arrived, p, lo, hi, pushed_at, colored=colored)))
            # the queue's bound: behind ``keep`` newer frames, a waiting frame would leave the ring
            # as soon as it was copied in (a renderer holding the lock, a producer outpacing the
            # copies: the queue grew without end); producers still never wait
            dropped = max(0, len(self._pending) - self.keep)
            for _ in range(dropped):
                self._pending.popleft()
            first_drop = dropped and not self.stats.frames_dropped  # said once
            self.stats.frames_dropped += dropped
        if first_drop:
            warn(f"{name}: frames arrive faster than they are copied into the ring (the lock held long): "
                 f"more than keep={self.keep} waited, the oldest are dropped unseen (stats.frames_dropped)", GigapointWarning)  # fmt: skip
        self._commit_pending()
        if self.recorder is not None and pose_tag is None:
            self.recorder.write_points(seq, xyz_in, rgb, pose, t, normals, attributes)
        return seq, t

    def _commit_pending(self) -> None:
        """Copy the frames waiting in ``_pending`` into the ring, in push order, whenever the lock
        is free: by the producer at once, else by whoever holds the lock (a frame being drawn)
        when it lets go (LiveLock's ``released``). A producer never waits for a frame to be drawn;
        one that finds another producer copying waits for it, then copies its own.

        A call copies only the frames waiting when it took the lock, and stops early for a frame
        that waits for it (the frame's ``released`` copies the rest): copying until the queue
        was empty, while producers pushed faster than that (three on two cores), kept a renderer
        or snapshot from the lock, or in its ``released``, for ever."""
        if not (self._pending and self.lock.try_write(behind_writers=True)):
            return
        committed = 0
        try:
            with self._pending_lock:
                waiting = len(self._pending)  # (pushes drop from the front at most: no more than these are taken)
            for _ in range(waiting):
                with self._pending_lock:
                    if not self._pending:  # a push dropped waiting frames meanwhile (the queue's bound)
                        break
                    frame, info = self._pending.popleft()
                self._insert(frame, info)
                self._expire()
                self.stats.frames_in += 1
                self.stats.points_in += info.n_points
                self.stats.arrivals.append(self.clock())
                committed += 1
                if self.lock.frame_waiting():
                    break
        finally:
            self.lock.release()
        if committed:
            self._notify()

    def _trial_colors(self) -> dict:
        """A copy of the stream's colour range for a frame's colours to be judged with, kept
        (``_keep_colors``) only once the frame is accepted: a frame refused after its colours were
        judged (a bad attribute or time, no valid point) decided the range of the whole stream.
        Under the pending lock: another producer's ``_keep_colors`` may add a kind meanwhile
        (iterating then raised "dictionary changed size during iteration")."""
        with self._pending_lock:
            return {kind: copy.copy(s) for kind, s in self._push_colors.items()}

    def _keep_colors(self, scalers: dict) -> None:
        """An accepted frame's range (``_trial_colors``) is the stream's where it decided one
        (or revised 8 to 16 bits) and no frame accepted meanwhile did (pending lock held)."""
        for kind, s in scalers.items():
            kept = self._push_colors.setdefault(kind, s)
            if kept.mode is None or (kept.mode, s.mode) == ("8", "16"):
                kept.mode = s.mode

    def _attribute_set(self, attrs: dict) -> None:
        """The first frame fixes the attributes; a later frame may leave some out (0 then) but
        not bring another (an InputError: it was dropped without a word), as the progressive octree's add()."""
        if self._attr_dtypes is None:
            self._attr_dtypes = {**BASE_ATTRIBUTES, **{a: attribute_dtype(v) for a, v in attrs.items()}}
        unknown = sorted(set(attrs) - set(self._attr_dtypes))
        if unknown:
            held = ", ".join(a for a in self._attr_dtypes if a not in BASE_ATTRIBUTES) or "none"
            raise InputError(f"{self.name}: push: attribute {unknown[0]!r} is not one of this cloud's ({held}): the first frame fixes them")
        for a, v in attrs.items():  # the ring holds the first frame's dtypes: 1000 in a uint8 was kept as 232
            dt = self._attr_dtypes[a]
            bad = _misfits(v, dt) if v.dtype != dt else None
            if bad is not None and bad.any():
                raise InputError(
                    f"{self.name}: push: attribute {a!r} holds values its {dt} (the first frame's) cannot hold exactly, e.g. {v[bad.argmax()].item()!r}"
                )

    def _insert(self, frame, info: FrameInfo) -> None:
        if isinstance(frame, SmallFrame):
            self._pack(frame, info)
        else:
            buf = self._room(len(frame.batches))
            buf.version += 1
            for rec in frame.batches:
                slot = heapq.heappop(self._free)
                f, c = int(rec["first"]), int(rec["count"])
                attrs = {a: (frame.attributes[a][f : f + c] if a in frame.attributes else 0) for a in buf.attributes}
                buf.write_chunk(slot, rec, frame.low[f : f + c], frame.med[f : f + c], frame.high[f : f + c], frame.color[f : f + c], attrs)
                info.chunks.append(slot)
                info.firsts.append(slot * self.chunk)
                info.counts.append(c)
            self._chunk_time[info.chunks] = info.arrived
        self.frames.append(info)
        self.points += info.n_points

    def _room(self, k: int) -> LiveBuffers:
        """The buffers, made or grown to have ``k`` free ring chunks (lock held)."""
        if self.buffers_ is None:
            self.buffers_ = LiveBuffers(self.name, max(_INITIAL_CHUNKS, 2 * k), self.chunk, 0, SNAPSHOT_CHUNK, self._attr_dtypes)
            self._free = list(range(self.buffers_.n_ring))
        buf = self.buffers_
        if len(self._free) < k:
            old = buf.n_ring
            buf = self.buffers_ = buf.grown(max(2 * old, old + k), buf.n_mirror)
            for s in range(old, buf.n_ring):
                heapq.heappush(self._free, s)
        self._chunk_time = self._sized(self._chunk_time, buf.n_ring)
        return buf

    @property
    def _pack_fill(self) -> int:
        """Points packed into a chunk at most: its size, up to PACK_FILL (each frame quantizes its
        chunk's points afresh: in a chunk of 2^20, frames of 50 points would cost quadratic time)."""
        return min(self.chunk, PACK_FILL)

    def _pack(self, frame: SmallFrame, info: FrameInfo) -> None:
        """A small frame goes after the frames before it in an open chunk, all of whose points
        are then quantized afresh in the box of them all (from their positions: no rounding of
        rounded words); a chunk per frame held 6 712 bytes a point of ring arrays for 2 000
        frames of 50 points (a sensor's packets), packed 105. A chunk's frames arrived in that
        order, and frames leave in arrival order, so its live points stay one run (``_expire``
        moves its first on). A frame joins the newest of up to PACK_OPEN open chunks that it
        fits, that lies near it (``_near``: a batch's box is what culling and adaptive precision
        see; two sensors' interleaved packets fill a chunk each), that no snapshot reads (its
        words must not move) and, with fading, whose first frame arrived at most a
        ``PACK_SPAN``-th of ``decay`` before (a chunk has one alpha); else it opens a new one."""
        m = len(frame.xyz)
        edge = float(np.max(info.hi - info.lo))
        self._seen = (info.lo, info.hi) if self._seen is None else (np.minimum(self._seen[0], info.lo), np.maximum(self._seen[1], info.hi))
        fill = self._pack_fill
        self._open = [o for o in self._open if self._pins[o.slot] == 0 and o.written < fill]  # (read by a snapshot, full: closed)
        fading = self.decay is not None and self.fade
        o = next((o for o in self._open if o.written + m <= fill and self._near(o, info, edge)
                  and not (fading and info.arrived - o.opened > self.decay / PACK_SPAN)), None)  # fmt: skip
        if o is None:
            buf = self._room(1)
            o = OpenChunk(heapq.heappop(self._free), np.empty((fill, 3)), 0, info.arrived, info.lo, info.hi, edge)
            self._open = [o, *self._open[: PACK_OPEN - 1]]
            buf.start_chunk(o.slot)
            self._chunk_time[o.slot] = info.arrived
        o.lo, o.hi, o.widest = np.minimum(o.lo, info.lo), np.maximum(o.hi, info.hi), max(o.widest, edge)
        buf = self.buffers_
        buf.version += 1
        o.xyz[o.written : o.written + m] = frame.xyz
        at = o.slot * self.chunk + o.written
        o.written += m
        buf.pack_into(o.slot, o.xyz[: o.written], m, frame.color, frame.attributes)
        info.chunks.append(o.slot)
        info.firsts.append(at)
        info.counts.append(m)

    @staticmethod
    def _sized(a: np.ndarray, n: int) -> np.ndarray:
        if len(a) >= n:
            return a
        out = np.full(n, np.nan, a.dtype)
        out[: len(a)] = a
        return out

    def _expire(self, keep: int | None = None) -> None:
        """Frames beyond ``keep`` (the cloud's by default) or ``decay`` seconds old leave the ring (lock held)."""
        keep = self.keep if keep is None else keep
        now = self.now()
        drop = []
        # (at ``decay`` seconds old a frame's fade is 0: drawn as nothing, it is not counted either)
        while len(self.frames) > keep or (self.decay is not None and self.frames and now - self.frames[0].arrived >= self.decay):
            drop.append(self.frames.popleft())
        if not drop:
            return
        buf = self.buffers_
        buf.version += 1
        for f in drop:
            for s, c in zip(f.chunks, f.counts):
                if buf.drop_first(s, c):  # the chunk's other points are newer frames' (packed): it stays
                    continue
                self._chunk_time[s] = np.nan
                self._open = [o for o in self._open if o.slot != s]
                if self._pins[s] > 0:  # a snapshot reads it: free when that is done (_unpin)
                    self._held.append(s)
                else:
                    heapq.heappush(self._free, s)
            self.points -= f.n_points

    def clear(self) -> None:
        """Drop every frame from the ring (snapshots stay); the next stream decides its own
        colour range (a 0..255 float stream after a 0..1 one was read as 0..1: all white). A
        recording records it: its replay clears there too (it kept the first range and frames)."""
        with self.lock.writing():
            self._expire(keep=0)  # (not self.keep = 0 meanwhile: a push then dropped every waiting frame)
            with self._pending_lock:
                self._push_colors = {}
        if self.recorder is not None:
            self.recorder.write_clear()
        self._notify()

    # ------------------------------------------------------------------ drawing (Renderable)
    def reading(self):
        """Held by the renderer from prepare until the frame is drawn: pushes wait (frames first)."""
        return self.lock.reading()

    def prepare(self, view: View, settings) -> DrawList:
        """Every ring chunk in view (``max_points``: every k-th point of each), then the snapshot
        octree's selection (its LOD within ``point_budget``), as one selection over the buffers."""
        refuse_hidden_classes(self.name, self.KIND, settings)  # (frames come and go: nothing to filter once)
        self._drop_decayed()
        self._sync_mirror()
        buf = self.buffers_
        if buf is None:
            empty = Selection(np.empty(0, np.int64), np.empty(0, np.int32), np.empty((0, 4, 4), np.float32), np.empty(0), 0)
            return DrawList(LiveBuffers(self.name, 1, self.chunk, 0, SNAPSHOT_CHUNK, BASE_ATTRIBUTES), empty, 0)
        buf.bounds = self._bounds()  # (the renderer holds the lock; decayed frames dropped above)
        used = np.flatnonzero(buf.batches["count"][: buf.n_ring] > 0)
        sel = select_view(buf.batches[used], view, settings)
        ids, bits, mats, size = used[sel.ids], sel.bits, sel.matrices, sel.projected_px
        step = subsample_step(buf.batches["count"][ids].astype(np.int64), settings.max_points) if len(ids) else 1
        culled = sel.n_culled
        n_batches = len(used)
        if self.snapshots is not None and self._mirror_pool is not None and self.snapshots.n_points:
            with self.snapshots.reading():
                od = self.snapshots.prepare(view, settings)
            ids = np.concatenate([ids, buf.n_ring + od.selection.ids])
            bits = np.concatenate([bits, od.selection.bits])
            mats = np.concatenate([mats, od.selection.matrices])
            size = np.concatenate([size, od.selection.projected_px])
            culled += od.selection.n_culled
            n_batches += od.n_batches
        if self.frames:  # what a frame of this version shows: the newest push it holds (latency, ``drawn``)
            self._version_pushed[buf.version] = self.frames[-1].pushed_at
            if len(self._version_pushed) > 256:
                for v in sorted(self._version_pushed)[:-128]:
                    del self._version_pushed[v]
        alpha = None
        if self.decay is not None and self.fade:  # per drawn batch: its frame's fade (render/passes/transparency.py composites it)
            t = np.full(len(ids), np.nan, np.float32)
            ring = ids < buf.n_ring
            t[ring] = self._chunk_time[ids[ring]]
            alpha = self.fade_alpha(t)
        sel = Selection(ids, bits.astype(np.int32), mats, size, culled)
        return DrawList(buf, sel, n_batches, step, alpha=alpha, spacing=self._kept_spacing(buf, step))

    def _drop_decayed(self) -> None:
        """Frames past their ``decay`` leave the ring now (the lock held, reading will do): no push
        or frame drawn may have come since they aged out."""
        if self.decay is not None and self.frames:
            self._expire()

    def _kept_spacing(self, buf: LiveBuffers, step: int) -> float:
        """The buffers' point spacing (what adaptive point sizes read), measured again only when a
        tenth of the kept frames are new since (or the buffers, ``step`` or the snapshots changed):
        the buffers change with every push, and measuring them (``point_spacing``: ~2 ms) in every
        frame of a stream cost what the spacing of a ring of similar frames hardly changes by."""
        key = (id(buf), step, self.snapshots.n_points if self.snapshots is not None else 0)
        kept = self._spacing
        if kept is None or kept[0] != key or self._seq - kept[1] >= max(1, len(self.frames) // 10):
            kept = self._spacing = (key, self._seq, point_spacing(buf, step))
        return kept[2]

    def prepare_views(self, views, settings):
        return None  # drawn one view at a time

    def drawn(self, frame) -> None:
        """Tell the cloud a frame drawn from it reached the screen (the viewer calls it): the
        push-to-pixels latency of the newest frame it showed, once per buffers version."""
        gen = frame.generation
        t = self._version_pushed.get(gen)
        if t is None or gen in self._counted_versions:
            return
        self._counted_versions.append(gen)
        self.stats.latencies.append(_time.perf_counter() - t)

    def hud(self) -> str:
        """One line for the viewer's HUD: frames in per second, live points, latency."""
        s = self.stats
        lat = s.latency_ms(50)
        p99 = s.latency_ms(99)
        latency = f", latency {lat:.0f} ms (p99 {p99:.0f})" if lat is not None else ""
        snap = f", {self.snapshots.n_points:,} snapshot points" if self.snapshots is not None else ""
        err = f"; last bad frame: {s.last_error}" if s.last_error else ""
        dropped = f", {s.frames_dropped} dropped unseen" if s.frames_dropped else ""
        with self._as_drawn_now():
            return f"live: {s.frames_per_second():.1f} frames/s in{dropped}, {len(self.frames)} frames, {self.points:,} live points{snap}{latency}{err}"[:400]

    # ------------------------------------------------------------------ snapshots
    def _sync_mirror(self) -> None:
        """Bring the mirror region up to the snapshot octree's pool (chunks written since last time)."""
        oct_ = self.snapshots
        if oct_ is None:
            return
        with oct_.reading():
            pool = oct_.pool
            if pool is None or (pool is self._mirror_pool and pool.version == self._mirror_version):
                return
            buf = self.buffers_
            if buf is None:
                self.buffers_ = buf = LiveBuffers(self.name, _INITIAL_CHUNKS, self.chunk, 0, pool.chunk, self._attr_dtypes or dict(BASE_ATTRIBUTES))
                self._free = list(range(buf.n_ring))
            if buf.mirror_chunk != pool.chunk:
                raise GigapointError(f"{self.name}: snapshot octree chunks of {pool.chunk} entries, mirror of {buf.mirror_chunk}")
            if pool.n_chunks > buf.n_mirror:
                buf = self.buffers_ = buf.grown(buf.n_ring, pool.n_chunks)
                changed = np.arange(pool.n_chunks)
            elif pool is not self._mirror_pool:
                changed = np.arange(pool.n_chunks)
            else:
                changed = np.flatnonzero(pool.batch_version > self._mirror_version)
            buf.version += 1
            buf.mirror_from(pool, changed.astype(np.int64))
            self._mirror_pool, self._mirror_version = pool, pool.version

    def frame_points(self, frames: list[FrameInfo] | None = None):
        """(xyz float64 world, rgba uint8 (N, 4), attributes) of the frames in the ring (30-bit
        positions), or of ``frames``, FrameInfo of ``cloud.frames`` still in it: a frame that has
        left the ring is a one-line InputError (its chunks hold newer frames' points: they were
        given as its own)."""
        with self._as_drawn_now(reading=True):
            frames = list(self.frames) if frames is None else self._frames_in_ring(frames)
            if not frames:
                return np.empty((0, 3)), np.empty((0, 4), np.uint8), {}
            return self.buffers_.gather(self._runs(frames), skip=("frame_time",))

    def _near(self, o: OpenChunk, info: FrameInfo, edge: float) -> bool:
        """Whether a frame may join open chunk ``o``: the box of them both is at most PACK_GROWTH
        times the largest of its frames' boxes, or a PACK_NEAR-th of the region frames have
        covered so far (frames of a point or two: a track of single points packs along it)."""
        joined = float(np.max(np.maximum(o.hi, info.hi) - np.minimum(o.lo, info.lo)))
        return joined <= max(PACK_GROWTH * max(o.widest, edge), float(np.max(self._seen[1] - self._seen[0])) / PACK_NEAR)

    def _runs(self, frames) -> Runs:
        """Where the points of ``frames`` (in the ring) are, in order (lock held)."""
        parts = [(s, f0, c) for f in frames for s, f0, c in zip(f.chunks, f.firsts, f.counts)]
        return self.buffers_.runs(*(list(p) for p in zip(*parts)))

    def _frames_in_ring(self, frames) -> list[FrameInfo]:
        where = f"{self.name}: frame_points"
        if isinstance(frames, FrameInfo) or not isinstance(frames, (list, tuple, deque)):
            raise InputError(f"{where}: frames must be a list of FrameInfo (of cloud.frames), got {type(frames).__name__}")
        held = {id(f) for f in self.frames}
        for f in frames:
            if not isinstance(f, FrameInfo):
                raise InputError(f"{where}: frames must be FrameInfo (of cloud.frames), got {f!r:.60}")
            if id(f) not in held:
                raise InputError(f"{where}: frame {f.seq} is not in the ring (it has left it, or is another cloud's): take frames from cloud.frames")
        return list(frames)

    def snapshot(self, normals: bool = True) -> int:
        """Freeze the frames now in the ring (world coordinates: their poses applied) into the
        accumulating snapshot octree, drawn with the live frames (``normals=False``: positions and
        colors only, ~1.5x faster). Returns the points added.

        Added in batches of SNAPSHOT_BATCH points (SimLOD's batch size): the octree inserts a
        million points with their attributes at twice the rate of seven million at once. Each
        batch is gathered from the ring when its turn comes, into the same arrays (the whole
        ring at once took 40 bytes a point of fresh memory: ~1 s of page faults for 18 M points
        on the Intel Xeon VM). Meanwhile the frames' chunks are pinned (a frame that leaves the
        ring frees them when the snapshot is done), rather than the lock held: frames are drawn
        and pushed as usual."""
        self.warnings.issue()  # (its player's thread's, in the user's: as save and close)
        self._check_open("snapshot")
        check_switch("normals", normals, f"{self.name}: snapshot")  # "no" kept the normals
        with self._as_drawn_now(reading=True):  # frames that faded out since the last push or drawn frame were frozen
            buf = self.buffers_
            slots = [s for f in self.frames for s in f.chunks]
            runs = self._runs(self.frames) if slots else None
            if runs is None or not runs.n_points:
                return 0
            self._pins.update(slots)
            self.snapshots_colored |= any(f.colored for f in self.frames)
        skip = ("frame_time",) if normals else ("frame_time", "normal")
        try:
            n = runs.n_points
            if self.snapshots is None:
                from ..lod.progressive import ProgressiveOctree

                lo, hi = buf.bounds_of(runs)
                if self.expected_bounds is not None:
                    lo, hi = np.minimum(lo, self.expected_bounds[0]), np.maximum(hi, self.expected_bounds[1])
                centre, edge = (lo + hi) / 2, float(np.max(hi - lo)) * 2 + 1e-6  # room to move: growing the root re-samples every point
                self.snapshots = ProgressiveOctree(name=f"{self.name} snapshots", cube=(centre - edge / 2, edge), capacity=n)
            if n > SNAPSHOT_BATCH:  # the tree shaped for all of them first: points go to their last leaf, not spilled on the way
                self.snapshots.expect(buf.sample(runs, SNAPSHOT_SAMPLE_STEP), SNAPSHOT_SAMPLE_STEP)
            added = 0
            out: dict = {}
            with self.snapshots.holding_work():  # one set of work arrays for all the batches
                for s in range(0, n, SNAPSHOT_BATCH):
                    xyz, rgba, attrs = buf.gather(runs, skip, s, min(s + SNAPSHOT_BATCH, n), out)
                    # the first snapshot's attributes (normals=False, then True: no normals)
                    added += self.snapshots.add(xyz, rgba, **self.snapshots.held_of(attrs))
        finally:
            with self.lock.writing():
                self._unpin(slots)
        self._notify()
        return added

    def _unpin(self, slots: list[int]) -> None:
        """A snapshot read chunks ``slots``: those of frames gone meanwhile are free now (lock held)."""
        self._pins.subtract(slots)
        held, self._held = self._held, []
        for s in held:
            if self._pins[s] > 0:
                self._held.append(s)
            else:
                heapq.heappush(self._free, s)
        self._pins = +self._pins  # drop the zero counts

    def save(self, path, overwrite: bool = False) -> int:
        """Write the accumulated snapshots: ``.las``/``.laz``/``.ply`` (points with normals),
        ``.copc.laz`` (the snapshot octree as COPC), else (a name without a point file's suffix) a
        gigapoint octree folder; each with colors unless no frame snapshotted had any. Returns the points written."""
        from .save import save_snapshots

        self.warnings.issue()
        self._check_open("save")
        check_switch("overwrite", overwrite, f"{self.name}: save")
        if self.snapshots is None or self.snapshots.n_points == 0:
            raise InputError(f"{self.name}: nothing to save: no snapshot taken yet (call snapshot())")
        return save_snapshots(self.snapshots, path, overwrite, has_color=self.snapshots_colored)

    # ------------------------------------------------------------------ recording
    def record(self, directory, overwrite: bool = False):
        """Record every frame pushed from now on into ``directory`` (an npz per frame with its pose
        and time, and index.json); returns the Recorder (``stop()`` or ``live.stop_recording()``)."""
        from .record import Recorder

        self._check_open("record")  # (a closed cloud's recording folder was made, never to get a frame)
        check_switch("overwrite", overwrite, f"{self.name}: record")
        if self.recorder is not None:
            raise InputError(f"{self.name}: already recording into {self.recorder.directory}")
        self._check_not_replaying(directory)
        self.recorder = Recorder(directory, overwrite=overwrite)
        return self.recorder

    def _check_not_replaying(self, directory) -> None:
        """Refuse to record into the recording its player replays: overwrite=True deleted its
        frames before they were read (nothing played, 0 frames recorded: the recording was lost)."""
        from .sources import ReplaySource

        source = self.player.source if self.player is not None else None
        if isinstance(source, ReplaySource) and isinstance(directory, (str, os.PathLike)) and Path(directory).resolve() == source.path.resolve():
            raise InputError(f"{directory}: the recording being replayed (recording into it would delete its frames); record into another folder")

    def stop_recording(self) -> None:
        rec, self.recorder = self.recorder, None
        if rec is not None:
            rec.stop()

    def close(self) -> None:
        """Stop its source and recording and free its frames and snapshots (it draws nothing
        afterwards); a later push, snapshot or save is a one-line InputError."""
        if self.player is not None:
            self.player.stop()
        self.stop_recording()
        self.closed = True
        self.clear()
        if self.snapshots is not None:
            self.snapshots.close()
        self.warnings.issue()

    def _check_open(self, what: str) -> None:
        if self.closed:
            raise InputError(f"{self.name}: {what}: the live cloud is closed")
