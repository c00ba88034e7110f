"""Orthophotos and surface models from Python: what `gigapoint render --gsd G -o ortho.tif
--depth-out dsm.tif [--fill-nodata]` writes, as ``gigapoint.orthophoto(source, gsd, out=, dsm=)``.

The cloud is drawn straight down through ``Camera.top_down`` (pixel edges on whole multiples of
the gsd, north up) with 30-bit positions, as the CLI draws it; the files go through the same
writers (render/georef.py: GeoTIFF tags, world files, .prj), so both ways give the same bytes."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.renderable import Renderable
from ..errors import CameraError, InputError, check_switch, is_real, number_text
from ..io.filters import point_filter
from ..io.paths import given_paths
from ..lod.reader import cloud_crs_units
from ..render import Camera, RenderSettings, render_frame
from ..render.georef import GEOTIFF_SUFFIXES, map_image, write_map
from ..render.image_files import IMAGE_SUFFIXES, check_output
from ..render.raster_fill import check_max_distance, fill_map
from ..render.surface import surface_heights


@dataclass(frozen=True)
class Orthophoto:
    """A top-down render on a ground grid: ``image`` (H, W, 4) uint8 RGBA and ``heights`` (H, W)
    float32 (the z of the highest point in each pixel, NaN where none: a DSM, or a DTM of ground
    points), drawn through ``camera`` (``Camera.top_down``: its ``world_file()``), pixels ``gsd``
    a side; ``crs`` and ``units`` (io.crs_units) those of the cloud."""

    image: np.ndarray
    heights: np.ndarray
    camera: Camera
    gsd: float
    crs: str | None
    units: dict

    def write(self, out=None, dsm=None, overwrite: bool = False) -> list[Path]:
        """The image as ``out`` (.png, .jpg, .webp, .tif: a GeoTIFF) and/or the heights as ``dsm``
        (a float32 GeoTIFF, NaN nodata), each with its world file, and the .prj of the CRS: the
        files ``gigapoint render --gsd -o OUT --depth-out DSM`` writes, byte for byte. All of them
        or none; an existing file is replaced only with ``overwrite=True``. Returns the paths."""
        check_switch("overwrite", overwrite, "orthophoto")
        if out is None and dsm is None:
            raise InputError("orthophoto: give out= (the image) and/or dsm= (the surface model) to write")
        return write_map(self.camera, self.crs, self.units, [(out, self.image), (dsm, self.heights)], overwrite)


def orthophoto(source, gsd, out=None, dsm=None, fill_nodata=None, classes=None, drop_classes=None, clip=None, clip_polygon=None,
               settings: RenderSettings | None = None, overwrite: bool = False, **setting_overrides) -> Orthophoto:  # fmt: skip
    """``source`` (paths as ``gigapoint.open`` takes them, or a cloud) drawn straight down, north
    up, ``gsd`` cloud units a pixel, covering it (``Camera.top_down``): an ``Orthophoto`` (image,
    heights, camera). ``out=``/``dsm=``: also written, as ``Orthophoto.write`` writes them (the
    paths checked before anything is read).

    ``fill_nodata``: "all" fills every NaN height inside the footprint linearly (a TIN), N only
    those within N pixels of a point, and then also gives the image's empty pixels there the
    nearest colour (``render --fill-nodata``; needs scipy). ``classes``/``drop_classes``/``clip``/
    ``clip_polygon``: only those points read (as ``gigapoint.open``). Settings as ``render``
    takes them (``settings`` and/or keywords: ``color_mode="elevation"``); positions are drawn at
    full precision whatever they say (exact pixels), and the heights are each pixel's highest
    point's whatever size they give the points (``render.surface``: splats are drawn only in the image)."""
    check_switch("overwrite", overwrite, "orthophoto")
    if not (is_real(gsd) and gsd > 0):
        raise InputError(f"orthophoto: gsd must be a number > 0 (cloud units per pixel), got {number_text(gsd)}")
    if fill_nodata is not None and fill_nodata != "all":
        check_max_distance("orthophoto: fill_nodata", fill_nodata)
    # the filters' bad values under orthophoto's name, before anything is read (gp.open's said "open: classes=...")
    keep = point_filter(classes, drop_classes, clip, "orthophoto", clip_polygon=clip_polygon)
    for path, suffixes in ((out, IMAGE_SUFFIXES), (dsm, GEOTIFF_SUFFIXES)):  # before anything is read (a long render lost to a name)
        if path is not None:
            check_output(path, overwrite, suffixes)
    settings = RenderSettings.of(settings)
    if setting_overrides:
        settings = settings.given(**setting_overrides)
    polygon = None if keep is None else keep.polygon  # (read once: a GeoJSON file)
    cloud = _cloud(source, {"classes": classes, "drop_classes": drop_classes, "clip": clip, "clip_polygon": polygon})
    try:
        camera = Camera.top_down(cloud.bounds, gsd)
    except CameraError as exc:
        raise CameraError(f"orthophoto: gsd: {exc}") from None
    settings = settings.replace(adaptive_precision=False)  # 30-bit positions: exact pixels
    frame = render_frame(cloud, camera, settings)
    distance = None if fill_nodata in (None, "all") else fill_nodata
    # (--fill-nodata's colours opaque again); the heights each pixel's highest point's, whatever splats the image draws
    image, heights = map_image(frame.image, frame.index < 0), surface_heights(cloud, camera, settings, frame)
    if fill_nodata is not None:
        image, heights = fill_map(image, frame.index < 0, heights, distance)
    crs, units = cloud_crs_units(cloud)
    result = Orthophoto(image, heights, camera, float(gsd), crs, units)
    if out is not None or dsm is not None:
        result.write(out, dsm, overwrite)
    return result


def _cloud(source, filters: dict):
    """``source`` as a cloud: one given as it is, paths opened with the filters."""
    given = {name: value for name, value in filters.items() if value is not None}
    if isinstance(source, Renderable):
        if given:  # (they would be dropped without a word)
            raise InputError(f"orthophoto: {', '.join(given)} filter the files read; a cloud is drawn as it is (filter it with gigapoint.open)")
        return source
    from .. import open_for

    return open_for("orthophoto", given_paths(source, "orthophoto", "source"), **given)  # (5 among them named by orthophoto, not gp.open)


__all__ = ["Orthophoto", "orthophoto"]
