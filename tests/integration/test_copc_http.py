"""COPC and EPT over HTTP: a local server with Range support (and ways to misbehave) started
here on 127.0.0.1; renders equal the local files' renders, requests go several at a time over
reused connections through a bounded cache, and every failure is one line naming the URL, in
bounded time."""

from __future__ import annotations

import gzip
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import InputError
from gigapoint.io import http as gphttp
from gigapoint.lod import CopcCloud, EptCloud, convert

pytest.importorskip("httpx")

AUTZEN = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "unit"))
from test_copc_interop import crs_past_a_mib  # a copc-lib file with its WKT EVLR past 1 MiB of EVLRs
from test_ept import make_scene, write_ept  # the EPT trees of the unit tests


class RangeServer:
    """Serves ``root`` on 127.0.0.1 with byte ranges; ``mode`` makes it misbehave: "error" (HTTP
    500), "ignore_range" (200 with the whole file), "short" (closes before the promised body
    ends), "short_206" (a 206 whose body and Content-Length are shorter than asked), "wrong_range"
    (another range than asked), "hang" (never answers), "gzip" (the file gzipped, Content-Encoding:
    gzip, despite Accept-Encoding: identity: ranges of the compressed bytes, as S3 serves an object
    stored so), "gzip_plain" (Content-Encoding: gzip on bytes that are not), "binary" (Content-Encoding:
    binary, a coding httpx passes as sent, on the file as stored), "unknown_size" (Content-Range
    'bytes A-B/*': RFC 9110's file of unknown size), "unknown_size_lies" (that, with the range
    asked in it and the body cut at the file's end), "backwards_range" (Content-Range 'bytes A-(A-5)/*':
    its last byte before its first). ``no_length``: answers
    without Content-Length (the connection closed at their end). ``fail_after``: behave for that many
    requests first. ``route(path)``: (status, Location or None) answered instead of the file
    (redirects, refusals), or None. Counts requests and connections."""

    def __init__(self, root: Path):
        self.root = root
        self.mode = "ok"
        self.fail_after = 0
        self.requests = 0
        self.ranges: list[str] = []
        self.paths: list[str] = []  # as requested, with any query
        self.auths: list[str] = []  # Authorization headers (a URL's user:password@)
        self.ports: set[int] = set()
        self.delay = 0.0  # seconds each answer waits (so that concurrent requests overlap)
        self.etag = None  # sent with each file's bytes when set
        self.rate = 0  # bytes a second each answer's body is sent at (0: at once)
        self.no_length = False
        self.inflight = self.max_inflight = 0
        self.route = None
        self.lock = threading.Lock()
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"  # keep-alive: connections are reused

            def log_message(self, *args):
                pass

            def do_GET(self):
                with server.lock:
                    server.requests += 1
                    server.ports.add(self.client_address[1])
                    n = server.requests
                    server.ranges.append(self.headers.get("Range", ""))
                    server.paths.append(self.path)
                    server.auths.append(self.headers.get("Authorization", ""))
                    server.inflight += 1
                    server.max_inflight = max(server.max_inflight, server.inflight)
                try:
                    time.sleep(server.delay)
                    self.answer(n)
                finally:
                    with server.lock:
                        server.inflight -= 1

            def answer(self, n):
                mode = server.mode if n > server.fail_after else "ok"
                routed = server.route(self.path) if server.route else None
                if routed is not None:
                    self.send_response(routed[0])
                    if routed[1]:
                        self.send_header("Location", routed[1])
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    return
                path = server.root / unquote(self.path.split("?")[0].lstrip("/"))
                if mode == "hang":
                    time.sleep(5)
                    return
                if mode == "error":
                    self.send_response(500)
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    return
                if not path.is_file():
                    self.send_response(404)
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    return
                data = path.read_bytes()
                if mode == "gzip":
                    data = gzip.compress(data, mtime=0)
                rng = self.headers.get("Range")
                if rng and mode != "ignore_range":
                    a, b = (int(v) for v in rng.split("=")[1].split("-"))
                    if a >= len(data):
                        self.send_response(416)
                        self.send_header("Content-Range", f"bytes */{len(data)}")
                        self.send_header("Content-Length", "0")
                        self.end_headers()
                        return
                    asked_end, b = b, min(b, len(data) - 1)
                    if mode == "whole_200" and a == 0 and b == len(data) - 1:  # the range is the whole file: 200
                        self.send_response(200)
                        self.send_header("Content-Length", str(len(data)))
                        self.end_headers()
                        self.wfile.write(data)
                        return
                    if mode == "wrong_range":
                        a, b = a + 1, min(b + 1, len(data) - 1)
                    if mode == "short_206":
                        b = a + max(0, (b - a) // 2)
                    body = data[a : b + 1]
                    self.send_response(206)
                    if mode == "unknown_size":
                        self.send_header("Content-Range", f"bytes {a}-{b}/*")
                    elif mode == "unknown_size_lies":  # the range asked said sent, the body cut at the file's end
                        self.send_header("Content-Range", f"bytes {a}-{asked_end}/*")
                    elif mode == "backwards_range":
                        self.send_header("Content-Range", f"bytes {a}-{a - 5}/*")
                    else:
                        self.send_header("Content-Range", f"bytes {a}-{b}/{len(data)}")
                else:
                    body = data
                    self.send_response(200)
                if server.no_length:
                    self.send_header("Connection", "close")
                    self.close_connection = True
                else:
                    self.send_header("Content-Length", str(len(body)))
                if mode in ("gzip", "gzip_plain"):
                    self.send_header("Content-Encoding", "gzip")
                if mode == "binary":
                    self.send_header("Content-Encoding", "binary")
                if server.etag:
                    self.send_header("ETag", server.etag)
                self.end_headers()
                if mode == "short":
                    self.wfile.write(body[: len(body) // 2])
                    self.close_connection = True
                    return
                step = max(1, server.rate // 20) if server.rate else len(body) + 1
                for i in range(0, len(body), step):  # (a slow link)
                    self.wfile.write(body[i : i + step])
                    if server.rate:
                        self.wfile.flush()
                        time.sleep(0.05)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.httpd.handle_error = lambda request, address: None  # a client that gave up is no news
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def url(self, name: str) -> str:
        return f"http://127.0.0.1:{self.httpd.server_address[1]}/{name}"

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    if not AUTZEN.exists():
        pytest.skip("shared sample autzen_trim.laz not present")
    d = tmp_path_factory.mktemp("http")
    convert([AUTZEN], d / "autzen.copc.laz", format="copc", max_leaf=4_000)
    scene = make_scene(20_000, seed=5)
    write_ept(d / "ept_laz", scene, "laszip")
    write_ept(d / "ept_bin", scene, "binary")
    return d


@pytest.fixture
def server(data):
    s = RangeServer(data)
    yield s
    s.close()


@pytest.fixture
def quick(monkeypatch):
    monkeypatch.setattr(gphttp, "TIMEOUT", 0.5)
    monkeypatch.setattr(gphttp, "RETRIES", 1)


def _frame(cloud, **kw):
    cam = gp.Camera.fit(cloud.bounds, view="iso", width=240, height=160)
    return gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", **kw))


def test_copc_over_http_renders_like_the_local_file(data, server):
    url = server.url("autzen.copc.laz")
    c = gp.open(url)
    assert isinstance(c, CopcCloud) and c.n_points == 110_000
    assert server.requests == 2  # the header and VLRs, then the root hierarchy page
    local = gp.open(data / "autzen.copc.laz")
    for kw in ({"point_budget": 10**9, "lod_threshold_px": 0.0}, {"point_budget": 30_000}):
        a, b = _frame(local, **kw), _frame(c, **kw)
        assert a.stats.points_processed == b.stats.points_processed
        np.testing.assert_array_equal(a.image, b.image)
    # every request a single range; neighbouring chunks joined; a few reused connections
    assert all(r.startswith("bytes=") for r in server.ranges)
    assert server.requests < 2 + c.node_reads
    assert len(server.ports) <= gphttp.WORKERS + 1
    # drawn again from the arena and the range cache: no new request
    c.arena = None
    before = server.requests
    _frame(c, point_budget=10**9, lod_threshold_px=0.0)
    assert server.requests == before
    c.close()


def test_a_closed_url_cloud_says_so_when_a_frame_needs_more_of_it(server):
    c = gp.open(server.url("autzen.copc.laz"))
    _frame(c, point_budget=5_000)
    c.close()
    before = server.requests
    with pytest.raises(InputError, match=r"^http://127\.0\.0\.1:\d+/autzen\.copc\.laz: bytes [\d,]+\.\.[\d,]+ not read: the cloud was closed \(close\(\)\); open it again to read more of it$"):
        _frame(c, point_budget=10**9, lod_threshold_px=0.0)  # (httpx's RuntimeError: "Cannot send a request, as the client has been closed.")
    assert server.requests == before


def test_several_requests_in_flight(server, monkeypatch):
    monkeypatch.setattr(gphttp, "MERGE_GAP", -1)  # one request per node
    c = gp.open(server.url("autzen.copc.laz"))
    server.delay = 0.05
    before = server.requests
    t = time.perf_counter()
    _frame(c, point_budget=10**9, lod_threshold_px=0.0)
    n = server.requests - before
    assert n == c.node_reads > 10
    assert server.max_inflight >= 2 and len(server.ports) <= gphttp.WORKERS + 1
    assert time.perf_counter() - t < n * 0.05  # not one after the other
    c.close()


def test_url_through_a_path_and_the_cli(data, server, tmp_path):
    url = server.url("autzen.copc.laz")
    c = gp.open(Path(url))  # what `gigapoint view URL` / `render URL` pass: typer makes a Path of it
    assert isinstance(c, CopcCloud)
    r = subprocess.run([sys.executable, "-m", "gigapoint.cli", "info", url], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "COPC 1.4" in r.stdout and "per level:" in r.stdout and url in r.stdout
    out = tmp_path / "http.png"
    r = subprocess.run(
        [sys.executable, "-m", "gigapoint.cli", "render", url, "-o", str(out), "--width", "160", "--height", "120"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 500


def test_a_section_over_http_reads_only_the_nodes_meeting_the_corridor(data, server):
    """gp.section of a COPC URL and an EPT one: the local file's section, through ranged reads of the meeting nodes (lod/query.py)."""
    local = gp.open(data / "autzen.copc.laz")
    lo, hi = local.bounds
    line = (float(lo[0]), float(lo[1]) + 100, float(lo[0]) + 400, float(lo[1]) + 300)  # a short corridor, 6 feet wide
    want = gp.section(data / "autzen.copc.laz", line, 6)
    c = gp.open(server.url("autzen.copc.laz"))
    cut = gp.section(c, line, 6)
    assert cut.cloud.n_points == want.cloud.n_points > 100
    np.testing.assert_allclose(np.sort(cut.z), np.sort(want.z), rtol=0, atol=1e-6)
    assert all(r.startswith("bytes=") for r in server.ranges)  # no whole-file download
    c.load_hierarchy()
    assert 0 < c.node_reads < np.count_nonzero(c.counts) / 3
    c.close()
    scene = gp.open(data / "ept_laz")
    lo, hi = scene.bounds
    line = (float(lo[0]), float(lo[1]) + 40, float(hi[0]), float(lo[1]) + 60)
    e = gp.open(server.url("ept_laz/ept.json"))
    assert np.array_equal(np.sort(gp.section(e, line, 4).z), np.sort(gp.section(scene, line, 4).z))
    e.close()


@pytest.mark.parametrize("folder", ["ept_laz", "ept_bin"])
def test_ept_over_http_renders_like_the_local_dataset(data, server, folder):
    local = gp.open(data / folder)
    for name in (f"{folder}/ept.json", f"{folder}/"):
        c = gp.open(server.url(name))
        assert isinstance(c, EptCloud) and c.n_points == local.n_points
        a = _frame(local, point_budget=10**9, lod_threshold_px=0.0)
        b = _frame(c, point_budget=10**9, lod_threshold_px=0.0)
        assert b.stats.points_processed == local.n_points
        np.testing.assert_array_equal(a.image, b.image)
        assert all(r == "" for r in server.ranges)  # whole files, no range
        c.close()


@pytest.mark.parametrize("name", ["1.2-with-color", "ellipsoid-binary-2k", "ellipsoid-zstandard-2k", "bcbf", "1.2-with-color.copc.laz"])
def test_pdals_datasets_over_http_render_like_the_local_ones(name):
    """Entwine's and PDAL's (tests/unit/data/pdal_ept): the same pixels over HTTP."""
    if "zstandard" in name:
        pytest.importorskip("zstandard")
    root = Path(__file__).resolve().parents[1] / "unit" / "data" / "pdal_ept"
    s = RangeServer(root)
    try:
        local, c = gp.open(root / name), gp.open(s.url(name if name.endswith(".laz") else f"{name}/"))
        assert c.n_points == local.n_points and c.meta["crs"] == local.meta["crs"]
        a = _frame(local, point_budget=10**9, lod_threshold_px=0.0)
        b = _frame(c, point_budget=10**9, lod_threshold_px=0.0)
        assert b.stats.points_processed == a.stats.points_processed > 0
        np.testing.assert_array_equal(a.image, b.image)
        c.close()
    finally:
        s.close()


def test_an_ept_folder_url_through_the_cli(data, server, tmp_path):
    """``gigapoint info http://host/ept/`` was "http://host/ept: HTTP 404 Not Found for bytes
    0..65,536": typer's Path drops the folder's '/', and the URL was read as a COPC file. A URL
    whose last part has no suffix that is not a file (404) is now tried as an EPT folder."""
    url = server.url("ept_laz/")
    r = subprocess.run([sys.executable, "-m", "gigapoint.cli", "info", url], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "EPT (laszip)" in r.stdout and "20,000" in r.stdout
    for name in ("ept_bin", "ept_bin?t=1"):  # the folder without its '/' in Python too
        c = gp.open(server.url(name))
        assert isinstance(c, EptCloud) and c.n_points == 20_000
        c.close()
    with pytest.raises(InputError, match=r"/nothing: HTTP 404 Not Found for bytes 0\.\.65,536$"):
        gp.open(server.url("nothing"))  # neither: the first error, naming the URL as given


def test_a_copc_url_with_a_trailing_slash(server):
    """``gp.open("http://host/scan.copc.laz/")`` was "…/scan.copc.laz/ept.json: HTTP 404" (a '/'
    names an EPT folder) while ``gigapoint info`` of the same URL opened the file (typer's Path
    drops the '/'); the file is now tried too, and the first error kept when it is not there."""
    for name in ("autzen.copc.laz/", "autzen.copc.laz/?t=1"):
        c = gp.open(server.url(name))
        assert isinstance(c, CopcCloud) and c.n_points == 110_000
        c.close()
    with pytest.raises(InputError, match=r"/nothing\.copc\.laz/ept\.json: HTTP 404 Not Found for the file$"):
        gp.open(server.url("nothing.copc.laz/"))


def test_a_small_copc_file_answered_whole_with_200(server, tmp_path):
    """A COPC file shorter than the head read (64 KiB): servers may answer a range that covers
    the whole file with 200 and the file, as RFC 9110 allows; that was "the server ignored the
    range request" and the file could not be opened."""
    rng = np.random.default_rng(1)
    xyz = rng.random((400, 3)) * (50, 40, 10) + (1000, 2000, 30)
    small = server.root / "small.copc.laz"
    convert(gp.from_arrays(xyz), small, format="copc")
    assert small.stat().st_size < gphttp_head()
    server.mode = "whole_200"
    c = gp.open(server.url("small.copc.laz"))
    assert isinstance(c, CopcCloud) and c.n_points == 400
    assert _frame(c, point_budget=10**9, lod_threshold_px=0.0).stats.points_processed == 400
    c.close()
    small.unlink()


def test_a_small_copc_file_of_unknown_size(server, tmp_path):
    """Ranges answered with 'bytes 0-N/*' (RFC 9110: a file of unknown size) and, past the file's
    end, a body cut where the file ends: the head of a file under 64 KiB was "the server
    answered bytes 0..N to a request for bytes 0..65,536" and it could not be opened; a body that
    is not the range its Content-Range says is still refused."""
    rng = np.random.default_rng(2)
    small = server.root / "small_unknown.copc.laz"
    convert(gp.from_arrays(rng.random((300, 3)) * (50, 40, 10) + (1000, 2000, 30)), small, format="copc")
    size = small.stat().st_size
    assert size < gphttp_head()
    server.mode = "unknown_size"
    c = gp.open(server.url(small.name))
    assert isinstance(c, CopcCloud) and c.n_points == 300
    assert _frame(c, point_budget=10**9, lod_threshold_px=0.0).stats.points_processed == 300
    c.close()
    server.mode = "unknown_size_lies"
    with pytest.raises(InputError) as e:
        gp.open(server.url(small.name))
    assert str(e.value) == f"{server.url(small.name)}: short read: {size:,} of the {gphttp_head():,} bytes asked for (bytes 0..{gphttp_head():,})"
    small.unlink()


def test_a_content_range_ending_before_it_starts_is_refused_as_malformed(server):
    """'bytes 10-5/*' to a read that may come short (a head read's) was taken for the file's end:
    -4 bytes expected, then "the server sent more than the -4 bytes asked for"."""
    (server.root / "backwards.bin").write_bytes(bytes(range(200)))
    url = server.url("backwards.bin")
    server.mode = "backwards_range"
    client = gphttp.HttpClient()
    with pytest.raises(InputError) as e:
        client.get(url, 10, 100, allow_short=True)
    assert str(e.value) == f"{url}: answer to a range request has no valid Content-Range header ('bytes 10-5/*')"
    client.close()


def gphttp_head() -> int:
    from gigapoint.lod.copc import HEAD_READ

    return HEAD_READ


def test_a_potree_metadata_url_is_named_as_one(server):
    """``gp.open('http://host/potree/metadata.json')`` said "ept.json lacks 'bounds', 'dataType',
    ..." of a file that is no ept.json: Potree octrees open from local folders only."""
    d = server.root / "potree"
    d.mkdir(exist_ok=True)
    (d / "metadata.json").write_text('{"version": "2.0", "name": "x", "points": 5, "hierarchy": {}, "encoding": "DEFAULT"}')
    url = server.url("potree/metadata.json")
    with pytest.raises(InputError) as e:
        gp.open(url)
    assert str(e.value) == f"{url}: a Potree metadata.json; Potree octrees open from a local folder (over HTTP: COPC files and EPT datasets)"


def test_a_potree_octrees_data_file_url_is_named_as_one(server):
    """``…/tree/octree.bin`` (or hierarchy.bin) was "not a COPC file (a file that starts with ...)":
    it is named as a Potree octree's file, which opens from a local folder."""
    d = server.root / "potree_bin"
    d.mkdir(exist_ok=True)
    for name in ("octree.bin", "hierarchy.bin"):
        (d / name).write_bytes(bytes(range(256)) * 4)
        url = server.url(f"potree_bin/{name}")
        for given in (url, url + "?sig=s"):
            with pytest.raises(InputError) as e:
                gp.open(given)
            shown = gphttp.shown_url(given)
            assert str(e.value) == f"{shown}: a Potree octree's {name}, part of its folder; Potree octrees open from a local folder (over HTTP: COPC files and EPT datasets)"


def test_ept_url_with_a_query_string(data, server):
    """``…/ept.json?sig=…`` (a shared-access token, GitHub's ``?raw=true``) was taken for a COPC
    file ("not a COPC file (a file that starts with b'{"bo')"); the token goes on to the
    hierarchy and node files beside it, as a container-wide token needs."""
    for name in ("ept_laz/ept.json?sig=a%2Fb&v=2", "ept_laz/?sig=a%2Fb&v=2"):
        server.paths.clear()
        c = gp.open(server.url(name))
        assert isinstance(c, EptCloud) and c.n_points == 20_000
        assert _frame(c, point_budget=10**9, lod_threshold_px=0.0).stats.points_processed == 20_000
        assert server.paths[0] == "/ept_laz/ept.json?sig=a%2Fb&v=2"
        assert len(server.paths) > 3 and all(p.endswith("?sig=a%2Fb&v=2") for p in server.paths)
        c.close()
    assert gphttp.HttpFile("http://h/e/ept.json?t=1").sibling("ept-data/0-0-0-0.laz?x=2").url == "http://h/e/ept-data/0-0-0-0.laz?x=2"


# --------------------------------------------------------------------------- failures


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    "mode, match",
    [
        ("error", "HTTP 500"),
        ("ignore_range", "ignored the range request"),
        ("short", "short read"),
        ("short_206", "answered bytes"),
        ("wrong_range", "answered bytes"),
        ("hang", "no answer within 0.5 s"),
    ],
)
def test_a_misbehaving_server_fails_in_one_line_naming_the_url(server, quick, mode, match):
    url = server.url("autzen.copc.laz")
    server.mode = mode
    t = time.perf_counter()
    with pytest.raises(InputError, match=match) as e:
        gp.open(url)
    assert url in str(e.value) and "\n" not in str(e.value)
    assert time.perf_counter() - t < 20


@pytest.mark.timeout(60)
@pytest.mark.parametrize("mode", ["error", "short", "hang"])
def test_a_failure_while_drawing_raises_instead_of_a_partial_image(server, quick, mode):
    url = server.url("autzen.copc.laz")
    c = gp.open(url)
    server.mode, server.fail_after = mode, server.requests  # from now on
    with pytest.raises(InputError) as e:
        _frame(c, point_budget=10**9, lod_threshold_px=0.0)
    assert url in str(e.value) and "\n" not in str(e.value)
    server.mode = "ok"  # the server recovers: the same cloud draws completely
    f = _frame(c, point_budget=10**9, lod_threshold_px=0.0)
    assert f.stats.points_processed == 110_000


def test_a_file_changed_on_the_server_while_it_is_read(data, server):
    """A COPC file replaced on the server after it was opened: the new bytes were decoded with
    the old header and hierarchy (a longer file drew without a word, a rewritten one failed as
    "cannot decode node"); another size or ETag than the first answer's is now named."""
    f = server.root / "changing.copc.laz"
    f.write_bytes((data / "autzen.copc.laz").read_bytes())
    url = server.url("changing.copc.laz")
    size = f.stat().st_size
    for change, message in (("size", f"its size went from {size:,} to {size + 10:,} bytes"), ("etag", 'ETag "v1" became "v2"')):
        server.etag = '"v1"'
        c = gp.open(url)
        if change == "size":
            f.write_bytes(f.read_bytes() + bytes(10))
        else:
            server.etag = '"v2"'
        with pytest.raises(InputError) as e:
            _frame(c, point_budget=10**9, lod_threshold_px=0.0)
        assert str(e.value) == f"{url}: the file changed on the server while it was read ({message}); open it again"
        c.close()
    c = gp.open(url)  # opened again: the new file draws
    assert _frame(c, point_budget=10**9, lod_threshold_px=0.0).stats.points_processed == 110_000
    c.close()
    f.unlink()
    server.etag = None


@pytest.mark.timeout(60)
def test_a_slow_link_is_given_time_by_the_bytes_asked(data, server, quick, monkeypatch):
    """Each request had 30 s (3 x TIMEOUT) whatever its size, and a frame's requests share the
    link: a frame of 10 M points (~120 MB) failed under 32 Mbit/s. Here, scaled down: 3 x 0.5 s,
    nodes of up to 1 MB at 400 KB/s a connection."""
    server.rate = 400_000
    monkeypatch.setattr(gphttp, "MIN_RATE", 200_000)  # half the link: 1 MB may take 1.5 + 5 s
    c = gp.open(server.url("autzen.copc.laz"))
    assert _frame(c, point_budget=10**9, lod_threshold_px=0.0).stats.points_processed == 110_000
    c.close()
    monkeypatch.setattr(gphttp, "MIN_RATE", 10_000_000)  # far faster than the link: a node is cut off
    c = gp.open(server.url("autzen.copc.laz"))
    with pytest.raises(InputError, match=r"autzen\.copc\.laz: bytes [\d,]+\.\.[\d,]+ did not arrive within \d\.\d s$"):
        _frame(c, point_budget=10**9, lod_threshold_px=0.0)
    c.close()
    server.rate = 0


@pytest.mark.timeout(30)
def test_a_server_trickling_its_headers_is_given_up_on(quick, monkeypatch):
    """A server that sends a header line every 0.2 s and never ends them: httpx's timeouts are per
    read, and the deadline was checked only between the body's parts, so this hung forever."""
    import socket

    listener = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def trickle():
        conn, _ = listener.accept()
        with conn:
            conn.recv(65536)
            conn.sendall(b"HTTP/1.1 206 Partial Content\r\n")
            while not stop.wait(0.2):
                try:
                    conn.sendall(b"X-Slow: 1\r\n")
                except OSError:
                    return

    threading.Thread(target=trickle, daemon=True).start()
    monkeypatch.setattr(gphttp, "MIN_RATE", 1 << 30)  # the deadline: 3 x 0.5 s, whatever the size
    url = f"http://127.0.0.1:{listener.getsockname()[1]}/x.copc.laz"
    t = time.perf_counter()
    try:
        with pytest.raises(InputError) as e:
            gp.open(url)
    finally:
        stop.set()
        listener.close()
    assert str(e.value) == f"{url}: bytes 0..65,536 did not arrive within 1.5 s"
    assert time.perf_counter() - t < 5


@pytest.mark.timeout(60)
def test_missing_files_over_http(server, quick):
    with pytest.raises(InputError, match="HTTP 404") as e:
        gp.open(server.url("nothing.copc.laz"))
    assert "nothing.copc.laz" in str(e.value)
    with pytest.raises(InputError, match="HTTP 404"):
        gp.open(server.url("nothing/ept.json"))


def test_the_range_cache_is_bounded():
    cache = gphttp._LruBytes(100)
    for i in range(10):
        cache.put(i, bytes(30))
    assert cache.held <= 100 and cache.get(9) is not None and cache.get(0) is None
    cache.put("big", bytes(200))  # larger than the whole cache: not kept
    assert cache.get("big") is None and cache.held <= 100


def test_urls_gigapoint_does_not_read_are_one_line(tmp_path):
    """'http://[::1' reached the CLI as "internal error: InvalidURL" (exit 2); 'ftp://h/x.laz' was
    read as the local path 'ftp:/h/x.laz' ("no such file")."""
    with pytest.raises(InputError, match=r"^http://\[::1: not a valid URL \(Invalid port"):
        gp.open("http://[::1")
    for url in ("ftp://host/x.laz", "s3://bucket/a.copc.laz"):
        for given in (url, Path(url)):  # (the CLI's typer makes a Path of it)
            with pytest.raises(InputError, match=rf"^{url}: only http:// and https:// URLs are read \(COPC and EPT octrees\)$"):
                gp.open(given)
        with pytest.raises(InputError, match=rf"^{url}: only http://"):
            gp.open([url], progressive=True)
    r = subprocess.run([sys.executable, "-m", "gigapoint.cli", "render", "ftp://host/x.laz", "-o", str(tmp_path / "x.png")],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 1 and r.stderr.strip() == "error: ftp://host/x.laz: only http:// and https:// URLs are read (COPC and EPT octrees)"


def test_a_copc_file_cut_short_on_the_server(server, tmp_path):
    """A server whose COPC file is shorter than its header says (an upload stopped part-way):
    as a local file cut there (test_copc_cut.py), the nodes before the cut are drawn with one
    warning naming the URL, and a cut before the hierarchy is one line naming the URL and both
    sizes; never a hang or a traceback."""
    import re

    from test_copc_cut import _drawn, _hierarchy_first, _layout, _whole_points, _write

    from gigapoint.errors import GigapointWarning

    flat = _write(tmp_path / "flat.copc.laz")
    b = _hierarchy_first(flat, tmp_path / "first.copc.laz").read_bytes()
    hdr, info, _ = _layout(b)
    data, evlr = int(hdr["offset_to_point_data"]), int(hdr["start_of_first_evlr"])
    end = (data + evlr) // 2
    want, _ = _whole_points(b, end)
    (server.root / "first_cut.copc.laz").write_bytes(b[:end])
    whole = flat.read_bytes()
    (server.root / "flat_cut.copc.laz").write_bytes(whole[:end])
    try:
        url = server.url("first_cut.copc.laz")
        with pytest.warns(GigapointWarning, match=rf"^{re.escape(url)}: truncated COPC file: it has {end:,} bytes, its header says at least {evlr + 60:,}: [\d,]+ points in \d+ nodes past the cut are left out$"):
            c = gp.open(url)
        assert 0 < want and _drawn(c) == want
        c.close()
        url = server.url("flat_cut.copc.laz")
        with pytest.raises(InputError, match=rf"^{re.escape(url)}: truncated COPC file: it has {end:,} bytes, its header says at least {len(whole):,} \(its hierarchy, .* is cut off: no node can be found\)$"):
            gp.open(url)
        # cut in its hierarchy, its points whole: a local file reads as plain LAZ, a URL (no LAZ reader) stays this error
        end = int(_layout(whole)[1]["root_hier_offset"]) + 40
        (server.root / "flat_cut.copc.laz").write_bytes(whole[:end])
        with pytest.raises(InputError, match=rf"^{re.escape(url)}: truncated COPC file: it has {end:,} bytes, .* no node can be found\)$"):
            gp.open(url)
    finally:
        (server.root / "first_cut.copc.laz").unlink()
        (server.root / "flat_cut.copc.laz").unlink()


# --------------------------------------------------------------------------- secrets in URLs

SECRET_URL = "http://reader:hunter2@127.0.0.1:{port}/{name}?sig=SIG%2Fsecret&se=2031"


def _no_secret(text: str, port: int, name: str) -> None:
    assert "hunter2" not in text and "SIG" not in text and "2031" not in text, text
    assert f"reader:***@127.0.0.1:{port}/{name}" in text, text


def test_shown_url_hides_passwords_and_query_values():
    s = gphttp.shown_url
    assert s("https://user:secret@host/x.copc.laz") == "https://user:***@host/x.copc.laz"
    assert s("https://u:p@ss@h:8/e/ept.json?X-Amz-Signature=ab%2F&token=t&raw#k=v") == "https://u:***@h:8/e/ept.json?X-Amz-Signature=***&token=***&***#k=***"
    assert s(Path("https://u:pw@h/a.laz?key=k")) == "https:/u:***@h/a.laz?key=***"  # (the CLI's Path of a URL)
    assert s("http://user:sec/ret@h:1/x") == "http://user:***@h:1/x"  # a raw '/' in the password
    assert s("http://u:1234@[::1]:80/x") == "http://u:***@[::1]:80/x"
    # a token as the user name (GitHub's, GitLab's) was shown whole
    assert s("https://ghp_T0KEN@raw.example/x.laz?a=1") == "https://***@raw.example/x.laz?a=***"
    assert s("https://me@mail.example@h/x") == "https://***@h/x"
    assert s("http://user:pw@host/x") == "http://user:***@host/x"
    assert s("http://token@host/p?q=@") == "http://***@host/p?q=***"
    # the user info ends at the first '/' (RFC 3986): 'h:8080/a@b' was shown as 'h:***@b'; a
    # password of digits up to a raw '/' is a port and a path there, as httpx reads it
    for same in ("http://h:8080/a@b", "http://user:1234/x@h:1/y", "http://h/x?", "http://[::1", "http://[::1]:80/a@b", "http://h/a:b@c", "http://h/a@b",
                 "/data/a?b=1.laz", "C:/x?y=1", "scan.laz"):  # fmt: skip
        assert s(same) == same
    with pytest.raises(InputError) as e:  # httpx: "Invalid port: 'sec'", a piece of the password
        gp.open("http://user:sec/ret@127.0.0.1:1/x.copc.laz")
    assert str(e.value) == "http://user:***@127.0.0.1:1/x.copc.laz: not a valid URL"


def test_a_url_with_a_password_and_a_token_is_never_shown_whole(data, server, quick, capsys, tmp_path):
    """``https://user:secret@host/x.copc.laz?sig=...`` (how signed COPC files are shared) was echoed
    whole in errors, ``gigapoint info``, the viewer's name and the cloud's repr; the request still
    goes to the URL itself (its query and its credentials as Basic auth)."""
    from gigapoint.cli import main

    port = server.httpd.server_address[1]
    url = SECRET_URL.format(port=port, name="autzen.copc.laz")
    c = gp.open(url)
    assert server.paths[0] == "/autzen.copc.laz?sig=SIG%2Fsecret&se=2031"
    assert server.auths[0] == "Basic cmVhZGVyOmh1bnRlcjI="  # reader:hunter2
    assert c.name == "autzen.copc.laz"
    _no_secret(repr(c) + c.source_name, port, "autzen.copc.laz?sig=***&se=***")
    c.close()
    c = gp.open(SECRET_URL.format(port=port, name="ept_bin/"))
    assert c.name == "ept_bin" and server.paths[-1] == "/ept_bin/ept-hierarchy/0-0-0-0.json?sig=SIG%2Fsecret&se=2031"
    _no_secret(c.node_file(int(c.keys[0])), port, "ept_bin/ept-data/0-0-0-0.bin?sig=***&se=***")
    c.close()
    assert main(["info", url]) == 0
    out = capsys.readouterr().out
    _no_secret(out, port, "autzen.copc.laz?sig=***&se=***")
    assert "COPC 1.4" in out
    assert main(["info", "--json", url, SECRET_URL.format(port=port, name="nothing.copc.laz")]) == 1
    out, err = capsys.readouterr()
    _no_secret(out.splitlines()[-1], port, "nothing.copc.laz")
    _no_secret(err + out, port, "")
    for name, mode, match in (("nothing.copc.laz", "ok", "HTTP 404"), ("autzen.copc.laz", "error", "HTTP 500"), ("e/ept.json", "ok", "HTTP 404")):
        server.mode = mode
        with pytest.raises(InputError, match=match) as e:
            gp.open(SECRET_URL.format(port=port, name=name))
        _no_secret(str(e.value), port, f"{name}?sig=***&se=***")
    server.mode = "ok"
    with pytest.raises(InputError, match="a URL opens alone") as e:
        gp.open(url, progressive=True)
    _no_secret(str(e.value), port, "autzen.copc.laz?sig=***&se=***")
    for other in ("ftp", "s3"):
        with pytest.raises(InputError, match="only http") as e:
            gp.open(url.replace("http", other, 1))
        _no_secret(str(e.value), port, "autzen.copc.laz?sig=***&se=***")
    with pytest.raises(InputError, match="an input must be a path") as e:
        convert([url], tmp_path / "o")
    _no_secret(str(e.value), port, "autzen.copc.laz?sig=***&se=***")
    assert main(["render", url, "--chunked", "-o", str(tmp_path / "x.png")]) == 1
    err = capsys.readouterr().err
    assert "is an octree, drawn as stored" in err
    _no_secret(err, port, "autzen.copc.laz?sig=***&se=***")


# --------------------------------------------------------------------------- redirects


def _moved(prefix: str, to: str, only: str | None = None):
    """A route: paths under ``prefix`` (only ``only`` when given) 302 to the same under ``to``."""
    return lambda path: (302, to + path[len(prefix) :]) if path.startswith(prefix) and (only is None or path == only) else None


def test_an_ept_json_redirected_alone_has_its_files_where_it_led(data, server):
    """``/latest/ept.json`` -> ``/v3/ept.json`` with only ept.json redirected: the hierarchy and
    data files were asked beside the URL given ("…/latest/ept-hierarchy/0-0-0-0.json: HTTP 404");
    they are beside where the redirect led, each asked once."""
    server.route = _moved("/latest/", "/ept_laz/", only="/latest/ept.json")
    c = gp.open(server.url("latest/ept.json"))
    assert isinstance(c, EptCloud) and c.n_points == 20_000
    a = _frame(gp.open(data / "ept_laz"), point_budget=10**9, lod_threshold_px=0.0)
    b = _frame(c, point_budget=10**9, lod_threshold_px=0.0)
    np.testing.assert_array_equal(a.image, b.image)
    assert server.paths[:2] == ["/latest/ept.json", "/ept_laz/ept.json"]
    assert len(server.paths) > 4 and all(p.startswith("/ept_laz/") for p in server.paths[1:])
    assert c.node_file(int(c.keys[0])) == server.url("ept_laz/ept-data/0-0-0-0.laz")
    c.close()


def test_a_moved_ept_tree_is_read_where_it_went_without_a_redirect_per_file(data, server):
    """``/old/*`` -> ``/ept_laz/*``, the query kept: worked before at two requests a file (each
    redirected); now one redirect, for ept.json."""
    server.route = _moved("/old/", "/ept_laz/")
    c = gp.open(server.url("old/ept.json?t=1"))
    assert _frame(c, point_budget=10**9, lod_threshold_px=0.0).stats.points_processed == 20_000
    files = len(set(server.paths)) - 1
    assert server.paths[:2] == ["/old/ept.json?t=1", "/ept_laz/ept.json?t=1"] and files > 4
    assert server.requests == files + 1  # (before: 2 x files)
    assert all(p.startswith("/ept_laz/") and p.endswith("?t=1") for p in server.paths[1:])
    c.close()


def test_a_redirect_to_signed_urls_is_followed_afresh_for_every_file(data, server):
    """``/s/ept.json`` -> ``/ept_laz/ept.json?sig=…`` (a store's signed URL: one signature a file,
    and the store refuses the others, 403): the files beside are asked beside the URL given, each
    redirected to its own signed URL; a signed COPC file's ranges are asked at the URL given every
    time (a signature expires), not at the signed URL of its first answer."""
    import zlib

    def store(to):  # "/s/x" -> "<to>x?sig=<crc of x>"; under <to>, another signature is refused
        def route(path):
            if path.startswith("/s/"):
                return 302, f"{to}{path[3:]}?sig={zlib.crc32(path[3:].encode())}"
            name, _, sig = path[len(to) :].partition("?sig=")
            return None if sig == str(zlib.crc32(name.encode())) else (403, None)

        return route

    server.route = store("/ept_laz/")
    c = gp.open(server.url("s/ept.json"))
    assert _frame(c, point_budget=10**9, lod_threshold_px=0.0).stats.points_processed == 20_000
    given = sorted(p[3:] for p in server.paths if p.startswith("/s/"))
    signed = sorted(p.split("?")[0][9:] for p in server.paths if not p.startswith("/s/"))
    assert given == signed and len(given) > 4 and len(set(given)) == len(given)  # each file once, redirected
    c.close()
    server.paths.clear()
    server.route = store("/")
    c = gp.open(server.url("s/autzen.copc.laz"))
    _frame(c, point_budget=30_000)
    n = len(server.paths) // 2  # each range redirected and signed afresh
    assert n > 2 and sorted(server.paths) == ["/autzen.copc.laz?sig=1766382414"] * n + ["/s/autzen.copc.laz"] * n
    c.close()


def test_an_ept_json_redirected_alone_to_a_folder_token_has_its_files_beside_it(data, server):
    """``/az/ept.json`` -> ``/ept_laz/ept.json?sv=…&sig=…`` (ept.json alone redirected to an
    Azure SAS URL whose token reads the container): the hierarchy was asked beside the URL given
    ("…/az/ept-hierarchy/0-0-0-0.json: HTTP 404"). A sibling not found there is asked beside the
    signed URL, with its token; once found there, so are the later files, each asked once. The
    token is never shown."""
    token = "sv=2031-01-01&sig=S3CRET%2Fsig"

    def azure(path):  # only ept.json redirects; the container refuses what lacks the token
        if path == "/az/ept.json":
            return 302, f"/ept_laz/ept.json?{token}"
        return (403, None) if path.startswith("/ept_laz/") and not path.endswith(f"?{token}") else None

    server.route = azure
    c = gp.open(server.url("az/ept.json"))
    assert isinstance(c, EptCloud) and c.n_points == 20_000
    a = _frame(gp.open(data / "ept_laz"), point_budget=10**9, lod_threshold_px=0.0)
    b = _frame(c, point_budget=10**9, lod_threshold_px=0.0)
    np.testing.assert_array_equal(a.image, b.image)
    assert server.paths[:4] == ["/az/ept.json", f"/ept_laz/ept.json?{token}", "/az/ept-hierarchy/0-0-0-0.json", f"/ept_laz/ept-hierarchy/0-0-0-0.json?{token}"]
    later = server.paths[4:]
    assert len(later) > 4 and len(set(later)) == len(later) and all(p.startswith("/ept_laz/") and p.endswith(f"?{token}") for p in later)
    assert c.node_file(int(c.keys[0])) == server.url("ept_laz/ept-data/0-0-0-0.laz?sv=***&sig=***")
    c.close()
    root_page = data / "ept_laz" / "ept-hierarchy" / "0-0-0-0.json"
    root_page.rename(data / "root-page.away")
    try:  # missing beside both: the 404 of the URL given, as before
        with pytest.raises(InputError) as e:
            gp.open(server.url("az/ept.json"))
        assert str(e.value) == f"{server.url('az/ept-hierarchy/0-0-0-0.json')}: HTTP 404 Not Found for the file"
    finally:
        (data / "root-page.away").rename(root_page)

def test_a_sibling_only_beside_the_signed_url_is_found_by_read_many(data, server):
    """The fallback beside the signed URL (the test above) was ``read_all``'s alone: ``read_many``
    asked the URL given and failed with its 404. Its ranges now fall back as well, and once found
    there so are the later siblings."""
    token = "sv=2031-01-01&sig=S3CRET%2Fsig"
    server.route = lambda path: (302, f"/ept_laz/ept.json?{token}") if path == "/az/ept.json" else None
    ept = gphttp.HttpFile(server.url("az/ept.json"))
    ept.read_all()  # (learns the signed URL)
    page = (data / "ept_laz" / "ept-hierarchy" / "0-0-0-0.json").read_bytes()
    got = ept.sibling("ept-hierarchy/0-0-0-0.json").read_many([(0, 8), (len(page) - 5, 5)])
    assert got == [page[:8], page[-5:]]
    assert server.paths[-1] == f"/ept_laz/ept-hierarchy/0-0-0-0.json?{token}"
    assert ept.sibling("ept.json").url == server.url(f"ept_laz/ept.json?{token}")
    ept.close()


def test_a_moved_copc_file_is_read_where_it_went(data, server):
    """A COPC file's every range request went to the URL given and was redirected again: now the
    first is, and the later ones go where it led."""
    server.route = _moved("/moved/", "/")
    c = gp.open(server.url("moved/autzen.copc.laz"))
    assert _frame(c, point_budget=10**9, lod_threshold_px=0.0).stats.points_processed == 110_000
    assert server.paths[:2] == ["/moved/autzen.copc.laz", "/autzen.copc.laz"]
    assert len(server.paths) > 4 and server.paths[2:] == ["/autzen.copc.laz"] * (len(server.paths) - 2)
    c.close()


@pytest.mark.timeout(60)
def test_bad_redirects_are_one_line_naming_the_url(server, quick):
    server.route = lambda path: {
        "/loop.copc.laz": (302, "/loop.copc.laz"),
        "/ftp.copc.laz": (302, "ftp://host/x.copc.laz?sig=secret"),
        "/nowhere.copc.laz": (302, None),
    }.get(path)
    url = server.url("loop.copc.laz")
    with pytest.raises(InputError) as e:
        gp.open(url)  # (httpx: "TooManyRedirects: Exceeded maximum allowed redirects.")
    assert str(e.value) == f"{url}: too many redirects (more than 20: a redirect loop?) for bytes 0..65,536"
    url = server.url("ftp.copc.laz")
    with pytest.raises(InputError) as e:
        gp.open(url)  # (httpx: "UnsupportedProtocol: Request URL has an unsupported protocol 'ftp://'.")
    assert str(e.value) == f"{url}: redirected to ftp://host/x.copc.laz?sig=***: only http:// and https:// URLs are read"
    url = server.url("nowhere.copc.laz")
    with pytest.raises(InputError) as e:
        gp.open(url)
    assert str(e.value) == f"{url}: unexpected HTTP 302 Found for bytes 0..65,536"


def test_a_redirect_from_https_to_http_is_not_followed():
    """httpx follows https -> http: the answer (and a signed URL's signature) in the clear."""
    import httpx

    asked = []

    def store(request):
        asked.append(str(request.url))
        if request.url.host == "cdn.example":
            return httpx.Response(404)
        return httpx.Response(302, headers={"Location": "http://cdn.example/x.copc.laz?sig=s"})

    client = gphttp.HttpClient()
    client.client._transport = httpx.MockTransport(store)  # (no TLS server here)
    url = "https://user:pw@store.example/x.copc.laz"
    with pytest.raises(InputError) as e:
        gphttp.HttpFile(url, client).read_head(100)
    assert str(e.value) == "https://user:***@store.example/x.copc.laz: redirected from https to http://cdn.example/x.copc.laz?sig=***: not followed (the answer would travel unencrypted)"
    assert asked == [url]
    client.close()


def test_an_ept_folder_url_that_the_server_redirects_to_its_slash(server):
    """``gigapoint info https://host/ept/``: typer's Path drops the '/', and servers answer a folder
    without its '/' with 301 to it (nginx, Apache), then 403 or an index page: that was "…/ept_laz:
    HTTP 403 Forbidden for bytes 0..65,536", a COPC file being expected. A redirect to the URL's
    own path and '/' says it is a folder: it is tried as an EPT folder, as a 404 is."""

    def route(path):
        folder, _, query = path.partition("?")
        if folder == "/ept_laz":
            return 301, "/ept_laz/" + (f"?{query}" if query else "")
        return (403, None) if folder == "/ept_laz/" else None

    server.route = route
    for name in ("ept_laz", "ept_laz?t=1"):
        c = gp.open(server.url(name))
        assert isinstance(c, EptCloud) and c.n_points == 20_000
        c.close()
    server.route = lambda path: (301, "/nothing/") if path == "/nothing" else None
    with pytest.raises(InputError) as e:
        gp.open(server.url("nothing"))
    assert str(e.value) == f"{server.url('nothing')}: a folder, not a file (the server redirected to {server.url('nothing/')})"


def test_a_moved_dataset_behind_a_password_keeps_it(server):
    """A same-host redirect to an absolute Location without the URL's user:password: httpx sends
    the credentials along, and the files then asked where it led must have them too."""
    port = server.httpd.server_address[1]
    server.route = lambda path: (302, f"http://127.0.0.1:{port}/ept_laz/{path[5:]}") if path.startswith("/old/") else None
    c = gp.open(f"http://reader:hunter2@127.0.0.1:{port}/old/ept.json")
    assert _frame(c, point_budget=10**9, lod_threshold_px=0.0).stats.points_processed == 20_000
    assert len(server.paths) > 4 and all(p.startswith("/ept_laz/") for p in server.paths[1:])
    assert server.auths == ["Basic cmVhZGVyOmh1bnRlcjI="] * len(server.paths)
    _no_secret(c.node_file(int(c.keys[0])), port, "ept_laz/ept-data/0-0-0-0.laz")
    c.close()


@pytest.mark.parametrize("name", ["shared_keys.copc.laz", "own_pages.copc.laz"])
def test_copclib_files_over_http_render_like_the_local_files(name):
    """copc-lib's paged layouts (tests/unit/data/copclib) read over HTTP: the pages a frame
    needs, then every node's points, drawn as the local file draws them."""
    root = Path(__file__).resolve().parents[1] / "unit" / "data" / "copclib"
    s = RangeServer(root)
    try:
        c, local = gp.open(s.url(name)), gp.open(root / name)
        assert c.n_points == 20_000 and s.requests == 3 and c.pending_pages > 0  # the head, the EVLRs (a CRS?), the root page
        assert c.meta["crs"] == local.meta["crs"] and (name == "shared_keys.copc.laz") == (c.meta["crs"] is not None)
        for kw in ({"point_budget": 5_000}, {"point_budget": 10**9, "lod_threshold_px": 0.0}):
            a, b = _frame(local, **kw), _frame(c, **kw)
            assert a.stats.points_processed == b.stats.points_processed
            np.testing.assert_array_equal(a.image, b.image)
        assert b.stats.points_processed == 20_000 and c.pending_pages == 0
    finally:
        s.close()


def test_a_crs_past_the_first_mib_of_evlrs_over_http(tmp_path):
    """The WKT EVLR 1.2 MiB past the hierarchy's (more than the one request of EVLRs read at
    open): found by reading the EVLRs' headers (60 bytes a request) and the WKT's bytes, never
    the 1.2 MiB between (it had no CRS)."""
    path = crs_past_a_mib(tmp_path)
    s = RangeServer(tmp_path)
    try:
        c = gp.open(s.url(path.name))
        assert (c.meta["crs"] or "").startswith('PROJCS["NAD_1983_HARN') and c.meta["crs"] == gp.open(path).meta["crs"]
        spans = [int(b) - int(a) + 1 for a, b in (r.removeprefix("bytes=").split("-") for r in s.ranges)]
        assert s.requests == 6 and spans.count(60) == 3 and max(spans) < 100_000, spans  # head, 3 EVLR headers, the WKT, the root page
    finally:
        s.close()
