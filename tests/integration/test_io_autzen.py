"""The real sample: autzen_trim.laz (110 000 points, RGB, state-plane feet) through readers, open and the CLI."""

from __future__ import annotations

import json

import laspy
import numpy as np

import gigapoint
from gigapoint.cli import main
from gigapoint.io import file_info, read_chunks


def test_autzen_reads_110000_points_with_colors(autzen_path):
    chunks = list(read_chunks(autzen_path, chunk_size=25_000))
    assert [len(c) for c in chunks] == [25_000] * 4 + [10_000]
    xyz = np.concatenate([c.xyz for c in chunks])
    rgba = np.concatenate([c.rgba for c in chunks])
    assert xyz.shape == (110_000, 3)
    # large projected coordinates (hundreds of km), read exactly as laspy scales them
    with laspy.open(autzen_path) as r:
        ref = r.read()
    np.testing.assert_array_equal(xyz[:, 0], np.asarray(ref.x))
    np.testing.assert_array_equal(xyz[:, 2], np.asarray(ref.z))
    assert 600_000 < xyz[:, 0].min() < xyz[:, 0].max() < 700_000
    assert 800_000 < xyz[:, 1].min() < xyz[:, 1].max() < 900_000
    # real colors: this file stores 8-bit values (max 236) in its 16-bit fields, so they are kept as they are
    assert np.asarray(ref.red).max() <= 255
    np.testing.assert_array_equal(rgba[:, :3], np.column_stack([ref.red, ref.green, ref.blue]).astype(np.uint8))
    assert len(np.unique(rgba[:, :3], axis=0)) > 1000
    assert (rgba[:, 3] == 255).all()
    np.testing.assert_array_equal(np.concatenate([c.attributes["intensity"] for c in chunks]), np.asarray(ref.intensity))


def test_autzen_open(autzen_path):
    cloud = gigapoint.open(autzen_path)
    assert cloud.n_points == 110_000 and cloud.name == "autzen_trim.laz"
    lo, hi = cloud.bounds
    info = file_info(autzen_path)
    np.testing.assert_allclose(lo, info["bounds"]["min"], atol=0.01)
    np.testing.assert_allclose(hi, info["bounds"]["max"], atol=0.01)
    assert {"intensity", "classification", "return_number", "number_of_returns", "point_source_id", "gps_time"} <= set(cloud.attributes)


def test_autzen_file_info(autzen_path):
    info = file_info(autzen_path)
    assert info["format"] == "LAZ"
    assert info["point_count"] == 110_000
    assert info["las_version"] == "1.2" and info["point_format"] == 3
    assert info["scale"] == [0.01, 0.01, 0.01]
    assert info["crs"] and "Lambert_Conformal_Conic" in info["crs"]
    assert info["file_size"] == autzen_path.stat().st_size
    assert info["has_color"]


def test_cli_info(autzen_path, capsys):
    assert main(["info", str(autzen_path)]) == 0
    out = capsys.readouterr().out
    assert str(autzen_path) in out
    assert "LAZ 1.2, point format 3" in out
    assert "110,000" in out
    assert "636001.76, 848935.20, 406.26 (header)" in out  # min from the header, at the file's scale (#17)
    assert "Lambert_Conformal_Conic" in out
    assert "intensity" in out


def test_cli_info_json_and_several_files(autzen_path, tmp_path, capsys):
    other = tmp_path / "b.xyz"
    other.write_text("1 2 3\n4 5 6\n")
    assert main(["info", "--json", str(autzen_path), str(other)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [json.loads(x)["point_count"] for x in lines] == [110_000, 2]


def test_cli_info_errors(tmp_path, capsys):
    missing = tmp_path / "missing.laz"
    assert main(["info", str(missing)]) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"error: {missing}: no such file"
    bad = tmp_path / "bad.las"
    bad.write_bytes(b"LASF" + bytes(100))
    assert main(["info", str(bad)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {bad}: truncated LAS header") and "\n" not in err
