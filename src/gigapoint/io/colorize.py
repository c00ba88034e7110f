"""Points coloured from an orthophoto (PDAL's filters.colorization, LAStools' lascolor):
``convert -o out.laz --colorize ortho.tif`` and ``tile --colorize`` (lod/convert/to_file.py's
PointFiles), through rasterio (GDAL), an optional dependency (``pip install 'gigapoint[gis]'``).

Each point takes the colour of the pixel it lies in (nearest: no blending), in the output's
coordinates: after ``--to-crs`` has moved it. Bands 1, 2, 3 are red, green, blue (a raster of one
or two bands: band 1 as grey). 8-bit values are written x 257 into LAS's 16-bit fields; gigapoint
holds 8 bits a channel, so a 16-bit raster's values keep their high byte (v >> 8, written x 257),
as 16-bit LAS colours do through ``convert``. A point outside the raster, or on a pixel GDAL's
mask says holds nothing (an alpha band's 0, the bands' nodata value), takes no colour from it: it
keeps the colour its file gave it, or 0 (black) where its file had none; those points are counted.

The raster is read in blocks of ``BLOCK`` x ``BLOCK`` pixels, those under a chunk's points, a few
of them kept (``CACHED_BLOCKS``): orthophotos are often tens of GB, and a chunk of points covers a
small part of one. A raster that cannot be opened, holds no 8- or 16-bit integers, or is in
another CRS than the points, is a one-line InputError before a point is read."""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import numpy as np

from ..core.chunk import PointChunk
from ..errors import GigapointWarning, InputError, first_line, warn

#: pixels along each edge of the blocks the raster is read in
BLOCK = 512
#: blocks kept between chunks (at most 32 x 512² pixels x 3 bytes: 24 MiB, their masks 8 MiB more)
CACHED_BLOCKS = 32


def rasterio_module(option: str):
    """rasterio, or a one-line InputError naming ``option`` where it is not installed."""
    try:
        import rasterio
    except ImportError:
        raise InputError(f"{option}: colouring from a raster needs rasterio (pip install 'gigapoint[gis]')") from None
    return rasterio


class Colorization:
    """The colours of the orthophoto ``raster`` for points (``colored``). ``where``: the operation
    ('convert', 'tile') its errors start with. A missing file, one GDAL cannot read, bands of
    another type than 8- or 16-bit integers: one-line InputErrors, here, before a point is read."""

    def __init__(self, raster, where: str = "convert"):
        rasterio = rasterio_module(f"{where}: colorize")
        self.path = Path(raster)
        self.where = where
        if not self.path.is_file():
            raise InputError(f"{self.path}: no such raster file ({where}: colorize)")
        try:
            self._dataset = rasterio.open(self.path)
        except rasterio.errors.RasterioError as exc:
            raise InputError(f"{self.path}: not a raster GDAL can read ({first_line(exc)})") from None
        ds = self._dataset
        if ds.dtypes[0] not in ("uint8", "uint16"):
            ds.close()
            raise InputError(f"{self.path}: its bands hold {ds.dtypes[0]} values; colorize reads orthophotos of 8- or 16-bit integers")
        self.bands = (1, 2, 3) if ds.count >= 3 else (1, 1, 1)  # (one or two bands: grey, and maybe its alpha)
        self.shift = 8 if ds.dtypes[0] == "uint16" else 0  # (gigapoint holds 8 bits a channel)
        self.masked = any(flag.name != "all_valid" for flags in ds.mask_flag_enums for flag in flags)
        self.transform = ds.transform
        self._blocks: OrderedDict[tuple[int, int], tuple[np.ndarray, np.ndarray | None]] = OrderedDict()

    def close(self) -> None:
        self._dataset.close()

    def check_crs(self, points_crs: str | None, label: str) -> None:
        """Refuse, in one line naming both, a raster in another CRS than the points' (``points_crs``:
        their WKT or 'EPSG:n', the output's); warn where either names none (taken to be the same)."""
        raster_crs = self._dataset.crs
        if raster_crs is None or not points_crs:
            which = f"{self.path} names no CRS" if raster_crs is None else f"{label} name no CRS"
            warn(f"{which}: its pixels are taken to be in the points' coordinates ({self.where}: colorize)", GigapointWarning)
            return
        from .reproject import parse_crs

        theirs = parse_crs(raster_crs.to_wkt(), f"{self.path}: its CRS")
        ours = parse_crs(points_crs, f"{label}: its CRS")
        if not theirs.equals(ours, ignore_axis_order=True):  # (rasterio's == told autzen's WKT from its GeoTIFF copy apart)
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
        inside = np.flatnonzero((rows >= 0) & (rows < self._dataset.height) & (cols >= 0) & (cols < self._dataset.width))
        colored = 0
        if len(inside):
            keys = (rows[inside] // BLOCK) * (self._dataset.width // BLOCK + 1) + cols[inside] // BLOCK
            order = np.argsort(keys, kind="stable")
            inside, keys = inside[order], keys[order]
            starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
            for start, end in zip(starts, np.r_[starts[1:], len(keys)]):
                points = inside[start:end]
                r, c = rows[points], cols[points]
                block_row, block_col = int(r[0]) // BLOCK, int(c[0]) // BLOCK
                values, valid = self._block(block_row, block_col)
                r, c = r - block_row * BLOCK, c - block_col * BLOCK
                if valid is not None:
                    keep = valid[r, c]
                    points, r, c = points[keep], r[keep], c[keep]
                rgba[points, :3] = values[:, r, c].T
                colored += len(points)
        return PointChunk(chunk.xyz, rgba, chunk.attributes, scale=chunk.scale, color_bits=16), len(chunk) - colored

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
        """(8-bit red, green, blue (3 x h x w), where GDAL's mask says a pixel holds something or None
        where every one does) of one block, read once while it stays among the ``CACHED_BLOCKS`` last used."""
        key = (block_row, block_col)
        if key in self._blocks:
            self._blocks.move_to_end(key)
            return self._blocks[key]
        from rasterio.errors import RasterioError
        from rasterio.windows import Window

        ds = self._dataset
        top, left = block_row * BLOCK, block_col * BLOCK
        window = Window(left, top, min(BLOCK, ds.width - left), min(BLOCK, ds.height - top))
        try:
            values = (ds.read(sorted(set(self.bands)), window=window) >> self.shift).astype(np.uint8)
            valid = ds.dataset_mask(window=window) != 0 if self.masked else None
        except RasterioError as exc:  # (a damaged file whose header reads: its pixels do not)
            raise InputError(f"{self.path}: its pixels at rows {top}-{top + window.height - 1}, columns {left}-{left + window.width - 1} "
                             f"cannot be read ({first_line(exc)}); nothing was written") from None  # fmt: skip
        if len(values) == 1:
            values = np.repeat(values, 3, axis=0)
        self._blocks[key] = (values, valid)
        if len(self._blocks) > CACHED_BLOCKS:
            self._blocks.popitem(last=False)
        return values, valid


def _crs_label(crs) -> str:
    """A pyproj CRS as errors name it: 'EPSG:n (its name)' where pyproj finds its code, else its name."""
    code = crs.to_epsg()
    return f"EPSG:{code} ({crs.name})" if code else crs.name


__all__ = ["BLOCK", "CACHED_BLOCKS", "Colorization", "rasterio_module"]
