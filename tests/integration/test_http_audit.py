"""Reading over HTTP, audited as a demanding user would (test_copc_http.py has the rest): URLs
given where point files are read, failures past a redirect, and servers that answer otherwise
than asked. Servers bind 127.0.0.1."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import InputError
from gigapoint.io import http as gphttp

pytest.importorskip("httpx")

from test_copc_http import RangeServer, _frame, quick  # noqa: F401 - quick: a fixture

SECRET = "http://reader:hunter2@127.0.0.1:9/{name}?sig=SIG%2Fsecret&se=2031"
SHOWN = "http://reader:***@127.0.0.1:9/{name}?sig=***&se=***"


@pytest.mark.parametrize("name", ["ept/", "ept/ept.json", "scan.copc.laz"])
def test_a_url_given_where_point_files_are_read_is_said_as_one_never_whole(tmp_path, capsys, name):
    """``gigapoint convert https://host/ept/?sig=... -o x.laz`` (tile, classify too) printed the
    URL whole, password and token ("http:/reader:hunter2@...: is an EPT dataset"); a COPC file's
    URL was "only http:// and https:// URLs are read", of an http URL. Both now say what a URL
    is read as, naming it as shown_url does (no server is asked)."""
    from gigapoint.cli import main

    url = SECRET.format(name=name)
    want = (
        f"{SHOWN.format(name=name)}: a URL is read only as an octree (a COPC file or an EPT dataset), opened alone to draw it "
        "(open, info, render, section, view); point files are read from this machine: download it first"
    )
    with pytest.raises(InputError) as e:
        gp.convert(url, tmp_path / "x.laz")
    assert str(e.value) == want
    for command in (["convert", url, "-o", str(tmp_path / "x.laz")], ["tile", url, "--size", "100", "-o", str(tmp_path / "tiles")],
                    ["classify", url, "--ground", "-o", str(tmp_path / "g.laz")]):  # fmt: skip
        assert main(command) == 1
        out, err = capsys.readouterr()
        assert err.strip() == f"error: {want}" and "hunter2" not in out + err
    assert sorted(tmp_path.iterdir()) == []


def test_a_url_among_others_is_named_with_its_two_slashes(tmp_path, capsys):
    """``gigapoint render https://host/ept/ b.laz`` named 'https:/host/ept' (the CLI's Path of the
    URL lost a '/'): the URL as given, to be copied back."""
    from gigapoint.cli import main

    url = SECRET.format(name="ept/")
    assert main(["render", url, str(tmp_path / "b.laz"), "-o", str(tmp_path / "x.png")]) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"error: {SHOWN.format(name='ept/')}: an EPT dataset opens alone, drawn level of detail as stored; it cannot join other files"


# --------------------------------------------------------------------------- failures past a redirect


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    """scan.copc.laz, converted once for the module (27 s on a cold numba cache, under load more:
    it was converted for each test, inside the tests' deadlock guards) and drawn once, so that
    its decoding and drawing kernels are compiled before any test's guard starts."""
    rng = np.random.default_rng(3)
    xyz = rng.random((3_000, 3)) * (50, 40, 10) + (1000, 2000, 30)
    path = tmp_path_factory.mktemp("scan") / "scan.copc.laz"
    gp.convert(gp.from_arrays(xyz), path, format="copc", max_leaf=500)
    c = gp.open(path)
    _frame(c, point_budget=10**9, lod_threshold_px=0.0)
    c.close()
    return path


@pytest.fixture
def server(tmp_path, scan):
    """scan.copc.laz served from ``tmp_path`` (a copy: tests move, remove and add files there)."""
    shutil.copyfile(scan, tmp_path / "scan.copc.laz")
    s = RangeServer(tmp_path)
    yield s
    s.close()


@pytest.mark.timeout(60, func_only=True)  # (the server fixture's conversion, once a module, is not timed)
def test_a_failure_past_a_redirect_names_where_it_led(server, quick):
    """A URL redirected to a host that refuses the connection (a CDN's, a retired mirror) or to a
    signed URL the store refuses (expired: 403) was said as the URL given's failure alone
    ("…/scan.copc.laz: cannot connect ([Errno 111] Connection refused)" of a server that answers):
    the message now says where the redirect led, its signature hidden."""
    url = server.url("s/scan.copc.laz")
    server.route = lambda path: (302, "http://127.0.0.1:1/scan.copc.laz?sig=SECRET") if path == "/s/scan.copc.laz" else None
    with pytest.raises(InputError) as e:
        gp.open(url)
    assert str(e.value).startswith(f"{url}: cannot connect (")
    assert str(e.value).endswith(") (redirected to http://127.0.0.1:1/scan.copc.laz?sig=***) (after 2 attempts)")
    server.route = lambda path: (302, "/bucket/scan.copc.laz?sig=SECRET") if path == "/s/scan.copc.laz" else (403, None)
    with pytest.raises(InputError) as e:
        gp.open(url)
    assert str(e.value) == f"{url}: HTTP 403 Forbidden for bytes 0..65,536 (redirected to {server.url('bucket/scan.copc.laz?sig=***')})"
    server.route = None
    with pytest.raises(InputError) as e:  # no redirect: as before
        gp.open(server.url("gone.copc.laz"))
    assert str(e.value) == f"{server.url('gone.copc.laz')}: HTTP 404 Not Found for bytes 0..65,536"


@pytest.mark.timeout(60, func_only=True)
def test_a_moved_file_gone_mid_render_is_named_where_it_was_read(server, quick):
    """A COPC file moved (its ranges then read where the redirect led, HttpClient.moved) and
    removed there while drawn: the 404 named only the URL given, which the server still
    redirects."""
    server.route = lambda path: (301, "/new/scan.copc.laz") if path == "/old/scan.copc.laz" else None
    (server.root / "new").mkdir()
    (server.root / "scan.copc.laz").rename(server.root / "new" / "scan.copc.laz")
    url = server.url("old/scan.copc.laz")
    c = gp.open(url)
    (server.root / "new" / "scan.copc.laz").unlink()
    with pytest.raises(InputError) as e:
        _frame(c, point_budget=10**9, lod_threshold_px=0.0)
    assert re.fullmatch(rf"{re.escape(url)}: HTTP 404 Not Found for bytes [\d,]+\.\.[\d,]+ \(redirected to {re.escape(server.url('new/scan.copc.laz'))}\)", str(e.value))
    c.close()


# --------------------------------------------------------------------------- servers and files


@pytest.mark.parametrize("mode", ["ok", "ignore_range"])
def test_an_empty_file_over_http_is_said_empty(server, capsys, mode):
    """An empty COPC file on the server (an upload that never started) was "bytes 0..65,536 lie
    past the end of the file (HTTP 416 Range Not Satisfiable)" (a server answering ranges) or
    "not a COPC file (a file that starts with b'')" (one answering 200 and the empty file); a
    local one is "file is empty (0 bytes)", and so is a URL's."""
    from gigapoint.cli import main
    from gigapoint.errors import EmptyCloudError

    (server.root / "empty.copc.laz").write_bytes(b"")
    server.mode = mode
    url = server.url("empty.copc.laz")
    with pytest.raises(EmptyCloudError) as e:
        gp.open(url)
    assert str(e.value) == f"{url}: file is empty (0 bytes)"
    assert main(["info", url]) == 1
    assert capsys.readouterr().err.strip() == f"error: {url}: file is empty (0 bytes)"


def test_a_rate_limited_server_is_asked_again_after_its_retry_after(monkeypatch):
    """HTTP 429 Too Many Requests (GCS's, R2's, GitHub's rate limits, which a frame's requests in
    flight together meet) failed the frame at once: it is now retried as 503 is, after the
    server's Retry-After (at most the timeout), and after the last attempt is one line."""
    import httpx

    answers = []

    def store(request):
        status, wait = answers.pop(0)
        if status == 429:
            return httpx.Response(429, headers={"Retry-After": wait} if wait else {})
        return httpx.Response(206, headers={"Content-Range": "bytes 0-9/100"}, content=bytes(range(10)))

    waits: list[float] = []
    monkeypatch.setattr(gphttp.time, "sleep", waits.append)
    client = gphttp.HttpClient()
    client.client._transport = httpx.MockTransport(store)  # (a Retry-After from a store, no waiting here)
    answers[:] = [(429, "3"), (429, "3600"), (206, None)]
    assert gphttp.HttpFile("https://store.example/x.copc.laz", client).read(0, 10) == bytes(range(10))
    assert waits == [3.0, client.timeout]
    answers[:] = [(429, None)] * 3
    with pytest.raises(InputError) as e:
        gphttp.HttpFile("https://store.example/y.copc.laz", client).read(0, 10)
    assert str(e.value) == "https://store.example/y.copc.laz: HTTP 429 Too Many Requests for bytes 0..10 (after 3 attempts)"
    assert waits[2:] == [0.05, 0.1] and answers == []
    client.close()


def test_a_potree_or_converted_octree_folder_url_is_named_as_one(server, capsys):
    """``gigapoint info http://host/potree/`` (the folder's URL, as a Potree viewer's page links
    it) was "…/potree/ept.json: HTTP 404 Not Found for the file", a gigapoint octree folder's the
    same: each opens from a local folder only, and the message now says so (metadata.json or
    octree.json asked once ept.json is not found). A folder of neither keeps the 404."""
    from gigapoint.cli import main

    for folder, name, what in (("potree", "metadata.json", "a Potree octree folder"), ("tree", "octree.json", "a converted octree folder")):
        (server.root / folder).mkdir()
        (server.root / folder / name).write_text("{}")
        want = f"{server.url(folder + '/')}: {what} ({name}); Potree and converted octrees open from a local folder (over HTTP: COPC files and EPT datasets)"
        for given in (folder + "/", folder):  # (the CLI's Path drops the '/')
            with pytest.raises(InputError) as e:
                gp.open(server.url(given))
            assert str(e.value) == want
        assert main(["info", server.url(folder + "/")]) == 1
        assert capsys.readouterr().err.strip() == f"error: {want}"
    (server.root / "other").mkdir()
    with pytest.raises(InputError) as e:
        gp.open(server.url("other/"))
    assert str(e.value) == f"{server.url('other/ept.json')}: HTTP 404 Not Found for the file"


def test_an_octree_json_url_is_named_for_what_it_is(server):
    """``gp.open('http://host/tree/octree.json')`` (a converted octree's metadata, as gigapoint
    writes it) said "ept.json lacks 'dataType', 'hierarchyType', 'schema'"; any other JSON file's
    URL "ept.json lacks ..." of a file that is no ept.json."""
    gp.convert(gp.from_arrays(np.random.default_rng(4).random((2_000, 3))), server.root / "tree", max_leaf=500)
    url = server.url("tree/octree.json")
    with pytest.raises(InputError) as e:
        gp.open(url)
    assert str(e.value) == f"{url}: a converted octree's octree.json; converted octrees open from a local folder (over HTTP: COPC files and EPT datasets)"
    (server.root / "tree" / "other.json").write_text('{"points": 5}')
    url = server.url("tree/other.json?sig=x")
    with pytest.raises(InputError) as e:
        gp.open(url)
    assert str(e.value) == f"{server.url('tree/other.json?sig=***')}: not an EPT ept.json (it lacks 'bounds', 'dataType', 'hierarchyType', 'schema')"


@pytest.mark.parametrize("mode", ["ok", "ignore_range"])
def test_a_cut_las_file_over_http_is_said_truncated_as_the_local_one(server, mode):
    """A 4-byte 'LASF' file (an upload cut short) was "not a COPC file (a LAS file without the
    COPC info VLR first)" over HTTP, "truncated LAS header: ..." on disk: now the local words."""
    cut = server.root / "cut.copc.laz"
    cut.write_bytes(b"LASF")
    with pytest.raises(InputError) as local:
        gp.open(cut)
    server.mode = mode
    url = server.url("cut.copc.laz")
    with pytest.raises(InputError) as e:
        gp.open(url)
    assert str(e.value) == str(local.value).replace(str(cut), url) == f"{url}: truncated LAS header: the file has 4 bytes, a LAS header needs at least 227"


@pytest.mark.timeout(60, func_only=True)
def test_an_answer_compressed_against_accept_encoding_identity(server, quick):
    """A server that gzips its answers though asked for none (S3 serving an object stored with
    Content-Encoding: gzip): a whole file is decoded (an EPT dataset draws); ranges of the
    compressed bytes cannot be read, which was "the server sent more than the N bytes asked for";
    a 'gzip' answer that is not was "DecodingError: Error -3 while decompressing data: ..."."""
    from test_ept import make_scene, write_ept

    write_ept(server.root / "ept", make_scene(2_000, seed=1), "laszip")
    server.mode = "gzip"
    c = gp.open(server.url("ept/"))
    assert _frame(c, point_budget=10**9, lod_threshold_px=0.0).stats.points_processed == 2_000
    c.close()
    url = server.url("scan.copc.laz")
    with pytest.raises(InputError) as e:
        gp.open(url)
    assert str(e.value) == (
        f"{url}: the server sent bytes 0..65,536 compressed (Content-Encoding: gzip) though asked for the file as stored "
        "(Accept-Encoding: identity): ranges of it cannot be read; serve the file without Content-Encoding"
    )
    server.mode = "gzip_plain"
    url = server.url("ept/ept.json")
    with pytest.raises(InputError) as e:
        gp.open(url)
    assert re.fullmatch(rf"{re.escape(url)}: the file does not decode as the server's Content-Encoding says \([^\n]+\)", str(e.value))


def test_a_range_with_a_content_encoding_httpx_does_not_decode_is_read_as_sent(server, quick):
    """A 206 with Content-Encoding: binary (as some stores label bytes; aws-chunked, none alike)
    was refused as "sent compressed": only what httpx decodes (gzip, deflate, br, zstd) is; the
    rest comes as stored, its Content-Length the bytes'."""
    data = bytes(range(256)) * 40
    (server.root / "labelled.bin").write_bytes(data)
    server.mode = "binary"
    f = gphttp.HttpFile(server.url("labelled.bin"))
    try:
        assert f.read(1000, 5000) == data[1000:6000]
        assert f.read_all() == data
    finally:
        f.close()


@pytest.mark.timeout(60, func_only=True)  # (as its neighbours: a deadlock guard of the test alone, the fixtures' conversion not)
def test_a_file_of_unknown_size_is_given_up_on_when_it_stalls_not_when_slow(server, quick, monkeypatch):
    """A whole file read without Content-Length had 3 x TIMEOUT (30 s) however it progressed: a
    big ept.json or node over a slow link failed. Now its deadline grows with the bytes come (at
    MIN_RATE, as a known size's), and a stall ends it sooner: no byte for TIMEOUT seconds (1.2 s
    here: parts 0.05 s apart leave a wide margin under load; the file takes 4.1 s at 5 KB/s, past
    3 x TIMEOUT)."""
    import socket
    import threading
    import time

    monkeypatch.setattr(gphttp, "TIMEOUT", 1.2)
    monkeypatch.setattr(gphttp, "MIN_RATE", 8 << 10)  # (the deadline 3.6 s + 20 KB at 8 KB/s = 6.1 s: the 4.1 s file has a wide margin under load)
    data = bytes(range(256)) * 80
    (server.root / "big.bin").write_bytes(data)
    server.no_length, server.rate = True, 5_000
    t = time.perf_counter()
    f = gphttp.HttpFile(server.url("big.bin"))
    assert f.read_all() == data
    f.close()
    assert 3 * 1.2 < time.perf_counter() - t < 8
    listener = socket.create_server(("127.0.0.1", 0))

    def stall():  # 100 bytes, then nothing
        conn, _ = listener.accept()
        with conn:
            conn.recv(65536)
            conn.sendall(b"HTTP/1.1 200 OK\r\nConnection: close\r\n\r\n" + bytes(100))
            time.sleep(3)

    threading.Thread(target=stall, daemon=True).start()
    url = f"http://127.0.0.1:{listener.getsockname()[1]}/big.bin"
    t = time.perf_counter()
    f = gphttp.HttpFile(url)
    try:
        with pytest.raises(InputError) as e:
            f.read_all()
    finally:
        f.close()
        listener.close()
    assert str(e.value) == f"{url}: the file stopped arriving: no byte for 1.2 s after 100 bytes (timed out)"
    assert time.perf_counter() - t < 2.8  # given up on at 1.2 s, before the server's 3 s stall ends


@pytest.mark.timeout(30)
def test_a_file_of_unknown_size_trickled_is_given_up_on_at_its_deadline(quick, monkeypatch):
    """A byte every 0.1 s kept a file of unknown size coming for ever (each byte put its deadline
    off again): its deadline now grows with the bytes come at MIN_RATE, as a known size's does:
    3 x TIMEOUT + bytes / MIN_RATE = 1.5 s + t / 4 s here, met at t = 2 s."""
    import socket
    import threading
    import time

    listener = socket.create_server(("127.0.0.1", 0))

    def trickle():  # 40 bytes over 4 s
        conn, _ = listener.accept()
        with conn:
            conn.recv(65536)
            conn.sendall(b"HTTP/1.1 200 OK\r\nConnection: close\r\n\r\n")
            try:
                for _ in range(40):
                    conn.sendall(b"y")
                    time.sleep(0.1)
            except OSError:
                pass  # the client gave up

    threading.Thread(target=trickle, daemon=True).start()
    url = f"http://127.0.0.1:{listener.getsockname()[1]}/slow.json"
    t = time.perf_counter()
    f = gphttp.HttpFile(url)
    try:
        monkeypatch.setattr(gphttp, "MIN_RATE", 40)
        with pytest.raises(InputError) as e:
            f.read_all()
    finally:
        f.close()
        listener.close()
    m = re.fullmatch(rf"{re.escape(url)}: the file did not arrive within ([0-9.]+) s", str(e.value))
    assert m and 1.8 <= float(m.group(1)) <= 2.3, str(e.value)
    assert time.perf_counter() - t < 3
