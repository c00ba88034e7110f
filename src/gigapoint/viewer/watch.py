"""Follow a cloud that is still being made: a conversion (newer previews, then the finished
octree: ConversionWatcher), a progressive octree filling (LoadWatcher), or a live cloud
receiving frames (LiveWatcher).

``gigapoint view OUT`` on an unfinished conversion starts with its preview (a
ConversionPreview, lod/preview.py). A thread polls the octree folder (lod/octree_dir.py)
about once a second and swaps the viewer's cloud when the preview file is rewritten, and for
good when the octree is complete (a COPC conversion's: its file, once its ``<out>.work`` folder
is gone); the tabs redraw with their camera unchanged.
"""

from __future__ import annotations

import threading
import time
from typing import Self

from ..errors import GigapointError, warnings_kept
from ..lod.kinds import copc_of_work_dir
from ..lod.octree_dir import OctreeDir


def preview_note(folder: OctreeDir) -> str:
    """One line for the viewer's HUD: what the preview shows of the conversion."""
    s = folder.status()
    if not s:
        return "preview of an unfinished conversion"
    stopped = f"; conversion stopped ({folder.resume_hint})" if s.get("running") is False else ""
    if s.get("phase") in (None, "read"):
        of = f" of {s['total']:,}" if s.get("total") else ""
        return f"preview: {s.get('points', 0):,}{of} points read, {s.get('preview_points', 0):,} shown{stopped}"
    return f"preview ({s.get('preview_points', 0):,} of {s.get('points', 0):,} points): conversion in phase {s['phase']}{stopped}"


def _stamp(path):
    try:
        st = path.stat()
        return st.st_mtime_ns, st.st_size
    except OSError:
        return None


class _Watcher:
    """A daemon thread (``_run``) following the viewer core's cloud until ``stop``, or until it
    is done with it (it sets ``finished`` itself)."""

    def __init__(self, core, thread_name: str) -> None:
        self.core = core
        self.finished = threading.Event()
        self._thread = threading.Thread(target=self._run, name=thread_name, daemon=True)

    def start(self) -> Self:
        self._thread.start()
        return self

    def stop(self) -> None:
        self.finished.set()

    def _run(self) -> None:
        raise NotImplementedError


class ConversionWatcher(_Watcher):
    def __init__(self, core, folder: OctreeDir, interval_s: float = 1.0):
        super().__init__(core, "gigapoint-conversion-watch")  # finished: once the octree is drawn (or the watch stopped)
        self.folder = folder
        self.seen = _stamp(folder.preview)
        self.interval_s = interval_s
        core.note = preview_note(folder)  # before the first frame is drawn

    def _finished(self):
        """The finished octree to draw, or None while the conversion is unfinished: the folder
        itself once complete, or for a COPC conversion's work folder (``<out>.work``, removed
        once ``<out>`` is written) the COPC file; the preview stayed on screen for good."""
        if self.folder.complete:
            return self.folder.path
        copc = copc_of_work_dir(self.folder.path)
        return copc if copc is not None and not self.folder.path.exists() and copc.is_file() else None

    def _run(self) -> None:
        from ..lod import open_octree
        from ..lod.preview import open_preview

        while not self.finished.wait(self.interval_s):
            try:
                finished = self._finished()
                if finished is not None:
                    self.core.replace_cloud(open_octree(finished))
                    self.core.note = ""
                    self.finished.set()
                    return
                self.core.note = preview_note(self.folder)
                stamp = _stamp(self.folder.preview)
                if stamp is not None and stamp != self.seen:
                    with warnings_kept():  # not said: the viewer's note says it (catch_warnings is not for threads)
                        cloud = open_preview(self.folder)
                    self.seen = stamp
                    self.core.replace_cloud(cloud)
            except (GigapointError, OSError, ValueError):
                continue  # caught between two atomic renames, or the conversion was restarted: look again


def load_note(cloud, rate: float) -> str:
    """One line for the HUD while a progressive octree fills: points loaded and their rate."""
    if cloud.error is not None:
        return f"loading stopped: {cloud.error}; showing the {cloud.n_points:,} points loaded"
    total = f" of {cloud.loader.total:,}" if cloud.loader.total else ""
    if not cloud.loading:  # its warnings said here too: the terminal may be another machine's
        said = cloud.warnings
        more = f" (and {len(said) - 1} more)" if len(said) > 1 else ""
        warned = f"; warning: {said[0]}{more}" if said else ""
        return f"loaded {cloud.n_points:,} points in {cloud.loader.finished_at - cloud.loader.started:.1f} s{warned}"
    return f"loading: {cloud.loader.read:,}{total} points read, {rate / 1e6:.1f} M points/s"


class LoadWatcher(_Watcher):
    """While a progressive octree fills: redraw every tab ``interval_s`` (what is loaded so far)
    and keep the HUD's line on points loaded and points/s; one last redraw when it is done. What
    the 'auto' view frames (a new tab's first view) is sampled again as the points double, and
    once all are loaded; a tab opened before the first point is fit to them (ViewerCore.redraw)."""

    def __init__(self, core, cloud, interval_s: float = 0.25):
        super().__init__(core, "gigapoint-load-watch")
        self.cloud = cloud
        self.interval_s = interval_s
        self.framed = cloud.n_points  # the points the core's framing was sampled from
        core.note = load_note(cloud, 0.0)

    def _run(self) -> None:
        last = (self.cloud.loader.read, self.cloud.loader.started)
        rate = 0.0
        while not self.finished.wait(self.interval_s):
            now = (self.cloud.loader.read, time.perf_counter())
            recent = (now[0] - last[0]) / max(now[1] - last[1], 1e-9)
            rate = 0.7 * rate + 0.3 * recent if rate else recent
            last = now
            done = not self.cloud.loading
            self.core.note = load_note(self.cloud, rate)
            n_points = self.cloud.n_points
            reframe = done or n_points >= max(2 * self.framed, 1)  # the 'auto' view framed the first points read for good
            if reframe:
                self.framed = n_points
            self.core.redraw(reframe=reframe)
            if done:
                self.finished.set()


class LiveWatcher(_Watcher):
    """While frames stream into a LiveCloud: redraw every tab when one arrives (at most every
    ``min_interval_s``; a tab renders only the latest state, so frames that arrive while it draws
    coalesce), and keep the HUD's line on frames in per second, live points and push-to-pixels
    latency (LiveCloud.hud)."""

    def __init__(self, core, cloud, min_interval_s: float = 1 / 120, hud_interval_s: float = 0.25):
        super().__init__(core, "gigapoint-live-watch")
        self.cloud = cloud
        self.min_interval_s = min_interval_s
        self.hud_interval_s = hud_interval_s
        core.note = cloud.hud()

    def _run(self) -> None:
        seen = self.cloud.changes
        hud_at = 0.0
        while not self.finished.is_set():
            now_seen = self.cloud.wait_frame(seen, timeout=self.hud_interval_s)
            now = time.monotonic()
            if now - hud_at >= self.hud_interval_s:
                self.core.note = self.cloud.hud()
                hud_at = now
            if now_seen != seen or self.cloud.decay is not None:
                seen = now_seen
                self.core.redraw()
            self.finished.wait(self.min_interval_s)
