"""`gigapoint convert dir/` reads exactly the files `gigapoint render dir/` reads (io.expand_paths)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from gigapoint.cli import main
from gigapoint.errors import GigapointWarning
from gigapoint.io import expand_paths
from gigapoint.lod import open_octree

laspy = pytest.importorskip("laspy")

SUFFIXES = [".las", ".laz", ".ply", ".xyz", ".xyzrgb", ".asc", ".txt", ".csv", ".pts", ".npy", ".npz"]


def _points(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return np.round(rng.random((n, 3)) * 100, 3), rng.integers(0, 256, (n, 3), dtype=np.uint8)


def _write(path, n: int, seed: int) -> None:
    """``n`` points in the format ``path``'s suffix names."""
    xyz, rgb = _points(n, seed)
    suffix = path.suffix
    if suffix in (".las", ".laz"):
        header = laspy.LasHeader(point_format=2, version="1.2")
        header.scales, header.offsets = [0.001] * 3, [0.0] * 3
        las = laspy.LasData(header)
        las.x, las.y, las.z = xyz.T
        las.red, las.green, las.blue = (rgb.astype(np.uint16) * 257).T
        las.write(str(path))  # .laz: compressed (lazrs)
    elif suffix == ".ply":
        head = f"ply\nformat ascii 1.0\nelement vertex {n}\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
        path.write_text(head + "".join(f"{x} {y} {z}\n" for x, y, z in xyz))
    elif suffix == ".npy":
        np.save(path, xyz)
    elif suffix == ".npz":
        np.savez(path, xyz=xyz, rgb=rgb)
    else:
        sep = {".csv": ",", ".asc": "  ", ".txt": "\t"}.get(suffix, " ")
        rows = [sep.join([*(f"{v:.3f}" for v in p), *(str(int(c)) for c in col)]) for p, col in zip(xyz, rgb)]
        path.write_text((f"{n}\n" if suffix == ".pts" else "") + "\n".join(rows) + "\n")


@pytest.fixture(scope="module")
def mixed_dir(tmp_path_factory):
    """Every supported suffix, file k holding 10·2^k points (any subset has its own total), and
    files gigapoint does not read: an unsupported suffix whose content would parse as XYZ, and a
    subdirectory."""
    d = tmp_path_factory.mktemp("mixed")
    counts = {}
    for k, suffix in enumerate(SUFFIXES):
        counts[f"part{k:02d}{suffix}"] = 10 * 2**k
        _write(d / f"part{k:02d}{suffix}", counts[f"part{k:02d}{suffix}"], seed=k)
    (d / "points.bak").write_text("1 2 3\n4 5 6\n")
    (d / "sub").mkdir()
    _write(d / "sub" / "inner.xyz", 7, seed=99)
    return d, counts


def test_convert_and_render_read_the_same_files(mixed_dir, tmp_path, capsys):
    d, counts = mixed_dir
    with pytest.warns(GigapointWarning, match=r"mixed\d*: its subfolders sub hold point files too, not read: read every file below it with --recursive"):
        found = expand_paths([d])
    assert [p.name for p in found] == sorted(counts)  # every suffix, nothing else (sub/ said, not read)
    total = sum(counts.values())

    assert main(["render", str(d), "-o", str(tmp_path / "r.png"), "--width", "64", "--height", "48", "--backend", "cpu"]) == 0
    rendered = int(re.search(r"([\d,]+) points\)", capsys.readouterr().out).group(1).replace(",", ""))

    out = tmp_path / "oct"
    assert main(["convert", str(d), "-o", str(out), "--quiet", "--max-leaf", "2000"]) == 0
    converted = int(re.search(r": ([\d,]+) points in", capsys.readouterr().out).group(1).replace(",", ""))

    assert rendered == converted == open_octree(out).n_points == total


def test_convert_refuses_an_octree_as_input(mixed_dir, tmp_path, capsys):
    d, _ = mixed_dir
    out = tmp_path / "oct"
    assert main(["convert", str(d), "-o", str(out), "--quiet", "--max-leaf", "2000"]) == 0
    capsys.readouterr()
    assert main(["convert", str(out), "-o", str(tmp_path / "again"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "is a converted octree" in err and err.count("\n") == 1


def test_a_conversion_says_which_attributes_not_every_file_has(tmp_path, capsys):
    """As opening them does: the attributes one file lacks (or brings alone) are left out, with a
    warning naming them (it went without a word)."""
    import gigapoint as gp
    from gigapoint.errors import GigapointWarning

    for name, extra in (("a.las", True), ("b.las", False)):
        header = laspy.LasHeader(point_format=6, version="1.4")
        header.scales, header.offsets = [0.01] * 3, [500_000.0, 4_000_000.0, 0.0]
        if extra:
            header.add_extra_dim(laspy.ExtraBytesParams(name="height", type=np.float32))
        las = laspy.LasData(header)
        x, _ = _points(2_000, len(name) + extra)
        las.x, las.y, las.z = 500_000.0 + x[:, 0], 4_000_000.0 + x[:, 1], x[:, 2]
        if extra:
            las.height = np.ones(2_000, np.float32)
        las.write(str(tmp_path / name))
    with pytest.warns(GigapointWarning, match=r"octree: attribute\(s\) height not in every file: left out"):
        gp.convert([tmp_path / "a.las", tmp_path / "b.las"], tmp_path / "octree")
    assert "height" not in open_octree(tmp_path / "octree").attribute_names and "intensity" in open_octree(tmp_path / "octree").attribute_names
    assert main(["convert", str(tmp_path / "b.las"), str(tmp_path / "a.las"), "-o", str(tmp_path / "octree2"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "warning: " in err and "octree2: attribute(s) height not in every file: left out" in err


def test_convert_says_how_to_watch_only_once_the_output_shows_points(autzen_path, tmp_path, capsys):
    """The "while this runs, `gigapoint view OUT` shows what has been read so far" hint came
    before the first file was read: a file that could not be read got the hint, then its error."""
    bad = tmp_path / "bad.laz"
    bad.write_bytes(b"garbage")
    assert main(["convert", str(bad), "-o", str(tmp_path / "bad_out")]) == 1
    err = capsys.readouterr().err
    assert err.strip().splitlines() == [f"error: {bad}: not a LAS/LAZ file (starts with b'garb', expected b'LASF')"]
    assert not (tmp_path / "bad_out").exists()
    assert main(["convert", str(autzen_path), "-o", str(tmp_path / "good")]) == 0
    assert f"while this runs, `gigapoint view {tmp_path / 'good'}` shows what has been read so far" in capsys.readouterr().err
