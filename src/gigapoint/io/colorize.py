"""Points coloured from an orthophoto (PDAL's filters.colorization, LAStools' lascolor):
``convert -o out.laz --colorize ortho.tif`` and ``tile --colorize`` (lod/convert/to_file.py's
PointFiles), through rasterio (GDAL), an optional dependency (``pip install 'gigapoint[gis]'``).

Each point takes the colour of the pixel it lies in (nearest: no blending), in the output's
coordinates: after ``--to-crs`` has moved it; a rotated or sheared raster (an affine with b, d
terms) too, through its inverse affine. Bands 1, 2, 3 are red, green, blue (a raster of one or two
bands: band 1 as grey; a paletted one's band 1 indexes its colour table). 8-bit values are written x 257 into LAS's 16-bit fields. gigapoint's
chunks hold 8 bits a channel (PointChunk.rgba), so a raster's values are scaled to 8 bits by its
real bit depth, n: GDAL's NBITS where the file gives one (a 16-bit orthophoto of 12- or 11-bit
data, 0-4095 or 0-2047), else its type's (8, 16); ``--colorize-bits n`` over both. A 16-bit
raster naming no NBITS whose values (GDAL's approximate statistics) reach only n < 16 bits is
warned of, naming n and the option: such colours come out dark (1/16 of full brightness for 12
bits), but a sample does not prove a bit depth (PDAL's filters.colorization does not scale either;
QGIS stretches for display only). n > 8 keeps each value's top 8 bits
(v >> (n - 8), as 16-bit LAS colours do through ``convert``), n < 8 is stretched to 0-255; then
written x 257. Keeping 16 bits would need 16-bit colours in PointChunk. A float raster is refused:
its values do not say their range (0-1 reflectance, 0-255, 0-10000, or a DSM's heights given by
mistake). A point outside the raster, or on a pixel GDAL's mask says holds nothing (an alpha
band's 0, the bands' nodata value), takes no colour from it: it keeps the colour its file gave it,
or 0 (black) where its file had none; those points are counted.

The raster is read in blocks of ``BLOCK`` x ``BLOCK`` pixels, those under a chunk's points, never
whole: orthophotos are often tens of GB, and a chunk of points covers a small part of one (the
blocks last used are kept, ``CACHE_BYTES`` of them; GDAL's own cache held to ``GDAL_CACHE_BYTES``).
A raster that cannot be opened, holds no 8- or 16-bit unsigned integers, or is in another CRS than
the points, is a one-line InputError before a point is read."""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import numpy as np

from ..core.chunk import PointChunk
from ..errors import GigapointWarning, InputError, check_whole, first_line, warn
from .crs import same_horizontal

#: pixels along each edge of the blocks the raster is read in
BLOCK = 1024
#: bytes of blocks kept, the last used, so that a chunk's blocks, and those of the next chunks over
#: the same ground, are read once: 256 MiB, 64 blocks (4 bytes a pixel), 8192 x 8192 pixels (410 m
#: square of a 5 cm orthophoto). 32 blocks of 512² with 5 M demo points in 20 chunks, each chunk
#: over all 272 blocks of an 8192² raster: every block read again in every chunk, 6.8 s against 2.0 s
CACHE_BYTES = 256 * 2**20
#: bytes of GDAL's own block cache while blocks are read (its default, 5% of the RAM, would keep a
#: second copy of what ``CACHE_BYTES`` keeps); more where the raster's blocks are wider than a
#: ``BLOCK`` (strips), which each block along a row decodes again: ``_gdal_cache_bytes``
GDAL_CACHE_BYTES = 16 * 2**20


def rasterio_module(option: str):
    """rasterio, or a one-line InputError naming ``option`` where it is not installed."""
    try:
        import rasterio
    except ImportError:
        raise InputError(f"{option}: colouring from a raster needs rasterio (pip install 'gigapoint[gis]')") from None
    return rasterio


def open_colorization(raster, bits, where: str) -> Colorization | None:
    """The Colorization of ``raster`` (convert's and tile's colorize, its values' ``bits``:
    colorize_bits), None without one; bits without a raster: a one-line InputError (not ignored)."""
    if raster is None:
        if bits is not None:
            raise InputError(f"{where}: --colorize-bits {bits!r}: the bit depth of a --colorize raster's values; give --colorize too")
        return None
    return Colorization(raster, where, bits)


class Colorization:
    """The colours of the orthophoto ``raster`` for points (``colored``). ``where``: the operation
    ('convert', 'tile') its errors start with. ``bits``: how many bits its values hold
    (--colorize-bits), in place of its NBITS or type's. A missing file, one GDAL cannot read, bands of
    another type than 8- or 16-bit integers, bits beyond its type's: one-line InputErrors, here, before a point is read."""

    def __init__(self, raster, where: str = "convert", bits=None):
        rasterio = rasterio_module(f"{where}: colorize")
        self.path = Path(raster)
        self.where = where
        if self.path.is_dir():  # (was "no such raster file" of a folder that is there)
            raise InputError(f"{self.path}: is a folder, not a raster file ({where}: colorize)")
        if not self.path.is_file():
            raise InputError(f"{self.path}: no such raster file ({where}: colorize)")
        try:
            self._dataset = rasterio.open(self.path)
        except rasterio.errors.RasterioError as exc:
            raise InputError(f"{self.path}: not a raster GDAL can read ({first_line(exc)})") from None
        ds = self._dataset
        if ds.transform.is_identity:  # (GDAL's stand-in where a raster has none: points coloured by pixel index)
            ds.close()
            raise InputError(f"{self.path}: not georeferenced (no geotransform, nor a world file beside it): colorize needs to know where its pixels lie")
        if ds.dtypes[0] not in ("uint8", "uint16"):
            ds.close()
            scale = " (gdal_translate -ot Byte -scale MIN MAX 0 255 makes one of its range)" if ds.dtypes[0].startswith("float") else ""
            raise InputError(f"{self.path}: its bands hold {ds.dtypes[0]} values; colorize reads orthophotos of 8- or 16-bit integers{scale}")
        self.bands = (1, 2, 3) if ds.count >= 3 else (1, 1, 1)  # (one or two bands: grey, and maybe its alpha)
        type_bits = np.dtype(ds.dtypes[0]).itemsize * 8
        if bits is not None:  # (--colorize-bits: the user's word over the file's; a bad one refused for a paletted raster too)
            try:
                self.nbits = check_whole(str(self.path), f"--colorize-bits for its {ds.dtypes[0]} values", bits, 1, type_bits)
            except InputError:
                ds.close()
                raise
        self.palette = _palette(ds, type_bits)
        if self.palette is not None:  # (its values are indices, of no bit depth: its table's colours are 8-bit, --colorize-bits or not)
            self.bands, self.nbits = (1, 1, 1), 8
        elif bits is None:
            self.nbits = max(_nbits(ds.tags(band, ns="IMAGE_STRUCTURE"), type_bits) for band in set(self.bands))
            if self.nbits == 16:  # (16-bit, naming no NBITS: maybe 12-bit data, dark as 16-bit)
                self._warn_of_fewer_bits(sorted(set(self.bands)))
        self.to_8_bits = _levels_8_bits(self.nbits, type_bits)  # (gigapoint holds 8 bits a channel)
        self.gdal_cache_bytes = _gdal_cache_bytes(ds)
        self.masked = any(flag.name != "all_valid" for flags in ds.mask_flag_enums for flag in flags)
        self.transform = ds.transform
        self._blocks: OrderedDict[tuple[int, int], tuple[np.ndarray, np.ndarray | None]] = OrderedDict()
        self._cached_bytes = 0

    def close(self) -> None:
        self._dataset.close()

    def _warn_of_fewer_bits(self, bands: list[int]) -> None:
        """Warn where a 16-bit raster naming no NBITS holds values of fewer bits (12-bit data, 0-4095,
        in a 16-bit file), by GDAL's approximate statistics: its overviews, else a sample of its
        blocks (about the square root of their number: 0.1 s for a 345 MB raster, against 3 s a band
        read whole). Taken as 16-bit, such values come out dark (12 bits: 1/16 of full brightness);
        they are not scaled by what the sample found (another sample, another scale; a dark 16-bit
        image made bright): the user says how many bits they hold (--colorize-bits)."""
        import rasterio
        from rasterio.errors import RasterioError

        try:  # (a second handle, without GDAL's .aux.xml: statistics would be written beside the raster)
            with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(self.path) as ds:
                highest = int(max(band.max for band in ds.stats(indexes=bands, approx=True)))
        except RasterioError:  # (no valid pixel in the sample: nothing to say)
            return
        found = highest.bit_length()
        if 0 < found < 16:
            warn(f"{self.path}: its 16-bit values name no bit depth (NBITS) and reach only {highest} ({found} bits) in GDAL's approximate statistics: "
                 f"read as 16-bit, its colours come out at most 1/{2 ** (16 - found)} of full brightness; if it holds {found}-bit values, say so "
                 f"with --colorize-bits {found} (colorize_bits={found}), or write NBITS into a copy: gdal_translate -co NBITS={found} {self.path} OUT.tif",
                 GigapointWarning)  # fmt: skip

    def check_crs(self, points_crs: str | None, label: str) -> None:
        """Refuse, in one line naming both, a raster in another horizontal CRS than the points'
        (``points_crs``: their WKT or 'EPSG:n', the output's; a compound one's heights are no
        pixel's: EPSG:26910+5703 points over an EPSG:26910 raster were refused); warn where either
        names none (taken to be the same)."""
        raster_crs = self._dataset.crs
        if raster_crs is None or not points_crs:
            which = f"{self.path} names no CRS" if raster_crs is None else f"the points ({label}) name no CRS"  # (one file or several)
            warn(f"{which}: the raster's pixels are taken to be in the points' coordinates ({self.where}: colorize)", GigapointWarning)
            return
        from .reproject import parse_crs

        theirs = parse_crs(raster_crs.to_wkt(), f"{self.path}: its CRS")
        ours = parse_crs(points_crs, f"{label}: its CRS")
        if not same_horizontal(theirs, ours):  # (rasterio's == told autzen's WKT from its GeoTIFF copy apart)
            raise InputError(
                f"{self.path}: is in {_crs_label(theirs)}, the points ({label}) in {_crs_label(ours)}; "
                f"move them into its CRS with --to-crs {f'EPSG:{theirs.to_epsg()}' if theirs.to_epsg() else 'and its WKT'}"
            )

    def colored(self, chunk: PointChunk, had_color: bool) -> tuple[PointChunk, int]:
        """(``chunk`` with each point's colour from its pixel, 16-bit LAS colours; the points that took
        none: outside the raster or under its mask). Those keep their colour (``had_color``: their
        file's), else take 0."""
        rgba = chunk.rgba.copy() if had_color else np.zeros_like(chunk.rgba)
        rgba[:, 3] = 255
        rows, cols = self._pixels(chunk.xyz)
        height, width = self._dataset.height, self._dataset.width
        inside = np.flatnonzero((rows >= 0) & (rows < height) & (cols >= 0) & (cols < width))
        rows, cols = rows[inside], cols[inside]
        block_rows, block_cols = rows // BLOCK, cols // BLOCK
        keys = block_rows * (width // BLOCK + 1) + block_cols
        few = len(keys) and keys.max() < 2**16  # (numpy sorts 16-bit integers by radix, "stable": 5x quicker)
        order = np.argsort(keys.astype(np.uint16), kind="stable") if few else np.argsort(keys)  # (each block's points together: one read, one take)
        inside, keys = inside[order], keys[order]
        block_widths = np.minimum(BLOCK, width - block_cols * BLOCK)
        in_block = ((rows % BLOCK) * block_widths + cols % BLOCK)[order]  # each point's pixel in its block's flat arrays
        values = np.empty(len(inside), np.uint32)  # red, green, blue, 0: bytes of one u32 (a 1-D take, ~3x a (n, 3) one's speed)
        valid = np.ones(len(inside), np.bool_)
        starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]) if len(keys) else np.empty(0, np.intp)
        for start, end in zip(starts, np.r_[starts[1:], len(keys)]):
            first = order[start]
            block_values, block_valid = self._block(int(block_rows[first]), int(block_cols[first]))
            np.take(block_values, in_block[start:end], out=values[start:end])
            if block_valid is not None:
                np.take(block_valid, in_block[start:end], out=valid[start:end])
        rgba[inside[valid], :3] = values.view(np.uint8).reshape(-1, 4)[valid, :3]
        return PointChunk(chunk.xyz, rgba, chunk.attributes, scale=chunk.scale, color_bits=16), len(chunk) - int(valid.sum())

    def _pixels(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) of the pixel each point lies in (-1 for a point whose x or y is not finite)."""
        t = self.transform
        x, y = xyz[:, 0], xyz[:, 1]
        if t.b == 0 and t.d == 0:  # north up (nearly every orthophoto): a division, exact at pixel edges
            col, row = (x - t.c) / t.a, (y - t.f) / t.e
        else:
            inverse = ~t
            col, row = inverse.a * x + inverse.b * y + inverse.c, inverse.d * x + inverse.e * y + inverse.f
        ok = np.isfinite(col) & np.isfinite(row) & (np.abs(col) < 2**62) & (np.abs(row) < 2**62)
        return (np.where(ok, np.floor(row), -1).astype(np.int64), np.where(ok, np.floor(col), -1).astype(np.int64))

    def _block(self, block_row: int, block_col: int) -> tuple[np.ndarray, np.ndarray | None]:
        """(8-bit red, green, blue, 0 of one block's pixels as the bytes of u32s, row by row (h·w); whether GDAL's mask says
        each holds something (h·w), None where every one does), read once while it stays among the
        blocks last used (``CACHE_BYTES``)."""
        key = (block_row, block_col)
        if key in self._blocks:
            self._blocks.move_to_end(key)
            return self._blocks[key]
        import rasterio
        from rasterio.errors import RasterioError
        from rasterio.windows import Window

        ds = self._dataset
        top, left = block_row * BLOCK, block_col * BLOCK
        window = Window(left, top, min(BLOCK, ds.width - left), min(BLOCK, ds.height - top))
        try:
            with rasterio.Env(GDAL_CACHEMAX=self.gdal_cache_bytes):  # (rasterio sets bytes: GDALSetCacheMax64)
                bands = ds.read(sorted(set(self.bands)), window=window)
                valid = ds.dataset_mask(window=window).ravel() != 0 if self.masked else None
        except RasterioError as exc:  # (a damaged file whose header reads: its pixels do not)
            raise InputError(f"{self.path}: its pixels at rows {top}-{top + window.height - 1}, columns {left}-{left + window.width - 1} "
                             f"cannot be read ({first_line(exc)}); nothing was written") from None  # fmt: skip
        rgb0 = np.zeros((bands.shape[1] * bands.shape[2], 4), np.uint8)
        if self.palette is not None:
            rgb0[:, :3] = self.palette[bands[0].ravel()]
        else:
            rgb0[:, :3] = self.to_8_bits[bands[[0, 0, 0] if len(bands) == 1 else [0, 1, 2]]].reshape(3, -1).T
        values = rgb0.view(np.uint32).ravel()
        self._blocks[key] = (values, valid)
        self._cached_bytes += values.nbytes + (valid.nbytes if valid is not None else 0)
        while self._cached_bytes > CACHE_BYTES:
            old_values, old_valid = self._blocks.popitem(last=False)[1]
            self._cached_bytes -= old_values.nbytes + (old_valid.nbytes if old_valid is not None else 0)
        return values, valid


def _palette(ds, type_bits: int) -> np.ndarray | None:
    """The red, green, blue of each value of a paletted raster's band 1 (its colour table: a map's
    classes; 2**type_bits x 3, black where the table has no entry), None for any other raster."""
    from rasterio.enums import ColorInterp

    if ds.colorinterp[0] != ColorInterp.palette:
        return None
    table = np.zeros((2**type_bits, 3), np.uint8)
    for value, rgba in ds.colormap(1).items():
        table[value] = rgba[:3]
    return table


def _nbits(image_structure: dict, type_bits: int) -> int:
    """A band's real bit depth: GDAL's NBITS (IMAGE_STRUCTURE metadata) where it gives a sane one, else ``type_bits``."""
    nbits = image_structure.get("NBITS", "")
    return int(nbits) if nbits.isdigit() and 1 <= int(nbits) <= type_bits else type_bits


def _levels_8_bits(nbits: int, type_bits: int) -> np.ndarray:
    """The 8-bit level of each value 0 .. 2**type_bits - 1 of ``nbits``-bit data, a look-up table: its
    top 8 bits, or under 8 bits stretched to 0-255; values past the n-bit range are 255."""
    values = np.minimum(np.arange(2**type_bits), 2**nbits - 1)
    return (values >> (nbits - 8) if nbits >= 8 else values * 255 // (2**nbits - 1)).astype(np.uint8)


def _gdal_cache_bytes(ds) -> int:
    """``GDAL_CACHE_BYTES``, or more where the raster's own blocks are wider than a ``BLOCK`` (strips,
    often of one row): twice the bytes of those under one row of ``BLOCK``s, which every block along
    the row decodes whole else (16384 x 2048 pixels of deflate strips, 32 blocks: 1.3 s in 16 MiB or
    in exactly those bytes, 0.2 s in 1.5 times them or in GDAL's default 5% of the RAM)."""
    block_height, block_width = ds.block_shapes[0]
    if block_width <= BLOCK:
        return GDAL_CACHE_BYTES
    rows = (-(-BLOCK // block_height) + 1) * block_height  # (a BLOCK's rows may start inside a strip)
    return max(GDAL_CACHE_BYTES, 2 * rows * ds.width * ds.count * np.dtype(ds.dtypes[0]).itemsize)


def _crs_label(crs) -> str:
    """A pyproj CRS as errors name it: 'EPSG:n (its name)' where pyproj finds its code, else its name."""
    code = crs.to_epsg()
    return f"EPSG:{code} ({crs.name})" if code else crs.name


__all__ = ["BLOCK", "CACHE_BYTES", "GDAL_CACHE_BYTES", "Colorization", "open_colorization", "rasterio_module"]
