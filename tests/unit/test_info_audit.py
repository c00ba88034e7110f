"""``gigapoint info`` (headers only) as a new user reads it: the CRS's units, the extent's
decimals, the memory of a small cloud."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
from test_crs_units import write_geokeys_only  # (tests/unit is on sys.path)

from gigapoint.io import file_info, files_units, folder_info

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


def test_info_says_the_units_a_las_files_geotiff_unit_keys_name(cli, tmp_path):
    """Oregon Lambert in feet (ProjectedCSTypeGeoKey 2992) with heights in metres by the file's
    VerticalUnitsGeoKey (9001): info said "z: foot (assumed...)" where measurements use metres."""
    path = write_geokeys_only(tmp_path / "feet_xy_metre_z.las", 2992, {4099: 9001})
    rc, out, err = cli("info", path)
    assert rc == 0, err
    assert "  units:       x, y: foot; z: metre" in out.splitlines()
    assert file_info(path)["units"] == files_units([path])


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


def test_a_coordinate_on_the_grid_has_no_decimals_of_float_noise():
    """At scale 1e-7 near 2e5 (float64 steps of 3e-11) a value one float step off the 7-decimal
    grid, offset + X * scale's rounding, showed 11 decimals: '193898.87588700003'."""
    from gigapoint.core.coords import value_decimals

    on_grid = 193898.875887
    noisy = float(np.nextafter(on_grid, np.inf))
    assert value_decimals(noisy, 1e-7) == 7 and value_decimals(on_grid, 1e-7) == 7
    assert value_decimals(float(np.nextafter(4e6 + 0.12345678, 0)), 1e-8) == 8
    assert value_decimals(637000.123456, 0.001) == 6  # off the grid by a fraction of a step: the file's value, as before
    assert value_decimals(193898.87588702643, 1e-7) == 10  # (PDAL's offset 'auto': 0.26 of a step off; its last float digit dropped)


def test_info_help_breaks_no_line_mid_sentence():
    """click keeps a docstring's line breaks: ``info --help`` at 80 columns read 'or of those the'
    / 'filters (--classes, ...) keep.'; each paragraph is one line, wrapped by the terminal's width."""
    import inspect

    from gigapoint.cli.info_cmd import info

    paragraphs = inspect.getdoc(info).split("\n\n")
    assert len(paragraphs) == 2 and all("\n" not in p for p in paragraphs), paragraphs


def test_a_potree_octree_shows_its_grid_and_counts_in_the_singular(cli, tmp_path):
    """A Potree folder's metadata.json names its scale and offset; info showed neither and its
    bounds at 3 decimals ('-2.060'); a one-node octree was '1 nodes in 1 levels'."""
    town = Path(__file__).parent / "data" / "potree_converter" / "town_DEFAULT"
    rc, out, err = cli("info", town)
    assert rc == 0, err
    lines = out.splitlines()
    assert "  scale:       0.01, 0.01, 0.01" in lines and "  offset:      0.52, -2.06, -13.96" in lines
    assert "  bounds min:  0.52, -2.06, -13.96" in lines and "  bounds max:  996.62, 1001.63, 57.73" in lines
    rc, out, err = cli("info", PDAL_EPT / "autzen_clip_4326.copc.laz")
    assert rc == 0 and "  octree:      1 node in 1 level, 1 hierarchy page, spacing 0.456803" in out.splitlines(), err


def test_a_folders_copc_files_show_as_naming_one_does(cli, tmp_path):
    """``info FOLDER`` showed its COPC files as plain 'LAZ 1.4' without their octree lines."""
    import shutil

    for name in ("autzen_clip_native.copc.laz", "autzen_clip_4326.copc.laz"):
        shutil.copy(PDAL_EPT / name, tmp_path / name)
    rc, named, err = cli("info", *sorted(tmp_path.iterdir()))
    assert rc == 0, err
    rc, listed, err = cli("info", tmp_path)
    assert rc == 0, err
    assert listed == named and listed.count("  format:      COPC 1.4, point format 7\n") == 2 and listed.count("  octree:") == 2
