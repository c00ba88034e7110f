"""``convert`` takes ``file://`` URLs for its inputs and output (the same octree as with paths);
other URLs get a one-line error naming them: workers read and write through the file system."""

from __future__ import annotations

import filecmp
from pathlib import Path

import pytest

from gigapoint.errors import InputError
from gigapoint.lod import convert
from gigapoint.lod.octree_dir import ConvertError

SAMPLE = Path(__file__).parents[1] / ".." / ".." / "shared" / "data" / "autzen_trim.laz"
pytestmark = pytest.mark.skipif(not SAMPLE.exists(), reason="shared sample missing")


def test_file_urls_give_the_octree_paths_give(tmp_path):
    convert([SAMPLE], tmp_path / "a", max_leaf=3000)
    convert([SAMPLE.resolve().as_uri()], (tmp_path / "b").as_uri(), max_leaf=3000)
    a, b = tmp_path / "a", tmp_path / "b"
    names = sorted(str(p.relative_to(a)) for p in a.rglob("*") if p.is_file())
    assert names == sorted(str(p.relative_to(b)) for p in b.rglob("*") if p.is_file())
    assert all(filecmp.cmp(a / n, b / n, shallow=False) for n in names)


@pytest.mark.parametrize("url", ["s3://bucket/scan.las", "memory://scan.las", "file://otherhost/data/scan.las"])
def test_other_input_urls_are_a_one_line_error(tmp_path, url):
    with pytest.raises(InputError, match=f"^{url}: an input must be a path or a file:// URL") as e:
        convert([url], tmp_path / "o")
    assert "\n" not in str(e.value)
    assert not (tmp_path / "o").exists()


def test_another_output_url_is_a_one_line_error(tmp_path):
    with pytest.raises(ConvertError, match="^memory://octree: the output must be a path or a file:// URL"):
        convert([SAMPLE], "memory://octree")


def test_the_cli_writes_a_file_url_where_it_points_and_refuses_another_url(tmp_path, monkeypatch, capsys):
    """``gigapoint convert a.laz -o file:///data/out`` wrote ./file:/data/out, and ``-o
    s3://bucket/out`` ./s3:/bucket/out (the CLI's Path of a URL: 'file:/data/out'); gp.open and
    render took no file:// URL ("only http:// and https:// URLs are read") nor '~/a.laz'."""
    import gigapoint as gp
    from gigapoint.cli import main

    monkeypatch.chdir(tmp_path)
    out = tmp_path / "deep" / "out"
    assert main(["convert", str(SAMPLE), "-o", out.as_uri(), "--quiet"]) == 0
    assert (out / "octree.json").is_file() and not (tmp_path / "file:").exists()
    assert main(["convert", str(SAMPLE), "-o", "s3://bucket/out", "--quiet"]) == 1
    assert capsys.readouterr().err.strip() == "error: s3://bucket/out: the output must be a path or a file:// URL on this machine (a file system every worker shares)"
    assert not (tmp_path / "s3:").exists()
    uri = SAMPLE.resolve().as_uri()
    assert gp.open(uri).n_points == gp.open(Path(uri)).n_points == gp.open(uri.replace("file://", "file://localhost")).n_points == 110_000
    with pytest.raises(InputError, match=r"^file://otherhost/x.laz: a file:// URL of another machine \(otherhost\); give a path on this one$"):
        gp.open("file://otherhost/x.laz")
    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / "a.laz").write_bytes(SAMPLE.read_bytes())
    assert gp.open("~/a.laz").source_files == (tmp_path / "a.laz",)
    assert main(["render", uri, "-o", str(tmp_path / "x.png"), "-W", "64", "-H", "48"]) == 0
