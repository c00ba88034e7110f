"""gigapoint.Viewer: the browser viewer inside Jupyter (an IFrame on a background server)."""

from __future__ import annotations

import importlib.util
import os
import secrets
import sys
from pathlib import Path
from typing import Self

from ..core.renderable import Renderable
from ..errors import GigapointError, InputError, check_switch, check_whole, is_whole_number, warn
from .protocol import MAX_SHOT_SIDE

VIEWER_URL_VARIABLE = "GIGAPOINT_VIEWER_URL"  # the user's address template for the notebook's browser
COLAB = "colab"  # shown through Colab's proxy of the kernel's ports (google.colab.output)
SHOWN_AT_EXAMPLE = "'https://myhost/proxy/{port}/'"


def _as_cloud(cloud_or_path):
    """A cloud (any Renderable) as it is; a path or a list of paths opened."""
    if isinstance(cloud_or_path, Renderable):
        return cloud_or_path
    from .. import open as open_cloud

    paths = cloud_or_path if isinstance(cloud_or_path, (list, tuple)) else [cloud_or_path]
    if not paths or not all(isinstance(p, (str, Path)) for p in paths):
        raise GigapointError(f"Viewer needs a PointCloud or file path(s), got {type(cloud_or_path).__name__}")
    return open_cloud(*paths)


def _importable(name: str) -> bool:
    """Whether module ``name`` can be imported, without importing it (jupyter_server_proxy pulls
    in jupyter_server and tornado)."""
    if name in sys.modules:
        return sys.modules[name] is not None
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def _checked_template(template, source: str) -> str:
    """A user's address template (``{port}`` stands for the server's port), or a one-line InputError.
    The page's own addresses ("ws", "static/...") are relative to it: it must name a folder."""
    if not isinstance(template, str) or not template.startswith(("http://", "https://", "/")) or "?" in template or "#" in template:
        raise InputError(f"{source} must be an http(s) address or a path, without a query, such as {SHOWN_AT_EXAMPLE}; got {template!r}")
    return template if template.endswith("/") else template + "/"


def _where_shown(url) -> str | None:
    """Where the notebook's browser reaches the viewer: an address template (``{port}`` in it),
    COLAB, or None for the server's own address (a browser on the kernel's machine). A template
    given (``url``, else GIGAPOINT_VIEWER_URL) wins; then Colab; then a JupyterHub's
    jupyter-server-proxy, which serves the kernel machine's ports under the user's prefix."""
    if url is not None:
        return _checked_template(url, "Viewer: url")
    if os.environ.get(VIEWER_URL_VARIABLE):
        return _checked_template(os.environ[VIEWER_URL_VARIABLE], VIEWER_URL_VARIABLE)
    if _importable("google.colab"):
        return COLAB
    prefix = os.environ.get("JUPYTERHUB_SERVICE_PREFIX")  # e.g. "/user/NAME/"
    if prefix and _importable("jupyter_server_proxy"):
        return prefix.rstrip("/") + "/proxy/{port}/"
    return None


def _remote_kernel() -> str | None:
    """Why the kernel looks to run on another machine than the notebook's browser, or None. Only
    signs that say so: a local JupyterLab sets JPY_SESSION_NAME and JPY_PARENT_PID too."""
    if os.environ.get("JUPYTERHUB_SERVICE_PREFIX"):
        return "the kernel runs on a JupyterHub (JUPYTERHUB_SERVICE_PREFIX is set) without jupyter-server-proxy"
    if os.environ.get("SSH_CONNECTION"):
        return "the kernel runs in an SSH session (SSH_CONNECTION is set)"
    return None


_MADE_BY_CELL: dict[str, list] = {}  # a notebook cell's id -> the Viewers its last run made


def _close_earlier_runs(info) -> None:
    """IPython's pre_run_cell: a cell runs again, so the Viewers its last run made are closed (their
    IFrames leave its output; each kept a server and its cloud until the kernel stopped)."""
    for viewer in _MADE_BY_CELL.pop(info.cell_id, []):
        viewer.close()


def _owned_by_cell(viewer) -> None:
    """Note the notebook cell that made ``viewer`` (where the frontend names its cells: JupyterLab,
    Notebook 7, VS Code); elsewhere nothing is done."""
    try:
        from IPython import get_ipython
    except ImportError:
        return
    ip = get_ipython()
    run = ip.displayhook.exec_result if ip is not None else None  # the cell running, None outside one
    if run is None or run.info.cell_id is None:
        return
    if _close_earlier_runs not in ip.events.callbacks["pre_run_cell"]:
        ip.events.register("pre_run_cell", _close_earlier_runs)
    _MADE_BY_CELL.setdefault(run.info.cell_id, []).append(viewer)


class PNG(bytes):
    """PNG bytes that a notebook shows as the image: as plain bytes, ``v.screenshot()`` in a
    cell printed their repr (470 KB of text for a 1280x720 view)."""

    def _repr_png_(self) -> bytes:
        return bytes(self)

    def __repr__(self) -> str:
        return f"<PNG, {len(self):,} bytes>"


class _StoppedServer:
    """What a closed Viewer keeps of its server: its address, not its sessions or cloud."""

    closed = True

    def __init__(self, server) -> None:
        self.url, self.host, self.port, self.push_url = server.url, server.host, server.port, server.push_url

    def close(self) -> None:
        """Closed already."""


class Viewer:
    """Serve ``cloud_or_path`` (a PointCloud, a path or a list of paths) and show it.

    The server runs in a background thread on 127.0.0.1 (a free port unless ``port``);
    in IPython/Jupyter the viewer is displayed as an IFrame. Its address (``shown_at``) is the
    server's own unless the browser runs elsewhere: ``url`` (or the environment variable
    GIGAPOINT_VIEWER_URL), an address template such as ``"https://myhost/proxy/{port}/"``; in
    Google Colab, Colab's proxy of the kernel's port; on a JupyterHub with jupyter-server-proxy,
    ``{JUPYTERHUB_SERVICE_PREFIX}proxy/{port}/``. Served through such a proxy, the server takes
    a token (in ``shown_at``), as the proxy lets others than the kernel's browser in.
    ``screenshot()`` renders the view of the most recently used tab (or the default view) to PNG bytes; ``close()``
    stops the server. Usable as a context manager. Running a notebook cell again closes the
    Viewers its last run made.
    """

    def __init__(self, cloud_or_path, width: int = 960, height: int = 600, host: str = "127.0.0.1", port: int = 0, settings=None, display: bool = True, url: str | None = None):
        from ..render.camera import MAX_IMAGE_SIDE
        from ..render.settings import RenderSettings
        from .server import ViewerServer, _require_starlette, listening_socket

        for name, v in (("width", width), ("height", height)):  # the IFrame's: 0 showed nothing, without a word
            check_whole("Viewer", name, v, 1, MAX_IMAGE_SIDE, " pixels")
        check_switch("display", display, "Viewer")  # "no" was taken as true
        self._where_shown = _where_shown(url)
        # said before a path's points are read (a bad port or settings came after 15 s of a 5 M point file)
        _require_starlette()
        sock = listening_socket(host, port)  # (a port in use, too)
        try:
            settings = RenderSettings.of(settings)  # (parsed once: the server takes the settings as they are)
            self.cloud = _as_cloud(cloud_or_path)
            self.name = self.cloud.name
            self._opened_here = self.cloud is not cloud_or_path  # (from paths: none but this Viewer holds it)
            token = None if self._where_shown is None else secrets.token_urlsafe(18)  # (its Host is the proxy's: no loopback check)
            self.server = ViewerServer(self.cloud, host=host, port=port, token=token, settings=settings, sock=sock).start()
        except BaseException:
            sock.close()
            raise
        self.width, self.height = width, height
        _owned_by_cell(self)
        if display:
            self.display()

    @property
    def url(self) -> str:
        """The server's own address, on the kernel's machine."""
        return self.server.url

    @property
    def shown_at(self) -> str | None:
        """The address the notebook's IFrame shows (``url`` where the browser runs on the kernel's
        machine; a path such as ``/user/NAME/proxy/PORT/?token=...`` on a JupyterHub); None in Colab,
        whose frontend alone knows its proxy's address."""
        if self._where_shown is None:
            return self.url
        if self._where_shown == COLAB:
            return None
        return self._where_shown.replace("{port}", str(self.server.port)) + "?" + self.url.partition("?")[2]

    @property
    def push_url(self) -> str | None:
        """Where another process pushes frames into a LiveCloud shown here (``ws://.../push?push_token=...``;
        gigapoint.live.wire.PushClient), None for other clouds."""
        return self.server.push_url

    def display(self) -> None:
        """Show the IFrame when running under IPython (a no-op elsewhere)."""
        self._check_open("show the cloud")  # (it showed a frame of a server that was gone)
        try:
            from IPython import get_ipython
            from IPython.display import IFrame, display
        except ImportError:
            return
        if get_ipython() is None:
            return
        if self._where_shown == COLAB:
            from google.colab import output

            query = self.url.partition("?")[2]
            output.serve_kernel_port_as_iframe(self.server.port, path=f"/?{query}", width=str(self.width), height=str(self.height))
            return
        remote = _remote_kernel() if self._where_shown is None else None
        if remote is not None:  # the IFrame stayed blank, without a word
            warn(
                f"Viewer: {remote}: the notebook's browser may not reach {self.url} and the viewer may stay blank; "
                f"pip install jupyter-server-proxy where the Jupyter server runs (then restart it), or set {VIEWER_URL_VARIABLE} "
                f"(or Viewer(url=...)) to an address of port {{port}} that the browser reaches, such as {SHOWN_AT_EXAMPLE}"
            )
        display(IFrame(self.shown_at, width=self.width, height=self.height))

    def screenshot(self, width: int | None = None, height: int | None = None, scale: int = 1) -> bytes:
        """PNG bytes of the current view at width x height (default: the tab's size x scale, else 1280x720)."""
        self._check_open("take a screenshot")  # (it still rendered the default view after close())
        for name, value in (("width", width), ("height", height)):  # "a" was int()'s ValueError, 100.5 cut to 100
            if value is not None:
                check_whole("Viewer.screenshot", name, value, 1, MAX_SHOT_SIDE, " pixels")
        if not is_whole_number(scale) or scale not in (1, 2, 4):  # the page's rule: 3 was taken here (2.0 made a float size)
            raise InputError(f"Viewer.screenshot: scale must be 1, 2 or 4, got {scale!r}")
        core = self.server.core
        active = core.last_active
        return PNG(core.screenshot(active.id if active is not None and active.id in core.sessions else None, width, height, scale))

    def redraw(self) -> None:
        """Every tab draws the cloud again, its view kept: after the program changed it
        (``cloud.set_colors``, ``cloud.changed()``), which the tabs do not watch."""
        self._check_open("redraw the cloud")
        self.server.core.redraw()

    @property
    def closed(self) -> bool:
        return self.server.closed

    def _check_open(self, to: str) -> None:
        if self.closed:
            raise InputError(f"Viewer of {self.name!r}: closed, its server stopped; open a new Viewer to {to}")

    def close(self) -> None:
        """Stop the server; a cloud the Viewer opened from paths is let go (``cloud`` None): a closed
        Viewer kept by a variable or the notebook's Out[] held its server and cloud until the kernel stopped."""
        self.server.close()
        self.server = _StoppedServer(self.server)
        if self._opened_here:
            self.cloud = None
        for made in _MADE_BY_CELL.values():  # its cell no longer keeps it (and its cloud) alive
            if self in made:
                made.remove(self)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        closed = ", closed" if self.closed else ""
        if self._where_shown is None:
            return f"Viewer({self.name!r}, {self.url}{closed})"
        shown = self.shown_at or f"Colab's proxy of port {self.server.port}"
        return f"Viewer({self.name!r}, shown at {shown}, served on {self.server.host}:{self.server.port}{closed})"
