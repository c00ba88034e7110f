"""The native window, driven headless through rendercanvas's offscreen canvas."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import gigapoint
from gigapoint import Camera, RenderSettings
from gigapoint.errors import BackendUnavailableError
from gigapoint.viewer.window import Orbit, open_window

offscreen = pytest.importorskip("rendercanvas.offscreen")
CPU = RenderSettings(backend="cpu")


@pytest.fixture(scope="module")
def cloud():
    return gigapoint.demo(40_000)


@pytest.fixture
def window(cloud):
    return open_window(cloud, settings=CPU, canvas=offscreen.RenderCanvas(size=(160, 120)))


def _event(kind, **fields):
    return {"event_type": kind, "x": 0.0, "y": 0.0, "buttons": (), "modifiers": (), "time_stamp": 0.0, **fields}


def test_orbit_reproduces_the_camera_it_came_from():
    cam = Camera.look_at((10.0, -20.0, 15.0), (1.0, 2.0, 3.0), fov=45, width=64, height=48)
    again = Orbit.from_camera(cam).camera(64, 48)
    np.testing.assert_allclose(again.eye, cam.eye, atol=1e-9)
    np.testing.assert_allclose(again.target, cam.target)
    assert again.fov == 45


def test_window_shows_the_rendered_frame(window, cloud):
    shown = np.asarray(window.canvas.draw())
    want = gigapoint.render_frame(cloud, window.orbit.camera(160, 120), CPU).image
    assert shown.shape == (120, 160, 4)
    assert np.array_equal(shown, want)
    assert np.count_nonzero(np.any(want[..., :3] > 0, axis=-1)) > 1000


def test_drag_wheel_and_reset(window):
    start = Orbit(window.orbit.target.copy(), window.orbit.yaw, window.orbit.pitch, window.orbit.distance)
    window.on_event(_event("pointer_down", x=50.0, y=50.0, button=1))
    window.on_event(_event("pointer_move", x=60.0, y=40.0, buttons=(1,)))
    window.on_event(_event("pointer_up", x=60.0, y=40.0, button=1))
    assert window.orbit.yaw == pytest.approx((start.yaw - 3.0) % 360)
    assert window.orbit.pitch == pytest.approx(start.pitch - 3.0)
    window.on_event(_event("pointer_move", x=90.0, y=90.0, buttons=()))  # no button held: nothing
    assert window.orbit.pitch == pytest.approx(start.pitch - 3.0)
    window.on_event(_event("wheel", dx=0.0, dy=100.0))
    assert window.orbit.distance == pytest.approx(start.distance * np.exp(0.1))
    window.on_event(_event("pointer_down", x=50.0, y=50.0, button=2))  # right drag pans
    window.on_event(_event("pointer_move", x=70.0, y=50.0, buttons=(2,)))
    assert not np.allclose(window.orbit.target, start.target)
    before = np.asarray(window.canvas.draw()).copy()
    window.on_event(_event("key_down", key="r"))
    assert window.orbit.distance == pytest.approx(start.distance) and np.allclose(window.orbit.target, start.target)
    assert not np.array_equal(np.asarray(window.canvas.draw()), before)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="display check is for Linux")
def test_no_display_is_a_clear_error(monkeypatch, cloud):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(BackendUnavailableError, match="no display"):
        open_window(cloud)
