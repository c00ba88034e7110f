"""``gigapoint info`` (headers only) as a new user reads it: the CRS's units, the extent's
decimals, the memory of a small cloud."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from gigapoint.io import file_info, folder_info

PDAL_EPT = Path(__file__).parent / "data" / "pdal_ept"


def test_info_says_the_units_of_the_crs(cli, autzen_path, tmp_path):
    """The CRS was named ('NAD_1983_HARN_Lambert_Conformal_Conic (WKT)') but not whether its
    numbers are feet or metres; a compound CRS's heights may be in another unit."""
    rc, out, err = cli("info", autzen_path, PDAL_EPT / "autzen_clip_native.copc.laz", PDAL_EPT / "autzen_clip_4326.copc.laz")
    assert rc == 0, err
    lines = out.splitlines()
    assert "  units:       x, y: foot; z: foot (assumed: the CRS names no vertical unit)" in lines
    assert "  units:       x, y: metre; z: US survey foot" in lines  # NAD83 / Oregon LCC (m) + NAVD88 height (ftUS)
    assert "  units:       x, y: degree; z: not named" in lines  # WGS 84
    rc, out, _ = cli("info", "--json", autzen_path)
    units = json.loads(out)["units"]
    assert units["horizontal"]["symbol"] == "ft" and units["horizontal"]["metres"] == 0.3048 and units["vertical_assumed"]
    summed = folder_info(tmp_path, [file_info(autzen_path), file_info(autzen_path)])
    assert summed["units"]["horizontal"]["name"] == "foot"  # a folder's tiles of one CRS, summed up
    no_crs = tmp_path / "p.npy"
    np.save(no_crs, np.arange(30, dtype=np.float64).reshape(10, 3))
    rc, out, _ = cli("info", no_crs)
    assert "units:" not in out  # (no CRS named: no line)


def test_the_extent_has_the_scales_decimals_whatever_the_offset(cli):
    """PDAL's offset 'auto' at scale 1e-7 showed the extent's float noise: '40.67000000001, 38.5300000'."""
    rc, out, err = cli("info", PDAL_EPT / "autzen_clip_native.copc.laz")
    assert rc == 0, err
    assert "  extent:      40.6700000, 38.5300000, 86.42" in out.splitlines()


def test_the_memory_of_a_small_cloud_is_not_zero_mib(cli, tmp_path):
    """``info --memory`` of 1 000 points said 'memory: 0.0 MiB, 16.06 bytes/point'."""
    path = tmp_path / "small.npy"
    np.save(path, np.random.default_rng(0).random((1000, 3)))
    rc, out, err = cli("info", "--memory", path)
    assert rc == 0, err
    line = next(line for line in out.splitlines() if line.startswith("memory:"))
    size, per_point = re.match(r"memory: ([\d.]+) KiB, ([\d.]+) bytes/point", line).groups()
    assert abs(float(size) * 1024 / 1000 - float(per_point)) < 0.1  # the total is the points' bytes
