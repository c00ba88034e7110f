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
