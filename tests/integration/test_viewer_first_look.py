"""The viewer's rough edges of issue #17, in a real headless Chromium: the HUD's rate when idle,
the panel's cloud line, picked coordinates as the file wrote them."""

from __future__ import annotations

import re
import time

import numpy as np
import pytest

pytestmark = [pytest.mark.browser, pytest.mark.timeout(180)]  # the browser: tests/integration/conftest.py
pytest.importorskip("starlette")
pytest.importorskip("uvicorn")

import gigapoint
from gigapoint.viewer.server import ViewerServer

NAME = "a_rather_long_survey_file_name_of_a_point_cloud_tile_0001.las"


@pytest.fixture(scope="module")
def las_cloud(tmp_path_factory):
    """A LAS file at centimetre scale with UTM-sized coordinates (float noise in float64 sums)."""
    import laspy

    g = np.stack(np.meshgrid(np.arange(0, 60, 0.37), np.arange(0, 40, 0.37), indexing="ij"), -1).reshape(-1, 2)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [0.01, 0.01, 0.01]
    header.offsets = [636000.0, 848000.0, 0.0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = g[:, 0] + 636317.71, g[:, 1] + 848935.2, 406.26 + 0.01 * g[:, 0]
    las.red = las.green = las.blue = np.full(len(g), 40000, np.uint16)
    path = tmp_path_factory.mktemp("las") / NAME
    las.write(path)
    return gigapoint.open(path)


@pytest.fixture(scope="module")
def page(browser, las_cloud):
    srv = ViewerServer(las_cloud).start()
    pg = browser.new_page(viewport={"width": 290 + 640, "height": 480})
    errors = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.goto(srv.url)
    pg.wait_for_function("() => document.getElementById('canvas').dataset.full === 'true'", timeout=30_000)
    yield pg
    pg.close()
    srv.close()
    assert not errors, errors


def test_the_hud_keeps_the_last_rate_when_idle(page):
    box = page.locator("#canvas").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 150, y + 20, steps=30)  # frames while moving: a rate
    page.mouse.up()
    page.wait_for_function("() => /fps \\d+/.test(document.getElementById('stats').textContent)", timeout=30_000)
    time.sleep(2.5)  # no new frame for more than a second
    text = page.locator("#stats").inner_text()
    # the latency as well: it was shown as now's ("idle (last fps 52)   latency 12 ms")
    assert "fps 0" not in text and re.match(r"idle \(last fps \d+, latency \d+ ms\)\n", text), text


def test_the_cloud_line_breaks_between_words(page):
    info = page.locator("#cloudinfo")
    assert NAME in info.inner_text() and "batches" in info.inner_text()
    # the counts and their units keep to one line each (no "batche|s"), the long name may break anywhere
    lines_of = page.evaluate("() => [...document.querySelectorAll('#cloudinfo .nowrap')].map((s) => s.getClientRects().length)")
    assert lines_of == [1, 1]


def test_a_picked_point_reads_as_the_file_wrote_it(page, las_cloud):
    page.get_by_role("button", name="top").click()
    page.wait_for_function("() => window.gigapoint.camera.pitch > 89", timeout=30_000)
    time.sleep(1.0)
    box = page.locator("#canvas").bounding_box()
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    pick = page.locator("#pickinfo")
    pick.wait_for(state="visible")
    page.wait_for_function("() => /^x /m.test(document.getElementById('pickinfo').textContent)", timeout=30_000)
    text = pick.inner_text()
    coords = {m.group(1): m.group(2) for m in re.finditer(r"^([xyz]) (\S+)$", text, re.MULTILINE)}
    assert set(coords) == {"x", "y", "z"}, text
    for v in coords.values():
        assert re.fullmatch(r"\d+(\.\d{1,2})?", v), text  # 636317.71, never 636317.7100002308


def test_a_cloud_of_one_batch_reads_one_batch(browser):
    srv = ViewerServer(gigapoint.demo(5_000)).start()  # fewer points than a batch holds
    pg = browser.new_page()
    try:
        pg.goto(srv.url)
        pg.wait_for_function("() => document.getElementById('cloudinfo').textContent.includes('points')", timeout=30_000)
        assert pg.locator("#cloudinfo").inner_text().endswith("5,000 points · 1 batch")  # was "1 batches"
    finally:
        pg.close()
        srv.close()
