"""Reading over HTTP, audited as a demanding user would (test_copc_http.py has the rest): URLs
given where point files are read, failures past a redirect, and servers that answer otherwise
than asked. Servers bind 127.0.0.1."""

from __future__ import annotations

import pytest

import gigapoint as gp
from gigapoint.errors import InputError

pytest.importorskip("httpx")

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
