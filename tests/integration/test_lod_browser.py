"""Potree output loaded by a real Potree 2.0 loader (potree-core + three.js from npm) in headless Chromium."""

from __future__ import annotations

import http.server
import os
import shutil
import subprocess
import threading
from pathlib import Path

import pytest

from gigapoint.io import demo_chunks
from gigapoint.lod import convert

pytestmark = pytest.mark.browser

NPM_PACKAGES = ["potree-core@2.0.15", "three@0.160.0"]
CACHE = Path(os.environ.get("GIGAPOINT_NPM_CACHE", Path.home() / ".cache" / "gigapoint-test-npm"))

PAGE = """<!doctype html><html><body style="margin:0;background:#000">
<canvas id="c" width="320" height="240"></canvas>
<script type="importmap">{"imports": {"three": "/node_modules/three/build/three.module.js"}}</script>
<script type="module">
import * as THREE from "three";
import {Potree} from "/node_modules/potree-core/dist/index.js";
window.__result = null;
try {
  const canvas = document.getElementById("c");
  const renderer = new THREE.WebGLRenderer({canvas, preserveDrawingBuffer: true});
  renderer.setClearColor(0x000000, 1);
  const scene = new THREE.Scene();
  const camera = new THREE.PerspectiveCamera(60, 320 / 240, 1, 100000);
  const potree = new Potree();
  potree.pointBudget = 2000000;
  const pco = await potree.loadPointCloud("metadata.json", "/cloud/");
  pco.material.size = 2;
  pco.material.pointColorType = 0;  // PointColorType.RGB: the points' own colors
  scene.add(pco);
  const box = pco.pcoGeometry.boundingBox;
  const size = new THREE.Vector3(); box.getSize(size);
  const center = new THREE.Vector3(); box.getCenter(center); center.z = 0;
  camera.up.set(0, 0, 1);
  camera.position.set(center.x, center.y - size.x * 0.9, size.x * 0.9);
  camera.lookAt(center);
  let frames = 0;
  const loop = () => {
    const r = potree.updatePointClouds([pco], camera, renderer);
    renderer.render(scene, camera);
    frames++;
    if (frames < 120) { requestAnimationFrame(loop); return; }
    const gl = renderer.getContext();
    const px = new Uint8Array(320 * 240 * 4);
    gl.readPixels(0, 0, 320, 240, gl.RGBA, gl.UNSIGNED_BYTE, px);
    let lit = 0; const sum = [0, 0, 0];
    for (let i = 0; i < px.length; i += 4) if (px[i] + px[i + 1] + px[i + 2] > 0) { lit++; for (let c = 0; c < 3; c++) sum[c] += px[i + c]; }
    window.__result = {visiblePoints: r.numVisiblePoints, visibleNodes: r.visibleNodes.length, lit, mean: sum.map(v => v / Math.max(lit, 1)),
                       numPoints: pco.pcoGeometry.root ? pco.pcoGeometry.root.numPoints : -1};
  };
  loop();
} catch (e) { window.__result = {error: String(e && e.stack || e)}; }
</script></body></html>"""


class _RangeHandler(http.server.SimpleHTTPRequestHandler):
    """Static files with single-range support (Potree 2 reads hierarchy.bin and octree.bin by range)."""

    def log_message(self, *args):
        pass

    def end_headers(self):
        self.send_header("Cache-Control", "no-store")
        super().end_headers()

    def do_GET(self):
        rng = self.headers.get("Range")
        path = Path(self.translate_path(self.path))
        if not rng or not path.is_file():
            return super().do_GET()
        start, _, end = rng.removeprefix("bytes=").partition("-")
        data = path.read_bytes()
        start, end = int(start), min(int(end) if end else len(data) - 1, len(data) - 1)
        body = data[start : end + 1]
        self.send_response(206)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Range", f"bytes {start}-{end}/{len(data)}")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)


def _npm_modules() -> Path:
    mods = CACHE / "node_modules"
    if (mods / "potree-core" / "dist" / "index.js").exists() and (mods / "three" / "build" / "three.module.js").exists():
        return mods
    if not shutil.which("npm"):
        pytest.skip("npm not installed")
    CACHE.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run(
        ["npm", "install", "--no-audit", "--no-fund", "--prefix", str(CACHE), *NPM_PACKAGES], capture_output=True, timeout=300, check=False
    )
    if proc.returncode != 0:
        pytest.skip(f"npm install failed: {proc.stderr.decode()[-300:]}")
    return mods


@pytest.mark.parametrize("encoding", ["DEFAULT", "BROTLI"])
def test_potree_core_loads_and_draws_our_output(tmp_path, encoding):
    playwright = pytest.importorskip("playwright.sync_api")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    mods = _npm_modules()
    root = tmp_path / "site"
    root.mkdir()
    (root / "node_modules").symlink_to(mods)
    convert(list(demo_chunks(60_000)), root / "cloud", format="potree", encoding=encoding, max_leaf=4_000)
    (root / "index.html").write_text(PAGE)
    handler = lambda *a, **k: _RangeHandler(*a, directory=str(root), **k)
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        with playwright.sync_playwright() as p:
            try:
                browser = p.chromium.launch(
                    executable_path=chromium, args=["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
                )
            except Exception as exc:  # noqa: BLE001 - no usable browser binary here: skip
                pytest.skip(f"cannot start Chromium: {str(exc).splitlines()[0]}")
            page = browser.new_page()
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"http://127.0.0.1:{server.server_address[1]}/index.html")
            page.wait_for_function("window.__result !== null", timeout=60_000)
            result = page.evaluate("window.__result")
            browser.close()
    finally:
        server.shutdown()
    assert "error" not in result, result["error"]
    assert not errors, errors
    assert result["visibleNodes"] >= 2 and result["visiblePoints"] > 5_000, result
    assert result["lit"] > 2_000, result
    # (potree-core's default material draws these points white, so colors are not checked here;
    # test_lod_potree.py checks them through gigapoint's own reader.)
