"""The viewer in a real headless Chromium against a real uvicorn server."""

from __future__ import annotations

import base64
import contextlib
import io
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.browser, pytest.mark.timeout(180)]  # the browser: tests/integration/conftest.py
pytest.importorskip("starlette")
pytest.importorskip("uvicorn")

from PIL import Image

import gigapoint
from gigapoint.viewer.server import ViewerServer

MARKER = np.array([637050.123456789, 4850040.987654321, 30.0])
VIEWPORT = {"width": 290 + 640, "height": 480}  # the panel is 290 px wide: the canvas is 640 x 480


def marker_scene():
    """Ground of two colours (so any camera move changes the image) and one red marker point above it."""
    g = np.stack(np.meshgrid(np.linspace(0, 100, 200), np.linspace(0, 80, 160), indexing="ij"), -1).reshape(-1, 2)
    ground = np.column_stack([g[:, 0] + 637000.0, g[:, 1] + 4850000.0, 10.0 + 0.02 * g[:, 0]])
    rgb = np.zeros((len(g) + 1, 3), np.uint8)
    rgb[:-1, 1] = 200
    rgb[:-1, 2] = np.where(g[:, 0] > 50, 200, 0)
    rgb[-1] = (255, 0, 0)
    intensity = np.ones(len(g) + 1, np.uint16)
    intensity[-1] = 4242
    return gigapoint.from_arrays(np.vstack([ground, MARKER]), rgb, name="marker", intensity=intensity)


@pytest.fixture(scope="module")
def server():
    srv = ViewerServer(marker_scene()).start()
    yield srv
    srv.close()


@pytest.fixture()
def page(browser, server):
    ctx = browser.new_context(viewport=VIEWPORT, accept_downloads=True)
    pg = ctx.new_page()
    errors = []
    pg.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.goto(server.url)
    wait_full_frame(pg, 0)
    yield pg
    ctx.close()
    assert not errors, errors


def frame_no(pg) -> int:
    return int(pg.evaluate("() => Number(document.getElementById('canvas').dataset.frame || 0)"))


def wait_full_frame(pg, after: int) -> int:
    pg.wait_for_function(
        "(n) => { const c = document.getElementById('canvas'); return Number(c.dataset.frame || 0) > n && c.dataset.full === 'true'; }",
        arg=after,
        timeout=30_000,
    )
    return frame_no(pg)


def camera(pg) -> dict:
    return pg.evaluate("() => window.gigapoint.camera")


def settle(pg, quiet_s: float = 0.4) -> dict:
    """The camera once it has stopped changing (all queued input applied)."""
    last, t_end = camera(pg), time.monotonic() + 30
    while time.monotonic() < t_end:
        time.sleep(quiet_s)
        now = camera(pg)
        if now == last:
            return now
        last = now
    raise AssertionError("the camera never came to rest")


def canvas_pixels(pg) -> np.ndarray:
    """What the canvas shows (without the overlays on top of it)."""
    url = pg.evaluate("() => document.getElementById('canvas').toDataURL('image/png')")
    png = base64.b64decode(url.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)


def canvas_box(pg) -> dict:
    return pg.locator("#canvas").bounding_box()


def drag(pg, dx, dy, button="left"):
    b = canvas_box(pg)
    x, y = b["x"] + b["width"] / 2, b["y"] + b["height"] / 2
    pg.mouse.move(x, y)
    pg.mouse.down(button=button)
    pg.mouse.move(x + dx, y + dy, steps=12)
    pg.mouse.up(button=button)


def test_page_loads_and_shows_a_frame(page):
    img = canvas_pixels(page)
    assert img.shape[:2] == (480, 640)
    assert (img.sum(axis=2) > 60).mean() > 0.05  # not all background
    assert page.locator("#stats").inner_text().count("points") == 1
    assert page.locator("#settings input, #settings select").count() >= 4  # the panel was built from the schema


def test_drag_orbits_and_changes_the_frame(page):
    before_img, before = canvas_pixels(page), camera(page)
    n = frame_no(page)
    drag(page, 120, 0)
    wait_full_frame(page, n)
    after = camera(page)
    assert after["yaw"] != pytest.approx(before["yaw"], abs=1.0)
    assert after["target"] == before["target"]
    assert np.abs(canvas_pixels(page) - before_img).mean() > 2


def test_right_drag_pans(page):
    before = camera(page)
    n = frame_no(page)
    drag(page, 80, 40, button="right")
    wait_full_frame(page, n)
    after = camera(page)
    assert after["target"] != before["target"] and after["yaw"] == before["yaw"]


def test_wheel_zooms(page):
    before_img, before = canvas_pixels(page), camera(page)
    n = frame_no(page)
    b = canvas_box(page)
    page.mouse.move(b["x"] + b["width"] / 2, b["y"] + b["height"] / 2)
    for _ in range(3):
        page.mouse.wheel(0, -200)
    page.wait_for_function("(d) => window.gigapoint.camera.distance < d * 0.9", arg=before["distance"], timeout=30_000)
    wait_full_frame(page, n)
    assert camera(page)["distance"] < before["distance"] * 0.9
    assert np.abs(canvas_pixels(page) - before_img).mean() > 2


def test_panel_change_changes_the_frame(page):
    assert canvas_pixels(page)[2, 2].max() < 40  # black background
    n = frame_no(page)
    page.locator("#setting-background").fill("#ffffff")
    wait_full_frame(page, n)
    page.wait_for_function("() => window.gigapoint.settings.background[0] === 255", timeout=30_000)
    # a frame requested before the change can arrive after it on a loaded machine: give the
    # frame the change asked for up to 30 s to replace it
    t_end = time.monotonic() + 30
    while canvas_pixels(page)[2, 2].min() <= 225 and time.monotonic() < t_end:
        time.sleep(0.2)
    assert canvas_pixels(page)[2, 2].min() > 225


def test_color_attribute_offers_the_clouds_attributes_and_colours_by_one(page):
    """The colour attribute field lists the cloud's attributes (a datalist); with one named, the
    'attribute' colour mode draws it (the mode without a name is refused, as any bad setting)."""
    names = page.eval_on_selector_all("#attribute-names option", "els => els.map(e => e.value)")
    assert names == ["intensity"]
    page.locator("#setting-color_attribute").fill("intensity")
    page.locator("#setting-color_attribute").dispatch_event("change")
    page.wait_for_function("() => window.gigapoint.settings.color_attribute === 'intensity'", timeout=30_000)
    before = canvas_pixels(page)
    n = frame_no(page)
    page.locator("#setting-color_mode").select_option('"attribute"')
    wait_full_frame(page, n)
    page.wait_for_function("() => window.gigapoint.settings.color_mode === 'attribute'", timeout=30_000)
    t_end = time.monotonic() + 30  # (a frame asked for before the change may arrive after it)
    while np.array_equal(canvas_pixels(page), before) and time.monotonic() < t_end:
        time.sleep(0.2)
    assert not np.array_equal(canvas_pixels(page), before)


def test_view_presets_and_fov(page):
    n = frame_no(page)
    page.get_by_role("button", name="top").click()
    page.wait_for_function("() => window.gigapoint.camera.pitch > 89", timeout=30_000)
    wait_full_frame(page, n)
    n = frame_no(page)
    page.locator("#fov").fill("30")
    page.wait_for_function("() => Math.abs(window.gigapoint.camera.fov - 30) < 0.01", timeout=30_000)
    page.get_by_role("button", name="reset").click()
    page.wait_for_function("() => window.gigapoint.camera.fov === 60 && window.gigapoint.camera.pitch < 40", timeout=30_000)


def marker_css_position(page, server):
    """Where the marker is on the page, from the camera of the last frame the server rendered."""
    (session,) = server.core.sessions.values()
    cam = session.last.camera
    x, y, w, _ = cam.screen_rows() @ np.append(MARKER, 1.0)
    b = canvas_box(page)
    return b["x"] + (x / w) / cam.width * b["width"], b["y"] + (y / w) / cam.height * b["height"]


def test_pick_shows_the_coordinates_of_the_marker_and_double_click_sets_the_pivot(page, server):
    n = frame_no(page)
    page.get_by_role("button", name="top").click()
    page.wait_for_function("() => window.gigapoint.camera.pitch > 89", timeout=30_000)
    wait_full_frame(page, n)
    cloud = server.core.cloud
    index = int(np.argmax(cloud.attributes["intensity"]))
    px, py, _ = (float(v) for v in cloud.positions([index])[0])
    x, y = marker_css_position(page, server)
    page.mouse.click(x, y)
    box = page.locator("#pickinfo")
    box.wait_for(state="visible")
    page.wait_for_function("(i) => document.getElementById('pickinfo').dataset.index === String(i)", arg=index, timeout=30_000)
    text = box.inner_text()
    assert f"x {px!r}" in text and f"y {py!r}" in text  # full float64 precision, as Python prints it
    assert abs(px - MARKER[0]) < 1e-6 and "intensity 4242" in text and "rgba 255, 0, 0, 255" in text
    n = frame_no(page)
    page.mouse.dblclick(x, y)
    page.wait_for_function("(x) => window.gigapoint.camera.target[0] === x", arg=px, timeout=30_000)
    wait_full_frame(page, n)
    assert camera(page)["target"] == cloud.positions([index])[0].tolist()


def test_measure_lists_the_lengths_between_clicked_points(page, server):
    n = frame_no(page)
    page.get_by_role("button", name="top").click()
    page.wait_for_function("() => window.gigapoint.camera.pitch > 89", timeout=30_000)
    wait_full_frame(page, n)
    x, y = marker_css_position(page, server)
    b = canvas_box(page)
    page.locator("#canvas").focus()
    page.keyboard.press("m")
    box = page.locator("#measureinfo")
    assert "click a point to start" in box.inner_text() and "measure" in page.locator("#help-keys").inner_text()
    page.mouse.click(x, y)
    page.wait_for_function("() => document.getElementById('measureinfo').dataset.points === '1'", timeout=30_000)
    page.mouse.click(b["x"] + b["width"] * 0.3, b["y"] + b["height"] * 0.6)  # the ground
    page.wait_for_function("() => document.getElementById('measureinfo').dataset.points === '2'", timeout=30_000)
    (session,) = server.core.sessions.values()
    p, q = np.array(session.measure)
    assert np.allclose(p, MARKER, atol=1e-6)  # the first click picked the marker
    d = q - p
    text = box.inner_text()  # the synthetic cloud has no file scale: 3 decimals
    assert f"1: {np.linalg.norm(d):.3f}   horizontal {np.hypot(d[0], d[1]):.3f}   height {d[2]:.3f}" in text, text
    assert f"total {np.linalg.norm(d):.3f}" in text and d[2] < -15
    page.wait_for_function("() => window.gigapoint.header.seq === window.gigapoint.seq && window.gigapoint.header.full", timeout=30_000)
    cam = session.last.camera  # the frame drawn since has the segment where the camera puts its middle
    mx, my, mw, _ = cam.screen_rows() @ np.append((p + q) / 2, 1.0)
    shot = np.asarray(Image.open(io.BytesIO(page.screenshot(clip=b))).convert("RGB"))
    r, g, bl = (int(v) for v in shot[int(my / mw / cam.height * shot.shape[0]), int(mx / mw / cam.width * shot.shape[1])])
    assert r > 180 and g > 150 and bl < 110, (r, g, bl)  # the measuring yellow
    page.mouse.click(b["x"] + 3, b["y"] + 3)  # the sky of the top view's corner
    page.wait_for_function("() => document.getElementById('measureinfo').textContent.includes('no point here: nothing added')", timeout=30_000)
    assert box.get_attribute("data-points") == "2"
    page.keyboard.press("Backspace")
    page.wait_for_function("() => document.getElementById('measureinfo').dataset.points === '1'", timeout=30_000)
    assert len(session.measure) == 1
    page.keyboard.press("Escape")
    box.wait_for(state="hidden")
    t_end = time.monotonic() + 10
    while session.measure and time.monotonic() < t_end:
        time.sleep(0.05)
    assert session.measure == []


def close_polygon_from_the_top(page, corners) -> None:
    """Seen from the top, the measuring tool's points clicked at ``corners`` (fractions of the
    canvas), then closed into a polygon (C)."""
    n = frame_no(page)
    page.get_by_role("button", name="top").click()
    page.wait_for_function("() => window.gigapoint.camera.pitch > 89", timeout=30_000)
    wait_full_frame(page, n)
    b = canvas_box(page)
    page.locator("#canvas").focus()
    page.keyboard.press("m")
    for k, (fx, fy) in enumerate(corners, start=1):
        page.mouse.click(b["x"] + b["width"] * fx, b["y"] + b["height"] * fy)
        page.wait_for_function("(k) => document.getElementById('measureinfo').dataset.points === String(k)", arg=k, timeout=30_000)
    page.keyboard.press("c")
    page.wait_for_function("() => document.getElementById('measureinfo').dataset.closed === 'true'", timeout=30_000)


def test_c_closes_the_measurement_into_a_polygon_and_volume_computes_the_volume_inside(page, server):
    from gigapoint.viewer import volume_tool as VT

    close_polygon_from_the_top(page, ((0.3, 0.3), (0.7, 0.3), (0.5, 0.7)))  # a triangle of ground around the marker
    (session,) = server.core.sessions.values()
    (x0, y0), (x1, y1), (x2, y2) = np.array(session.measure)[:, :2]
    area = abs((x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)) / 2
    assert f"polygon: area {area:.3f}" in page.locator("#measureinfo").inner_text()
    page.get_by_role("button", name="volume", exact=True).click()
    page.wait_for_function("() => document.getElementById('volume-info').dataset.fill !== undefined", timeout=30_000)
    gsd, note = VT.default_gsd(session.measure, VT.point_spacing(server.core.bounds, server.core.cloud.n_points))
    expected = gigapoint.volume(server.core.cloud, VT.toe(session.measure), gsd)
    assert float(page.locator("#volume-info").get_attribute("data-fill")) == pytest.approx(expected.fill)
    text = page.locator("#volume-info").inner_text()
    assert f"fill {expected.fill:,.2f} cubic units" in text and "base plane through the toe" in text and note in text, text


def test_the_volume_panel_shows_gp_volumes_warning_of_a_toe_beyond_the_data(page, server):
    """The panel said "49.5 % left empty" and the server's terminal the warning that says why (the
    toe runs beyond the data) and how to mend it; the panel now says it."""
    from gigapoint.errors import GigapointWarning
    from gigapoint.viewer import volume_tool as VT

    x0, y0 = 637000.0, 4850000.0  # the ground's corner: it spans 100 x 80
    toe = [[x0 + 50, y0 + 20, 11.0], [x0 + 150, y0 + 20, 11.0], [x0 + 150, y0 + 60, 11.0], [x0 + 50, y0 + 60, 11.0]]  # half beyond x 100
    page.locator("#canvas").focus()
    page.keyboard.press("m")
    page.evaluate("(toe) => window.gigapoint.ws.send(JSON.stringify({ type: 'measure', action: 'restore', points: toe, closed: true }))", toe)
    page.wait_for_function("() => document.getElementById('measureinfo').dataset.closed === 'true'", timeout=30_000)
    page.get_by_role("button", name="volume", exact=True).click()
    page.wait_for_function("() => document.getElementById('volume-info').dataset.fill !== undefined", timeout=30_000)
    gsd, _ = VT.default_gsd(toe, VT.point_spacing(server.core.bounds, server.core.cloud.n_points))
    with pytest.warns(GigapointWarning) as said:
        gigapoint.volume(server.core.cloud, VT.toe(toe), gsd)
    (warning,) = [str(w.message) for w in said]
    assert warning.startswith("the measured polygon: 49.5% of the pile's pixels hold no height") and warning.endswith("the toe runs beyond the data's footprint (draw it inside the points)")
    assert page.locator("#volume-info").inner_text().splitlines()[-1] == f"warning: {warning}"


def test_a_polygon_crossing_itself_shows_why_instead_of_an_area_and_offers_no_volume(page, server):
    close_polygon_from_the_top(page, ((0.3, 0.3), (0.7, 0.3), (0.3, 0.7), (0.7, 0.7)))  # a bow tie: its 2nd and 4th sides cross
    crossing = "the polygon crosses itself (edges 2 and 4): no area or volume; move a point so that no two edges cross"
    text = page.locator("#measureinfo").inner_text()
    assert crossing in text and "area" not in text.replace(crossing, ""), text  # the message, not a wrong area
    assert page.locator("#btn-volume").is_disabled() and page.locator("#volume-info").inner_text() == crossing


def test_measure_in_feet_says_so_and_survives_a_lost_connection(browser, autzen_path):
    """autzen_trim.laz is in feet: the HUD writes "ft" by each number and the totals in metres
    too; after the connection drops, the page's new session has the measurement again."""
    srv = ViewerServer(gigapoint.open(autzen_path)).start()
    ctx = browser.new_context(viewport=VIEWPORT)
    pg = ctx.new_page()
    try:
        pg.goto(srv.url)
        n = wait_full_frame(pg, 0)
        pg.get_by_role("button", name="top").click()
        pg.wait_for_function("() => window.gigapoint.camera.pitch > 89", timeout=30_000)
        wait_full_frame(pg, n)
        b = canvas_box(pg)
        pg.locator("#canvas").focus()
        pg.keyboard.press("m")
        for k, (fx, fy) in enumerate([(0.45, 0.5), (0.6, 0.4)], start=1):  # two points of the town, seen from above
            pg.mouse.click(b["x"] + b["width"] * fx, b["y"] + b["height"] * fy)
            pg.wait_for_function("(k) => document.getElementById('measureinfo').dataset.points === String(k)", arg=k, timeout=30_000)
        (session,) = srv.core.sessions.values()
        p, q = np.array(session.measure)
        d = q - p
        text = pg.locator("#measureinfo").inner_text()  # the file's 0.01 ft grid: 2 decimals
        length, across = np.linalg.norm(d), np.hypot(d[0], d[1])
        assert "units: ft (heights taken as ft: the CRS names no vertical unit)" in text, text
        assert f"1: {length:.2f} ft   horizontal {across:.2f} ft   height {d[2]:+.2f} ft" in text, text
        assert f"total {length:.2f} ft ({length * 0.3048:.2f} m)   horizontal {across:.2f} ft ({across * 0.3048:.2f} m)" in text, text
        pg.evaluate("() => window.gigapoint.ws.close()")  # the connection drops: the page connects again
        pg.wait_for_function("(old) => window.gigapoint.session && window.gigapoint.session !== old", arg=session.id, timeout=30_000)
        pg.wait_for_function("() => document.getElementById('measureinfo').dataset.points === '2'", timeout=30_000)
        (again,) = srv.core.sessions.values()
        assert again is not session and again.measure == [p.tolist(), q.tolist()]
        assert pg.locator("#measureinfo").inner_text() == text
    finally:
        ctx.close()
        srv.close()


def test_keyboard_fly_moves_the_camera(page):
    before = camera(page)
    page.locator("#canvas").focus()
    page.keyboard.down("w")
    time.sleep(0.4)
    page.keyboard.up("w")
    page.wait_for_function("(t) => window.gigapoint.camera.target.some((v, i) => v !== t[i])", arg=before["target"], timeout=30_000)
    after = camera(page)
    assert after["distance"] == pytest.approx(before["distance"]) and after["yaw"] == before["yaw"]


def content_box(img: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(img.sum(axis=2) > 60)
    return np.array([xs.min(), ys.min(), xs.max(), ys.max()], np.float64)


def test_screenshot_downloads_a_png_of_the_requested_size(page):
    view = content_box(canvas_pixels(page))
    page.locator("#shot-scale").select_option("2")
    with page.expect_download(timeout=60_000) as dl:
        page.locator("#btn-shot").click()
    path = dl.value.path()
    assert dl.value.suggested_filename == "gigapoint_1280x960.png"
    img = Image.open(path)
    assert img.format == "PNG" and img.size == (1280, 960)
    shot = np.asarray(img.convert("RGB")).astype(np.int16)
    assert (shot.sum(axis=2) > 60).mean() > 0.01
    np.testing.assert_allclose(content_box(shot), view * 2, atol=1280 * 0.03)  # the same view, twice the pixels


def test_touch_one_finger_orbits_two_fingers_pinch(browser, server):
    ctx = browser.new_context(viewport=VIEWPORT, has_touch=True)
    pg = ctx.new_page()
    try:
        pg.goto(server.url)
        wait_full_frame(pg, 0)
        cdp = ctx.new_cdp_session(pg)
        b = canvas_box(pg)
        cx, cy = b["x"] + b["width"] / 2, b["y"] + b["height"] / 2

        def touch(kind, points):
            cdp.send("Input.dispatchTouchEvent", {"type": kind, "touchPoints": [{"x": x, "y": y, "id": i} for i, (x, y) in enumerate(points)]})

        before = camera(pg)
        touch("touchStart", [(cx, cy)])
        for k in range(1, 11):
            touch("touchMove", [(cx + 10 * k, cy)])
        touch("touchEnd", [])
        pg.wait_for_function("(y) => Math.abs(window.gigapoint.camera.yaw - y) > 5", arg=before["yaw"], timeout=30_000)
        before = settle(pg)
        touch("touchStart", [(cx - 40, cy), (cx + 40, cy)])
        for k in range(1, 11):
            touch("touchMove", [(cx - 40 - 8 * k, cy), (cx + 40 + 8 * k, cy)])  # fingers apart: zoom in
        touch("touchEnd", [])
        pg.wait_for_function("(d) => window.gigapoint.camera.distance < d * 0.8", arg=before["distance"], timeout=30_000)
        assert camera(pg)["yaw"] == pytest.approx(before["yaw"])
    finally:
        ctx.close()


def test_a_rejected_setting_shows_an_error_and_the_panel_keeps_the_valid_value(page):
    field = page.locator("#setting-precision_threshold_px")
    field.fill("-5")
    field.press("Enter")
    page.locator("#error").wait_for(state="visible")
    assert "precision_threshold_px" in page.locator("#error").inner_text()
    page.wait_for_function("() => document.getElementById('setting-precision_threshold_px').value === '500'", timeout=30_000)
    field.fill("400")  # a valid value then: taken, and the error about the refused one goes (it stayed 5 s)
    field.press("Enter")
    page.locator("#error").wait_for(state="hidden", timeout=3_000)
    assert page.locator("#setting-precision_threshold_px").input_value() == "400"
    field.fill("500")  # the module's server as the other tests find it
    field.press("Enter")


def test_the_viewer_draws_in_an_iframe_of_a_page_of_any_scheme(browser, server, tmp_path):
    """gp.Viewer's IFrame inside a notebook page: one from file:// (a saved notebook) or a webview
    (VS Code's vscode-webview://) was blocked ('frame-ancestors *' admits http(s) parents only)."""
    parent = tmp_path / "notebook.html"
    parent.write_text(f'<iframe src="{server.url}" width="930" height="480"></iframe>')
    ctx = browser.new_context(viewport=VIEWPORT)
    try:
        pg = ctx.new_page()
        pg.goto(parent.as_uri())
        viewer = pg.wait_for_selector("iframe").content_frame()
        wait_full_frame(viewer, 0)
        assert (canvas_pixels(viewer).sum(axis=2) > 60).mean() > 0.05  # the ground is drawn
    finally:
        ctx.close()


def draw_section(pg, width: str) -> str:
    """The section tool across the marker scene's ground seen from above, the corridor ``width``
    wide, once its numbers are shown; the width the panel offered first."""
    n = frame_no(pg)
    pg.get_by_role("button", name="top").click()
    pg.wait_for_function("() => window.gigapoint.camera.pitch > 89", timeout=30_000)
    wait_full_frame(pg, n)
    b = canvas_box(pg)
    pg.get_by_role("button", name="section").click()
    pg.locator("#section-info").get_by_text("click the line's first end").wait_for(timeout=30_000)
    offered = pg.locator("#section-width").input_value()
    pg.locator("#section-width").fill(width)
    pg.locator("#section-width").press("Enter")
    for k, fx in enumerate((0.3, 0.7), start=1):  # two points of the ground
        pg.mouse.click(b["x"] + b["width"] * fx, b["y"] + b["height"] * 0.5)
        pg.wait_for_function("(k) => document.getElementById('section-info').dataset.points === String(k)", arg=k, timeout=30_000)
    pg.wait_for_function("() => document.getElementById('section-info').dataset.count", timeout=30_000)
    return offered


def image_size(pg, element_id: str) -> list[int]:
    """The pixels of the image an <img> shows (its PNG's, not its box's)."""
    return pg.evaluate("(id) => { const i = document.getElementById(id); return [i.naturalWidth, i.naturalHeight]; }", element_id)


def test_section_tool_shows_the_cross_section_of_two_clicked_points(page, server):
    assert draw_section(page, "3") == "2"  # 1/50 of the ground's 100 units first
    info = page.locator("#section-info")
    (session,) = server.core.sessions.values()
    (x1, y1, _), (x2, y2, _) = session.section
    expected = gigapoint.section(server.core.cloud, (x1, y1, x2, y2), 3.0)
    text = info.inner_text()
    assert f"{len(expected.z):,} points · length {expected.length:.2f} · width 3.00" in text, text
    assert f"heights {expected.z.min():.2f} to {expected.z.max():.2f}" in text and "units unknown" in text, text
    image = page.locator("#section-image")
    assert image.is_visible()
    src = image.get_attribute("src")
    shown = np.asarray(Image.open(io.BytesIO(base64.b64decode(src.split(",", 1)[1]))).convert("RGB"))
    width = int(page.evaluate("() => document.getElementById('section-image').parentElement.clientWidth"))
    assert shown.shape == (160, width, 3) and (shown.max(axis=2) > 0).sum() > 50  # the panel's size, points drawn
    with page.expect_download() as download:
        page.get_by_role("button", name="CSV").click()
    rows = Path(download.value.path()).read_text().splitlines()
    assert rows[0] == "distance_along,offset,z" and len(rows) == 1 + len(expected.z)
    page.keyboard.press("Escape")
    page.locator("#section-panel").wait_for(state="hidden")
    t_end = time.monotonic() + 10
    while session.section and time.monotonic() < t_end:
        time.sleep(0.05)
    assert session.section == []


def test_the_enlarged_section_is_drawn_at_its_size_over_the_view_and_esc_closes_it(page):
    draw_section(page, "3")
    assert image_size(page, "section-image")[1] == 160
    page.get_by_role("button", name="enlarge").click()
    overlay = page.locator("#section-overlay")
    assert overlay.is_visible() and overlay.bounding_box() == canvas_box(page)  # over the whole 3D view
    # drawn again for the overlay's box (not the panel's image stretched): its PNG is the box's size
    page.wait_for_function(
        "() => { const i = document.getElementById('section-large'), b = document.getElementById('section-large-box');"
        " return i.naturalWidth === b.clientWidth && i.naturalHeight === b.clientHeight; }",
        timeout=30_000,
    )
    assert image_size(page, "section-large")[1] > 400 and image_size(page, "section-large")[0] > 600
    assert "points · length" in page.locator("#section-overlay").inner_text()
    page.keyboard.press("Escape")  # closes the overlay, not the tool
    overlay.wait_for(state="hidden")
    assert page.locator("#section-panel").is_visible()
    page.wait_for_function("() => document.getElementById('section-image').naturalHeight === 160", timeout=30_000)  # the panel's again
    page.locator("#section-image").click()  # the image itself enlarges too
    overlay.wait_for(state="visible")
    page.get_by_role("button", name="close").click()
    overlay.wait_for(state="hidden")
    page.keyboard.press("Escape")  # the next Esc ends the tool
    page.locator("#section-panel").wait_for(state="hidden")


def test_a_reconnect_draws_the_section_again(browser):
    scene = marker_scene()
    srv = ViewerServer(scene).start()
    ctx = browser.new_context(viewport=VIEWPORT)
    errors = []
    try:
        pg = ctx.new_page()
        pg.on("pageerror", lambda e: errors.append(str(e)))
        pg.goto(srv.url)
        wait_full_frame(pg, 0)
        draw_section(pg, "3")
        (before,) = srv.core.sessions.values()
        line, count = before.section, pg.locator("#section-info").get_attribute("data-count")
        pg.evaluate("() => delete document.getElementById('section-info').dataset.count")  # set again by the new session's section
        srv.close()
        pg.wait_for_function("() => document.getElementById('status').textContent.startsWith('no answer from the viewer server')", timeout=30_000)
        again = ViewerServer(scene, port=srv.port).start()  # the same address: the page reconnects by itself
        try:
            pg.wait_for_function("() => document.getElementById('section-info').dataset.count", timeout=30_000)
            (after,) = again.core.sessions.values()
            assert after.section == line and after.section_width == 3.0  # the same line, the same corridor
            assert pg.locator("#section-info").get_attribute("data-count") == count
            assert "width 3.00" in pg.locator("#section-info").inner_text()
            assert pg.locator("#section-image").is_visible() and image_size(pg, "section-image")[1] == 160
        finally:
            again.close()
    finally:
        ctx.close()
    assert not errors, errors


def test_unticking_a_class_hides_it_and_ticking_it_shows_it_again(browser, autzen_path):
    """autzen_trim.laz holds classes 1 (unclassified) and 2 (ground): the Classes panel lists
    them with their colours; unticking ground redraws without it, through a lost connection
    too, and ticking it again draws the first frame again."""
    srv = ViewerServer(gigapoint.open(autzen_path), settings=gigapoint.RenderSettings(color_mode="classification")).start()
    ctx = browser.new_context(viewport=VIEWPORT)
    pg = ctx.new_page()
    ground = np.array([160, 82, 45])  # the classification colour mode's class 2

    def ground_pixels(img) -> int:  # (a JPEG's colours: near it)
        return int((np.abs(img - ground).max(axis=2) < 40).sum())

    def drawn_pixels(img) -> int:
        return int((img.max(axis=2) > 40).sum())

    def shown(want, what):  # the frame asked for can come after one asked before it: up to 30 s
        t_end = time.monotonic() + 30
        while not want(canvas_pixels(pg)) and time.monotonic() < t_end:
            time.sleep(0.2)
        assert want(canvas_pixels(pg)), what

    try:
        pg.goto(srv.url)
        wait_full_frame(pg, 0)
        rows = pg.locator("#classes label")
        assert rows.all_text_contents() == ["1 unclassified", "2 ground"]
        assert pg.evaluate("() => getComputedStyle(document.querySelector('#classes label:nth-child(2) .swatch')).backgroundColor") == "rgb(160, 82, 45)"
        time.sleep(0.5)  # (the full frame at rest)
        before = canvas_pixels(pg)
        assert ground_pixels(before) > 2_000
        n = frame_no(pg)
        pg.locator('#classes input[data-code="2"]').uncheck()
        pg.wait_for_function("() => window.gigapoint.settings.hidden_classes.join() === '2'", timeout=30_000)
        wait_full_frame(pg, n)
        shown(lambda img: ground_pixels(img) == 0, "ground still drawn")
        hidden = canvas_pixels(pg)
        assert 1_000 < drawn_pixels(hidden) < drawn_pixels(before) - ground_pixels(before) // 2, (drawn_pixels(hidden), drawn_pixels(before))
        (session,) = srv.core.sessions.values()
        pg.evaluate("() => window.gigapoint.ws.close()")  # the connection drops: the page's new session hides ground too
        pg.wait_for_function("(old) => window.gigapoint.session && window.gigapoint.session !== old", arg=session.id, timeout=30_000)
        pg.wait_for_function("() => window.gigapoint.settings.hidden_classes.join() === '2'", timeout=30_000)
        (again,) = srv.core.sessions.values()
        assert again.settings.hidden_classes == (2,) and not pg.locator('#classes input[data-code="2"]').is_checked()
        n = frame_no(pg)
        pg.locator('#classes input[data-code="2"]').check()
        pg.wait_for_function("() => window.gigapoint.settings.hidden_classes.length === 0", timeout=30_000)
        wait_full_frame(pg, n)
        shown(lambda img: np.array_equal(img, before), "the first frame not drawn again")
        pg.locator("#btn-classes-none").click()  # every class listed hidden: nothing drawn
        shown(lambda img: drawn_pixels(img) == 0, "points drawn with every class hidden")
        pg.locator("#btn-classes-all").click()
        shown(lambda img: np.array_equal(img, before), "the first frame not drawn again")
    finally:
        ctx.close()
        srv.close()


@contextlib.contextmanager
def served_page(browser, cloud):
    """(server, page): ``cloud`` served and a new page of the viewport's size, not opened yet (a
    test may set its clock first); both closed after."""
    srv = ViewerServer(cloud).start()
    ctx = browser.new_context(viewport=VIEWPORT)
    try:
        yield srv, ctx.new_page()
    finally:
        ctx.close()
        srv.close()


def test_the_fly_speed_follows_a_loading_cloud_as_it_grows(browser, strips_loading):
    """The fly speed (a quarter of the scene's radius a second) was set from the bounds the page's
    hello held: a file read west to east flew at its first strip's pace (126/s over a 1000 x 1000
    survey, not 177/s), one served before its first point at 0.25/s. The cloud's line each frame
    carries again as it grows sets it."""
    xyz, cloud, go_on = strips_loading
    with served_page(browser, cloud) as (srv, pg):
        pg.goto(srv.url)
        wait_full_frame(pg, 0)
        first_strip = np.linalg.norm(np.ptp(xyz[:20_000], axis=0)) / 2
        assert pg.locator("#speed-value").text_content() == f"{first_strip * 0.25:.3g}/s" == "126/s"
        go_on.set()
        cloud.wait(timeout=60)
        whole = np.linalg.norm(np.ptp(xyz, axis=0)) / 2
        pg.wait_for_function("(s) => document.getElementById('speed-value').textContent === s", arg=f"{whole * 0.25:.3g}/s", timeout=10_000)
        assert pg.locator("#speed-value").text_content() == "177/s"


@pytest.fixture
def classes_loading(gated_loading):
    """``load(*classes)``: (cloud, gates), a progressive cloud "survey" loading one strip of 20,000
    points of each class of ``classes`` in turn, each held until its gate is set (a slow file); the
    clouds are closed after."""

    def load(*classes):
        gates = [threading.Event() for _ in classes]
        xyz = np.random.default_rng(1).uniform((0, 0, 0), (1000, 1000, 5), (20_000 * len(classes), 3))
        strips = [(xyz[20_000 * k : 20_000 * (k + 1)], {"classification": np.full(20_000, code, np.uint8)}) for k, code in enumerate(classes)]
        return gated_loading(strips, gates), gates

    return load


def class_rows(pg) -> list[str]:
    return pg.locator("#classes label").all_text_contents()


def test_a_cloud_served_before_its_first_points_enables_its_classes_panel_once_they_come(browser, classes_loading):
    """A progressive cloud served before its first points (a slow file: view waits 5 s for them)
    holds no attribute yet: its Classes panel was disabled saying it has no classification, and
    complete, as if for good. It says its first points are not in yet, and lists their classes,
    enabled, once they are."""
    cloud, (first,) = classes_loading(6)
    with served_page(browser, cloud) as (srv, pg):
        pg.goto(srv.url)
        wait_full_frame(pg, 0)
        assert pg.locator("#classes-note").text_content() == "hidden_classes: survey's first points are not in yet; its classes are listed once they are"
        assert class_rows(pg) == [] and pg.locator("#btn-classes-none").is_disabled()
        first.set()
        pg.wait_for_function("() => document.querySelectorAll('#classes label').length > 0", timeout=30_000)
        assert class_rows(pg) == ["6 building"] and pg.locator("#classes-note").text_content() == ""
        assert pg.locator('#classes input[data-code="6"]').is_enabled() and pg.locator("#btn-classes-none").is_enabled()
        pg.locator('#classes input[data-code="6"]').uncheck()  # and it hides the class
        pg.wait_for_function("() => window.gigapoint.settings.hidden_classes.join() === '6'", timeout=30_000)


def test_a_class_that_comes_within_the_class_lists_throttle_is_listed_after_it(browser, classes_loading):
    """The page asks for the class list at most every 2 s, and a change within them is asked for
    once they are past, not dropped: the last points of a load brought a class the list missed for
    good, no frame coming after them to ask again. The page's clock stands still here, so the
    class comes within the 2 s however long the load takes."""
    cloud, (ground, building) = classes_loading(2, 6)
    ground.set()
    cloud.wait_first_points()
    with served_page(browser, cloud) as (srv, pg):
        pg.clock.install(time=0)
        pg.clock.pause_at(1_000)  # (the page's timers run only as the test moves its clock)
        pg.goto(srv.url)
        wait_full_frame(pg, 0)  # loading: the list is not complete, and the frame asks for it again
        pg.clock.run_for(200)  # (that ask, and the page's resize: its frame asks within the 2 s)
        pg.wait_for_function("() => window.gigapoint.classesAsked > 0", polling=50, timeout=30_000)
        assert class_rows(pg) == ["2 ground"]
        building.set()
        assert cloud.wait(timeout=60)
        # the frame of the grown cloud asks for the list again, within the 2 s of the last ask
        pg.wait_for_function("() => window.gigapoint.cloud.points === 40000 && window.gigapoint.cloud.load_progress === 1", polling=50, timeout=30_000)
        assert class_rows(pg) == ["2 ground"]  # (not asked yet)
        pg.clock.run_for(2_000)
        pg.wait_for_function("() => document.querySelectorAll('#classes label').length === 2", polling=50, timeout=30_000)
        assert class_rows(pg) == ["2 ground", "6 building"]
