"""Viewer sessions: one per browser tab, each with its camera, settings and render worker thread.

The worker renders only the latest state: input updates a version counter and wakes it; a
request that arrives while a frame renders replaces the previous one (never queued). While
the camera moves the worker renders at a reduced resolution chosen so a frame (render +
JPEG) fits the frame-time budget; once the camera has rested for REST_S it renders once
more at full resolution. All renders go through one process-wide lock: the CPU backend
keeps scratch buffers per backend instance and uses every core already, so concurrent
renders would only fight (and share those buffers).
"""

from __future__ import annotations

import logging
import os
import secrets
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ..core.layout import EMPTY_PIXEL
from ..errors import GigapointError, warn, warnings_kept
from ..lod.reader import cloud_units
from ..render.camera import sample_points
from ..render.frame import Frame, encode_image
from ..render.renderer import render_frame
from ..render.settings import RenderSettings
from ..survey.volume import volume
from . import classes as C
from . import measure as M
from . import protocol as P
from . import section_tool as ST
from . import volume_tool as VT
from .state import OrbitState

log = logging.getLogger("gigapoint.viewer")

RENDER_LOCK = threading.Lock()
REST_S = 0.15  # no camera input for this long = at rest: refine to full resolution
FRAME_BUDGET_S = 0.045  # render + encode while moving (>= 20 frames/s with the transfer)
SCALES = (1, 2, 4, 8)  # resolution divisors while moving
MOVING_RENDER_S = 0.015  # a moving frame draws what the measured point rate renders in this time
MIN_MOVING_POINTS = 1_000_000
SEND_TIMEOUT_S = 0.25
MAX_SESSIONS = 64


def memory_rss() -> int:
    """Resident memory of this process in bytes (0 if unknown)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        try:
            import resource

            return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        except Exception:  # noqa: BLE001
            return 0


def cloud_bytes(cloud) -> int:
    """Bytes the cloud's point arrays hold (``PointCloud.memory``; 0 for kinds without a breakdown)."""
    from ..core import PointCloud

    return cloud.nbytes if isinstance(cloud, PointCloud) else 0


def view_frame(cloud, camera, settings) -> Frame:
    """render_frame for a viewer: "no point is in view" is normal while flying around, not said."""
    with warnings_kept() as said:
        frame = render_frame(cloud, camera, settings)
    for message, category in said:
        if "no point is in view" not in message:
            warn(message, category)
    return frame


def over_pixel_limit(width: int, height: int, supersample: int) -> bool:
    """Whether a ``width`` x ``height`` frame rendered at ``supersample`` times each side is over the screenshots' pixel limit."""
    return width * height * supersample * supersample > P.MAX_SHOT_PIXELS


def within_frame_pixels(settings: RenderSettings, width: int, height: int) -> tuple[RenderSettings, str]:
    """``settings`` at the highest supersample (halved from its own: 4, 2, 1) that renders a
    ``width`` x ``height`` frame within the screenshots' pixel limit, and a HUD line where it was
    lowered: a 4096x4096 tab at 4 rendered 268 M pixels a frame."""
    ss = settings.supersample
    while ss > 1 and over_pixel_limit(width, height, ss):
        ss //= 2
    if ss == settings.supersample:
        return settings, ""
    said = f"anti-aliasing {settings.supersample} lowered to {ss} at {width}x{height} (at most {P.MAX_SHOT_PIXELS:,} pixels rendered a frame)"
    return settings.replace(supersample=ss), said


def render_locked(cloud, camera, settings, cancelled=None):
    """view_frame under the process-wide lock; None if ``cancelled()`` turned true while waiting for it."""
    with RENDER_LOCK:
        if cancelled is not None and cancelled():
            return None
        return view_frame(cloud, camera, settings)


def depth_position(camera, px: float, py: float, depth: float) -> np.ndarray:
    """World point at pixel centre (px, py) and view depth ``depth`` (float32 precision of the depth)."""
    origin, d = camera.ray(px + 0.5, py + 0.5)
    _, _, back = camera.basis()
    return origin + d * (depth / float(np.dot(d, -back)))


def point_info(last: LastFrame, index: int, px: int, py: int, depth: float) -> dict:
    """What is known about the point drawn at (px, py) of the last frame, for any kind of cloud.

    The frame's point buffers answer (a PointCloud exactly: float64 position, color,
    attributes; an octree's arena its 30-bit position, color and level) while they still
    hold what the frame drew (Frame.point_info); after a later frame rewrote them, the
    position comes from the depth buffer.
    """
    if RENDER_LOCK.acquire(timeout=0.2):  # called from the event loop: never wait out a long screenshot
        try:
            info = last.frame.point_info(index)
        finally:
            RENDER_LOCK.release()
        if info is not None:
            return info
    return {"position": depth_position(last.camera, px, py, depth).tolist(), "source": "depth buffer"}


@dataclass
class LastFrame:
    camera: object
    frame: Frame  # the last frame sent: its visibility buffer (depth bits << 32 | index) and point buffers
    cloud: object  # what it was drawn from (the core's cloud can be swapped since: viewer/watch.py)

    @property
    def visibility(self) -> np.ndarray:
        return self.frame.visibility

    def window(self, y0, y1, x0, x1):
        """(index, depth) of a window: int64 (-1 where empty) and float32 (inf where empty)."""
        v = self.visibility[y0:y1, x0:x1]
        empty = v == EMPTY_PIXEL
        index = (v & np.uint64(0xFFFFFFFF)).astype(np.int64)
        index[empty] = -1
        depth = (v >> np.uint64(32)).astype(np.uint32).view(np.float32)
        depth[empty] = np.inf
        return index, depth


@dataclass
class ScaleControl:
    """Picks the resolution divisor while moving from measured frame times."""

    level: int = 1  # index into SCALES
    times: dict = field(default_factory=dict)  # level -> smoothed seconds

    def scale(self) -> int:
        return SCALES[self.level]

    def record(self, level: int, seconds: float) -> None:
        old = self.times.get(level)
        self.times[level] = seconds if old is None else 0.6 * old + 0.4 * seconds
        t = self.times[level]
        if level != self.level:
            return
        if t > FRAME_BUDGET_S and self.level < len(SCALES) - 1:
            self.level += 1
        elif self.level > 0:
            # the finer level's old time drifts toward this level's time x 2 (4x the pixels, but the
            # point cost, most of a frame, is capped by MovingBudget), so it is retried once the
            # load that made it slow has gone
            guess = t * 2.0
            finer = self.times.get(self.level - 1, guess)
            finer = self.times[self.level - 1] = 0.85 * finer + 0.15 * guess
            if finer < FRAME_BUDGET_S * 0.8:
                self.level -= 1


@dataclass
class MovingBudget:
    """The point cap while moving, from the measured draw rate (points/s) of recent frames.

    Resolution scaling alone cannot keep a 100 M point plain cloud interactive: its cost is
    per point. Applied as max_points (plain clouds: every k-th point of each batch) and as a
    lower point_budget (octrees)."""

    rate: float | None = None  # smoothed points per second

    def points(self) -> int:
        return 0 if self.rate is None else max(MIN_MOVING_POINTS, int(self.rate * MOVING_RENDER_S))

    def record(self, points: int, seconds: float) -> None:
        if points <= 0 or seconds <= 0:
            return
        rate = points / seconds
        self.rate = rate if self.rate is None else 0.6 * self.rate + 0.4 * rate

    def settings_for(self, settings: RenderSettings) -> RenderSettings:
        cap = self.points()
        if cap == 0:
            return settings
        return settings.replace(max_points=cap, point_budget=min(settings.point_budget, cap))


class ViewerCore:
    """What all tabs share: the cloud, the session registry, screenshots."""

    def __init__(self, cloud, settings: RenderSettings | None = None, max_sessions: int = MAX_SESSIONS):
        self.cloud = cloud
        self.settings = RenderSettings.of(settings)
        self.sessions: dict[str, Session] = {}
        self.max_sessions = max_sessions
        self.lock = threading.Lock()
        self.last_active: Session | None = None
        self._take_bounds()
        self.framing = sample_points(cloud)  # what the 'auto' view frames: the data, not its box
        self.units = cloud_units(cloud)  # its CRS's: what measured lengths are in (read once: a file's header)
        self.section_width = ST.default_width(self.bounds)  # the section tool's first width
        self.watcher = None
        self.note = ""  # a line for the HUD (what a conversion preview shows)
        self.push_token: str | None = None  # a live cloud's: the key of the /push WebSocket
        self.live = None  # the LiveCloud shown, if it is one
        from ..live import LiveCloud
        from ..lod.preview import ConversionPreview
        from ..lod.progressive import ProgressiveOctree

        if isinstance(cloud, ConversionPreview):  # an unfinished conversion: follow it to its octree
            from .watch import ConversionWatcher

            self.watcher = ConversionWatcher(self, cloud.octree_dir).start()
        elif isinstance(cloud, ProgressiveOctree) and cloud.loader is not None:  # filling: redraw as it grows
            from .watch import LoadWatcher

            self.watcher = LoadWatcher(self, cloud).start()
        elif isinstance(cloud, LiveCloud):  # frames stream in: redraw on each, the HUD's line on rates and latency
            from .watch import LiveWatcher

            self.live = cloud
            self.push_token = secrets.token_urlsafe(18)  # another process pushes frames only with it (server.py /push)
            self.watcher = LiveWatcher(self, cloud).start()

    def replace_cloud(self, cloud) -> None:
        """Draw ``cloud`` from now on (a newer preview, or the finished octree); every tab redraws, views stay."""
        self.framing = sample_points(cloud)  # before it is drawn: no frame reads its buffers yet
        self.units = cloud_units(cloud)
        self.cloud = cloud
        self.redraw()

    def _take_bounds(self) -> None:
        lo, hi = self.cloud.bounds
        self.bounds = (np.asarray(lo, np.float64), np.asarray(hi, np.float64))

    def redraw(self, reframe: bool = False) -> None:
        """Every tab draws again (the cloud changed: swapped, or grown while it loads); views stay.
        ``reframe``: a loading cloud grew (its first points may be a strip of the survey, or none):
        sample again what the 'auto' view frames, and fit to it the tabs opened before the first
        point and not moved since: they looked at nothing, then at the first points only (a strip
        of the survey, where the file is in scan order). The bounds are read, and each tab told, once."""
        reframe = reframe and self.cloud.n_points > 0  # (nothing to frame yet; once points are counted, the bounds hold them)
        self._take_bounds()
        if reframe:
            with RENDER_LOCK:  # sample_points prepares the cloud as a frame does (the octree's pool): not beside one
                self.framing = sample_points(self.cloud)
        for s in list(self.sessions.values()):
            with s.cond:
                if reframe and s.follows_auto:
                    s.state = self.default_state(s.width, s.height, fov=s.state.fov)
                s._draw_again()

    def cloud_info(self) -> dict:
        lo, hi = self.bounds
        return {
            "name": self.cloud.name,
            "points": int(self.cloud.n_points),
            "batches": len(self.cloud.batches),
            "bounds": [lo.tolist(), hi.tolist()],
            # (an octree read node by node, Potree, COPC, EPT, has none in ``attributes`` before its nodes are read)
            "attributes": sorted(self.cloud.attribute_names),
            "load_progress": float(self.cloud.load_progress),
            "units": self.units,
        }

    def class_panel(self, hidden=()) -> dict:
        """The Classes panel's list for the cloud drawn now (classes.py); an octree's resident
        nodes join it when the render lock is free at once (a frame may be loading them)."""
        seen = RENDER_LOCK.acquire(timeout=0.2)  # called from the event loop: never wait out a long screenshot
        try:
            return C.class_panel(self.cloud, hidden, seen)
        finally:
            if seen:
                RENDER_LOCK.release()

    def open_session(self, send, width: int = 1280, height: int = 720) -> Session:
        with self.lock:
            if len(self.sessions) >= self.max_sessions:
                raise P.ProtocolError(f"too many open viewer tabs (limit {self.max_sessions})")
            s = Session(self, send, width, height)
            self.sessions[s.id] = s
            self.last_active = s
        s.start()
        return s

    def close_session(self, s: Session) -> None:
        s.close()
        with self.lock:
            self.sessions.pop(s.id, None)
            if self.last_active is s:
                self.last_active = next(iter(self.sessions.values()), None)

    def close_all(self) -> None:
        if self.watcher is not None:
            self.watcher.stop()
        for s in list(self.sessions.values()):
            self.close_session(s)

    def default_state(self, width: int, height: int, view="auto", fov=60.0) -> OrbitState:
        return OrbitState.fit(self.bounds, view=view, width=width, height=height, fov=fov, points=self.framing if view == "auto" else None)

    def screenshot(self, session_id: str | None = None, width=None, height=None, scale: int = 1) -> bytes:
        """PNG of a tab's view (or the default view) at its size x ``scale`` or at width x height."""
        s = self.sessions.get(session_id) if session_id else None
        if session_id and s is None:
            raise P.ProtocolError("screenshot: unknown session")
        if s is not None:
            state, settings, (vw, vh) = s.snapshot()
        else:
            vw, vh = 1280, 720
            state, settings = self.default_state(vw, vh), self.settings
        lines = s.lines() if s is not None else ([], [])  # a tab's measurement and section line are in its screenshot too
        if width is not None and height is None:  # one side given: keep the view's aspect
            height = max(1, round(int(width) * vh / vw))
        elif height is not None and width is None:
            width = max(1, round(int(height) * vw / vh))
        w = int(width) if width is not None else vw * scale
        h = int(height) if height is not None else vh * scale
        if not (1 <= w <= P.MAX_SHOT_SIDE and 1 <= h <= P.MAX_SHOT_SIDE) or over_pixel_limit(w, h, 1):
            raise P.ProtocolError(f"screenshot: {w}x{h} is outside 1..{P.MAX_SHOT_SIDE} per side / {P.MAX_SHOT_PIXELS:,} pixels")
        ss = settings.supersample  # rendered at ss times each side: 4096x4096 at 4 was 268 M pixels, ~5.6 GB and a minute
        if over_pixel_limit(w, h, ss):
            raise P.ProtocolError(
                f"screenshot: {w}x{h} at supersample {ss} renders {w * ss}x{h * ss}, over {P.MAX_SHOT_PIXELS:,} pixels: ask a smaller size or lower the anti-aliasing"
            )
        cam = state.camera(w, h)
        frame = render_locked(self.cloud, cam, settings)
        return encode_image(overlaid(frame.image, cam, lines), "PNG")

    def section_csv(self, session_id: str) -> bytes:
        """The CSV of the last section a tab was sent (``Section.write_csv``'s rows)."""
        s = self.sessions.get(session_id)
        cut = None if s is None else s.section_cut
        if cut is None:
            raise P.ProtocolError("section: no section drawn in this tab yet")
        return ST.csv_bytes(cut)


def overlaid(image, camera, lines) -> np.ndarray:
    """``image`` with a tab's measurement (``lines[0]``) and section line (``lines[1]``) drawn over it."""
    measure, section = lines
    return M.draw(M.draw(image, camera, measure), camera, section, ST.COLOR)


class Session:
    """One tab: orbit state, settings, viewport, and the worker thread that renders them."""

    def __init__(self, core: ViewerCore, send, width: int, height: int):
        self.id = secrets.token_hex(8)
        self.core = core
        self.send = send  # send(kind, payload) -> bool, blocking; False once the tab is gone
        self.cond = threading.Condition()
        self.width, self.height = width, height
        self.state = core.default_state(width, height)
        # opened before the first point (fit to an empty box: the origin, at 5e-08, zoom held under 0.01):
        # it follows the 'auto' view as the points come (ViewerCore.redraw), until moved
        self.follows_auto = core.cloud.n_points == 0
        self.settings = core.settings
        self.good_settings = self.settings
        self.cloud_shown = core.cloud_info()  # the panel's cloud line, as hello sent it; a frame carries it again once it changes
        self.version = 0  # bumped by every change
        self.seq = 0  # the client's latest input sequence number
        self.last_motion = 0.0
        self.adaptive = True
        self.jpeg_quality = 85
        self.closed = False
        self.last: LastFrame | None = None
        self.measure: list[list[float]] = []  # the measuring tool's points (world), drawn over each frame
        self.measure_closed = False  # closed into a polygon (3 points or more): its area, and its volume on request
        self.volume_job = 0  # bumped by every change of the measurement: a volume computed for an older one is not sent
        self.volume_lock = threading.Lock()  # one volume computed at a time per tab
        self.section: list[list[float]] = []  # the section tool's line: 0 to 2 picked points (world), drawn too
        self.section_width = core.section_width
        self.section_size = [600, 240]  # pixels of the panel's image
        self.section_job = 0  # bumped by every change of the line: a section computed for an older one is not sent
        self.section_cut = None  # the last section sent (its CSV)
        self.section_lock = threading.Lock()  # one section computed at a time per tab
        self.scales = ScaleControl()
        self.budget = MovingBudget()
        self.frames = 0
        self._done_version = -1
        self._done_full = True
        self.thread = threading.Thread(target=self._run, name=f"gigapoint-viewer-{self.id}", daemon=True)

    # --- called from the event loop ------------------------------------------------------
    def start(self) -> None:
        self.thread.start()

    def close(self) -> None:
        with self.cond:
            self.closed = True
            self.cond.notify_all()

    def snapshot(self):
        with self.cond:
            return OrbitState(**{**self.state.__dict__, "target": self.state.target.copy()}), self.settings, (self.width, self.height)

    def _changed(self, motion: bool) -> None:
        """The user changed this tab: it draws again, and is the one Viewer.screenshot shows."""
        if motion:
            self.last_motion = time.monotonic()
        self.core.last_active = self
        self._draw_again()

    def _draw_again(self) -> None:
        """Draw the latest state (under ``cond``); not the user's doing: the active tab stays."""
        self.version += 1
        self.cond.notify_all()

    def handle(self, msg: dict) -> dict | None:
        """Apply one validated client message; returns a JSON reply or None. Raises ProtocolError."""
        kind = msg["type"]
        seq = msg.get("seq")
        if seq is not None:
            seq = P.integer(msg, "seq", 0, 2**53)
        reply = None
        with self.cond:
            motion = True
            st = self.state
            if kind == "resize":
                self.width = P.integer(msg, "width", 1, P.MAX_VIEW_SIDE)
                self.height = P.integer(msg, "height", 1, P.MAX_VIEW_SIDE)
                motion = False
            elif kind in ("orbit", "look"):
                dyaw, dpitch = P.number(msg, "dyaw", -3600, 3600, 0.0), P.number(msg, "dpitch", -3600, 3600, 0.0)
                (st.orbit if kind == "orbit" else st.look)(dyaw, dpitch)
            elif kind == "pan":
                st.pan(P.number(msg, "dx", -1e4, 1e4, 0.0), P.number(msg, "dy", -1e4, 1e4, 0.0))
            elif kind == "zoom":
                factor = P.number(msg, "factor", 1e-3, 1e3)
                anchor = None
                if "x" in msg or "y" in msg:
                    anchor = self._world_at(P.number(msg, "x", 0, 1), P.number(msg, "y", 0, 1))
                st.zoom(factor, anchor)
            elif kind == "move":
                lim = st.scene_radius * 100
                st.move(P.number(msg, "forward", -lim, lim, 0.0), P.number(msg, "right", -lim, lim, 0.0), P.number(msg, "up", -lim, lim, 0.0))
            elif kind == "camera":
                st.set(
                    target=P.vec3(msg, "target") if "target" in msg else None,
                    yaw=P.number(msg, "yaw", -1e6, 1e6) if "yaw" in msg else None,
                    pitch=P.number(msg, "pitch", -90, 90) if "pitch" in msg else None,
                    distance=P.number(msg, "distance", 1e-9, P.MAX_ABS_COORD) if "distance" in msg else None,
                    fov=P.number(msg, "fov", 1, 150) if "fov" in msg else None,
                )
            elif kind in ("view", "reset"):
                name = msg.get("name", "auto") if kind == "view" else "auto"
                if name not in P.VIEW_NAMES:
                    raise P.ProtocolError(f"view: unknown view {str(name)[:20]!r}; choose one of {', '.join(P.VIEW_NAMES)}")
                fov = 60.0 if kind == "reset" else st.fov
                self.state = self.core.default_state(self.width, self.height, view=name, fov=fov)
            elif kind == "fov":
                st.set(fov=P.number(msg, "value", 1, 150))
            elif kind == "pick":
                x, y = P.number(msg, "x", 0, 1), P.number(msg, "y", 0, 1)
                pivot = P.flag(msg, "pivot")
                reply = self._pick(x, y, pivot, msg.get("id"))
                motion = pivot
                if not pivot:
                    return reply
            elif kind == "section":
                reply = self._section(msg)
                motion = False
            elif kind == "measure":
                reply = self._measure(msg)
                if reply is None:
                    return {"type": "measure", "id": msg.get("id"), "added": False, "message": "no point here: nothing added", **self._measured()}
                motion = False
            elif kind == "volume":
                return self._volume(msg)  # (nothing drawn changes)
            elif kind == "settings":
                settings = P.apply_settings(self.settings, msg.get("values"))
                refused = C.refusal(self.core.cloud) if settings.hidden_classes else ""
                if refused:  # (not a frame that fails: the panel is disabled for it)
                    raise P.ProtocolError(f"settings: {refused}")
                hidden_changed = settings.hidden_classes != self.settings.hidden_classes
                self.settings = settings
                motion = False
                reply = {"type": "settings", "values": P.settings_values(self.settings)}
                if hidden_changed:  # the section (where a line is drawn) shows what the view shows: drawn again without them
                    self._start_section()
            elif kind == "classes":
                return {"type": "classes", **self.core.class_panel(self.settings.hidden_classes)}
            elif kind == "quality":
                self.adaptive = P.flag(msg, "adaptive", self.adaptive)
                self.jpeg_quality = P.integer(msg, "jpeg_quality", 10, 100, self.jpeg_quality)
                motion = False
            elif kind == "ping":
                return {"type": "pong", "t": P.number(msg, "t", -1e15, 1e15, 0.0)}
            elif kind == "refresh":
                motion = False
            if seq is not None:
                self.seq = seq
            self.follows_auto = self.follows_auto and not motion  # (moved: the view the user chose stays)
            self._changed(motion)
        return reply

    # --- picking -------------------------------------------------------------------------
    def _hit(self, x: float, y: float, radius: int = 4):
        """(index, depth, camera, px, py) of the visible point nearest to (x, y) in the last frame, or None."""
        last = self.last
        if last is None:
            return None
        h, w = last.visibility.shape
        px, py = min(int(x * w), w - 1), min(int(y * h), h - 1)
        y0, y1, x0, x1 = max(py - radius, 0), min(py + radius + 1, h), max(px - radius, 0), min(px + radius + 1, w)
        win, depth = last.window(y0, y1, x0, x1)
        ys, xs = np.nonzero(win >= 0)
        if len(ys) == 0:
            return None
        d2 = (ys + y0 - py) ** 2 + (xs + x0 - px) ** 2
        k = int(np.lexsort((depth[ys, xs], d2))[0])
        return int(win[ys[k], xs[k]]), float(depth[ys[k], xs[k]]), last.camera, xs[k] + x0, ys[k] + y0

    def _world_at(self, x: float, y: float):
        """World point under the cursor: the visible point there (from the depth buffer), else the target plane."""
        hit = self._hit(x, y)
        if hit is not None:
            _, depth, cam, px, py = hit
            return depth_position(cam, px, py, depth)
        if self.last is None:
            return None
        cam = self.last.camera
        origin, d = cam.ray(x * cam.width, y * cam.height)
        _, _, back = cam.basis()
        denom = float(np.dot(d, -back))
        if denom <= 1e-9:
            return None
        dist = float(np.dot(np.asarray(cam.target) - origin, -back)) / denom
        return origin + d * dist

    def _pick(self, x, y, pivot, pick_id) -> dict:
        hit = self._hit(x, y)
        if hit is None:
            return {"type": "pick", "id": pick_id, "found": False}
        index, depth, _, px, py = hit
        info = point_info(self.last, index, px, py, depth)
        if pivot:
            self.state.set_pivot(info["position"])
        return {"type": "pick", "id": pick_id, "found": True, "pivot": pivot, "info": P.json_safe(info)}

    def _picked(self, msg) -> list[float] | None:
        """The world point of the visible point nearest to a message's (x, y) in the last frame
        (as ``pick`` finds it), or None: a click on nothing. The measuring and section tools' picks."""
        hit = self._hit(P.number(msg, "x", 0, 1), P.number(msg, "y", 0, 1))
        if hit is None:
            return None
        index, depth, _, px, py = hit
        return [float(v) for v in point_info(self.last, index, px, py, depth)["position"]]

    def lines(self) -> tuple[list, list]:
        """(measurement points, section line points) as frames draw them (a closed measurement back to its first point)."""
        return M.drawn(self.measure, self.measure_closed), list(self.section)

    # --- the section tool ----------------------------------------------------------------
    def _section(self, msg) -> dict:
        """Apply a section message (add a picked point, set points/width/size, clear); with two
        points the section is computed on a thread of its own and sent as "section_result"."""
        action, message = msg.get("action"), None
        if action == "add":
            picked = self._picked(msg)
            if picked is None:
                message = "no point here: nothing added"
            else:  # a third click starts a new line
                self.section = [*self.section[-1:], picked] if len(self.section) == 1 else [picked]
        elif action == "set":
            values = ST.parse(msg)
            self.section = values.get("points", self.section)
            self.section_width = values.get("width", self.section_width)
            self.section_size = values.get("size", self.section_size)
        elif action == "clear":
            self.section = []
        else:
            raise P.ProtocolError(f"section: action must be add, set or clear, got {str(action)[:20]!r}")
        computing = self._start_section()
        reply = {"type": "section", "id": msg.get("id"), "points": self.section, "width": self.section_width, "computing": computing}
        return reply if message is None else {**reply, "message": message}

    def _start_section(self) -> bool:
        """Compute the section of the line (when it has two points) on a thread of its own, without
        the classes the view hides (as the volume leaves them out); whether it was started."""
        self.section_job += 1  # what is on its way for the old line is not sent
        if len(self.section) != 2:
            return False
        job = (self.section_job, [p[:2] for p in self.section], self.section_width, tuple(self.section_size), self.settings.hidden_classes)
        threading.Thread(target=self._compute_section, args=job, name=f"gigapoint-section-{self.id}", daemon=True).start()
        return True

    def _compute_section(self, job: int, ends, width: float, size, hidden_classes) -> None:
        """The section of the viewer's cloud along ``ends`` but the points of ``hidden_classes``,
        sent to the tab (off the render loop: only its image is drawn under the render lock, and
        the corridor's points are few)."""
        with self.section_lock:
            if job != self.section_job or self.closed:
                return  # the line changed again while an older one was computed
            line = (*ends[0], *ends[1])
            cut = None
            try:
                cut, note = ST.capped(ST.section_of(self.core.cloud, line, width, hidden_classes), ST.MAX_POINTS)
                result = ST.summary(cut, self.core.units, note)
                with RENDER_LOCK:
                    image = cut.render(size=size)
                result["image"] = ST.image_url(image)
            except GigapointError as exc:  # an octree without source files, an empty corridor: said in the panel
                result, cut = {"error": str(exc)[:500]}, None
            except Exception as exc:  # a bug: this section fails (logged), the tab goes on
                log.exception("viewer: a section failed")
                result, cut = {"error": f"internal error: {exc}"[:300]}, None
            with self.cond:
                if job != self.section_job:
                    return
                self.section_cut = cut
        self.send("json", {"type": "section_result", "id": job, **result})

    def _measured(self) -> dict:
        """The measurement's reply fields: its points, lengths, and closed: its area (measure.summary)."""
        return M.summary(self.measure, self.core.units, self.measure_closed)

    def _measure(self, msg) -> dict | None:
        """Apply a measure message (add a picked point, restore points, undo the last, clear, close
        into a polygon, open it again); None: a click on nothing."""
        action = msg.get("action")
        if action == "restore":  # a reconnected page's measurement (world points): the new session had none
            points = msg.get("points")
            if not isinstance(points, list) or len(self.measure) + len(points) > M.MAX_POINTS:
                raise P.ProtocolError(f"measure: points must be a list of at most {M.MAX_POINTS} points in all")
            closed = P.flag(msg, "closed", self.measure_closed)  # (sent with the last batch of a closed one)
            self.measure = self.measure + [P.vec3({"type": "measure", "point": p}, "point") for p in points]
            self.measure_closed = closed
        elif action == "add":
            if len(self.measure) >= M.MAX_POINTS:
                raise P.ProtocolError(f"measure: at most {M.MAX_POINTS} points; clear the measurement first")
            picked = self._picked(msg)
            if picked is None:
                return None
            self.measure.append(picked)
        elif action == "undo":
            self.measure = self.measure[:-1]
        elif action == "clear":
            self.measure = []
        elif action == "close":
            if len(self.measure) < 3:
                raise P.ProtocolError(f"measure: a polygon needs 3 points or more; {len(self.measure)} measured")
            self.measure_closed = True
        elif action == "open":
            self.measure_closed = False
        else:
            raise P.ProtocolError(f"measure: action must be add, restore, undo, clear, close or open, got {str(action)[:20]!r}")
        self.measure_closed = self.measure_closed and len(self.measure) >= 3  # (undone below 3 points: a polyline again)
        self.volume_job += 1  # what is on its way for the old polygon is not sent
        return {"type": "measure", "id": msg.get("id"), "added": action == "add", **self._measured()}

    # --- the stockpile volume inside the closed measurement ------------------------------
    def _volume(self, msg) -> dict:
        """Start the volume inside the closed measurement (``base``, ``gsd``: volume_tool.parse; the
        gsd offered first: volume_tool.default_gsd) on a thread of its own, sent as "volume_result"."""
        values = VT.parse(msg)
        if not self.measure_closed:
            raise P.ProtocolError("volume: close the measurement into a polygon first (3 points or more, C)")
        crossing = self._measured()["crossing"]
        if crossing:  # (the panel shows it in place of the area, its volume button off)
            raise P.ProtocolError(f"volume: {crossing}")
        points = [list(p) for p in self.measure]
        if "gsd" in values:
            gsd, note = values["gsd"], f"a grid of {values['gsd']:g}"
        else:
            gsd, note = VT.default_gsd(points, VT.point_spacing(self.core.bounds, self.core.cloud.n_points))
        VT.check_gsd(points, gsd)
        self.volume_job += 1
        job = (self.volume_job, points, gsd, values.get("base", "plane"), note, self.settings.hidden_classes)
        threading.Thread(target=self._compute_volume, args=job, name=f"gigapoint-volume-{self.id}", daemon=True).start()
        return {"type": "volume", "id": msg.get("id"), "job": self.volume_job, "computing": True, "gsd": gsd, "base": job[3]}

    def _compute_volume(self, job: int, points, gsd: float, base, note: str, hidden_classes) -> None:
        """``gp.volume`` inside ``points`` sent to the tab (off the render loop: the box's points
        read first, only the surface model drawn under the render lock)."""
        with self.volume_lock:
            if job != self.volume_job or self.closed:
                return  # the measurement changed again while an older one was computed
            try:
                # its warnings (a toe beyond the data) are the panel's to show: issued here, on this
                # thread, they went to the server's terminal, once per request
                with warnings_kept() as said:
                    cloud, seen, step = VT.points_in_box(self.core.cloud, points, gsd, hidden_classes, VT.MAX_POINTS)
                    gsd, note, thinned = VT.thinned_grid(points, cloud, seen, step, gsd, note)
                    with RENDER_LOCK:
                        measured = volume(cloud, VT.toe(points), gsd, base)
                result = VT.summary(measured, self.core.units, note, thinned, [message for message, _ in said])
            except GigapointError as exc:  # no point inside, an octree without source files: said in the panel
                result = {"error": str(exc)[:500]}
            except Exception as exc:  # a bug: this volume fails (logged), the tab goes on
                log.exception("viewer: a volume failed")
                result = {"error": f"internal error: {exc}"[:300]}
            with self.cond:
                if job != self.volume_job:
                    return
        self.send("json", P.json_safe({"type": "volume_result", "id": job, **result}))

    # --- the worker ----------------------------------------------------------------------
    def _next_job(self):
        """Wait for work; returns (version, seq, state, settings, size, scale_level, quality, moving, lines drawn over it) or None when closed."""
        with self.cond:
            while True:
                if self.closed:
                    return None
                now = time.monotonic()
                moving = self.adaptive and now - self.last_motion < REST_S
                if self.version != self._done_version:
                    level = self.scales.level if moving else 0
                    break
                if not self._done_full:
                    if moving:
                        self.cond.wait(REST_S - (now - self.last_motion) + 0.005)
                        continue
                    level = 0
                    break
                self.cond.wait()
            st = self.state
            job_state = OrbitState(st.target.copy(), st.yaw, st.pitch, st.distance, st.fov, st.scene_radius)
            return self.version, self.seq, job_state, self.settings, (self.width, self.height), level, self.jpeg_quality, moving, self.lines()

    def _run(self) -> None:
        while True:
            job = self._next_job()
            if job is None:
                return
            version, seq, state, settings, (w, h), level, quality, moving, lines = job
            scale = SCALES[level]
            t0 = time.perf_counter()
            cloud = self.core.cloud
            try:
                cam = state.camera(max(1, round(w / scale)), max(1, round(h / scale)))
                drawn, lowered = within_frame_pixels(self.budget.settings_for(settings) if moving else settings, cam.width, cam.height)
                frame = render_locked(cloud, cam, drawn, cancelled=lambda: self.closed)
                if frame is None:
                    return
            except GigapointError as exc:
                ok = self._render_failed(version, exc, settings)
                if not ok:
                    return
                continue
            except Exception as exc:  # a bug must not kill the tab silently
                log.exception("viewer: a frame failed")  # (its traceback was lost: the tab got one line, the terminal nothing)
                if not self._render_failed(version, exc, settings):
                    return
                continue
            t1 = time.perf_counter()
            self.budget.record(frame.stats.points_processed, frame.stats.time_ms / 1000.0)
            jpeg = encode_image(overlaid(frame.image, cam, lines), "JPEG", quality if level == 0 else min(quality, 75))
            t2 = time.perf_counter()
            if cloud is self.core.live:  # a live cloud measures push-to-pixels latency
                cloud.drawn(frame)
            if moving:
                self.scales.record(level, t2 - t0)
            with self.cond:
                self.last = LastFrame(cam, frame, cloud)
                self._done_version = version
                self._done_full = level == 0
                self.good_settings = settings
            self.frames += 1
            stats = frame.stats
            header = {
                "frame": self.frames,
                "seq": seq,
                "width": int(frame.image.shape[1]),
                "height": int(frame.image.shape[0]),
                "scale": scale,
                "full": level == 0,
                "render_ms": (t1 - t0) * 1000,
                "encode_ms": (t2 - t1) * 1000,
                "points": stats.points_processed,
                "points_total": stats.points_total,
                "batches": stats.batches_rendered,
                "batches_total": stats.batches_total,
                "visible_pixels": stats.visible_pixels,
                "backend": stats.backend,
                "memory": memory_rss(),
                "cloud_bytes": cloud_bytes(cloud),
                "load_progress": float(cloud.load_progress),
                "note": "\n".join(line for line in (self.core.note, lowered) if line),
                "camera": state.as_dict(),
            }
            info = self.core.cloud_info()
            if info != self.cloud_shown:  # a live or loading cloud grew: the line hello sent went stale (only when it changes)
                header["cloud"] = self.cloud_shown = info
            if not self.send("bytes", P.pack_frame(header, jpeg)):
                return

    def _render_failed(self, version, exc, settings) -> bool:
        """Report a failed render, fall back to the last settings that worked; False if the tab is gone."""
        with self.cond:
            self._done_version = version
            self._done_full = True
            reverted = self.settings is settings and settings is not self.good_settings
            if reverted:
                self.settings = self.good_settings
                self._changed(False)
        msg = {"type": "error", "message": f"render failed: {exc}"[:500]}
        if not self.send("json", msg):
            return False
        if reverted:
            return self.send("json", {"type": "settings", "values": P.settings_values(self.good_settings)})
        return True
