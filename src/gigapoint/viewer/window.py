"""A native window showing a cloud, with orbit controls (rendercanvas: glfw, Qt, wx...).

Each frame is rendered by ``gigapoint.render_frame`` (any backend) and shown through
rendercanvas's bitmap context. Controls: left drag orbits, right (or shift+left) drag
pans, the wheel zooms, R resets the view.

    from gigapoint.viewer.window import run_window
    run_window(gigapoint.demo(2_000_000))
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass

import numpy as np

from ..errors import BackendUnavailableError
from ..render.camera import Camera
from ..render.settings import RenderSettings
from .session import view_frame

_HINT = "install with: pip install 'gigapoint[window]' (rendercanvas + glfw) and run on a desktop with a display"


@dataclass
class Orbit:
    """Orbit camera state: the eye sits at ``distance`` from ``target`` at (yaw, pitch) degrees."""

    target: np.ndarray
    yaw: float
    pitch: float
    distance: float
    fov: float = 60.0

    @classmethod
    def from_camera(cls, camera: Camera) -> Orbit:
        d = np.subtract(camera.eye, camera.target)
        dist = float(np.linalg.norm(d))
        return cls(
            np.array(camera.target, float), math.degrees(math.atan2(d[1], d[0])), math.degrees(math.asin(d[2] / dist)), dist, camera.fov
        )

    def camera(self, width: int, height: int) -> Camera:
        return Camera.orbit(tuple(self.target), self.yaw, self.pitch, self.distance, fov=self.fov, width=width, height=height)

    def rotate(self, dx_px: float, dy_px: float) -> None:
        """A drag of (dx, dy) pixels: 0.3 degrees per pixel, pitch kept off the poles."""
        self.yaw = (self.yaw - 0.3 * dx_px) % 360.0
        self.pitch = min(89.0, max(-89.0, self.pitch + 0.3 * dy_px))

    def pan(self, dx_px: float, dy_px: float, height_px: int) -> None:
        """Move the target in the view plane so the scene follows the pointer."""
        cam = self.camera(max(height_px, 1), max(height_px, 1))
        right, up, _ = cam.basis()
        scale = 2.0 * self.distance * math.tan(math.radians(self.fov) / 2) / max(height_px, 1)
        self.target = self.target - scale * dx_px * np.asarray(right) + scale * dy_px * np.asarray(up)

    def zoom(self, wheel_dy: float) -> None:
        """Wheel steps scale the distance (about 10 % per notch of 100)."""
        self.distance = max(1e-6, self.distance * math.exp(0.001 * wheel_dy))


class PointCloudWindow:
    """Draws ``cloud`` into a rendercanvas canvas and reacts to its pointer events."""

    def __init__(self, canvas, cloud, camera: Camera | None = None, settings: RenderSettings | None = None) -> None:
        self.canvas = canvas
        self.cloud = cloud
        self.settings = RenderSettings.of(settings)
        w, h = canvas.get_physical_size()
        self.home = camera or Camera.fit(cloud.bounds, width=max(w, 1), height=max(h, 1))
        self.orbit = Orbit.from_camera(self.home)
        self.last_frame = None
        self._drag: tuple[float, float, bool] | None = None  # (x, y, pan?)
        self._context = canvas.get_context("bitmap")
        canvas.add_event_handler(self.on_event, "pointer_down", "pointer_move", "pointer_up", "wheel", "key_down", "resize")
        canvas.request_draw(self.draw)

    def draw(self) -> None:
        w, h = self.canvas.get_physical_size()
        frame = view_frame(self.cloud, self.orbit.camera(max(w, 1), max(h, 1)), self.settings)
        self.last_frame = frame
        self._context.set_bitmap(frame.image)
        s = frame.stats
        self.canvas.set_title(f"gigapoint - {self.cloud.name} - {s.points_processed:,} points in {s.time_ms:.0f} ms ({s.backend})")

    def on_event(self, event: dict) -> None:
        kind = event["event_type"]
        if kind == "pointer_down":
            pan = event.get("button") == 2 or "Shift" in event.get("modifiers", ())
            self._drag = (event["x"], event["y"], pan)
            return
        if kind == "pointer_up":
            self._drag = None
            return
        if kind == "pointer_move" and self._drag is not None:
            x0, y0, pan = self._drag
            dx, dy = event["x"] - x0, event["y"] - y0
            ratio = self.canvas.get_pixel_ratio()
            if pan:
                self.orbit.pan(dx * ratio, dy * ratio, self.canvas.get_physical_size()[1])
            else:
                self.orbit.rotate(dx, dy)
            self._drag = (event["x"], event["y"], pan)
        elif kind == "wheel":
            self.orbit.zoom(event.get("dy", 0.0))
        elif kind == "key_down" and str(event.get("key", "")).lower() == "r":
            self.orbit = Orbit.from_camera(self.home)
        elif kind != "resize":
            return
        self.canvas.request_draw()


def check_display() -> None:
    """A one-line BackendUnavailableError on Linux without a display (glfw would abort the
    process: an assertion, not an exception)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise BackendUnavailableError(f"native window: no display (DISPLAY / WAYLAND_DISPLAY unset); {_HINT}")


def open_window(
    cloud, camera: Camera | None = None, settings: RenderSettings | None = None, *, size=(1280, 720), canvas=None
) -> PointCloudWindow:
    """A window (or the given rendercanvas ``canvas``) showing ``cloud``; run the loop to see it."""
    if canvas is None:
        check_display()
        try:
            from rendercanvas.auto import RenderCanvas
        except Exception as exc:  # noqa: BLE001 - rendercanvas raises several types when no GUI backend works
            raise BackendUnavailableError(f"native window not available ({exc}); {_HINT}") from None
        try:
            canvas = RenderCanvas(size=size, title="gigapoint", update_mode="ondemand")
        except Exception as exc:  # noqa: BLE001 - e.g. glfw without a display
            raise BackendUnavailableError(f"cannot open a window ({exc}); {_HINT}") from None
    return PointCloudWindow(canvas, cloud, camera, settings)


def run_window(cloud, camera: Camera | None = None, settings: RenderSettings | None = None, *, size=(1280, 720)) -> None:
    """Open a window on ``cloud`` and block until it is closed."""
    open_window(cloud, camera, settings, size=size)
    run_loop()


def run_loop() -> None:
    """Block until the windows opened are closed."""
    from rendercanvas.auto import loop

    loop.run()
