"""Every file gigapoint writes gets the permissions of a new file under the umask (0644 under 022):
images, videos, depth/index arrays, and every file of gigapoint and Potree octrees."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.cli import main
from gigapoint.io import demo_chunks
from gigapoint.lod import convert
from gigapoint.lod.convert import hooks


@pytest.fixture
def umask():
    """``umask(mask)`` sets the process's umask for one test; the old one comes back after it."""
    old = os.umask(0o022)
    yield os.umask
    os.umask(old)


def _modes(folder) -> dict:
    """{relative path: permission bits} of every file and folder under ``folder``."""
    return {str(p.relative_to(folder)): stat.S_IMODE(p.stat().st_mode) for p in sorted(folder.rglob("*"))}


@pytest.fixture(scope="module")
def cloud_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("in") / "cloud.npy"
    np.save(path, np.random.default_rng(0).random((3000, 3)) * 10)
    return path


@pytest.mark.parametrize("mask, mode", [(0o022, 0o644), (0o027, 0o640)])
def test_cli_images_and_arrays_follow_the_umask(cloud_file, tmp_path, umask, mask, mode):
    umask(mask)
    size = ["--width", "64", "--height", "48", "--backend", "cpu"]
    png, jpg, depth, index = tmp_path / "a.png", tmp_path / "a.jpg", tmp_path / "d.npy", tmp_path / "i.npy"
    assert main(["render", str(cloud_file), "-o", str(png), *size, "--depth-out", str(depth), "--index-out", str(index)]) == 0
    assert main(["render", str(cloud_file), "-o", str(jpg), *size]) == 0
    assert _modes(tmp_path) == {"a.png": mode, "a.jpg": mode, "d.npy": mode, "i.npy": mode}  # no temporary file left
    assert np.load(depth).shape == (48, 64) and np.load(index).shape == (48, 64)


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
def test_videos_are_0644(tmp_path, umask, suffix):
    if suffix == ".mp4":
        pytest.importorskip("imageio_ffmpeg")
        pytest.importorskip("imageio")
    umask(0o022)
    cloud = gp.demo(5_000)
    path = gp.render_turntable(cloud, 3, tmp_path / f"turn{suffix}", width=32, height=24)
    assert path.stat().st_size > 0
    assert _modes(tmp_path) == {f"turn{suffix}": 0o644}


@pytest.mark.parametrize("fmt", ["gigapoint", "potree"])
def test_every_octree_file_is_0644(tmp_path, umask, fmt, monkeypatch):
    umask(0o022)
    chunks = list(demo_chunks(60_000, seed=1, chunk_size=20_000))
    out = tmp_path / "oct"

    # interrupted after its first partition: the working files are 0644 too (folders 0755)
    def stop(done):
        raise KeyboardInterrupt("test interrupt")

    monkeypatch.setattr(hooks, "after_partition_built", stop)
    with pytest.raises(KeyboardInterrupt):
        convert(chunks, out, format=fmt, max_leaf=2_000, partition_points=20_000)
    partial = _modes(out)
    assert any(name.endswith("state.json") for name in partial) and any(name.endswith("preview.npz") for name in partial)
    assert {m for name, m in partial.items() if (out / name).is_file()} == {0o644}
    assert {m for name, m in partial.items() if (out / name).is_dir()} == {0o755}

    monkeypatch.undo()
    convert(chunks, out, format=fmt, max_leaf=2_000, partition_points=20_000)
    files = _modes(out)
    expected = {"metadata.json", "hierarchy.bin", "octree.bin"} if fmt == "potree" else {"octree.json", "nodes.npy", "keys.npy"}
    assert expected <= set(files) and len(files) >= len(expected)
    assert set(files.values()) == {0o644}
    assert stat.S_IMODE(out.stat().st_mode) == 0o755
