"""The viewer page's own state in a real headless Chromium: the HUD's long lines, the status
while the first view is drawn, a stopped server and a reconnect, the pick box, a half-filled range."""

from __future__ import annotations

import json
import re
import time

import numpy as np
import pytest

pytestmark = [pytest.mark.browser, pytest.mark.timeout(180)]  # the browser: tests/integration/conftest.py
pytest.importorskip("starlette")
pytest.importorskip("uvicorn")

import gigapoint
from gigapoint.viewer import session
from gigapoint.viewer.server import ViewerServer

VIEWPORT = {"width": 290 + 640, "height": 480}  # the panel is 290 px wide: the canvas is 640 x 480


@pytest.fixture(scope="module")
def cloud():
    return gigapoint.demo(20_000)


@pytest.fixture()
def server(cloud):
    srv = ViewerServer(cloud).start()
    yield srv
    srv.close()


@pytest.fixture()
def page(browser):
    ctx = browser.new_context(viewport=VIEWPORT)
    pg = ctx.new_page()
    errors = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    yield pg
    ctx.close()
    assert not errors, errors


def wait_full_frame(pg, after: int = 0) -> int:
    pg.wait_for_function(
        "(n) => { const c = document.getElementById('canvas'); return Number(c.dataset.frame || 0) > n && c.dataset.full === 'true'; }",
        arg=after,
        timeout=30_000,
    )
    return int(pg.evaluate("() => Number(document.getElementById('canvas').dataset.frame)"))


def test_a_long_hud_line_wraps_inside_the_view(page, server):
    # a progressive load's error names its file: the line ran on under the panel, its end unread
    server.core.note = "loading stopped: /data/" + "survey_tile_" * 20 + ".laz: truncated or corrupt LAZ file; showing the 60,000 points loaded"
    page.goto(server.url)
    wait_full_frame(page)
    page.wait_for_function("() => document.getElementById('stats').textContent.includes('points loaded')", timeout=30_000)
    stats, view = (page.locator(s).bounding_box() for s in ("#stats", "#canvas"))
    assert stats["x"] + stats["width"] <= view["x"] + view["width"], (stats, view)
    assert page.evaluate("() => { const e = document.getElementById('stats'); return e.scrollWidth <= e.clientWidth; }")


def test_the_status_says_the_view_is_being_drawn_until_it_is(page, server):
    with session.RENDER_LOCK:  # the first frame takes seconds (a big cloud, a first run's compile)
        page.goto(server.url)
        page.wait_for_function("() => window.gigapoint.session", timeout=30_000)
        assert page.locator("#status").inner_text() == "connected — drawing the view…"
    wait_full_frame(page)
    assert page.locator("#status").inner_text() == "connected"


def test_a_stopped_server_is_said_and_a_restarted_one_keeps_the_tabs_view(page, cloud):
    srv = ViewerServer(cloud).start()
    try:
        page.goto(srv.url)
        n = wait_full_frame(page)
        page.get_by_role("button", name="top").click()
        page.locator("#setting-color_mode").select_option(json.dumps("elevation"))
        page.wait_for_function("() => window.gigapoint.camera.pitch > 89 && window.gigapoint.settings.color_mode === 'elevation'", timeout=30_000)
        for view in ("front", "side", "iso", "front", "side", "top"):  # frames: a new session's 1, 2, ... were dropped as old
            page.get_by_role("button", name=view).click()
            n = wait_full_frame(page, n)
        page.locator("#jpeg").fill("40")
        page.locator("#jpeg").dispatch_event("change")
    finally:
        srv.close()
    page.wait_for_function("() => document.getElementById('status').textContent.startsWith('no answer from the viewer server')", timeout=30_000)
    assert page.evaluate("() => getComputedStyle(document.getElementById('canvas')).opacity") == "0.45"  # the last picture, dimmed
    again = ViewerServer(cloud, port=srv.port).start()  # the same address: the page reconnects by itself
    try:
        page.wait_for_function("() => document.getElementById('status').textContent === 'connected'", timeout=30_000)
        t_end = time.monotonic() + 30
        while time.monotonic() < t_end and not (len(again.core.sessions) == 1 and next(iter(again.core.sessions.values())).jpeg_quality == 40):
            time.sleep(0.1)
        tab = next(iter(again.core.sessions.values()))
        state, settings, _ = tab.snapshot()
        assert state.pitch == pytest.approx(90.0) and settings.color_mode == "elevation" and tab.jpeg_quality == 40
        assert page.evaluate("() => getComputedStyle(document.getElementById('canvas')).opacity") == "1"
        assert page.evaluate("() => window.gigapoint.settings.color_mode") == "elevation"
        page.get_by_role("button", name="front").click()  # the new session's frames are drawn
        page.wait_for_function("() => Math.abs(window.gigapoint.camera.pitch) < 1", timeout=30_000)
    finally:
        again.close()


def test_a_view_wider_than_the_largest_frame_keeps_its_aspect(browser, server):
    # 2 device pixels a CSS pixel: the canvas is 2310 x 600 CSS px, 4620 x 1200 device px, past the 4096 a side
    ctx = browser.new_context(viewport={"width": 290 + 2310, "height": 600}, device_scale_factor=2)
    try:
        pg = ctx.new_page()
        pg.goto(server.url)
        wait_full_frame(pg)
        header = pg.evaluate("() => window.gigapoint.header")
        assert (header["width"], header["height"]) == (4096, 1064)  # 4620 x 1200 scaled by 4096 / 4620, not squeezed to 4096 x 1200
        assert pg.evaluate("() => [canvas.width, canvas.height]") == [4096, 1064]
    finally:
        ctx.close()


def test_the_keys_and_the_reload_do_what_the_help_says(page, server):
    page.goto(server.url)
    n = wait_full_frame(page)
    help_keys = page.locator("#help-keys").inner_text()
    assert "R reset" in help_keys and "1–5 top, front, side, iso, auto" in help_keys and "+/− fly speed" in help_keys
    assert "reloading the page starts again from the first view and the default settings" in help_keys
    first = page.evaluate("() => window.gigapoint.camera")
    page.locator("#canvas").focus()
    page.keyboard.press("3")  # side
    page.wait_for_function("() => Math.abs(window.gigapoint.camera.pitch) < 0.01 && Math.abs(window.gigapoint.camera.yaw) < 0.01", timeout=30_000)
    speed = page.locator("#speed-value").inner_text()
    page.keyboard.press("+")
    assert float(page.locator("#speed-value").inner_text().rstrip("/s")) == pytest.approx(float(speed.rstrip("/s")) * 2 ** 0.5, rel=1e-2)
    page.keyboard.press("f")
    assert page.locator("#fly").is_checked()
    page.keyboard.press("r")
    page.wait_for_function("(yaw) => window.gigapoint.camera.yaw === yaw", arg=first["yaw"], timeout=30_000)
    page.locator("#setting-color_mode").select_option(json.dumps("elevation"))
    page.wait_for_function("() => window.gigapoint.settings.color_mode === 'elevation'", timeout=30_000)
    n = wait_full_frame(page, n)
    page.reload()
    wait_full_frame(page)
    assert page.evaluate("() => window.gigapoint.settings.color_mode") == "rgb"
    assert page.evaluate("() => window.gigapoint.camera") == first


def test_the_jpeg_quality_field_shows_the_quality_used(page, server):
    page.goto(server.url)
    wait_full_frame(page)
    (tab,) = server.core.sessions.values()
    for typed, used in (("40", 40), ("", 85), ("500", 100), ("3", 10)):  # emptied: 10 was used, the field blank
        page.locator("#jpeg").fill(typed)
        page.locator("#jpeg").dispatch_event("change")
        page.wait_for_function("(q) => document.getElementById('jpeg').value === String(q)", arg=used, timeout=5_000)
        t_end = time.monotonic() + 10
        while tab.jpeg_quality != used and time.monotonic() < t_end:
            time.sleep(0.05)
        assert tab.jpeg_quality == used, typed


def pick_replies(pg) -> list:
    """The pick messages the server sends the page, as they arrive."""
    replies = []

    def on_socket(ws):
        ws.on("framereceived", lambda payload: isinstance(payload, str) and '"pick"' in payload and replies.append(json.loads(payload)))

    pg.on("websocket", on_socket)
    return replies


def test_the_pick_box_of_an_octree_says_point_or_voxel(page):
    # an octree's entries have no index: the box's first line was "point " with nothing after it
    from gigapoint.lod.progressive.octree import ProgressiveOctree

    octree = ProgressiveOctree("prog", max_leaf=500)
    octree.add(np.random.default_rng(3).random((20_000, 3)) * 10)
    gigapoint.render_frame(octree, gigapoint.Camera.fit_cloud(octree, width=64, height=48))  # its kernels compiled outside the page's waits
    srv = ViewerServer(octree).start()
    try:
        replies = pick_replies(page)
        page.goto(srv.url)
        wait_full_frame(page)
        for budget, word in ((None, "point"), (2_000, "voxel")):  # few points a frame: inner nodes' voxels drawn
            if budget:
                n = int(page.evaluate("() => Number(document.getElementById('canvas').dataset.frame)"))
                page.locator("#setting-point_budget").fill(str(budget))
                page.locator("#setting-point_budget").dispatch_event("change")
                wait_full_frame(page, n)
            replies.clear()
            box = page.locator("#canvas").bounding_box()
            page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
            page.wait_for_function("() => !document.getElementById('pickinfo').classList.contains('hidden')", timeout=10_000)
            t_end = time.monotonic() + 10
            while not replies and time.monotonic() < t_end:
                page.wait_for_timeout(50)
            (reply,) = replies
            assert reply["found"] and reply["info"]["voxel"] is (word == "voxel")
            page.wait_for_function("(w) => document.getElementById('pickinfo').textContent.split('\\n')[0] === w", arg=word, timeout=10_000)
            assert "voxel" not in page.locator("#pickinfo").text_content().split("\n", 1)[1]  # said once, in the first line
    finally:
        srv.close()


def test_a_colour_held_approximately_is_said_in_the_pick_box(page, server):
    # the demo cloud's colours are held as palettes (colors="auto"): the box showed them as the file's
    page.goto(server.url)
    wait_full_frame(page)
    box = page.locator("#canvas").bounding_box()
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.wait_for_function("() => /^rgba /m.test(document.getElementById('pickinfo').textContent)", timeout=10_000)
    (rgba,) = [line for line in page.locator("#pickinfo").text_content().split("\n") if line.startswith("rgba")]
    assert re.fullmatch(r"rgba \d+, \d+, \d+, 255 \(approx\.: colours held as 256-colour palettes\)", rgba), rgba


def test_half_an_elevation_range_is_said_not_dropped(page, server):
    page.goto(server.url)
    wait_full_frame(page)
    low, high = page.locator("#setting-elevation_range input").all()
    low.fill("1")
    low.dispatch_event("change")
    page.wait_for_function("() => !document.getElementById('error').classList.contains('hidden')", timeout=5_000)
    assert page.locator("#error").text_content() == "elevation range: give both low and high (both empty: the default)"
    assert "invalid" in high.get_attribute("class") and "invalid" not in (low.get_attribute("class") or "")
    high.fill("4")
    high.dispatch_event("change")
    page.wait_for_function("() => JSON.stringify(window.gigapoint.settings.elevation_range) === '[1,4]'", timeout=10_000)
    assert "invalid" not in (high.get_attribute("class") or "") and page.locator("#error").is_hidden()
    (tab,) = server.core.sessions.values()
    assert tab.snapshot()[1].elevation_range == (1.0, 4.0)

