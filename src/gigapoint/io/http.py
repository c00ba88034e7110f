"""Byte ranges of local files and of HTTP(S) resources: what the COPC and EPT readers read through.

``open_source(path_or_url)`` gives a ``ByteSource``: ``read(offset, size)`` (exactly ``size``
bytes or an InputError), ``read_many(ranges)``, ``read_head(n)`` (up to ``n`` bytes),
``read_all()`` and ``sibling(relative)`` (another file of the same dataset: EPT's hierarchy and
data files beside ``ept.json``).

Over HTTP every dataset shares one ``HttpClient``: one ``httpx.Client`` (keep-alive
connections reused), a small thread pool so that several requests are in flight
(``read_many``), a timeout on every request (connect, each read) and an overall deadline per
request, so that a server that stalls or trickles never hangs a frame, a bounded in-memory
LRU cache of the ranges read, and two retries of transient failures (connection errors,
HTTP 429/502/503/504, after the server's Retry-After up to a timeout). Whatever goes wrong is a one-line ``InputError`` naming the URL: an HTTP
error status, a short read, a server that ignores ``Range`` (200 with the whole file) or
answers another range than asked, a range past the end of the file, a timeout, a file that
changed on the server since its first answer (size, ETag or Last-Modified), too many redirects,
a redirect from https to http or to another scheme (not followed), ranges sent compressed
(a Content-Encoding httpx decodes, despite ``Accept-Encoding: identity``: a whole file so is
decoded), a whole file of unknown size that stops arriving (no byte for the timeout) or comes
slower than its deadline, which grows with the bytes come as a known size's does; a failure past a redirect also names where it led. Messages name a URL
as ``shown_url`` gives it: its password (or a user name alone, a token) and query values as ***
(signed URLs are how COPC files are shared); requests use the URL itself.

Redirects: a redirect that keeps the URL's query (a moved file or dataset, ``/latest/`` ->
``/v3/``) is remembered: the file's later ranges are asked where it led, and its siblings are
the files beside where it led (an EPT's ``ept.json`` alone redirected has its hierarchy and data
there). A redirect to another query (a signed URL: ``/ept.json`` -> ``/bucket/ept.json?sig=...``)
is followed afresh at every request (a signature is for one file and expires), and siblings
are beside the URL as given, each redirected and signed by the server on its own; a sibling
not found there (HTTP 404: ept.json alone redirected, to a URL whose token reads the whole
folder, an Azure SAS) is asked beside where the redirect led, with its query, and once found
there so are the later siblings.

httpx is an optional dependency (``pip install 'gigapoint[http]'``).
"""

from __future__ import annotations

import os
import re
import threading
import time
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from urllib.parse import urljoin, urlsplit

from ..errors import InputError

#: Seconds to connect and for each read of a request; a request's whole answer must come
#: within ``DEADLINE_FACTOR`` times this plus its bytes at ``MIN_RATE`` bytes a second (a server
#: trickling bytes is cut off too; a frame's MBs over an ordinary link are not: its requests
#: share the link, and a frame of 10 M points, ~120 MB, took longer than 30 s under 32 Mbit/s).
TIMEOUT = 10.0
DEADLINE_FACTOR = 3.0
MIN_RATE = 16 << 10
#: Requests in flight at once (``read_many``).
WORKERS = 6
#: Bytes of ranges kept in memory (least recently used dropped first).
CACHE_BYTES = 256 << 20
#: Extra attempts after a transient failure (connection error, HTTP 429/502/503/504).
RETRIES = 2
#: ``read_many`` joins ranges less than this far apart into one request (the bytes between are
#: read and dropped), up to MERGE_MAX bytes a request: a frame's nodes often lie side by side.
MERGE_GAP = 64 << 10
MERGE_MAX = 8 << 20
#: Content-Encodings httpx decodes (its own list, httpx._decoders.SUPPORTED_DECODERS, is not public).
_DECODED = ("gzip", "deflate", "br", "zstd")
_RETRY_STATUS = (429, 502, 503, 504)  # 429 Too Many Requests: a store's rate limit (GCS, R2, GitHub), met by a frame's requests in flight
_URL = re.compile(r"^(https?):/+(.+)$", re.IGNORECASE)
#: a URL's scheme (a Path of one has lost a '/') and the rest; a path or request target's ?query and #fragment
_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]+:/+)(.*)$", re.DOTALL)
_QUERY = re.compile(r"^([^?#]*)(\?[^#]*|)(#.*|)$", re.DOTALL)
_HOST_PORT = re.compile(r"^[^:@]*(:\d*)?$")  # an authority without user info
_CONTENT_RANGE = re.compile(r"^\s*bytes\s+(\d+)-(\d+)/(\d+|\*)\s*$", re.IGNORECASE)


def as_url(source) -> str | None:
    """The http(s) URL that ``source`` names, else None. A ``Path`` made from a URL lost one of
    its slashes (``Path("https://h/x")`` is ``https:/h/x``); it is given back."""
    if isinstance(source, os.PathLike):
        text = os.fspath(source)
        if Path(text).exists():  # a local folder that happens to be called 'http:'
            return None
    elif isinstance(source, str):
        text = source
    else:
        return None
    m = _URL.match(str(text).strip())
    if m is None:
        return None
    return f"{m.group(1).lower()}://{m.group(2)}"


def shown_url(text) -> str:
    """``text`` (a URL or a path) as messages, ``info`` and the viewer show it: a URL's password, a
    user name alone (a token: ``https://TOKEN@host/``) and the values of its query as ***
    (``https://user:***@host/a.copc.laz?sig=***&se=***``). Signed and credentialed URLs are how
    COPC files are shared, and what is shown ends up in logs and issues; requests use the URL
    itself. Anything else is given back as it is."""
    text = os.fspath(text) if isinstance(text, os.PathLike) else str(text)
    m = _SCHEME.match(text)
    if m is None:
        return text
    return m.group(1) + _hidden_user_info(hidden_query(m.group(2)))


def last_name(text) -> str:
    """The last part of a path or URL, a URL's query and fragment aside (its token no part of its
    name): 'https://host/d/ept.json?sig=x' -> 'ept.json'."""
    text = os.fspath(text) if isinstance(text, os.PathLike) else str(text)
    if _SCHEME.match(text):
        text = text.split("?")[0].split("#")[0]
    return text.rstrip("/").rsplit("/", 1)[-1]


def _hidden_user_info(rest: str) -> str:
    """A URL's part after ``scheme://`` with its user info hidden: 'user:pw@host/x' ->
    'user:***@host/x', 'token@host/x' -> '***@host/x'. The user info ends at the last '@' of the
    authority (a password may hold a raw '@'), which ends at the first '/' (RFC 3986): an '@'
    after it is the path's ('host:8080/a@b' was shown as 'host:***@b'). An authority that is no
    host[:port] ('user:sec/ret@host/x': a raw '/' in a password, a URL no request can use) has
    its user info up to the last '@' before the query hidden, never shown."""
    main = _QUERY.match(rest).group(1)
    authority = main.split("/", 1)[0]
    at = authority.rfind("@")
    if at < 0 and (main.startswith("[") or _HOST_PORT.match(authority)):
        return rest
    at = at if at >= 0 else main.rfind("@")
    if at < 0:
        return rest
    user, colon, _ = main[:at].partition(":")
    return (f"{user}:***" if colon else "***") + rest[at:]


def hidden_query(target: str) -> str:
    """'/ws?w=64&token=t' -> '/ws?w=***&token=***': a path's (a request target's) query and
    fragment with their names kept and their values hidden."""
    main, query, fragment = _QUERY.match(target).groups()
    return main + _hidden_values(query) + _hidden_values(fragment)


def _hidden_values(part: str) -> str:
    """'?a=1&b' -> '?a=***&***': the names of a query (or fragment) kept, its values hidden."""
    if len(part) <= 1:
        return part
    items = part[1:].split("&")
    return part[0] + "&".join(kv.split("=", 1)[0] + "=***" if "=" in kv else "***" if kv else "" for kv in items)


def _one_line(exc: object) -> str:
    s = " ".join(str(exc).split())
    return s if len(s) <= 300 else s[:297] + "..."


class ByteSource:
    """Bytes of one file, local or remote (see the module's docstring)."""

    name: str = ""

    def size(self) -> int | None:
        """The file's size in bytes (None: not known yet)."""
        raise NotImplementedError

    def read(self, offset: int, size: int) -> bytes:
        raise NotImplementedError

    def read_head(self, size: int) -> bytes:
        """The first ``size`` bytes, fewer when the file is shorter."""
        raise NotImplementedError

    def read_all(self) -> bytes:
        raise NotImplementedError

    def read_many(self, ranges) -> list[bytes]:
        """``read(offset, size)`` of each (offset, size), in order."""
        return [self.read(int(o), int(s)) for o, s in ranges]

    def sibling(self, relative: str) -> ByteSource:
        """The file ``relative`` to this one's folder."""
        raise NotImplementedError

    def read_all_many(self, sources: list[ByteSource]) -> list[bytes]:
        """``read_all()`` of each of ``sources`` (siblings of this one), in order."""
        return [s.read_all() for s in sources]

    def close(self) -> None:
        pass

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


class LocalFile(ByteSource):
    """A local file read with ``os.pread`` (the page cache is its cache)."""

    def __init__(self, path):
        self.path = Path(path)
        self.name = str(self.path)

    def _fail(self, exc: OSError) -> InputError:
        if isinstance(exc, FileNotFoundError):
            return InputError(f"{self.name}: no such file")
        return InputError(f"{self.name}: cannot read ({exc.strerror or _one_line(exc)})")

    def size(self) -> int:
        try:
            return self.path.stat().st_size
        except OSError as exc:
            raise self._fail(exc) from None

    def read(self, offset: int, size: int) -> bytes:
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except OSError as exc:
            raise self._fail(exc) from None
        try:
            data = os.pread(fd, size, offset) if size > 0 else b""
        except OSError as exc:
            raise self._fail(exc) from None
        finally:
            os.close(fd)
        if len(data) != size:
            raise InputError(f"{self.name}: truncated file: bytes {offset:,}..{offset + size:,} lie past its end ({self.size():,} bytes)")
        return data

    def read_head(self, size: int) -> bytes:
        try:
            with open(self.path, "rb") as f:
                return f.read(size)
        except OSError as exc:
            raise self._fail(exc) from None

    def read_all(self) -> bytes:
        try:
            return self.path.read_bytes()
        except OSError as exc:
            raise self._fail(exc) from None

    def sibling(self, relative: str) -> LocalFile:
        return LocalFile(self.path.parent / relative)


class _LruBytes:
    """A bounded map of byte strings (least recently used dropped first), thread-safe."""

    def __init__(self, capacity: int):
        self.capacity = int(capacity)
        self.held = 0
        self._items: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key) -> bytes | None:
        with self._lock:
            v = self._items.get(key)
            if v is not None:
                self._items.move_to_end(key)
            return v

    def put(self, key, value: bytes) -> None:
        if len(value) > self.capacity:
            return
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self.held -= len(old)
            self._items[key] = value
            self.held += len(value)
            while self.held > self.capacity:
                _, v = self._items.popitem(last=False)
                self.held -= len(v)


def _httpx():
    try:
        import httpx
    except ImportError:
        raise InputError("reading over HTTP needs the httpx package (pip install 'gigapoint[http]')") from None
    return httpx


class HttpClient:
    """The connection pool, worker threads and range cache that the files of one dataset share."""

    def __init__(
        self, timeout: float | None = None, cache_bytes: int | None = None, workers: int | None = None, retries: int | None = None
    ):
        httpx = _httpx()
        self.timeout = float(TIMEOUT if timeout is None else timeout)
        self.retries = RETRIES if retries is None else int(retries)
        self.workers = WORKERS if workers is None else int(workers)
        self.client = httpx.Client(
            timeout=httpx.Timeout(self.timeout),
            limits=httpx.Limits(max_connections=2 * self.workers, max_keepalive_connections=self.workers),
            follow_redirects=True,
            headers={"User-Agent": "gigapoint", "Accept-Encoding": "identity"},
            event_hooks={"response": [_check_redirect]},
        )
        self.cache = _LruBytes(CACHE_BYTES if cache_bytes is None else cache_bytes)
        self._pool: ThreadPoolExecutor | None = None
        self._pool_lock = threading.Lock()
        self.sizes: dict[str, int] = {}  # file sizes learnt from Content-Range
        self.versions: dict[str, str] = {}  # each file's first ETag (else Last-Modified): a change is noticed
        self.moved: dict[str, str] = {}  # URL -> where a redirect that kept its query led (see the module's docstring)
        self.signed: dict[str, str] = {}  # URL -> where its latest redirect to another query led (a signed URL)
        self.siblings_beside_signed: set[str] = set()  # URLs whose siblings were found beside their signed URL
        self.requests = 0  # requests sent (cache misses), for tests and benchmarks
        self.bytes_read = 0
        self.closed = False  # (httpx's own "Cannot send a request" was a RuntimeError traceback)

    def map(self, fn, items: list) -> list:
        """``fn(item)`` of each item, several at once; the first failure is raised."""
        if len(items) <= 1:
            return [fn(i) for i in items]
        with self._pool_lock:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix="gigapoint-http")
        return list(self._pool.map(fn, items))

    def close(self) -> None:
        self.closed = True
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
        self.client.close()

    def get(self, url: str, start: int | None = None, size: int | None = None, allow_short: bool = False, cache: bool = True) -> bytes:
        """The bytes ``start..start+size`` of ``url`` (the whole resource when ``start`` is None);
        ``allow_short``: fewer when the file ends before (the head of a small file); ``cache``:
        look up and keep the answer in the range cache."""
        key = (url, start, size)
        hit = self.cache.get(key) if cache else None
        if hit is not None:
            return hit
        httpx = _httpx()
        what = f"bytes {start:,}..{start + size:,}" if start is not None else "the file"
        if start is not None and size <= 0:
            return b""
        if self.closed:
            raise InputError(f"{shown_url(url)}: {what} not read: the cloud was closed (close()); open it again to read more of it")
        known = self.sizes.get(url)
        if start is not None and not allow_short and known is not None and start + size > known:
            raise InputError(f"{shown_url(url)}: {what} lie past the end of the file ({known:,} bytes)")
        headers = {"Range": f"bytes={start}-{start + size - 1}"} if start is not None else {}
        for attempt in range(self.retries + 1):
            last = attempt == self.retries
            try:
                data = self._get_once(httpx, url, start, size, headers, allow_short, what)
            except _Transient as exc:
                if last:
                    raise InputError(f"{shown_url(url)}: {exc} (after {self.retries + 1} attempts)") from None
                time.sleep(max(0.05 * 2**attempt, min(exc.retry_after, self.timeout)))
                continue
            if cache:
                self.cache.put(key, data)
            return data
        raise AssertionError("unreachable")  # pragma: no cover

    def _get_once(self, httpx, url, start, size, headers, allow_short, what) -> bytes:
        """``_request`` in a daemon thread, given up on after the deadline: httpx's timeouts are per
        read, so a server that sent its headers a line every few seconds was waited on forever
        (the body's deadline is checked between its parts). A thread given up on ends with the
        connection; a daemon one does not keep the process from exiting."""
        out: list = []
        done = threading.Event()
        t0 = time.monotonic()
        limit = [self._limit(size)]  # seconds; a whole file's grows once its Content-Length is known

        def work() -> None:
            try:
                out.append(self._request(httpx, url, start, size, headers, allow_short, what, t0, limit))
            except BaseException as exc:  # noqa: BLE001 - raised in the caller's thread
                out.append(exc)
            finally:
                done.set()

        threading.Thread(target=work, daemon=True, name="gigapoint-http-request").start()
        while not done.wait(max(0.0, t0 + limit[0] + 1.0 - time.monotonic())):  # (the body's own deadline fires first)
            if time.monotonic() >= t0 + limit[0] + 1.0:
                raise InputError(f"{shown_url(url)}: {what} did not arrive within {limit[0]:g} s")
        if isinstance(out[0], BaseException):
            raise out[0]
        return out[0]

    def _limit(self, size: int | None) -> float:
        """Seconds a request's whole answer may take (``size`` bytes; None: not known yet)."""
        return round(DEADLINE_FACTOR * self.timeout + (size or 0) / MIN_RATE, 1)

    def _request(self, httpx, url, start, size, headers, allow_short, what, t0, limit) -> bytes:
        self.requests += 1
        body = bytearray()
        try:
            with self.client.stream("GET", self.moved.get(url, url), headers=headers) as r:
                if r.history and urlsplit(str(r.url)).path == urlsplit(url).path + "/":  # (nginx's answer to a folder's URL)
                    raise HttpNotFound(f"{shown_url(url)}: a folder, not a file (the server redirected to {shown_url(str(r.url))})")
                if r.history and urlsplit(str(r.url)).query == urlsplit(url).query:  # moved, not signed
                    self.moved[url] = _led_to(r)  # (no redirect per range, and a /latest/ that moves on stays put)
                elif r.history:  # signed: asked afresh next time; its siblings may be beside it (HttpFile.sibling)
                    self.signed[url] = _led_to(r)
                status = r.status_code
                there = _redirected(httpx, url, r.url) if status >= 400 else ""  # (for the failures' messages: not every node read)
                if status in _RETRY_STATUS:
                    raise _Transient(f"HTTP {status} {r.reason_phrase} for {what}{there}", _retry_after(r.headers))
                if status == 416 and start == 0 and allow_short:  # the head of an empty file (no first byte to give)
                    return b""
                if status == 416:
                    raise InputError(f"{shown_url(url)}: {what} lie past the end of the file (HTTP 416 Range Not Satisfiable){there}")
                if status >= 400:
                    error = HttpNotFound if status == 404 else InputError
                    raise error(f"{shown_url(url)}: HTTP {status} {r.reason_phrase} for {what}{there}")
                expect = size
                whole = False  # a 200 with the whole file, taken as the head of a small file
                ignored = (
                    f"{shown_url(url)}: the server ignored the range request for {what} (HTTP 200 with the whole file); "
                    "COPC and EPT over HTTP need a server that answers Range requests (HTTP 206)"
                )
                encoding = r.headers.get("content-encoding", "").strip().lower()
                compressed = any(e.strip() in _DECODED for e in encoding.split(","))  # (others, binary or aws-chunked, come as sent)
                if status == 206 and compressed:  # (S3's object stored gzipped: ranges of the compressed bytes)
                    raise InputError(
                        f"{shown_url(url)}: the server sent {what} compressed (Content-Encoding: {encoding}) though asked for the "
                        "file as stored (Accept-Encoding: identity): ranges of it cannot be read; serve the file without Content-Encoding"
                    )
                # (a compressed answer's Content-Length is not the file's: its bytes, decoded, are)
                length = "" if compressed else r.headers.get("content-length", "")
                if start == 0 and allow_short and status == 200 and length.isdigit() and int(length) <= size:
                    # a range that covers the whole file may be answered 200 (RFC 9110): a small
                    # COPC's head read ("ignored the range request" before), not an ignored range
                    whole = True
                elif start is not None:
                    if status == 200:
                        raise InputError(ignored)
                    if status != 206:
                        raise InputError(f"{shown_url(url)}: unexpected HTTP {status} {r.reason_phrase} for {what}")
                    m = _CONTENT_RANGE.match(r.headers.get("content-range", ""))
                    if m is None or int(m.group(2)) < int(m.group(1)):  # ('bytes 10-5/*': no range; a head read expected -4 bytes)
                        raise InputError(
                            f"{shown_url(url)}: answer to a range request has no valid Content-Range header ({r.headers.get('content-range')!r})"
                        )
                    a, b, total = int(m.group(1)), int(m.group(2)), m.group(3)
                    self._same_file(url, r.headers, None if total == "*" else int(total))
                    # a range past the file's end comes cut at it: at the size said, or where the size
                    # is not known ('bytes 0-99/*', RFC 9110) below the end asked (the body then checked against it)
                    ends_file = b == min(start + size, int(total)) - 1 if total != "*" else b < start + size
                    if allow_short and a == start and ends_file:
                        expect = b - a + 1
                    elif a != start or b != start + size - 1:
                        end = f" (the file has {int(total):,} bytes)" if total != "*" else ""
                        raise InputError(f"{shown_url(url)}: the server answered bytes {a:,}..{b + 1:,} to a request for {what}{end}")
                elif status != 200:
                    raise InputError(f"{shown_url(url)}: unexpected HTTP {status} {r.reason_phrase}")
                if status == 200:
                    self._same_file(url, r.headers, int(length) if length.isdigit() else None)
                    if start is None and length.isdigit():
                        limit[0] = self._limit(int(length))
                for part in r.iter_bytes():
                    body += part
                    if start is None and not length.isdigit():  # a file of unknown size: its deadline grows with the bytes come
                        limit[0] = self._limit(len(body))
                    if whole and len(body) > expect:
                        raise InputError(ignored)
                    if expect is not None and len(body) > expect:
                        raise InputError(f"{shown_url(url)}: the server sent more than the {expect:,} bytes asked for ({what})")
                    if time.monotonic() > t0 + limit[0]:
                        raise InputError(f"{shown_url(url)}: {what} did not arrive within {limit[0]:g} s")
        except InputError:
            raise
        except _Transient:
            raise
        except _BadRedirect as exc:
            raise InputError(f"{shown_url(url)}: {exc}") from None
        except httpx.TooManyRedirects:
            raise InputError(f"{shown_url(url)}: too many redirects (more than {self.client.max_redirects}: a redirect loop?) for {what}") from None
        except httpx.TimeoutException as exc:
            if body:  # (it was "no answer" of a file that stopped half-way)
                raise InputError(f"{shown_url(url)}: {what} stopped arriving: no byte for {self.timeout:g} s after {len(body):,} bytes (timed out)") from None
            raise InputError(f"{shown_url(url)}: no answer within {self.timeout:g} s for {what} (timed out){_redirected(httpx, url, exc.request.url)}") from None
        except (httpx.RemoteProtocolError, httpx.ReadError) as exc:
            raise _Transient(f"short read of {what}: the connection broke off ({_one_line(exc)}){_redirected(httpx, url, exc.request.url)}") from None
        except (httpx.ConnectError, httpx.WriteError) as exc:
            raise _Transient(f"cannot connect ({_one_line(exc)}){_redirected(httpx, url, exc.request.url)}") from None
        except httpx.DecodingError as exc:
            raise InputError(f"{shown_url(url)}: {what} does not decode as the server's Content-Encoding says ({_one_line(exc)})") from None
        except httpx.HTTPError as exc:
            raise InputError(f"{shown_url(url)}: {type(exc).__name__}: {_one_line(exc)}") from None
        except httpx.InvalidURL as exc:  # not an HTTPError: 'http://[::1' reached the CLI as an internal error
            why = f" ({_one_line(exc)})" if shown_url(url) == url else ""  # ('Invalid port: ...' may be part of a password)
            raise InputError(f"{shown_url(url)}: not a valid URL{why}") from None
        if whole:
            if len(body) != int(length):
                raise InputError(f"{shown_url(url)}: short read: {len(body):,} of the {int(length):,} bytes of the file")
        elif expect is not None and len(body) != expect:
            raise InputError(f"{shown_url(url)}: short read: {len(body):,} of the {expect:,} bytes asked for ({what})")
        self.bytes_read += len(body)
        return bytes(body)

    def _same_file(self, url: str, headers, size: int | None) -> None:
        """Note the file's size and version (ETag, else Last-Modified) from its first answer; a
        later answer with another is a one-line InputError: the ranges read before belong to the
        old file (a changed COPC decoded to garbage or failed as "cannot decode node")."""
        version = headers.get("etag") or headers.get("last-modified")
        known, seen = self.sizes.get(url), self.versions.get(url)
        change = None
        if size is not None and known is not None and size != known:
            change = f"its size went from {known:,} to {size:,} bytes"
        elif version and seen and version != seen:
            change = f"{'ETag' if headers.get('etag') else 'Last-Modified'} {seen} became {version}"
        if change:
            raise InputError(f"{shown_url(url)}: the file changed on the server while it was read ({change}); open it again")
        if size is not None:
            self.sizes[url] = size
        if version and not seen:
            self.versions[url] = version


class _BadRedirect(Exception):
    """A redirect not followed (its text becomes the InputError's, which names the URL asked)."""


def _check_redirect(response) -> None:
    """httpx's response hook: a redirect from https to http (the answer, and any signature in the
    URL, in the clear) or to another scheme than http(s) is refused (httpx follows the first and
    failed on the second as "UnsupportedProtocol")."""
    if not response.has_redirect_location:
        return
    old = response.request.url
    new = old.join(response.headers["location"])
    where = shown_url(str(new))
    if new.scheme not in ("http", "https"):
        raise _BadRedirect(f"redirected to {where}: only http:// and https:// URLs are read")
    if old.scheme == "https" and new.scheme == "http":
        raise _BadRedirect(f"redirected from https to {where}: not followed (the answer would travel unencrypted)")


def _redirected(httpx, url: str, final) -> str:
    """' (redirected to FINAL)' where a request for ``url`` was last sent to another URL (a
    redirect now, or one remembered: ``HttpClient.moved``), else '': a failure there (a host that
    does not resolve, a 403 of an expired signature) was said as the URL given's alone."""
    return "" if final == httpx.URL(url) else f" (redirected to {shown_url(str(final))})"


def _led_to(response) -> str:
    """The URL a redirected request ended at, with the user:password of the URL asked where httpx
    sent them along (the same host): its ``url`` has them only when the Location had them."""
    first = response.history[0].request.url
    if first.userinfo and not response.url.userinfo and "authorization" in response.request.headers:
        return str(response.url.copy_with(userinfo=first.userinfo))
    return str(response.url)


class HttpNotFound(InputError):
    """HTTP 404 or a redirect to the URL and '/': the URL names no file (an EPT folder whose '/'
    was dropped is tried as one)."""


class _Transient(Exception):
    """A failure worth another attempt (its text becomes the InputError's after the last one),
    ``retry_after`` seconds from now at the soonest (the server's Retry-After)."""

    def __init__(self, text: str, retry_after: float = 0.0):
        super().__init__(text)
        self.retry_after = retry_after


def _retry_after(headers) -> float:
    """The seconds an answer's Retry-After header asks to wait (its delay-seconds form), else 0."""
    value = headers.get("retry-after", "").strip()
    return float(value) if value.isdigit() else 0.0


class HttpFile(ByteSource):
    """A file over HTTP(S), read by range requests through a shared ``HttpClient``. ``fallback``
    (a sibling's): (where else to ask it when the URL answers 404, the file it is a sibling of)."""

    def __init__(self, url: str, client: HttpClient | None = None, fallback: tuple[str, str] | None = None):
        self.url = url
        self.name = shown_url(url)  # what messages say (the URL itself is what is requested)
        self.client = client or HttpClient()
        self.fallback = fallback

    def size(self) -> int | None:
        return self.client.sizes.get(self.url)

    def _get(self, *args, **kwargs) -> bytes:
        """``client.get`` of this file; where its URL answers 404, of its ``fallback`` (the 404
        said where that fails too), which it is from then on, as its siblings are. Every read
        goes through here (``read_many``'s requests too, several at once: hence the URL and
        fallback taken once, so that a request that fell back does not undo another's)."""
        url, fallback = self.url, self.fallback
        try:
            return self.client.get(url, *args, **kwargs)
        except HttpNotFound as exc:
            if fallback is None:
                raise
            not_found = exc
        url, of = fallback
        try:
            data = self.client.get(url, *args, **kwargs)
        except InputError:
            raise not_found from None
        self.url, self.name, self.fallback = url, shown_url(url), None
        self.client.siblings_beside_signed.add(of)
        return data

    def read(self, offset: int, size: int) -> bytes:
        return self._get(int(offset), int(size))

    def read_head(self, size: int) -> bytes:
        return self._get(0, int(size), allow_short=True)

    def read_all(self) -> bytes:
        return self._get()

    def read_many(self, ranges) -> list[bytes]:
        """The ranges not in the cache fetched several at once, neighbours joined into one
        request (MERGE_GAP, MERGE_MAX, and no more than an even share of the bytes per worker,
        so that the requests still run side by side); every range then cached on its own."""
        ranges = [(int(o), int(s)) for o, s in ranges]
        out: list[bytes | None] = [self.client.cache.get((self.url, o, s)) for o, s in ranges]
        missing = sorted((i for i, v in enumerate(out) if v is None), key=lambda i: ranges[i][0])
        if not missing:
            return out
        total = sum(ranges[i][1] for i in missing)
        share = min(MERGE_MAX, max(1 << 20, -(-total // self.client.workers)))
        groups: list[list] = []  # [first byte, end byte, indices of its ranges], by first byte
        for i in missing:
            o, s = ranges[i]
            g = groups[-1] if groups else None
            if g is not None and o - g[1] <= MERGE_GAP and max(g[1], o + s) - g[0] <= share:
                g[1] = max(g[1], o + s)
                g[2].append(i)
            else:
                groups.append([o, o + s, [i]])

        def fetch(group: list) -> None:
            start, end, members = group
            data = self._get(start, end - start, cache=len(members) == 1)
            for j in members:
                o, s = ranges[j]
                piece = data[o - start : o - start + s]
                self.client.cache.put((self.url, o, s), piece)  # (the URL that answered: a fallback's once taken)
                out[j] = piece

        self.client.map(fetch, groups)
        return out

    def read_all_many(self, sources: list[ByteSource]) -> list[bytes]:
        return self.client.map(lambda s: s.read_all(), list(sources))

    def sibling(self, relative: str) -> HttpFile:
        url = _beside(self.client.moved.get(self.url, self.url), relative)  # beside where a move led (it kept the query)
        signed = self.client.signed.get(self.url)
        if signed is None:
            return HttpFile(url, self.client)
        if self.url in self.client.siblings_beside_signed:
            return HttpFile(_beside(signed, relative), self.client)
        return HttpFile(url, self.client, fallback=(_beside(signed, relative), self.url))

    def close(self) -> None:
        self.client.close()


def _beside(url: str, relative: str) -> str:
    """The URL of ``relative`` beside ``url``, with ``url``'s query where ``relative`` has none: a
    token in the query (a container's SAS) reads the files beside it too."""
    query = urlsplit(url).query
    beside = urljoin(url, relative)
    return f"{beside}?{query}" if query and not urlsplit(relative).query else beside


def open_source(source, client: HttpClient | None = None) -> ByteSource:
    """A ByteSource for a local path or an http(s) URL (see ``as_url``)."""
    url = as_url(source)
    if url is not None:
        return HttpFile(url, client)
    return LocalFile(source)
