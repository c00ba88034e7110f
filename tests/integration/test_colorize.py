"""``convert -o out.laz --colorize ortho.tif`` / ``tile --colorize`` (io/colorize.py): each point
takes the colour of the orthophoto's pixel it lies in (GeoTIFFs written here with rasterio, over
autzen's extent in its CRS, the expected pixel found with rasterio's own rowcol), after --to-crs;
points outside it or under alpha 0 keep their colour (0 where none) and are counted; rasters that
cannot be read or lie in another CRS are refused in one line before a point is read."""

from __future__ import annotations

import importlib
import sys

import laspy
import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointWarning, InputError
from gigapoint.io.las import read_las_header

rasterio = pytest.importorskip("rasterio")
pyproj = pytest.importorskip("pyproj")
from rasterio.transform import Affine, from_origin, rowcol

#: the test rasters' pixel edge (feet, in autzen's CRS) and their top-left corner: half a grid step
#: off autzen's 0.01 ft grid, so no point lies on a pixel edge
PIXEL = 5.0
LEFT, TOP = 636_000.005, 849_500.005
WIDTH, HEIGHT = 237, 114  # (to x 637 185, y 848 930: past autzen's 637 179.22, 848 935.20)


def _pattern(height=HEIGHT, width=WIDTH) -> np.ndarray:
    """Bands 1-3 (3 x height x width, uint8) of a pattern whose neighbours all differ."""
    row, col = np.mgrid[0:height, 0:width]
    return np.stack([(col * 3) % 256, (row * 5) % 256, (col + 2 * row) % 256]).astype(np.uint8)


def _geotiff(path, bands, crs, transform=None, alpha: bool = False, **creation):
    """A GeoTIFF of ``bands`` (k x h x w); ``alpha``: its last band marked as alpha; ``creation``: GDAL's creation options (nbits=12)."""
    count, height, width = bands.shape
    transform = transform or from_origin(LEFT, TOP, PIXEL, PIXEL)
    with rasterio.open(path, "w", driver="GTiff", width=width, height=height, count=count, dtype=bands.dtype, crs=crs, transform=transform, **creation) as ds:
        ds.write(bands)
        if alpha:
            ds.colorinterp = [rasterio.enums.ColorInterp.red, rasterio.enums.ColorInterp.green, rasterio.enums.ColorInterp.blue, rasterio.enums.ColorInterp.alpha]
    return path


@pytest.fixture(scope="module")
def no_rgb(autzen_path, tmp_path_factory):
    """autzen without colours: point format 1 (LAS 1.2), its CRS and grid kept."""
    path = tmp_path_factory.mktemp("colorize") / "autzen_no_rgb.las"
    laspy.convert(laspy.read(str(autzen_path)), point_format_id=1).write(str(path))
    assert not {"red", "green", "blue"} & set(laspy.read(str(path)).point_format.dimension_names)
    return path


def _pixels_under(x, y, transform=None):
    """(row, column) of the pixel under each point ``x``, ``y`` (rasterio's rowcol: floor)."""
    rows, cols = rowcol(transform or from_origin(LEFT, TOP, PIXEL, PIXEL), np.asarray(x), np.asarray(y))
    return np.asarray(rows), np.asarray(cols)


def _pixels_of(path, transform=None):
    """(row, column) of the pixel under each point of ``path``, and its points."""
    las = laspy.read(str(path))
    return *_pixels_under(las.x, las.y, transform), las


def _rgb(las) -> np.ndarray:
    return np.column_stack([np.asarray(las[c]) for c in ("red", "green", "blue")])


def test_every_point_takes_its_pixels_colour_x_257_and_gains_rgb(cli, no_rgb, tmp_path):
    wkt = read_las_header(no_rgb).crs()
    ortho = _geotiff(tmp_path / "ortho.tif", _pattern(), wkt)
    out = tmp_path / "colored.laz"
    rc, stdout, err = cli("convert", no_rgb, "-o", out, "--colorize", ortho, "-q")
    assert (rc, err) == (0, "")
    assert stdout.startswith(f"{out}: 110,000 points (laz), every point coloured from {ortho}, ")
    rows, cols, source = _pixels_of(no_rgb)
    assert rows.min() >= 0 and rows.max() < HEIGHT and cols.min() >= 0 and cols.max() < WIDTH  # (the raster covers every point)
    written = laspy.read(str(out))
    assert written.header.point_format.id == 7  # (format 1 had no RGB)
    assert np.array_equal(np.asarray(written.X), np.asarray(source.X)) and np.array_equal(np.asarray(written.Y), np.asarray(source.Y))
    expected = _pattern()[:, rows, cols].T.astype(np.uint16) * 257
    assert np.array_equal(_rgb(written), expected)
    assert len(np.unique(expected, axis=0)) > 1000  # (a pattern, not one colour)


def test_a_paletted_raster_gives_each_point_its_pixels_colour_from_the_table(cli, no_rgb, tmp_path):
    """A one-band raster of indices into a colour table (a classified map, GDAL's palette): was read
    as grey, each point the grey of its index (index 1: 257, near black)."""
    indices = (_pattern()[0] % 4).astype(np.uint8)[np.newaxis]
    table = {0: (255, 0, 0, 255), 1: (0, 255, 0, 255), 2: (0, 0, 255, 255), 3: (250, 200, 10, 255)}
    paletted = _geotiff(tmp_path / "classes.tif", indices, read_las_header(no_rgb).crs())
    with rasterio.open(paletted, "r+") as ds:
        ds.write_colormap(1, table)
    rc, _, err = cli("convert", no_rgb, "-o", tmp_path / "out.las", "--colorize", paletted, "-q")
    assert (rc, err) == (0, "")
    rows, cols, las = _pixels_of(tmp_path / "out.las")
    expected = np.array([table[i][:3] for i in range(4)], np.uint16)[indices[0, rows, cols]] * 257
    assert np.array_equal(_rgb(las), expected) and len(np.unique(expected, axis=0)) == 4
    # --colorize-bits means nothing to a table's 8-bit colours, but a bad one is still refused (it passed unchecked)
    rc, _, err = cli("convert", no_rgb, "-o", tmp_path / "bits.las", "--colorize", paletted, "--colorize-bits", "99", "-q")
    assert rc != 0 and f"error: {paletted}: --colorize-bits for its uint8 values must be an integer from 1 to 8, got 99\n" in err, err


def test_a_16_bit_raster_keeps_its_values_high_byte(no_rgb, tmp_path):
    wkt = read_las_header(no_rgb).crs()
    bands = _pattern().astype(np.uint16) * 256 + 77  # (low bytes 77: gigapoint holds 8 bits a channel)
    result = gp.convert(no_rgb, tmp_path / "out.las", colorize=_geotiff(tmp_path / "ortho16.tif", bands, wkt))
    assert result.uncolored == 0
    rows, cols, _ = _pixels_of(no_rgb)
    assert np.array_equal(_rgb(laspy.read(str(tmp_path / "out.las"))), (bands[:, rows, cols] >> 8).T * 257)


@pytest.mark.parametrize(("dtype", "nbits"), [("uint16", 12), ("uint16", 11), ("uint8", 4)])
def test_a_raster_of_fewer_bits_than_its_type_is_scaled_by_its_nbits(no_rgb, tmp_path, dtype, nbits):
    wkt = read_las_header(no_rgb).crs()
    if nbits > 8:  # the pattern in the top 8 of 12 or 11 bits, the bits below all 1: 0-4095 (was v >> 8: 0-15, near black)
        bands = (_pattern().astype(np.uint16) << (nbits - 8)) | (2 ** (nbits - 8) - 1)
        expected_8_bits = _pattern()
    else:  # 4-bit levels 0-15, stretched to 0-255 (was 0-15)
        bands = _pattern() >> 4
        expected_8_bits = bands * 17
    ortho = _geotiff(tmp_path / f"ortho{nbits}.tif", bands.astype(dtype), wkt, nbits=nbits)
    with rasterio.open(ortho) as ds:
        assert (ds.dtypes[0], ds.tags(1, ns="IMAGE_STRUCTURE")["NBITS"]) == (dtype, str(nbits))
    result = gp.convert(no_rgb, tmp_path / "out.las", colorize=ortho)
    assert result.uncolored == 0
    rows, cols, _ = _pixels_of(no_rgb)
    rgb = _rgb(laspy.read(str(tmp_path / "out.las")))
    assert np.array_equal(rgb, expected_8_bits[:, rows, cols].T.astype(np.uint16) * 257)
    assert rgb.max() == 255 * 257  # (the brightest level comes out white)


def _bits_warning(raster, highest: int, bits: int) -> str:
    """The warning of a 16-bit ``raster`` naming no NBITS whose values reach only ``highest`` (``bits`` bits)."""
    return (
        f"warning: {raster}: its 16-bit values name no bit depth (NBITS) and reach only {highest} ({bits} bits) in GDAL's approximate statistics: "
        f"read as 16-bit, its colours come out at most 1/{2 ** (16 - bits)} of full brightness; if it holds {bits}-bit values, say so "
        f"with --colorize-bits {bits} (colorize_bits={bits}), or write NBITS into a copy: gdal_translate -co NBITS={bits} {raster} OUT.tif\n"
    )


def test_a_16_bit_raster_of_12_bit_values_naming_no_nbits_is_warned_of_and_colorize_bits_reads_it_as_nbits_does(cli, no_rgb, tmp_path):
    wkt = read_las_header(no_rgb).crs()
    (tmp_path / "nbits").mkdir()
    bands = (_pattern().astype(np.uint16) << 4) | 15  # 12-bit values, 0-4095, in a 16-bit file naming no NBITS
    ortho = _geotiff(tmp_path / "ortho12.tif", bands, wkt)
    with rasterio.open(ortho) as ds:
        assert (ds.dtypes[0], "NBITS" in ds.tags(1, ns="IMAGE_STRUCTURE")) == ("uint16", False)
    with_nbits = _geotiff(tmp_path / "nbits" / "nbits12.tif", bands, wkt, nbits=12)  # the same values, NBITS=12
    as_nbits = _rgb(laspy.read(str(gp.convert(no_rgb, tmp_path / "nbits" / "nbits.las", colorize=with_nbits).out)))
    rows, cols, _ = _pixels_of(no_rgb)
    rc, _, err = cli("convert", no_rgb, "-o", tmp_path / "dark.las", "--colorize", ortho, "-q")
    assert (rc, err) == (0, _bits_warning(ortho, 4095, 12))  # (was no word)
    dark = _rgb(laspy.read(str(tmp_path / "dark.las")))
    assert np.array_equal(dark, (bands[:, rows, cols] >> 8).T * 257) and dark.max() == 15 * 257  # (read as 16-bit: near black)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dark.las", "nbits", "ortho12.tif"]  # (GDAL's statistics not written beside it: no .aux.xml)

    rc, _, err = cli("convert", no_rgb, "-o", tmp_path / "bright.las", "--colorize", ortho, "--colorize-bits", "12", "-q")
    assert (rc, err) == (0, "")
    bright = _rgb(laspy.read(str(tmp_path / "bright.las")))
    assert np.array_equal(bright, as_nbits) and np.array_equal(bright, _pattern()[:, rows, cols].T.astype(np.uint16) * 257)
    assert bright.max() == 255 * 257
    result = gp.tile(no_rgb, tmp_path / "tiles", 500, colorize=ortho, colorize_bits=12)  # tile's too
    for tile in result.tiles:
        rows, cols, las = _pixels_of(tile)
        assert np.array_equal(_rgb(las), _pattern()[:, rows, cols].T.astype(np.uint16) * 257), tile


def test_a_16_bit_raster_of_8_bit_values_is_warned_of_naming_8_bits(no_rgb, tmp_path):
    eight = _geotiff(tmp_path / "ortho8in16.tif", _pattern().astype(np.uint16), read_las_header(no_rgb).crs())
    with pytest.warns(GigapointWarning) as warned:
        gp.convert(no_rgb, tmp_path / "out.las", colorize=eight)
    assert [str(w.message) + "\n" for w in warned] == [_bits_warning(eight, 255, 8).removeprefix("warning: ")]


def test_a_full_range_16_bit_raster_is_not_warned_of(cli, no_rgb, tmp_path):
    bands = _pattern().astype(np.uint16) * 257  # 0-65535
    ortho = _geotiff(tmp_path / "ortho16.tif", bands, read_las_header(no_rgb).crs())
    rc, _, err = cli("convert", no_rgb, "-o", tmp_path / "out.las", "--colorize", ortho, "-q")
    assert (rc, err) == (0, "")
    rows, cols, _ = _pixels_of(no_rgb)
    assert np.array_equal(_rgb(laspy.read(str(tmp_path / "out.las"))), _pattern()[:, rows, cols].T.astype(np.uint16) * 257)


def test_colorize_bits_beyond_the_rasters_type_or_without_a_raster_is_refused_in_one_line(cli, no_rgb, tmp_path):
    ortho = _geotiff(tmp_path / "ortho.tif", _pattern(), read_las_header(no_rgb).crs())
    out = tmp_path / "out.laz"
    rc, _, err = cli("convert", no_rgb, "-o", out, "--colorize", ortho, "--colorize-bits", "12", "-q")
    assert (rc, err.strip()) == (1, f"error: {ortho}: --colorize-bits for its uint8 values must be an integer from 1 to 8, got 12")
    rc, _, err = cli("tile", no_rgb, "--size", "500", "-o", tmp_path / "tiles", "--colorize-bits", "12", "-q")
    assert (rc, err.strip()) == (1, "error: tile: --colorize-bits 12: the bit depth of a --colorize raster's values; give --colorize too")
    with pytest.raises(InputError, match=r"^convert: --colorize-bits 12: the bit depth of a --colorize raster's values; give --colorize too$"):
        gp.convert(no_rgb, out, colorize_bits=12)  # (was ignored)
    with pytest.raises(InputError, match=r"--colorize-bits for its uint8 values must be an integer from 1 to 8, got '8'$"):
        gp.convert(no_rgb, out, colorize=ortho, colorize_bits="8")
    assert not out.exists() and not (tmp_path / "tiles").exists()


def test_a_float_raster_of_reflectance_is_refused_naming_it_and_its_dtype(cli, no_rgb, tmp_path):
    reflectance = _geotiff(tmp_path / "reflectance.tif", _pattern().astype(np.float32) / 255, read_las_header(no_rgb).crs())
    out = tmp_path / "out.laz"
    rc, _, err = cli("convert", no_rgb, "-o", out, "--colorize", reflectance, "-q")
    expected = (
        f"error: {reflectance}: its bands hold float32 values; colorize reads orthophotos of 8- or 16-bit integers "
        "(gdal_translate -ot Byte -scale MIN MAX 0 255 makes one of its range)"
    )
    assert (rc, err.strip()) == (1, expected)
    assert not out.exists()


def test_a_rotated_raster_gives_each_point_its_pixels_colour(no_rgb, tmp_path):
    # rotated 90 degrees from north up: rows run east from LEFT, columns north from the bottom edge
    bottom = TOP - HEIGHT * PIXEL
    transform = Affine.translation(LEFT, bottom) @ Affine.rotation(90) @ Affine.scale(PIXEL, -PIXEL)
    assert (transform.a, transform.b, transform.d, transform.e) == (0, PIXEL, PIXEL, 0)
    bands = _pattern(WIDTH, HEIGHT)  # (237 rows east, 114 columns north)
    ortho = _geotiff(tmp_path / "rotated.tif", bands, read_las_header(no_rgb).crs(), transform)
    with rasterio.open(ortho) as ds:
        assert ds.transform == transform  # (GDAL wrote and read the rotation back)
    result = gp.convert(no_rgb, tmp_path / "out.las", colorize=ortho)
    assert result.uncolored == 0
    las = laspy.read(str(tmp_path / "out.las"))
    rows = np.floor((np.asarray(las.x) - LEFT) / PIXEL).astype(int)
    cols = np.floor((np.asarray(las.y) - bottom) / PIXEL).astype(int)
    assert rows.min() >= 0 and rows.max() < WIDTH and cols.min() >= 0 and cols.max() < HEIGHT
    assert np.array_equal(_rgb(las), bands[:, rows, cols].T.astype(np.uint16) * 257)
    first = np.asarray([las.x[0], las.y[0]])  # one point by hand: its pixel's colour
    row, col = int((first[0] - LEFT) // PIXEL), int((first[1] - bottom) // PIXEL)
    assert list(_rgb(las)[0]) == [int(v) * 257 for v in bands[:, row, col]]


def _gdal_cache_during_reads(monkeypatch) -> list:
    """GDAL_CACHEMAX as rasterio's environment gives it during each read of a raster's pixels (None: not set)."""
    seen = []
    read = rasterio.io.DatasetReader.read

    def read_noting_the_cache(self, *args, **kwargs):
        seen.append(rasterio.env.getenv().get("GDAL_CACHEMAX") if rasterio.env.hasenv() else None)
        return read(self, *args, **kwargs)

    monkeypatch.setattr(rasterio.io.DatasetReader, "read", read_noting_the_cache)
    return seen


def test_gdals_block_cache_is_held_small_while_blocks_are_read(no_rgb, tmp_path, monkeypatch):
    colorize = importlib.import_module("gigapoint.io.colorize")
    wkt = read_las_header(no_rgb).crs()
    ortho = _geotiff(tmp_path / "tiled.tif", _pattern(), wkt, tiled=True, blockxsize=64, blockysize=64)
    seen = _gdal_cache_during_reads(monkeypatch)
    gp.convert(no_rgb, tmp_path / "out.las", colorize=ortho)
    assert seen == [16 * 2**20] == [colorize.GDAL_CACHE_BYTES]  # (one block of 1024²: the whole raster)
    assert not rasterio.env.hasenv() or "GDAL_CACHEMAX" not in rasterio.env.getenv()  # (set only around the reads)


def test_a_wide_strip_raster_gets_gdal_cache_for_a_row_of_blocks(no_rgb, tmp_path, monkeypatch):
    pixel, width, height = 0.4, 3000, 1420  # (3 blocks of 1024 across autzen's 1 179 ft, 2 down)
    transform = from_origin(LEFT, TOP, pixel, pixel)
    ortho = _geotiff(tmp_path / "strips.tif", _pattern(height, width), read_las_header(no_rgb).crs(), transform, compress="deflate", blockysize=1)
    with rasterio.open(ortho) as ds:
        assert ds.block_shapes[0] == (1, width)  # strips of one row: each block decodes all 1024 under it, whole
    seen = _gdal_cache_during_reads(monkeypatch)
    result = gp.convert(no_rgb, tmp_path / "out.las", colorize=ortho)
    assert result.uncolored == 0
    assert seen == [2 * 1025 * width * 3] * 6  # twice the strips under a row of blocks (16 MiB: a 16 384-wide one read 5.7x slower)
    rows, cols, las = _pixels_of(tmp_path / "out.las", transform)
    assert np.array_equal(_rgb(las), _pattern(height, width)[:, rows, cols].T.astype(np.uint16) * 257)


def test_points_outside_a_half_raster_keep_their_colour_or_zero_and_are_counted(cli, autzen_path, no_rgb, tmp_path):
    wkt = read_las_header(no_rgb).crs()
    half = _geotiff(tmp_path / "west.tif", _pattern()[:, :, : WIDTH // 2], wkt)  # columns 0-117: the west half
    rows, cols, _ = _pixels_of(no_rgb)
    inside = cols < WIDTH // 2
    outside = int((~inside).sum())
    assert 30_000 < outside < 80_000

    out = tmp_path / "no_rgb.laz"
    rc, stdout, _ = cli("convert", no_rgb, "-o", out, "--colorize", half, "-q")
    assert rc == 0 and f", {outside:,} outside {half} or under its mask (colour kept, 0 where none), " in stdout
    rgb = _rgb(laspy.read(str(out)))
    assert np.array_equal(rgb[inside], _pattern()[:, rows[inside], cols[inside]].T.astype(np.uint16) * 257)
    assert not rgb[~inside].any()  # (no colour in the file: 0)

    colored = tmp_path / "colored.laz"
    result = gp.convert(autzen_path, colored, colorize=half)
    assert result.uncolored == outside
    own, rgb = _rgb(laspy.read(str(autzen_path))), _rgb(laspy.read(str(colored)))
    assert own.max() <= 255 and own[~inside].any()  # (autzen stores 8-bit values in LAS's 16-bit fields)
    assert np.array_equal(rgb[~inside], own[~inside] * 257)  # its own colours, on the 16-bit scale of the raster's
    assert np.array_equal(rgb[inside], _pattern()[:, rows[inside], cols[inside]].T.astype(np.uint16) * 257)


def test_points_under_alpha_0_keep_no_colour_and_are_counted(no_rgb, tmp_path):
    wkt = read_las_header(no_rgb).crs()
    alpha = np.where(np.arange(HEIGHT)[:, None] % 3 == 0, 0, 255) * np.ones((1, WIDTH))  # every third row transparent
    ortho = _geotiff(tmp_path / "rgba.tif", np.concatenate([_pattern(), alpha[None].astype(np.uint8)]), wkt, alpha=True)
    result = gp.convert(no_rgb, tmp_path / "out.laz", colorize=ortho)
    rows, cols, _ = _pixels_of(no_rgb)
    hidden = rows % 3 == 0
    assert result.uncolored == int(hidden.sum()) > 10_000
    rgb = _rgb(laspy.read(str(tmp_path / "out.laz")))
    assert not rgb[hidden].any()
    assert np.array_equal(rgb[~hidden], _pattern()[:, rows[~hidden], cols[~hidden]].T.astype(np.uint16) * 257)


def test_small_blocks_evicted_from_a_small_cache_give_the_same_colours(no_rgb, tmp_path, monkeypatch):
    colorize = importlib.import_module("gigapoint.io.colorize")
    monkeypatch.setattr(colorize, "BLOCK", 50)  # 237 x 114 pixels: 5 x 3 blocks, the last column's and row's narrower
    monkeypatch.setattr(colorize, "CACHE_BYTES", 3 * 50 * 50 * 5)  # three blocks with their masks: most are read again
    wkt = read_las_header(no_rgb).crs()
    alpha = np.where((np.arange(WIDTH)[None, :] + np.arange(HEIGHT)[:, None]) % 7 == 0, 0, 255) * np.ones((HEIGHT, 1))
    ortho = _geotiff(tmp_path / "rgba.tif", np.concatenate([_pattern(), alpha[None].astype(np.uint8)]), wkt, alpha=True)
    result = gp.convert(no_rgb, tmp_path / "out.laz", colorize=ortho, chunk_size=7_000)
    rows, cols, _ = _pixels_of(no_rgb)
    hidden = (rows + cols) % 7 == 0
    assert result.uncolored == int(hidden.sum()) > 5_000
    rgb = _rgb(laspy.read(str(tmp_path / "out.laz")))
    assert not rgb[hidden].any()
    assert np.array_equal(rgb[~hidden], _pattern()[:, rows[~hidden], cols[~hidden]].T.astype(np.uint16) * 257)


def test_a_raster_in_another_crs_is_refused_naming_both(cli, no_rgb, tmp_path):
    utm = _geotiff(tmp_path / "utm.tif", _pattern(), "EPSG:32610", from_origin(494_000, 4_878_000, 2, 2))
    out = tmp_path / "out.laz"
    rc, _, err = cli("convert", no_rgb, "-o", out, "--colorize", utm, "-q")
    expected = (
        f"error: {utm}: is in EPSG:32610 (WGS 84 / UTM zone 10N), the points ({no_rgb}) in NAD_1983_HARN_Lambert_Conformal_Conic; "
        "move them into its CRS with --to-crs EPSG:32610"
    )
    assert (rc, err.strip()) == (1, expected)
    assert not out.exists()


def test_points_in_a_compound_crs_take_the_colours_of_a_raster_in_its_horizontal_part(cli, no_rgb, tmp_path):
    """NAD83 / UTM 10N + NAVD88 heights over an orthophoto in NAD83 / UTM 10N: the heights are no
    pixel's (was refused: "move them into its CRS with --to-crs EPSG:26910", which drops them)."""
    compound = tmp_path / "utm_navd88.las"
    gp.convert(no_rgb, compound, to_crs="EPSG:26910+5703", from_crs="EPSG:2994+6360")
    transform = from_origin(494_000.0005, 4_878_000.0005, 2, 2)
    raster = _geotiff(tmp_path / "utm.tif", _pattern(1000, 1000), "EPSG:26910", transform)
    out = tmp_path / "out.las"
    rc, _, err = cli("convert", compound, "-o", out, "--colorize", raster, "-q")
    assert (rc, err) == (0, "")
    rows, cols, las = _pixels_of(out, transform)
    assert np.array_equal(_rgb(las), _pattern(1000, 1000)[:, rows, cols].T.astype(np.uint16) * 257)
    assert las.header.parse_crs() == pyproj.CRS("EPSG:26910+5703")  # (the points' CRS kept, heights and all)
    other = _geotiff(tmp_path / "wgs84.tif", _pattern(1000, 1000), "EPSG:32610", transform)  # (WGS 84's UTM: another datum)
    rc, _, err = cli("convert", compound, "-o", tmp_path / "other.las", "--colorize", other, "-q")
    assert (rc, err.split(";")[0]) == (1, f"error: {other}: is in EPSG:32610 (WGS 84 / UTM zone 10N), the points ({compound}) in NAD83 / UTM zone 10N + NAVD88 height")


def test_points_naming_no_crs_are_said_to_in_one_warning(cli, tmp_path):
    """(was "plain.las name no CRS")"""
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.array([5.0, 55.0]), np.array([5.0, 55.0]), np.array([1.0, 2.0])
    plain = tmp_path / "plain.las"
    las.write(str(plain))
    raster = _geotiff(tmp_path / "utm.tif", _pattern(10, 10), "EPSG:32610", from_origin(0, 100, 10, 10))
    rc, _, err = cli("convert", plain, "-o", tmp_path / "out.las", "--colorize", raster, "-q")
    assert (rc, err) == (0, f"warning: the points ({plain}) name no CRS: the raster's pixels are taken to be in the points' coordinates (convert: colorize)\n")


def test_colours_are_taken_after_to_crs_in_the_output_crs(no_rgb, tmp_path):
    transform = from_origin(494_000.0005, 4_878_000.0005, 2, 2)  # UTM metres, over autzen moved there (x 494 2xx-494 6xx)
    utm = _geotiff(tmp_path / "utm.tif", _pattern(1000, 1000), "EPSG:32610", transform)
    out = tmp_path / "utm.laz"
    with pytest.warns(GigapointWarning, match="z is kept"):
        result = gp.convert(no_rgb, out, to_crs="EPSG:32610", colorize=utm)
    assert result.uncolored == 0
    las = laspy.read(str(no_rgb))
    move = pyproj.Transformer.from_crs(pyproj.CRS(read_las_header(no_rgb).crs()), "EPSG:32610", always_xy=True)
    x, y, _ = move.transform(np.asarray(las.x), np.asarray(las.y), np.asarray(las.z))  # (as convert moves them: x, y and z)
    rows, cols = (np.asarray(v) for v in rowcol(transform, x, y))
    assert np.array_equal(_rgb(laspy.read(str(out))), _pattern(1000, 1000)[:, rows, cols].T.astype(np.uint16) * 257)


def test_tiles_are_coloured_too(no_rgb, tmp_path):
    wkt = read_las_header(no_rgb).crs()
    result = gp.tile(no_rgb, tmp_path / "tiles", 500, colorize=_geotiff(tmp_path / "ortho.tif", _pattern(), wkt))
    assert result.uncolored == 0 and len(result.tiles) > 1
    for tile in result.tiles:
        rows, cols, las = _pixels_of(tile)
        assert np.array_equal(_rgb(las), _pattern()[:, rows, cols].T.astype(np.uint16) * 257), tile


def test_a_missing_or_damaged_raster_is_refused_before_a_point_is_read(cli, no_rgb, tmp_path, monkeypatch):
    def no_read(*args):
        raise AssertionError("read")

    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.to_file"), "read_chunks", no_read)
    out = tmp_path / "out.laz"
    rc, _, err = cli("convert", no_rgb, "-o", out, "--colorize", tmp_path / "missing.tif", "-q")
    assert (rc, err.strip()) == (1, f"error: {tmp_path / 'missing.tif'}: no such raster file (convert: colorize)")
    (tmp_path / "rasters").mkdir()
    rc, _, err = cli("convert", no_rgb, "-o", out, "--colorize", tmp_path / "rasters", "-q")
    assert (rc, err.strip()) == (1, f"error: {tmp_path / 'rasters'}: is a folder, not a raster file (convert: colorize)")  # (was "no such raster file")
    damaged = tmp_path / "damaged.tif"
    damaged.write_bytes(b"II*\0" + bytes(range(256)) * 4)
    rc, _, err = cli("convert", no_rgb, "-o", out, "--colorize", damaged, "-q")
    assert rc == 1 and err.startswith(f"error: {damaged}: not a raster GDAL can read (") and len(err.strip().splitlines()) == 1
    with pytest.raises(InputError, match=r"float32 values; colorize reads orthophotos of 8- or 16-bit integers \(gdal_translate -ot Byte"):
        gp.tile(no_rgb, tmp_path / "tiles", 500, colorize=_geotiff(tmp_path / "f.tif", _pattern().astype(np.float32), read_las_header(no_rgb).crs()))
    assert not out.exists() and not (tmp_path / "tiles").exists()


def test_a_raster_whose_pixels_cannot_be_read_leaves_no_output(no_rgb, tmp_path):
    wkt = read_las_header(no_rgb).crs()
    ortho = tmp_path / "cut.tif"
    with rasterio.open(
        ortho, "w", driver="GTiff", width=WIDTH, height=HEIGHT, count=3, dtype="uint8", crs=wkt, transform=from_origin(LEFT, TOP, PIXEL, PIXEL),
        compress="deflate", tiled=True, blockxsize=16, blockysize=16,
    ) as ds:
        ds.write(_pattern())
    data = ortho.read_bytes()
    ortho.write_bytes(data[:4096] + bytes(len(data) - 4096))  # its header whole, its compressed pixels zeros
    out = tmp_path / "out.laz"
    with pytest.raises(InputError, match=r"cut\.tif: its pixels at rows \d+-\d+, columns \d+-\d+ cannot be read \(.*\); nothing was written$"):
        gp.convert(no_rgb, out, colorize=ortho)
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] == ["cut.tif"]


def test_without_rasterio_the_option_says_how_to_install_it(no_rgb, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rasterio", None)  # (import rasterio raises ImportError)
    with pytest.raises(InputError, match=r"^convert: colorize: colouring from a raster needs rasterio \(pip install 'gigapoint\[gis\]'\)$"):
        gp.convert(no_rgb, tmp_path / "out.laz", colorize=tmp_path / "ortho.tif")


def _octree_points(path):
    """Every point of the octree folder ``path`` (gp.open): positions (n x 3), 8-bit RGB (n x 3), gps_time; and octree.json's has_color."""
    tree = gp.open(path)
    parts = [tree.node_points(i) for i in range(len(tree.nodes))]
    rgb = np.concatenate([p["rgba"] for p in parts]).view(np.uint8).reshape(-1, 4)[:, :3]
    return np.concatenate([p["xyz"] for p in parts]), rgb, np.concatenate([p["gps_time"] for p in parts]), tree.meta["has_color"]


def _in_order(rgb, xyz, gps_time, step=0.01):
    """``rgb`` in the order of (gps_time, x, y, z on the grid of ``step``): the same points of two outputs in one order (an octree's is its own)."""
    cells = np.round(np.asarray(xyz, np.float64) / step).astype(np.int64)
    return np.asarray(rgb)[np.lexsort([cells[:, 2], cells[:, 1], cells[:, 0], np.asarray(gps_time)])]


def _las_in_order(las, step=0.01):
    """A LAS file's RGB in ``_in_order``'s order."""
    return _in_order(_rgb(las), np.column_stack([las.x, las.y, las.z]), las.gps_time, step)


def test_a_copc_file_takes_each_points_pixel_colour_as_a_plain_file_does(cli, no_rgb, tmp_path):
    ortho = _geotiff(tmp_path / "ortho.tif", _pattern(), read_las_header(no_rgb).crs())
    plain = laspy.read(str(gp.convert(no_rgb, tmp_path / "plain.las", colorize=ortho).out))
    copc = tmp_path / "rgb.copc.laz"
    rc, stdout, err = cli("convert", no_rgb, "-o", copc, "--colorize", ortho, "-q")
    assert (rc, err) == (0, "")
    assert stdout.startswith(f"{copc}: 110,000 points in ") and f" (copc, grid), every point coloured from {ortho}, " in stdout
    written = laspy.read(str(copc))
    assert written.header.point_format.id == 7  # (format 1 had no RGB)
    rows, cols = _pixels_under(written.x, written.y)
    expected = _pattern()[:, rows, cols].T.astype(np.uint16) * 257
    assert np.array_equal(_rgb(written), expected) and len(np.unique(expected, axis=0)) > 1000
    assert np.array_equal(_las_in_order(written), _las_in_order(plain))


def test_an_octree_folder_takes_its_pixels_colours_black_outside_and_counts_those(cli, no_rgb, tmp_path):
    half = _geotiff(tmp_path / "west.tif", _pattern()[:, :, : WIDTH // 2], read_las_header(no_rgb).crs())  # columns 0-117: the west half
    plain = laspy.read(str(gp.convert(no_rgb, tmp_path / "plain.las", colorize=half).out))
    outside = int((_pixels_of(no_rgb)[1] >= WIDTH // 2).sum())
    assert 30_000 < outside < 80_000
    out = tmp_path / "octree"
    rc, stdout, err = cli("convert", no_rgb, "-o", out, "--colorize", half, "-q")
    assert (rc, err) == (0, "")
    assert f" (gigapoint, grid), {outside:,} outside {half} or under its mask (colour kept, 0 where none), " in stdout
    xyz, rgb, gps_time, has_color = _octree_points(out)
    assert has_color is True and len(xyz) == 110_000  # (the file had no colours: octree.json said false)
    rows, cols = _pixels_under(xyz[:, 0], xyz[:, 1])
    inside = cols < WIDTH // 2
    assert int((~inside).sum()) == outside and not rgb[~inside].any()  # (no colour in the file: 0, not the grey it is drawn in)
    assert np.array_equal(rgb[inside], _pattern()[:, rows[inside], cols[inside]].T)
    assert np.array_equal(_in_order(rgb.astype(np.uint16) * 257, xyz, gps_time), _las_in_order(plain))


def test_octrees_and_copc_are_coloured_after_to_crs_as_a_plain_file(autzen_path, tmp_path):
    transform = from_origin(494_000.0005, 4_878_000.0005, 2, 2)  # UTM metres, over autzen moved there; pixel edges half a step off the 0.001 m grid
    utm = _geotiff(tmp_path / "utm.tif", _pattern(1000, 1000), "EPSG:32610", transform)
    with pytest.warns(GigapointWarning, match="z is kept"):
        plain = laspy.read(str(gp.convert(autzen_path, tmp_path / "plain.las", to_crs="EPSG:32610", colorize=utm).out))
    with pytest.warns(GigapointWarning, match="z is kept"):
        result = gp.convert(autzen_path, tmp_path / "utm.copc.laz", to_crs="EPSG:32610", colorize=utm)
    assert result.uncolored == 0
    written = laspy.read(str(result.out))
    assert written.header.parse_crs() == pyproj.CRS.from_epsg(32610)
    rows, cols = _pixels_under(written.x, written.y, transform)  # (the moved points' pixels: in feet, autzen's lie off this raster)
    assert np.array_equal(_rgb(written), _pattern(1000, 1000)[:, rows, cols].T.astype(np.uint16) * 257)
    assert np.array_equal(_las_in_order(written, 0.001), _las_in_order(plain, 0.001))
    with pytest.warns(GigapointWarning, match="z is kept"):
        assert gp.convert(autzen_path, tmp_path / "utm", to_crs="EPSG:32610", colorize=utm).uncolored == 0
    xyz, rgb, gps_time, _ = _octree_points(tmp_path / "utm")
    rows, cols = _pixels_under(xyz[:, 0], xyz[:, 1], transform)
    assert np.array_equal(rgb, _pattern(1000, 1000)[:, rows, cols].T)
    assert np.array_equal(_in_order(rgb.astype(np.uint16) * 257, xyz, gps_time, 0.001), _las_in_order(plain, 0.001))


def test_an_octree_conversion_resumes_only_with_the_same_raster_and_counts_across_runs(no_rgb, tmp_path, monkeypatch, interrupted_read):
    colorize = importlib.import_module("gigapoint.io.colorize")
    closed = []
    monkeypatch.setattr(colorize.Colorization, "close", lambda self, close=colorize.Colorization.close: (closed.append(self.path.name), close(self)))

    def stopped(out, raster):
        interrupted_read(lambda: gp.convert(no_rgb, out, colorize=raster, chunk_size=20_000))

    wkt = read_las_header(no_rgb).crs()
    half = _geotiff(tmp_path / "west.tif", _pattern()[:, :, : WIDTH // 2], wkt)
    whole = _geotiff(tmp_path / "ortho.tif", _pattern(), wkt)
    rows, cols, _ = _pixels_of(no_rgb)
    stopped(tmp_path / "same", half)
    assert closed == ["west.tif"]  # (closed on the way out of a stopped run too)
    same = gp.convert(no_rgb, tmp_path / "same", colorize=half, chunk_size=20_000)
    assert (same.resumed, same.points, same.uncolored) == (True, 110_000, int((cols >= WIDTH // 2).sum()))  # (the chunks of both runs counted)
    stopped(tmp_path / "other", half)
    other = gp.convert(no_rgb, tmp_path / "other", colorize=whole, chunk_size=20_000)  # another raster: starts over, not a mix of both
    assert (other.resumed, other.points, other.uncolored) == (False, 110_000, 0)
    xyz, rgb, _, _ = _octree_points(tmp_path / "other")
    rows, cols = _pixels_under(xyz[:, 0], xyz[:, 1])
    assert np.array_equal(rgb, _pattern()[:, rows, cols].T)
    assert closed == ["west.tif", "west.tif", "west.tif", "ortho.tif"]


def test_colorize_is_refused_for_a_clouds_points(no_rgb, tmp_path):
    with pytest.raises(InputError, match=r"^convert: colorize colours the points read from files; the inputs are a cloud or PointChunks$"):
        gp.convert(gp.open(no_rgb), tmp_path / "octree", colorize=tmp_path / "ortho.tif")
    assert not (tmp_path / "octree").exists()


def test_an_octree_conversion_resumes_only_with_the_same_colorize_bits(no_rgb, tmp_path, interrupted_read):
    bands = (_pattern().astype(np.uint16) << 4) | 15  # 12-bit values naming no NBITS
    ortho = _geotiff(tmp_path / "ortho12.tif", bands, read_las_header(no_rgb).crs())
    for out in (tmp_path / "same", tmp_path / "other"):
        interrupted_read(lambda out=out: gp.convert(no_rgb, out, colorize=ortho, colorize_bits=12, chunk_size=20_000))
    assert gp.convert(no_rgb, tmp_path / "same", colorize=ortho, colorize_bits=12, chunk_size=20_000).resumed is True
    other = gp.convert(no_rgb, out, colorize=ortho, colorize_bits=11, chunk_size=20_000)  # other colours: starts over, not a mix of both
    assert (other.resumed, other.points) == (False, 110_000)
    xyz, rgb, _, _ = _octree_points(out)
    rows, cols = _pixels_under(xyz[:, 0], xyz[:, 1])
    assert np.array_equal(rgb, (np.minimum(bands, 2047) >> 3)[:, rows, cols].T)  # (as 11-bit values: those past 2047 white)
