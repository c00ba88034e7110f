"""Where gp.Viewer's IFrame points: the server's own address, a user's template, a JupyterHub's
jupyter-server-proxy, Google Colab's port proxy; and a warning where the browser cannot reach it."""

from __future__ import annotations

import re
import sys
import types

import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("uvicorn")
httpx = pytest.importorskip("httpx")

import gigapoint
from gigapoint.errors import GigapointWarning

pytestmark = [pytest.mark.timeout(120)]

REMOTE_SIGNS = ("GIGAPOINT_VIEWER_URL", "JUPYTERHUB_SERVICE_PREFIX", "SSH_CONNECTION")


@pytest.fixture(scope="module")
def cloud():
    return gigapoint.from_arrays(np.random.default_rng(0).uniform(0, 10, (500, 3)), name="dots")


@pytest.fixture()
def shown(monkeypatch):
    """A notebook (a fake IPython whose display records the IFrames) on the kernel's machine: no
    sign of a remote kernel, neither Colab nor jupyter-server-proxy importable."""
    frames = []
    ipython = types.ModuleType("IPython")
    ipython.get_ipython = lambda: types.SimpleNamespace(displayhook=types.SimpleNamespace(exec_result=None))
    display_mod = types.ModuleType("IPython.display")
    display_mod.IFrame = lambda url, width, height: ("iframe", url, width, height)
    display_mod.display = frames.append
    ipython.display = display_mod
    monkeypatch.setitem(sys.modules, "IPython", ipython)
    monkeypatch.setitem(sys.modules, "IPython.display", display_mod)
    for name in ("google.colab", "jupyter_server_proxy"):
        monkeypatch.setitem(sys.modules, name, None)  # None in sys.modules: not importable
    for name in REMOTE_SIGNS:
        monkeypatch.delenv(name, raising=False)
    return frames


def fake_colab(monkeypatch) -> list:
    """google.colab.output in sys.modules, recording serve_kernel_port_as_iframe's calls."""
    calls = []
    google, colab, output = types.ModuleType("google"), types.ModuleType("google.colab"), types.ModuleType("google.colab.output")
    output.serve_kernel_port_as_iframe = lambda port, **kw: calls.append((port, kw))
    colab.output, google.colab = output, colab
    for name, module in (("google", google), ("google.colab", colab), ("google.colab.output", output)):
        monkeypatch.setitem(sys.modules, name, module)
    return calls


@pytest.mark.filterwarnings("error")
def test_a_local_notebook_shows_the_servers_own_address_without_a_word(cloud, shown, monkeypatch):
    """A local JupyterLab sets JPY_SESSION_NAME and JPY_PARENT_PID: no sign of a remote kernel."""
    monkeypatch.setenv("JPY_SESSION_NAME", "/home/me/clouds.ipynb")
    monkeypatch.setenv("JPY_PARENT_PID", "4242")
    with gigapoint.Viewer(cloud, width=700, height=400) as v:
        assert shown == [("iframe", f"http://127.0.0.1:{v.server.port}/", 700, 400)] and v.shown_at == v.url
        assert v.server.token is None
        assert repr(v) == f"Viewer('dots', http://127.0.0.1:{v.server.port}/)"


def test_a_jupyterhub_with_jupyter_server_proxy_shows_the_proxy_path(cloud, shown, monkeypatch):
    monkeypatch.setenv("JUPYTERHUB_SERVICE_PREFIX", "/user/ana/")
    monkeypatch.setitem(sys.modules, "jupyter_server_proxy", types.ModuleType("jupyter_server_proxy"))
    with gigapoint.Viewer(cloud, width=700, height=400) as v:
        port, token = v.server.port, v.server.token
        assert shown == [("iframe", f"/user/ana/proxy/{port}/?token={token}", 700, 400)]
        assert repr(v) == f"Viewer('dots', shown at /user/ana/proxy/{port}/?token={token}, served on 127.0.0.1:{port})"
        # the proxy lets the hub's users in, by any Host: the token keeps them out
        assert httpx.get(f"http://127.0.0.1:{port}/", timeout=30).status_code == 403
        assert httpx.get(f"http://127.0.0.1:{port}/?token={token}", headers={"Host": "hub.example.org"}, timeout=30).status_code == 200


def test_an_address_given_wins(cloud, shown, monkeypatch):
    """Viewer(url=...) over GIGAPOINT_VIEWER_URL over Colab and a JupyterHub's proxy; the page's
    addresses are relative to it, so it always names a folder."""
    fake_colab(monkeypatch)
    monkeypatch.setenv("JUPYTERHUB_SERVICE_PREFIX", "/user/ana/")
    monkeypatch.setitem(sys.modules, "jupyter_server_proxy", types.ModuleType("jupyter_server_proxy"))
    monkeypatch.setenv("GIGAPOINT_VIEWER_URL", "https://myhost/tunnel/{port}")
    with gigapoint.Viewer(cloud) as v:
        assert shown[-1][1] == f"https://myhost/tunnel/{v.server.port}/?token={v.server.token}"
    with gigapoint.Viewer(cloud, url="http://localhost:{port}/") as v:
        assert shown[-1][1] == f"http://localhost:{v.server.port}/?token={v.server.token}"
    for bad in ("myhost/proxy/{port}/", "https://myhost/?x=1", 5):
        with pytest.raises(gigapoint.GigapointError, match=rf"^Viewer: url must be an http\(s\) address or a path, without a query, such as 'https://myhost/proxy/{{port}}/'; got {re.escape(repr(bad))}$"):
            gigapoint.Viewer(cloud, url=bad, display=False)
    monkeypatch.setenv("GIGAPOINT_VIEWER_URL", "myhost:8000")
    with pytest.raises(gigapoint.GigapointError, match=r"^GIGAPOINT_VIEWER_URL must be an http\(s\) address .*; got 'myhost:8000'$"):
        gigapoint.Viewer(cloud, display=False)


def test_colab_shows_the_kernel_port_through_its_own_proxy(cloud, shown, monkeypatch):
    calls = fake_colab(monkeypatch)
    with gigapoint.Viewer(cloud, width=700, height=400) as v:
        port, token = v.server.port, v.server.token
        assert calls == [(port, {"path": f"/?token={token}", "width": "700", "height": "400"})] and shown == []
        assert v.shown_at is None  # (Colab's frontend alone knows its proxy's address)
        assert repr(v) == f"Viewer('dots', shown at Colab's proxy of port {port}, served on 127.0.0.1:{port})"


@pytest.mark.parametrize(
    ("variable", "value", "why"),
    [
        ("JUPYTERHUB_SERVICE_PREFIX", "/user/ana/", "the kernel runs on a JupyterHub (JUPYTERHUB_SERVICE_PREFIX is set) without jupyter-server-proxy"),
        ("SSH_CONNECTION", "10.0.0.5 52814 10.0.0.9 22", "the kernel runs in an SSH session (SSH_CONNECTION is set)"),
    ],
)
def test_a_remote_kernel_without_a_proxy_says_the_frame_may_stay_blank(cloud, shown, monkeypatch, variable, value, why):
    monkeypatch.setenv(variable, value)
    with pytest.warns(GigapointWarning) as caught, gigapoint.Viewer(cloud) as v:
        assert shown == [("iframe", v.url, 960, 600)]
    assert [str(w.message) for w in caught] == [
        (
            f"Viewer: {why}: the notebook's browser may not reach {v.url} and the viewer may stay blank; "
            "pip install jupyter-server-proxy where the Jupyter server runs (then restart it), or set GIGAPOINT_VIEWER_URL "
            "(or Viewer(url=...)) to an address of port {port} that the browser reaches, such as 'https://myhost/proxy/{port}/'"
        )
    ]
