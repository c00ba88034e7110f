"""Stockpile volume from one survey (`gigapoint volume`, gp.volume: volume.py): a surface model
inside the toe polygon against a base (a plane through the toe, its lowest height, an elevation)."""

from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest
from PIL import Image

import gigapoint as gp
from gigapoint.errors import GigapointWarning, InputError
from gigapoint.render.colors import colormap_table
from gigapoint.survey.volume import PREVIEW_COLORMAP, TOE_RGB

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
    unfilled = (
        r"^volume: the GeoJSON geometry: 4\.0% of the pile's pixels hold no height and count no volume \(its figures are short by them\): the toe "
        r"runs beyond the data's footprint \(draw it inside the points\), or holes are left unfilled \(fill_nodata=None; 'all' fills them\)$"
    )
    with pytest.warns(GigapointWarning, match=unfilled):  # (the share alone, in the figures, is easily missed)
        pile = gp.volume(holed, square(10, 10, 30, 30), 0.5, base=100, fill_nodata=None).piles[0]
    assert pile.fill == 500.0 - 5 * 16 and pile.filled == 0.0 and pile.empty == 16 / 400


def test_a_toe_beyond_the_data_warns_that_its_empty_pixels_count_no_volume():
    """The toe 30 x 30 over the survey's corner, 20 x 20 of it with points: its pixels beyond the
    data hold no height, even filled (a TIN does not extrapolate), and count no volume; said, as
    a warning naming the toe and the share, and in ``empty``."""
    beyond = r"^volume: the GeoJSON geometry: 55\.6% of the pile's pixels hold no height and count no volume \(its figures are short by them\): the toe runs beyond the data's footprint \(draw it inside the points\)$"
    with pytest.warns(GigapointWarning, match=beyond):
        pile = gp.volume(box_pile(), square(20, 20, 50, 50), 0.5, base=100).piles[0]
    assert (pile.fill, pile.area, pile.empty) == (5 * 25.0, 900.0, 2000 / 3600)  # the block's 5 x 5 corner inside it, 5 high


def test_a_toe_of_points_on_one_line_is_refused_for_having_no_area():
    """A toe whose points lie on one line said "no pixel centre of the 0.25 grid lies inside it:
    give a finer gsd", which no grid could help; the viewer's volume tool said why, the library not."""
    line = {"type": "Polygon", "coordinates": [[[15, 15], [30, 15], [45, 15], [15, 15]]]}
    slanted = {"type": "Polygon", "coordinates": [[[10.1, 10.3], [20.2, 20.6], [30.3, 30.9], [10.1, 10.3]]]}
    for toe in (line, slanted):
        with pytest.raises(InputError) as err:
            gp.volume(box_pile(), toe, 0.25, base=100)
        assert str(err.value) == "volume: the GeoJSON geometry: the polygon's points lie on one line: it has no area; move a point off the line"


def test_a_long_geojson_toes_error_stays_one_short_line():
    """A dict toe was labelled by its repr: a 2000-vertex polygon on one line made a 33,932-character message."""
    ring = [[15 + 0.001 * i, 15.0] for i in range(2000)] + [[15, 15]]
    with pytest.raises(InputError) as err:
        gp.volume(box_pile(), {"type": "Polygon", "coordinates": [ring]}, 0.25, base=100)
    assert str(err.value) == "volume: the GeoJSON geometry: the polygon's points lie on one line: it has no area; move a point off the line"
    assert len(str(err.value)) < 300


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


def cone_on_flat_ground():
    x, y = lattice()
    cx, cy, r, h = CONE
    return gp.from_arrays(np.column_stack([x, y, 100 + np.maximum(0.0, h * (1 - np.hypot(x - cx, y - cy) / r))]))


def pixel_of(camera, x, y) -> tuple[int, int]:
    """(row, col) of the pixel of top-down ``camera`` whose centre is nearest ``x``, ``y``."""
    size, _, _, _, x0, y0 = camera.world_file()
    return round((y0 - y) / size), round((x - x0) / size)


def test_the_preview_colours_the_height_above_the_base_and_draws_the_toe(tmp_path):
    cx, cy, r, h = CONE
    v = gp.volume(cone_on_flat_ground(), circle(cx, cy, r), 0.5, base=100)  # (the four pixels round the apex alike)
    (pile,) = v.piles
    image, colours = v.preview(), colormap_table(PREVIEW_COLORMAP)
    apex = pixel_of(v.camera, *pile.highest[:2])
    assert math.dist(pile.highest[:2], (cx, cy)) < 0.5 and v.above_base[apex] == np.float32(pile.height)
    assert tuple(image[apex]) == tuple(colours[255])  # the cone's top: the colormap's top colour
    halfway = pixel_of(v.camera, cx + r / 2, cy)
    assert abs(v.above_base[halfway] - h / 2) < 0.5 and tuple(image[halfway]) == tuple(colours[round(255 * v.above_base[halfway] / pile.height)])
    assert tuple(image[pixel_of(v.camera, cx + r, cy)]) == (*TOE_RGB, 255)  # the toe drawn over it
    for outside in (pixel_of(v.camera, cx + r + 1, cy), (0, 0)):  # beyond the toe: transparent, no height
        assert image[outside][3] == 0 and np.isnan(v.above_base[outside])
    with pytest.warns(GigapointWarning, match="no .prj written: the inputs name no CRS"):
        written = v.write_preview(tmp_path / "cone.png")
    assert written == [tmp_path / "cone.png", tmp_path / "cone.pgw"]
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "cone.png")), image)
    assert (tmp_path / "cone.pgw").read_text().split() == [f"{v:.15g}" for v in v.camera.world_file()]


def test_the_geotiff_is_the_height_above_the_base_the_volume_sums(tmp_path):
    """On a slope the base is a tilted plane: each pixel's height above it, not above a level."""
    v = gp.volume(cone_on_a_slope(), circle(*CONE[:3]), 0.5)
    (pile,) = v.piles
    with pytest.warns(GigapointWarning, match="no .prj written"):
        assert v.write_geotiff(tmp_path / "above.tif") == [tmp_path / "above.tif", tmp_path / "above.tfw"]
    above = np.asarray(Image.open(tmp_path / "above.tif"))
    np.testing.assert_array_equal(above, v.above_base)
    assert (~np.isnan(above)).sum() == pile.pixels and np.nanmax(above) == np.float32(pile.height)
    assert above[above > 0].sum(dtype=np.float64) * 0.25 == pytest.approx(pile.fill, rel=1e-6)  # float32 heights: 1e-7 each
    assert -above[above < 0].sum(dtype=np.float64) * 0.25 == pytest.approx(pile.cut, rel=1e-6, abs=1e-9)
    assert abs(float(np.nanmax(above)) - CONE[3]) < 0.5  # the apex: the cone's height, the slope under it taken away
    box = gp.volume(box_pile(), square(10, 10, 30, 30), 0.5, base=102)  # 3 above the block's 100, 2 below over the rest's 300
    assert sorted(np.unique(box.above_base[~np.isnan(box.above_base)]).tolist()) == [-2.0, 3.0]
    assert (np.nansum(np.where(box.above_base > 0, box.above_base, 0)) * 0.25, box.piles[0].fill) == (300.0, 300.0)


def test_a_multipolygon_feature_is_one_pile_each_part_on_its_own_base():
    """A pile split by a step in the ground (100 left of x 30, 110 right of it): one pile named
    by its Feature, its volume the two parts', each part's plane laid through its own toe (one
    plane through both toes would tilt across the step and count the ground as volume)."""
    x, y = lattice(60.0)
    ground = np.where(x < 30, 100.0, 110.0)
    z = ground + np.where((x >= 10) & (x < 20) & (y >= 10) & (y < 20), 2.0, 0.0) + np.where((x >= 40) & (x < 45) & (y >= 40) & (y < 50), 3.0, 0.0)
    cloud = gp.from_arrays(np.column_stack([x, y, z]))
    parts = [square(5, 5, 25, 25)["coordinates"], square(35, 35, 55, 55)["coordinates"]]
    split = {"type": "Feature", "properties": {"name": "gravel"}, "geometry": {"type": "MultiPolygon", "coordinates": parts}}
    v = gp.volume(cloud, {"type": "FeatureCollection", "features": [split, square(5, 35, 25, 55, "sand")]}, 0.5)
    gravel, sand = v.piles
    assert (gravel.name, sand.name) == ("gravel", "sand")
    assert gravel.fill == pytest.approx(200.0 + 150.0, abs=1e-6) and gravel.cut < 1e-6
    assert (gravel.area, gravel.polygon_area, gravel.pixels, gravel.height) == (800.0, 800.0, 3200, pytest.approx(3.0, abs=1e-6))
    assert gravel.highest[2] == 113.0 and gravel.base["type"] == "plane"
    assert [part["z"] for part in gravel.base["parts"]] == pytest.approx([100.0, 110.0]) and gravel.base["z"] == pytest.approx(105.0)
    assert np.nansum(np.where(v.above_base > 0, v.above_base, 0), dtype=np.float64) * 0.25 == pytest.approx(v.fill, rel=1e-6)
    unnamed = gp.volume(cloud, {**split, "properties": {}}, 0.5, base="lowest")
    assert [(p.name, p.pixels) for p in unnamed.piles] == [("pile 1", 3200)] and unnamed.fill == 350.0  # each part level at its own toe's lowest


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


def test_cli_writes_the_heights_above_the_base_and_a_preview_as_python_does(cli, tmp_path, autzen_path):
    toe = tmp_path / "toe.geojson"
    toe.write_text(json.dumps(square(*AUTZEN_BLOCK, "block")))
    (tmp_path / "cli").mkdir()
    rc, out, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", 2, "-o", tmp_path / "cli/above.tif", "--preview", tmp_path / "cli/above.png", "--json")
    assert rc == 0, err
    names = ["above.tif", "above.png", "above.tfw", "above.pgw", "above.prj"]
    assert json.loads(out)["outputs"] == [str(tmp_path / "cli" / n) for n in names]  # one .prj for both
    result = gp.volume(autzen_path, toe, 2.0)
    result.write_geotiff(tmp_path / "above.tif")
    result.write_preview(tmp_path / "above.png")  # (keeps the .prj the GeoTIFF wrote: the same CRS)
    for name in names:
        assert (tmp_path / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name
    preview = np.asarray(Image.open(tmp_path / "above.png"))
    assert preview.shape == (*result.above_base.shape, 4) and (preview[..., 3] == 0).sum() > 0  # the margin beyond the toe


def test_cli_keeps_the_prj_of_the_same_map_and_refuses_another_maps(cli, tmp_path, autzen_path):
    """a.png's a.prj holds autzen's CRS: --dsm-out a.tif beside it keeps it (it was refused,
    'already exists', though write_dsm keeps it); a .prj of another CRS is refused."""
    toe = tmp_path / "toe.geojson"
    toe.write_text(json.dumps(square(*AUTZEN_BLOCK, "block")))
    rc, _, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", 4, "-o", tmp_path / "a1.tif", "--preview", tmp_path / "a.png")
    assert rc == 0, err
    prj = (tmp_path / "a.prj").read_bytes()
    rc, out, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", 4, "--dsm-out", tmp_path / "a.tif", "--json")
    assert rc == 0, err
    assert json.loads(out)["outputs"] == [str(tmp_path / "a.tif"), str(tmp_path / "a.tfw")]
    assert (tmp_path / "a.prj").read_bytes() == prj == (tmp_path / "a1.prj").read_bytes()
    (tmp_path / "b.prj").write_text('PROJCS["some other map"]')
    rc, _, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", 4, "-o", tmp_path / "b.tif")
    assert rc == 1 and err.strip() == f"error: {tmp_path / 'b.prj'}: already exists; pass --overwrite to replace it", err
    assert not list(tmp_path.glob("b.t*")) and (tmp_path / "b.prj").read_text() == 'PROJCS["some other map"]'


def test_cli_reports_a_multipolygon_feature_as_one_pile_in_parts(cli, tmp_path, autzen_path):
    x0, y0, x1, y1 = AUTZEN_BLOCK
    middle = (x0 + x1) / 2
    halves = [square(x0, y0, middle - 4, y1)["coordinates"], square(middle + 4, y0, x1, y1)["coordinates"]]  # a road between
    toe = tmp_path / "toe.geojson"
    toe.write_text(json.dumps({"type": "Feature", "properties": {"name": "block"}, "geometry": {"type": "MultiPolygon", "coordinates": halves}}))
    rc, out, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", 2)
    assert rc == 0, err
    assert out.startswith("block: fill ") and out.count("fill ") == 1 and "total" not in out
    assert "  in 2 parts, each on a base of its own toe\n" in out


def test_cli_outputs_are_refused_before_anything_is_read(cli, tmp_path, monkeypatch, autzen_path):
    import os

    toe = tmp_path / "toe.geojson"
    toe.write_text(json.dumps(square(*AUTZEN_BLOCK)))
    monkeypatch.setattr(gp, "volume", lambda *args, **kwargs: pytest.fail("volumes measured"))
    (tmp_path / "p.pgw").write_text("precious")
    rc, _, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", 2, "-o", tmp_path / "h.tif", "--preview", tmp_path / "p.png")
    assert rc == 1 and err.strip() == f"error: {tmp_path / 'p.pgw'}: already exists; pass --overwrite to replace it", err
    rc, _, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", 2, "-o", tmp_path / "h.png")
    assert rc == 1 and err.strip() == f"error: {tmp_path / 'h.png'}: unsupported output type '.png'; use one of .tif, .tiff", err
    rc, _, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", 2, "-o", tmp_path / "h.tif", "--dsm-out", tmp_path / "h.tiff")
    assert rc == 1 and err.strip() == f"error: {tmp_path / 'h.tfw'}: named for two outputs", err  # (one h.tfw)
    locked = tmp_path / "locked"
    locked.mkdir()
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if str(p) == str(locked) else real_access(p, mode, **kw))  # (root writes anywhere)
    rc, _, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", 2, "--preview", locked / "p.png")
    assert rc == 1 and err.strip() == f"error: {locked / 'p.png'}: cannot write into {locked} (permission denied)", err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["locked", "p.pgw", "toe.geojson"] and (tmp_path / "p.pgw").read_text() == "precious"


@pytest.mark.parametrize(
    ("polygon", "kwargs", "message"),
    [
        (None, {}, "volume: clip_polygon is needed"),
        (square(1000, 1000, 1010, 1010), {}, r"^volume: the GeoJSON geometry: no point of arrays lies in its box x 1000..1010, y 1000..1010: the polygon is outside the data"),
        (square(10, 10, 30, 30), {"gsd": 0}, "volume: gsd must be a number > 0"),
        (square(10, 10, 30, 30), {"base": "top"}, "volume: base must be 'plane', 'lowest' or an elevation"),
    ],
)
def test_bad_inputs_are_one_line_errors(polygon, kwargs, message):
    with pytest.raises(InputError, match=message) as error:
        gp.volume(box_pile(), polygon, **{"gsd": 0.5, **kwargs})
    assert "\n" not in str(error.value)


def test_a_toe_crossing_itself_is_refused_naming_its_edges():
    """A bow tie's shoelace area (its two triangles subtracted) and its pixels inside (the even-odd
    rule: both triangles) disagree: refused before anything is read, in every polygon of several."""
    bow_tie = {"type": "Polygon", "coordinates": [[[10, 10], [30, 10], [10, 30], [30, 30], [10, 10]]]}
    why = "a toe must not cross itself (its area and the pixels inside it would disagree): redraw it"
    with pytest.raises(InputError) as error:
        gp.volume(box_pile(), bow_tie, 0.5)
    assert str(error.value) == f"volume: the GeoJSON geometry: the polygon crosses itself (edges 2 and 4): {why}"
    piles = {"type": "MultiPolygon", "coordinates": [square(0, 0, 5, 5)["coordinates"], bow_tie["coordinates"]]}
    with pytest.raises(InputError, match=r"^volume: the GeoJSON geometry: polygon 2 crosses itself \(edges 2 and 4\): "):
        gp.volume(box_pile(), piles, 0.5)
    holed = {"type": "Polygon", "coordinates": [*square(0, 0, 40, 40)["coordinates"], *bow_tie["coordinates"]]}
    with pytest.raises(InputError, match=r"^volume: the GeoJSON geometry: the polygon's hole 1 crosses itself \(edges 2 and 4\): "):
        gp.volume(box_pile(), holed, 0.5)


def test_a_hole_outside_its_outline_is_refused_not_measured_between_the_rings():
    """Rings swapped (the larger second): the pixels between them were measured and the polygon's
    area came out negative (400 - 900 = -500); a hole beside the outline likewise. A hole inside
    it is measured without its pixels."""
    outline, hole = square(10, 10, 30, 30)["coordinates"][0], square(15, 15, 20, 20)["coordinates"][0]
    pile = gp.volume(box_pile(), {"type": "Polygon", "coordinates": [outline, hole]}, 0.5, base=100).piles[0]
    assert (pile.polygon_area, pile.area, pile.fill) == (375.0, 375.0, 500.0 - 25 * 5)
    for rings in ([outline, square(5, 5, 35, 35)["coordinates"][0]], [outline, square(32, 10, 38, 16)["coordinates"][0]]):
        with pytest.raises(InputError) as error:
            gp.volume(box_pile(), {"type": "Polygon", "coordinates": rings}, 0.5, base=100)
        assert str(error.value) == "volume: the GeoJSON geometry: the polygon's hole 1 is not inside its outline (its first ring): redraw it, the outline first"


def test_a_hole_crossing_its_outline_or_another_hole_is_refused():
    """Only a hole wholly beside its outline (or larger) was refused: one half outside it was
    measured by the even-odd rule (the part outside counted) while polygon_area took the whole
    hole off (area 400 against polygon_area 350); so were holes over one another, or one
    holding another. A hole crossing a notch of its outline has every vertex inside it. A hole
    touching its outline at a vertex is inside it."""
    outline = square(10, 10, 30, 30)["coordinates"][0]
    u_shape = [[10, 10], [30, 10], [30, 30], [22, 30], [22, 15], [18, 15], [18, 30], [10, 30], [10, 10]]  # a notch down to y 15
    not_inside = "volume: the GeoJSON geometry: the polygon's hole 1 is not inside its outline (its first ring): redraw it, the outline first"
    overlap = "volume: the GeoJSON geometry: the polygon's holes 1 and 2 overlap (by the even-odd rule their overlap is inside): make them one hole"
    cases = [
        ([outline, square(25, 15, 35, 20)["coordinates"][0]], not_inside),  # half outside
        ([outline, [[5, 5], [12, 5], [12, 12], [5, 12], [5, 5]]], not_inside),  # over the outline's corner
        ([u_shape, square(12, 20, 28, 25)["coordinates"][0]], not_inside),  # across the notch, every vertex inside
        ([outline, square(12, 12, 18, 18)["coordinates"][0], square(15, 15, 20, 20)["coordinates"][0]], overlap),
        ([outline, square(12, 12, 28, 28)["coordinates"][0], square(15, 15, 20, 20)["coordinates"][0]], overlap),  # one in the other
        ([outline, square(15, 15, 20, 20)["coordinates"][0], square(12, 12, 28, 28)["coordinates"][0]], overlap),
        ([outline, square(15, 15, 20, 20)["coordinates"][0], square(15, 15, 20, 20)["coordinates"][0][::-1]], overlap),  # the same hole twice (was accepted)
    ]
    for rings, message in cases:
        with pytest.raises(InputError) as error:
            gp.volume(box_pile(), {"type": "Polygon", "coordinates": rings}, 0.5, base=100)
        assert str(error.value) == message, rings
    touching = [outline, [[10, 10], [14, 10], [10, 14], [10, 10]], square(16, 16, 20, 20)["coordinates"][0], square(20, 16, 24, 20)["coordinates"][0]]
    pile = gp.volume(box_pile(), {"type": "Polygon", "coordinates": touching}, 0.5, base=100).piles[0]
    assert pile.polygon_area == 400 - 8 - 16 - 16


def test_a_hole_error_names_the_toe_as_the_other_volume_errors_do(cli, tmp_path, autzen_path):
    """A GeoJSON geometry's hole errors said 'the GeoJSON geometry: ...' where its other errors
    (a ring on one line) say 'volume: the GeoJSON geometry: ...'; a file's name the file, from
    Python and the command line alike."""
    outline, hole = square(10, 10, 30, 30)["coordinates"][0], square(15, 15, 20, 20)["coordinates"][0]
    overlap = "the polygon's holes 1 and 2 overlap (by the even-odd rule their overlap is inside): make them one hole"
    for holes in ([hole, hole], [hole, [[1, 1], [2, 2], [3, 3], [1, 1]]]):
        with pytest.raises(InputError, match=r"^volume: the GeoJSON geometry: the polygon's hole"):
            gp.volume(box_pile(), {"type": "Polygon", "coordinates": [outline, *holes]}, 0.5)
    toe = tmp_path / "toe.geojson"
    x0, y0, x1, y1 = AUTZEN_BLOCK
    ring = square(x0 + 10, y0 + 10, x0 + 20, y0 + 20)["coordinates"][0]
    toe.write_text(json.dumps({"type": "Polygon", "coordinates": [square(*AUTZEN_BLOCK)["coordinates"][0], ring, ring[::-1]]}))
    with pytest.raises(InputError) as error:
        gp.volume(autzen_path, toe, 2)
    assert str(error.value) == f"{toe}: {overlap}"
    rc, _, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", "2")
    assert rc != 0 and err.strip() == f"error: {toe}: {overlap}"


def test_a_toes_crossing_and_no_point_errors_name_it_as_its_ring_and_hole_errors_do(cli, tmp_path, autzen_path):
    """A GeoJSON dict's ring and hole errors start 'volume: the GeoJSON geometry: '; its crossing
    and its no-point errors said 'the GeoJSON geometry: ...'. A dict naming its own source (the
    viewer's polygon) and a file are named by it, from Python and the command line alike."""
    x, y = lattice(40.0)
    gap = (x >= 14.5) & (x < 25.5) & (y >= 14.5) & (y < 25.5)  # points in the box read, none inside
    cloud = gp.from_arrays(np.column_stack([x, y, np.full(x.size, 100.0)])[~gap])
    bow_tie = [[10, 10], [30, 10], [10, 30], [30, 30], [10, 10]]
    crossing = "the polygon crosses itself (edges 2 and 4): a toe must not cross itself (its area and the pixels inside it would disagree): redraw it"
    cases = [
        ([bow_tie], crossing),
        ([*square(0, 0, 40, 40)["coordinates"], bow_tie], crossing.replace("the polygon", "the polygon's hole 1")),
        (square(15, 15, 25, 25)["coordinates"], "no point of arrays lies inside it"),
        (square(1000, 1000, 1010, 1010)["coordinates"], "no point of arrays lies in its box x 1000..1010, y 1000..1010: the polygon is outside the data"),
    ]
    for coordinates, problem in cases:
        for source, name in (({}, "volume: the GeoJSON geometry"), ({"source": "the measured polygon"}, "the measured polygon")):
            with pytest.raises(InputError) as error:
                gp.volume(cloud, {"type": "Polygon", "coordinates": coordinates, **source}, 0.5)
            assert str(error.value) == f"{name}: {problem}"
    toe = tmp_path / "toe.geojson"
    toe.write_text(json.dumps({"type": "Polygon", "coordinates": [bow_tie]}))
    with pytest.raises(InputError) as error:
        gp.volume(cloud, toe, 0.5)
    assert str(error.value) == f"{toe}: {crossing}"
    rc, _, err = cli("volume", autzen_path, "--clip-polygon", toe, "--gsd", "2")
    assert rc != 0 and err.strip() == f"error: {toe}: {crossing}"


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
    with pytest.raises(InputError, match=r"^volume: the GeoJSON geometry: no point of arrays lies inside it$"):
        gp.volume(cloud, square(15, 15, 25, 25), 0.5)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((), "--clip-polygon is needed"),
        (("--clip-polygon", "toe.geojson", "--gsd", "0"), "--gsd must be a number > 0"),
        (("--clip-polygon", "toe.geojson", "--base", "top"), "--base must be 'plane', 'lowest' or an elevation"),
        (("--clip-polygon", "missing.geojson"), "no such file"),
        (("--clip-polygon", "POLYGON ((636455 849225, 636535 849225, 636455 849260, 636535 849260, 636455 849225))"), "the polygon crosses itself (edges 2 and 4)"),
    ],
)
def test_cli_errors_are_one_line(cli, tmp_path, monkeypatch, autzen_path, args, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "toe.geojson").write_text(json.dumps(square(*AUTZEN_BLOCK)))
    rc, out, err = cli("volume", autzen_path, *(args if "--gsd" in args else (*args, "--gsd", "2")))
    assert rc != 0 and message in err and len(err.strip().splitlines()) == 1, err


def test_render_and_open_still_clip_by_a_self_crossing_polygon(cli, autzen_path, tmp_path):
    """Only volume refuses a bow tie: clipping by one is well defined (the even-odd rule), as before."""
    x0, y0, x1, y1 = AUTZEN_BLOCK
    bow_tie = f"POLYGON (({x0} {y0}, {x1} {y0}, {x0} {y1}, {x1} {y1}, {x0} {y0}))"
    xyz = gp.open(autzen_path, clip_polygon=bow_tie).positions()
    u, v = (xyz[:, 0] - x0) / (x1 - x0), (xyz[:, 1] - y0) / (y1 - y0)
    assert len(xyz) > 100 and ((v - u) * (v - (1 - u)) >= -1e-9).all()  # in the lower or the upper triangle, none beside them
    rc, _, err = cli("render", autzen_path, "--clip-polygon", bow_tie, "-o", tmp_path / "bow.png", "-W", 64, "-H", 48)
    assert rc == 0 and (tmp_path / "bow.png").is_file(), err


# --- an LOD octree: its levels the gsd needs (survey/change.py's surface) --------------------------------

AUTZEN_MIDDLE = (636200.0, 849000.0, 636900.0, 849400.0)  # most of autzen_trim: roofs, trees, roads


@pytest.mark.parametrize("base", ["plane", "lowest"])
def test_an_octree_gives_its_point_files_volume_from_its_upper_levels(autzen_layered, autzen_path, base):
    """At 16 ft the octree's levels down to 2.3 ft are read (a quarter pixel: 79,000 of its
    110,000 points): the highest of a sample in each pixel, a little low on roofs and trees, so
    the net volume lies below the LAZ file's by at most 0.15 ft over the footprint (measured: 0.118
    on a plane base, 0.112 on the lowest) and the fill by at most 2 % (1.5 %, 0.5 %). Every node
    read (full=True): the LAZ file's volumes, but for the float32 heights' rounding (the camera's eye
    at the octree's top, not the box's points'). An opened octree takes no clip box: the grid's
    edge pixels then hold the points beyond the box too, which the holes' TIN reaches (measured:
    4e-5 of the fill on a plane base)."""
    toe = square(*AUTZEN_MIDDLE)
    las = gp.volume(autzen_path, toe, 16, base=base)
    sampled = gp.volume(autzen_layered["gigapoint"], toe, 16, base=base, full=False)
    assert sampled.area == las.area == 292_864.0 and las.fill > 2e6
    assert -0.15 * las.area <= sampled.net - las.net < 0 and abs(sampled.fill - las.fill) <= 0.02 * las.fill
    every = gp.volume(autzen_layered["copc"], toe, 16, base=base, full=True)
    assert every.fill == pytest.approx(las.fill, rel=1e-7) and every.cut == pytest.approx(las.cut, rel=1e-7, abs=1e-3)
    assert np.nanmax(np.abs(every.heights - las.heights)) <= 2 * np.spacing(np.float32(600))  # 2 ulps of the heights
    opened = gp.volume(gp.open(autzen_layered["gigapoint"]), toe, 16, base=base, full=False)
    assert opened.fill == pytest.approx(sampled.fill, rel=1e-4)


def test_cli_volume_of_an_octree_folder_with_all_points_is_the_point_files(cli, autzen_layered, autzen_path, tmp_path):
    toe = tmp_path / "toe.geojson"
    toe.write_text(json.dumps(square(*AUTZEN_MIDDLE, "middle")))
    figures = {}
    for name, source, *more in (("las", autzen_path), ("octree", autzen_layered["gigapoint"], "--levels-only"), ("every", autzen_layered["gigapoint"])):
        rc, out, err = cli("volume", source, "--clip-polygon", toe, "--gsd", 16, "--base", "lowest", "--json", *more)
        assert rc == 0, err
        figures[name] = json.loads(out)["total"]["fill"]
    assert figures["every"] == pytest.approx(figures["las"], rel=1e-7) and figures["octree"] < figures["las"]
    outside = {"type": "Polygon", "coordinates": [[[1000, 1000], [1010, 1000], [1010, 1010], [1000, 1000]]]}  # (at 0..10: lon/lat, refused as such)
    with pytest.raises(InputError, match=r"^volume: the GeoJSON geometry: no point of .*autzen_octree lies in its box x 1000\.\.1010, y 1000\.\.1010: the polygon is outside the data$"):
        gp.volume(autzen_layered["gigapoint"], outside, 16)


def test_a_class_filter_leaving_no_point_in_the_box_is_not_said_to_be_outside_the_data(cli, autzen_layered, autzen_path, tmp_path):
    """--classes 99 over a toe inside the data said "the polygon is outside the data": the class
    filter left no point there; said so, of the point files and of an octree alike."""
    toe = tmp_path / "toe.geojson"
    toe.write_text(json.dumps(square(*AUTZEN_BLOCK)))
    box = "lies in its box x 636455..636535, y 849225..849260"
    for source, name in ((autzen_path, autzen_path.name), (autzen_layered["gigapoint"], "autzen_octree")):
        for filters, kept in (({"classes": 99}, "classes 99"), ({"classes": [98, 99], "drop_classes": 2}, "classes 98, 99; drop classes 2")):
            with pytest.raises(InputError) as caught:
                gp.volume(source, toe, 2, **filters)
            said = str(caught.value)
            assert said.startswith(f"{toe}: no point of ") and said.endswith(f"{name} ({kept}) {box}: the class filter left none there, or the polygon is outside the data"), said
        rc, _, err = cli("volume", source, "--clip-polygon", toe, "--gsd", 2, "--classes", 99)
        assert rc == 1 and err.strip().endswith(f"{name} (classes 99) {box}: the class filter left none there, or the polygon is outside the data") and len(err.strip().splitlines()) == 1, err
    assert gp.volume(autzen_path, toe, 2, classes=2).area > 0  # (the toe is over the data)


BLOCK_OFF_CENTRES = (636455.9375, 849225.875, 636535.9375, 849260.875)  # AUTZEN_BLOCK, its edges off the 2 ft pixels' centres (the test below says how far)


def block_in_degrees(autzen_path):
    """(ring, toe): autzen's raised block (``BLOCK_OFF_CENTRES``, Lambert feet), each edge cut into 64 pieces,
    and that ring moved into lon/lat as a GeoJSON Polygon whose crs member names EPSG:4326."""
    pyproj = pytest.importorskip("pyproj")
    from gigapoint.io.las import read_las_header

    x0, y0, x1, y1 = BLOCK_OFF_CENTRES
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    along = np.arange(64)[None, :, None] / 64
    ring = (corners[:, None, :] + along * (np.roll(corners, -1, axis=0) - corners)[:, None, :]).reshape(-1, 2)
    feet = pyproj.CRS.from_wkt(read_las_header(autzen_path).crs())
    lon, lat = pyproj.Transformer.from_crs(feet, "EPSG:4326", always_xy=True).transform(*ring.T)
    crs = {"type": "name", "properties": {"name": "EPSG:4326"}}
    return ring, {"type": "Polygon", "crs": crs, "coordinates": [[*zip(lon, lat), (lon[0], lat[0])]]}

def test_a_toe_naming_another_crs_is_moved_into_the_surveys_before_its_box_is_read(cli, tmp_path, autzen_path):
    """autzen's raised block (Lambert feet) drawn in lon/lat, a crs member naming EPSG:4326: moved
    into the survey's feet before the read box and the grid are made from it (it was refused as
    outside the data), it measures what the same ring given in feet does: each edge cut into 64
    pieces, moved back it lies within 1e-6 ft of the feet ring (pyproj's round trip; the mover
    adds no vertex). Its edges lie at least half a foot from the 2 ft pixels' centres and the
    toe's samples for the base (every foot at most) 0.047 ft from the pixels' edges: the same
    pixels and the same samples' pixels; the plane through those is fitted at the samples'
    positions, which move by up to 3e-7 ft: the volumes agree within 1e-7 (measured: 7e-9)."""
    ring, in_degrees = block_in_degrees(autzen_path)
    x0, y0, x1, y1 = BLOCK_OFF_CENTRES
    degrees = tmp_path / "toe4326.geojson"
    degrees.write_text(json.dumps(in_degrees))
    given = gp.volume(autzen_path, {"type": "Polygon", "coordinates": [[*ring.tolist(), ring[0].tolist()]]}, 2.0)
    moved = gp.volume(autzen_path, degrees, 2.0)
    assert given.fill > 1000 and moved.piles[0].pixels == given.piles[0].pixels == 40 * 17
    assert moved.camera.world_file() == given.camera.world_file()  # (the same grid: the box made from the moved toe)
    assert moved.fill == pytest.approx(given.fill, rel=1e-7) and moved.cut == pytest.approx(given.cut, rel=1e-7)
    assert moved.piles[0].polygon_area == pytest.approx((x1 - x0) * (y1 - y0), rel=1e-7)
    assert np.abs(np.concatenate(moved.toes[0]) - ring).max() < 1e-6  # (in feet: the preview draws them)
    rc, out, err = cli("volume", autzen_path, "--clip-polygon", degrees, "--gsd", 2, "--json")
    assert rc == 0, err
    assert json.loads(out)["total"]["fill"] == pytest.approx(given.fill, rel=1e-7)



@pytest.mark.parametrize("kind", ["gigapoint", "copc"])
def test_a_toe_naming_a_crs_over_an_octrees_path_opens_it_once(autzen_layered, autzen_path, monkeypatch, kind):
    """The octree was opened for its CRS and bounds (to move the toe), then again to read it: now
    once, and the toe moved from lon/lat measures what the same ring given in its feet does."""
    ring, in_degrees = block_in_degrees(autzen_path)
    given = gp.volume(autzen_layered[kind], {"type": "Polygon", "coordinates": [[*ring.tolist(), ring[0].tolist()]]}, 2.0)
    opens = []
    real_open = gp.open_for  # (gp.open under the operation's name)
    monkeypatch.setattr(gp, "open_for", lambda where, *paths, **options: opens.append(paths) or real_open(where, *paths, **options))
    moved = gp.volume(autzen_layered[kind], in_degrees, 2.0)
    assert opens == [(autzen_layered[kind],)]
    assert moved.piles[0].pixels == given.piles[0].pixels == 40 * 17 and given.fill > 1000
    assert moved.fill == pytest.approx(given.fill, rel=1e-7) and moved.cut == pytest.approx(given.cut, rel=1e-7)

def test_a_lon_lat_toe_naming_no_crs_over_a_projected_survey_is_refused_as_a_read_filter_refuses_it(autzen_path, tmp_path, autzen_layered):
    """RFC 7946 GeoJSON is longitude/latitude: over autzen's feet it was "outside the data"; now
    the one line gp.open gives, naming the survey (its point files, an octree's path or one opened)."""
    toe = tmp_path / "lonlat.geojson"
    toe.write_text(json.dumps({"type": "Polygon", "coordinates": [[[-123.1, 44.0], [-123.0, 44.0], [-123.0, 44.1], [-123.1, 44.0]]]}))
    says = "x -123.1..-123, y 44..44.1 looks like longitude/latitude (RFC 7946 GeoJSON) while {} is in NAD_1983_HARN_Lambert_Conformal_Conic (WKT): "
    with pytest.raises(InputError) as err:
        gp.volume(autzen_path, toe, 2.0)
    assert str(err.value) == f"{toe}: {says.format(autzen_path)}add a crs member naming its CRS, or reproject it into the files' coordinates"
    with pytest.raises(InputError) as err:
        gp.volume(gp.open(autzen_path), toe, 2.0)
    assert str(err.value).startswith(f"{toe}: {says.format('autzen_trim.laz')}")
    with pytest.raises(InputError) as err:
        gp.volume(autzen_layered["copc"], toe, 2.0)
    assert str(err.value).startswith(f"{toe}: {says.format(autzen_layered['copc'])}")


def test_a_geojson_dicts_crs_refusals_name_it_as_volumes_other_errors_do(autzen_path, monkeypatch):
    """A GeoJSON dict toe refused in placing it over the survey (lon/lat naming no CRS over
    autzen's feet; a CRS PROJ does not know; a CRS to move from without pyproj) said 'the GeoJSON
    geometry: ...' where its other errors say 'volume: the GeoJSON geometry: ...'."""
    ring = [[-123.1, 44.0], [-123.0, 44.0], [-123.0, 44.1], [-123.1, 44.0]]
    with pytest.raises(InputError) as err:
        gp.volume(autzen_path, {"type": "Polygon", "coordinates": [ring]}, 2.0)
    assert str(err.value) == (
        "volume: the GeoJSON geometry: x -123.1..-123, y 44..44.1 looks like longitude/latitude (RFC 7946 GeoJSON) while "
        f"{autzen_path} is in NAD_1983_HARN_Lambert_Conformal_Conic (WKT): add a crs member naming its CRS, or reproject it into the files' coordinates"
    )
    unknown = {"type": "Polygon", "crs": {"type": "name", "properties": {"name": "EPSG:99999"}}, "coordinates": [ring]}
    with pytest.raises(InputError, match=r"^volume: the GeoJSON geometry: names EPSG:99999"):  # (PROJ knows it not; without pyproj: it is needed)
        gp.volume(autzen_path, unknown, 2.0)
    monkeypatch.setitem(sys.modules, "pyproj", None)  # (import pyproj raises ImportError)
    in_degrees = {**unknown, "crs": {"type": "name", "properties": {"name": "EPSG:4326"}}}
    with pytest.raises(InputError, match=r"^volume: the GeoJSON geometry: names EPSG:4326 while .* is in .*: moving it there needs pyproj"):
        gp.volume(autzen_path, in_degrees, 2.0)


def test_a_survey_in_degrees_is_refused_not_measured_in_square_degrees(tmp_path):
    """A pile in WGS 84 (GeoTIFF keys: geographic, EPSG:4326): its fill came out in square degrees
    times metres (~1e-9) under the label of cubic units: refused in one line, as change refuses."""
    from test_change import write_degrees_grid  # (tests/unit is on sys.path)

    path = write_degrees_grid(tmp_path / "pile.las", 40)  # 0.0008 x 0.0008 degrees from DEGREES_ORIGIN (-123, 44)
    toe = "POLYGON ((-122.9998 44.0002, -122.9994 44.0002, -122.9994 44.0006, -122.9998 44.0006, -122.9998 44.0002))"
    with pytest.raises(InputError) as caught:
        gp.volume(path, toe, 0.00002, base=0.0)
    assert str(caught.value) == (
        f"volume: {path} has coordinates in degrees (EPSG:4326); measuring a volume needs metres or feet: "
        "reproject first (gigapoint convert --to-crs EPSG:32610, WGS 84 / UTM zone 10N, where the data lie)"
    )
