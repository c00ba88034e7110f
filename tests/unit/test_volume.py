"""Stockpile volume from one survey (`gigapoint volume`, gp.volume: volume.py): a surface model
inside the toe polygon against a base (a plane through the toe, its lowest height, an elevation)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import InputError

STEP = 0.1  # the synthetic surveys' point spacing, at 0.05, 0.15, ...: the same lattice in every pixel
CONE = (50.0, 50.0, 20.0, 10.0)  # centre x, y, radius r, height h
TILT = (0.1, 0.05)  # the ground's dz/dx, dz/dy


def lattice(size=100.0):
    x, y = np.meshgrid(np.arange(STEP / 2, size, STEP), np.arange(STEP / 2, size, STEP))
    return x.ravel(), y.ravel()


def cone_on_a_slope():
    """A cone of radius r, height h standing on the tilted plane z = 100 + TILT . (x, y)."""
    x, y = lattice()
    cx, cy, r, h = CONE
    z = 100 + TILT[0] * x + TILT[1] * y + np.maximum(0.0, h * (1 - np.hypot(x - cx, y - cy) / r))
    return gp.from_arrays(np.column_stack([x, y, z]))


def circle(cx, cy, r, n=720, name=None):
    ring = [[cx + r * math.cos(2 * math.pi * k / n), cy + r * math.sin(2 * math.pi * k / n)] for k in range(n)]
    polygon = {"type": "Polygon", "coordinates": [[*ring, ring[0]]]}
    return polygon if name is None else {"type": "Feature", "properties": {"name": name}, "geometry": polygon}


def square(x0, y0, x1, y1, name=None):
    polygon = {"type": "Polygon", "coordinates": [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]}
    return polygon if name is None else {"type": "Feature", "properties": {"name": name}, "geometry": polygon}


def cone_error_bound(gsd, base):
    """How far the cone's volume on a gsd grid can be from the exact one. The surface is Lipschitz
    with slope G = h / r + |TILT| (+ the cone's): a pixel's highest point lies within half a
    diagonal of its centre, so its height is within G gsd / sqrt(2) of the true one there; a toe
    sample's pixel may hold a point a whole diagonal away, G gsd sqrt(2). A least-squares plane's
    integral over the disc is the area times its value at the toe's centroid (the disc's
    centre), the mean of the samples: within the same bound; the lowest sample too. The pixels
    whose centre is inside differ from the disc in a band gsd / sqrt(2) either side of the toe,
    where the pile rises at most G gsd / sqrt(2) above the base (+ both errors)."""
    cx, cy, r, h = CONE
    slope = h / r + math.hypot(*TILT)
    surface, toe = slope * gsd / math.sqrt(2), slope * gsd * math.sqrt(2)
    band = 2 * math.pi * r * math.sqrt(2) * gsd
    wedge = math.hypot(*TILT) * gsd * math.sqrt(2) if base == "lowest" else 0.0  # the flat base lies up to this far from the slope in the band
    return math.pi * r * r * (surface + toe) + band * (surface + surface + toe + wedge)


@pytest.mark.parametrize("base", ["plane", "lowest"])
def test_a_cone_on_a_slope_is_its_volume_within_the_discretisation_error(base):
    """Plane: pi r^2 h / 3. Lowest: that and the wedge of slope between the toe's lowest point and
    the plane: integral of |TILT| r + TILT . (x - c) over the disc = pi r^3 |TILT|."""
    cx, cy, r, h = CONE
    exact = math.pi * r * r * h / 3 + (math.pi * r**3 * math.hypot(*TILT) if base == "lowest" else 0.0)
    cloud, errors = cone_on_a_slope(), []
    for gsd in (0.5, 0.25):
        v = gp.volume(cloud, circle(cx, cy, r), gsd, base=base)
        (pile,) = v.piles
        errors.append(abs(pile.fill - exact))
        assert errors[-1] <= cone_error_bound(gsd, base), (gsd, pile.fill, exact)
        assert pile.cut < 1e-3 * exact and v.fill == pile.fill and v.net == pile.fill - pile.cut
        assert abs(pile.area - math.pi * r * r) <= 2 * math.pi * r * gsd  # the toe's pixels count whole or not at all
        assert pile.highest[:2] == (cx + gsd / 2, cy + gsd / 2) or np.hypot(pile.highest[0] - cx, pile.highest[1] - cy) <= gsd
        assert abs(pile.highest[2] - (100 + TILT[0] * cx + TILT[1] * cy + h)) <= gsd  # the apex
        assert (pile.filled, pile.empty) == (0.0, 0.0)
    assert errors[1] < errors[0]  # finer pixels, closer
    if base == "plane":
        assert pile.base["type"] == "plane" and np.allclose(pile.base["slope"], TILT, atol=0.01)
    else:
        toe_lowest = 100 + TILT[0] * cx + TILT[1] * cy - math.hypot(*TILT) * r
        assert pile.base["type"] == "lowest" and abs(pile.base["z"] - toe_lowest) <= cone_error_bound(0.25, "plane") / (math.pi * r * r)


def box_pile():
    """Flat ground at z 100 with a 10 x 10 block 5 high on it (pixel edges at whole units)."""
    x, y = lattice(40.0)
    z = np.where((x >= 15) & (x < 25) & (y >= 15) & (y < 25), 105.0, 100.0)
    return gp.from_arrays(np.column_stack([x, y, z]))


def test_a_box_above_a_given_elevation_is_exact_and_below_it_is_cut():
    v = gp.volume(box_pile(), square(10, 10, 30, 30), 0.5, base=100)
    (pile,) = v.piles
    assert (pile.fill, pile.cut, pile.area, pile.polygon_area, pile.height) == (500.0, 0.0, 400.0, 400.0, 5.0)
    assert pile.base == {"type": "elevation", "z": 100.0} and pile.highest[2] == 105.0
    pile = gp.volume(box_pile(), square(10, 10, 30, 30), 0.5, base=102).piles[0]
    assert (pile.fill, pile.cut, pile.net) == (300.0, 600.0, -300.0)  # 3 over the block's 100; 2 over the rest's 300
    assert gp.volume(box_pile(), square(10, 10, 30, 30), 0.5).piles[0].fill == pytest.approx(500.0, abs=1e-9)  # the plane through the toe: z 100 (a least-squares fit: 1e-14 off)


def test_holes_inside_the_polygon_are_filled_and_counted():
    """Points missing from the block's top: filled from its edges, the volume kept; without
    filling the holes count no volume and are reported empty."""
    x, y = lattice(40.0)
    z = np.where((x >= 15) & (x < 25) & (y >= 15) & (y < 25), 105.0, 100.0)
    hole = (x >= 18) & (x < 22) & (y >= 18) & (y < 22)
    holed = gp.from_arrays(np.column_stack([x, y, z])[~hole])
    pile = gp.volume(holed, square(10, 10, 30, 30), 0.5, base=100).piles[0]
    assert pile.fill == 500.0 and pile.filled == 16 / 400 and pile.empty == 0.0
    pile = gp.volume(holed, square(10, 10, 30, 30), 0.5, base=100, fill_nodata=None).piles[0]
    assert pile.fill == 500.0 - 5 * 16 and pile.filled == 0.0 and pile.empty == 16 / 400


def test_two_piles_in_a_feature_collection_are_named_and_summed():
    x, y = lattice(60.0)
    z = 100.0 + np.where((x >= 10) & (x < 20) & (y >= 10) & (y < 20), 2.0, 0.0) + np.where((x >= 40) & (x < 45) & (y >= 40) & (y < 50), 3.0, 0.0)
    cloud = gp.from_arrays(np.column_stack([x, y, z]))
    piles = {"type": "FeatureCollection", "features": [square(5, 5, 25, 25, "sand"), square(35, 35, 55, 55, "gravel")]}
    v = gp.volume(cloud, piles, 0.5, base=100)
    assert [(p.name, p.fill, p.area) for p in v.piles] == [("sand", 200.0, 400.0), ("gravel", 150.0, 400.0)]
    assert (v.fill, v.area) == (350.0, 800.0)
    summary = v.summary()
    assert [p["name"] for p in summary["piles"]] == ["sand", "gravel"] and summary["total"]["fill"] == 350.0
    unnamed = gp.volume(cloud, {"type": "MultiPolygon", "coordinates": [square(5, 5, 25, 25)["coordinates"], square(35, 35, 55, 55)["coordinates"]]}, 0.5, base=100)
    assert [p.name for p in unnamed.piles] == ["pile 1", "pile 2"]


# a raised flat area in autzen_trim (which has no building class): its roof at ~422-425 ft, the ground ~410
AUTZEN_BLOCK = (636455.0, 849225.0, 636535.0, 849260.0)


def test_autzen_a_raised_area_has_a_positive_volume_and_the_polygons_footprint(cli, tmp_path, autzen_path):
    toe = tmp_path / "toe.geojson"
    toe.write_text(json.dumps(square(*AUTZEN_BLOCK, "block")))
    gsd = 2.0
    rc, out, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", gsd, "--json", "--dsm-out", tmp_path / "dsm.tif")
    assert rc == 0, err
    got = json.loads(out)
    (pile,) = got["piles"]
    x0, y0, x1, y1 = AUTZEN_BLOCK
    assert pile["name"] == "block" and pile["polygon_area"] == (x1 - x0) * (y1 - y0)
    assert abs(pile["area"] - pile["polygon_area"]) <= 2 * ((x1 - x0) + (y1 - y0)) * gsd  # a pixel along the outline
    assert pile["fill"] > 1000 and got["units"] == {"length": "ft", "area": "ft²", "volume": "ft³"}
    assert got["outputs"] == [str(tmp_path / n) for n in ("dsm.tif", "dsm.tfw", "dsm.prj")]
    rc, text, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", gsd, "--base", "lowest")
    assert rc == 0, err
    assert text.startswith("block: fill ") and "ft³" in text and "above a lowest base" in text


@pytest.mark.parametrize(
    ("polygon", "kwargs", "message"),
    [
        (None, {}, "volume: clip_polygon is needed"),
        (square(1000, 1000, 1010, 1010), {}, r"the GeoJSON geometry: no point of arrays lies in its box x 1000..1010, y 1000..1010: the polygon is outside the data"),
        (square(10, 10, 30, 30), {"gsd": 0}, "volume: gsd must be a number > 0"),
        (square(10, 10, 30, 30), {"base": "top"}, "volume: base must be 'plane', 'lowest' or an elevation"),
    ],
)
def test_bad_inputs_are_one_line_errors(polygon, kwargs, message):
    with pytest.raises(InputError, match=message) as error:
        gp.volume(box_pile(), polygon, **{"gsd": 0.5, **kwargs})
    assert "\n" not in str(error.value)


def test_a_toe_without_heights_says_why_and_how_to_mend_it():
    """Points 2 units apart and a 0.25 grid: the toe's pixels hold none, so no plane can be laid
    (the message named neither the grid nor a coarser one); a 3-unit grid finds the toe."""
    x, y = np.meshgrid(np.arange(0.0, 40.0, 2.0), np.arange(0.0, 40.0, 2.0))
    cloud = gp.from_arrays(np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 100.0)]))
    toe = square(10.3, 10.3, 29.7, 29.7)
    with pytest.raises(InputError, match=r"no point near the toe \(it runs off the data, or the points lie further apart than the 0\.25 grid: a coarser gsd\)"):
        gp.volume(cloud, toe, 0.25, fill_nodata=None)
    assert gp.volume(cloud, toe, 3.0).piles[0].fill == pytest.approx(0.0, abs=1e-6)


def test_a_polygon_over_a_gap_in_the_data_holds_no_point():
    x, y = lattice(40.0)
    gap = (x >= 14.5) & (x < 25.5) & (y >= 14.5) & (y < 25.5)  # points in the box read (a pixel beyond), none inside
    cloud = gp.from_arrays(np.column_stack([x, y, np.full(x.size, 100.0)])[~gap])
    with pytest.raises(InputError, match=r"^the GeoJSON geometry: no point of arrays lies inside it$"):
        gp.volume(cloud, square(15, 15, 25, 25), 0.5)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((), "--clip-polygon is needed"),
        (("--clip-polygon", "toe.geojson", "--gsd", "0"), "--gsd must be a number > 0"),
        (("--clip-polygon", "toe.geojson", "--base", "top"), "--base must be 'plane', 'lowest' or an elevation"),
        (("--clip-polygon", "missing.geojson"), "no such file"),
    ],
)
def test_cli_errors_are_one_line(cli, tmp_path, monkeypatch, autzen_path, args, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "toe.geojson").write_text(json.dumps(square(*AUTZEN_BLOCK)))
    rc, out, err = cli("volume", autzen_path, *(args if "--gsd" in args else (*args, "--gsd", "2")))
    assert rc != 0 and message in err and len(err.strip().splitlines()) == 1, err
