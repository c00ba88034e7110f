"""RenderCache: arrays the renderer derives from point buffers, kept between frames.

Color modes (an elevation ramp, classification colors), decoded elevations and float32
normals cost a pass over every point; a frame should pay only a lookup. The cache holds
them per point buffers (by identity, weakly: buffers that are garbage-collected drop their
entries) and per ``version`` of the buffers: buffers rewritten in place (an octree's arena)
bump their version, which empties their entry (renderable.PointBuffers).
"""

from __future__ import annotations

import threading
import weakref


class RenderCache:
    """{key: array} per point buffers, valid while the buffers' version is unchanged."""

    def __init__(self) -> None:
        self._entries: dict[int, tuple[weakref.ref, object, dict]] = {}  # id -> (buffers, version, arrays)
        self._lock = threading.Lock()

    def arrays(self, points) -> dict:
        """The derived arrays of ``points`` (a dict to read and fill)."""
        with self._lock:
            entry = self._entries.get(id(points))
            if entry is None or entry[0]() is not points or entry[1] != points.version:
                for key in [k for k, (ref, _, _) in self._entries.items() if ref() is None]:
                    del self._entries[key]
                entry = (weakref.ref(points), points.version, {})
                self._entries[id(points)] = entry
            return entry[2]

    def forget(self, points) -> None:
        """Drop what was derived from ``points`` (after changing its attributes)."""
        with self._lock:
            self._entries.pop(id(points), None)


#: The renderer's one cache (colors.py, passes/lighting.py).
render_cache = RenderCache()
