"""Cross-sections (Potree's profile tool, CloudCompare's cross-section): the points of a thin
corridor along a line, seen from the side, to read the heights of a road, a wall, a ditch.

``section`` reads only the corridor's points (the read-time filter's ``corridor``,
io/filters.py: chunk by chunk, on every read path) and gives them as distances along the line,
offsets square to it and heights (``Section``: the CSV ``gigapoint section --csv`` writes), and
draws them with the renderer through an orthographic camera looking across the line
(``Camera.section``), on one scale on both axes unless a vertical exaggeration is asked for.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..core.chunk import PointChunk
from ..core.cloud import PointCloud, build_cloud
from ..errors import CameraError, InputError, check_switch, count_or_inf, count_text, is_real, number_text, numbers_text
from ..io._base import headers_once
from ..io.crs import crs_units, files_length_units, refuse_angles
from ..io.filters import PointFilter, along_and_across, corridor_of, point_filter
from ..io.http import shown_url
from ..io.paths import expand_paths, given_paths
from ..lod import is_lod_source
from ..lod.query import is_octree, kept_points, opened_octree
from ..lod.reader import cloud_crs_units
from ..render import Camera, Frame, RenderSettings, render_frame
from ..render.camera import MAX_IMAGE_SIDE, image_side

BORDER = 1  # pixels around the corridor's points: a point on the frame's edge is not lost to rounding
DEFAULT_WIDTH = 1920  # an image's width where neither a scale nor a size is given


@dataclass(frozen=True)
class Section:
    """The corridor's points (``cloud``, in the files' coordinates) along ``line`` (x1, y1, x2, y2),
    ``width`` wide. ``distance`` (from the line's start, along it), ``offset`` (square to it,
    positive to the left looking from the start to the end), ``z`` and ``classification`` (None
    where the points have none) are rows sorted by distance; ``index``: each row's point in ``cloud``;
    ``units``: io.crs_units of the source's CRS (what its distances and heights are in)."""

    cloud: PointCloud
    line: tuple[float, float, float, float]
    width: float
    units: dict = field(default_factory=lambda: crs_units(None))

    @property
    def length(self) -> float:
        return math.dist(self.line[:2], self.line[2:])

    @cached_property
    def _rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        xyz = self.cloud.positions()
        distance, offset = along_and_across(xyz, self.line)
        order = np.argsort(distance, kind="stable")
        return order, distance[order], offset[order], xyz[order, 2]

    @property
    def index(self) -> np.ndarray:
        return self._rows[0]

    @property
    def distance(self) -> np.ndarray:
        return self._rows[1]

    @property
    def offset(self) -> np.ndarray:
        return self._rows[2]

    @property
    def z(self) -> np.ndarray:
        return self._rows[3]

    @property
    def classification(self) -> np.ndarray | None:
        if "classification" not in self.cloud.attributes:
            return None
        return self.cloud.attributes.at("classification", self.index)

    def write_csv(self, path, overwrite: bool = False) -> None:
        """The rows as ``distance_along,offset,z[,classification]`` (a header line, then a point a
        line, by distance), written atomically, the folders missing on its way made; an existing
        file is replaced only with ``overwrite=True`` (as the other writers: it was, silently)."""
        from ..atomic import atomic_write, folders_for
        from ..render.image_files import check_output

        check_switch("overwrite", overwrite, "section")
        check_output(path, overwrite, suffixes=None)  # (any name: the CLI's --csv asks for a .csv itself)

        columns = [self.distance, self.offset, self.z]
        header, formats = "distance_along,offset,z", ["%.6f"] * 3
        if self.classification is not None:
            columns.append(self.classification)
            header, formats = header + ",classification", [*formats, "%d"]
        table = np.column_stack(columns)
        with folders_for(path):
            atomic_write(path, lambda tmp: np.savetxt(tmp, table, fmt=formats, delimiter=",", header=header, comments=""))

    def camera(self, scale=None, size=None, vertical_exaggeration=1.0) -> Camera:
        """The camera of the section's image (``Camera.section``): the line's whole length across,
        the points' heights (times ``vertical_exaggeration``) up, with a ``BORDER`` pixel border;
        pixel edges on whole multiples of the pixel's size from the line's start and from z 0.
        ``scale``: pixels per unit of the cloud (the image sized to fit); ``size`` (width, height):
        that image, the section as large as fits, centred; neither: ``DEFAULT_WIDTH`` pixels
        wide, as tall as the section is at that scale."""
        exaggeration = _exaggeration(vertical_exaggeration)
        z_lo, z_hi = float(self.z.min()) * exaggeration, float(self.z.max()) * exaggeration
        if scale is not None and size is not None:
            raise InputError("section: give scale= or size=, not both (a size sets the scale)")

        def needed(pixel: float) -> tuple[int, int]:
            """Pixels across and up that hold every point at ``pixel`` units a pixel, borders included."""
            return (count_or_inf(lambda: math.floor(self.length / pixel) + 1 + 2 * BORDER),
                    count_or_inf(lambda: math.ceil(z_hi / pixel) - math.floor(z_lo / pixel) + 1 + 2 * BORDER))

        if scale is not None:
            if not (is_real(scale) and scale > 0):
                raise CameraError(f"section: scale (pixels per unit) must be a number > 0, got {number_text(scale)}")
            pixel = 1.0 / scale
            image = needed(pixel)
            if max(image) > MAX_IMAGE_SIDE:
                fits = (MAX_IMAGE_SIDE - 2 * BORDER - 2) / max(self.length, z_hi - z_lo)
                raise CameraError(f"section: scale {number_text(scale)} makes a {count_text(image[0])}x{count_text(image[1])} image, over {MAX_IMAGE_SIDE:,} pixels a side: a scale of {fits:.3g} or less fits")
        else:  # the largest pixel that fits the section into the size (1e-9: division's rounding never needs one more)
            fit = (DEFAULT_WIDTH, MAX_IMAGE_SIDE) if size is None else check_size(size)
            pixel = max(self.length / (fit[0] - 2 * BORDER - 1), (z_hi - z_lo) / (fit[1] - 2 * BORDER - 2)) * (1 + 1e-9)
            image = (fit[0], needed(pixel)[1]) if size is None else fit
        # the points centred in the image by whole pixels (so the pixel edges stay on the grid)
        margin = [BORDER + (i - n) // 2 for i, n in zip(image, needed(pixel))]
        return Camera.section(self.line, self.width, pixel, left=-margin[0] * pixel, top=(math.ceil(z_hi / pixel) + margin[1]) * pixel,
                              width=image[0], height=image[1])  # fmt: skip

    def render_frame(self, scale=None, size=None, vertical_exaggeration=1.0, settings=None, **setting_overrides) -> Frame:
        """The section drawn (``render_frame`` through ``camera``'s camera): settings as ``render``
        takes them (``color_mode="classification"``, ``point_size=2``), with 30-bit positions
        (points in their exact pixels, as ``render --gsd``'s)."""
        camera = self.camera(scale, size, vertical_exaggeration)
        settings = RenderSettings.of(settings)
        if setting_overrides:
            settings = settings.given(**setting_overrides)
        return render_frame(self._drawn(_exaggeration(vertical_exaggeration)), camera, settings.replace(adaptive_precision=False))

    def render(self, scale=None, size=None, vertical_exaggeration=1.0, settings=None, **setting_overrides):
        """(H, W, 4) uint8 image of the section (``render_frame``'s)."""
        return self.render_frame(scale, size, vertical_exaggeration, settings, **setting_overrides).image

    def _drawn(self, exaggeration: float) -> PointCloud:
        """The cloud drawn: the corridor's, its heights times ``exaggeration`` (an orthographic
        camera has one scale: the points are stretched instead)."""
        if exaggeration == 1.0:
            return self.cloud

        def stretched(chunk: PointChunk) -> PointChunk:
            scale = None if chunk.scale is None else (chunk.scale[0], chunk.scale[1], chunk.scale[2] * exaggeration)
            return PointChunk(chunk.xyz * (1.0, 1.0, exaggeration), chunk.rgba, chunk.attributes, scale=scale)

        return build_cloud(map(stretched, self.cloud.chunks()), name=self.cloud.name, colors="rgba")  # (its colours as the cloud holds them)


def _exaggeration(value) -> float:
    if not (is_real(value) and value > 0):
        raise CameraError(f"section: vertical_exaggeration must be a number > 0 (1: heights at the scale of distances), got {number_text(value)}")
    return float(value)


def check_size(size) -> tuple[int, int]:
    """(width, height) of an image size given as a pair, each side at least 2 * BORDER + 3 pixels."""
    try:
        width, height = size
    except (TypeError, ValueError):
        raise CameraError(f"section: size must be (width, height) in pixels, got {size!r}") from None
    width, height = image_side("width", width), image_side("height", height)
    if min(width, height) < 2 * BORDER + 3:
        raise CameraError(f"section: an image of {width}x{height} pixels has no room for a section; give at least {2 * BORDER + 3} a side")
    return width, height


def section(source, line, width, classes=None, drop_classes=None, clip_polygon=None) -> Section:
    """The cross-section of ``source`` (a path, a list of paths, as ``gigapoint.open`` takes them,
    a PointCloud, or an LOD octree: opened, or its path or URL) along ``line`` = (x1, y1, x2, y2),
    in the cloud's coordinates: the points within ``width`` / 2 of the line, square to it in x and
    y, between its ends, any z (only those are read from files: ``gigapoint.open(...,
    corridor=)``; of an octree, only the nodes whose boxes meet the corridor, at every level:
    lod/query.py); ``classes``/``drop_classes``: only those LAS classes, or all but those;
    ``clip_polygon``: only the points inside it (as ``gigapoint.open``'s). Bad
    values are one-line InputErrors before anything is read; a corridor that holds no point an
    EmptyCloudError naming the files.

    ``Section.distance``, ``.offset``, ``.z``, ``.classification``: the points along the line;
    ``.render(scale=pixels per unit or size=(w, h), vertical_exaggeration=1, **settings)``: the image."""
    lane = corridor_of(line, width, f"section: line={numbers_text(line)}", f"section: width={number_text(width)}")
    keep = point_filter(classes, drop_classes, where="section", corridor=lane, clip_polygon=clip_polygon)  # (its bad values before anything is read)
    if isinstance(source, PointCloud):
        units = _units_in_lengths(source)
        kept = list(keep.apply(source.chunks(), source.name))  # (the corridor's points only)
        keep.check_passed(source.name)
        cloud = build_cloud(kept, name=source.name, colors="rgba")  # (its colours as the cloud holds them)
    elif is_octree(source):
        units = _units_in_lengths(source)
        cloud = build_cloud(kept_points(source, keep, source.name, _region(keep)), name=source.name, colors="rgba")
    else:
        paths = given_paths(source, "section", "source")  # (5 among them: "section: source[0]: ...", not gp.open's "open: paths[0]")
        if len(paths) == 1 and is_lod_source(paths[0]):
            with opened_octree(paths[0], "section the point files, or wait for the octree") as octree:
                units = _units_in_lengths(octree, shown_url(paths[0]))
                cloud = build_cloud(kept_points(octree, keep, shown_url(paths[0]), _region(keep)), name=octree.name, colors="rgba")
        else:  # only the corridor's points are read
            from .. import open_for

            with headers_once():  # (the header naming the CRS read once: here, then by open_for)
                units = files_length_units("section", expand_paths(paths, where="section"), DRAWN_ALONG)
                cloud = open_for("section", paths, classes=classes, drop_classes=drop_classes, corridor=lane, clip_polygon=keep.polygon)
    return Section(cloud, lane[:4], lane[4], units)


#: what a section needs lengths for, as its refusal of degrees says it (in degrees the image drew
#: 0.0007 degrees along the line on the heights' metre scale: 2 pixels wide, 16,384 tall)
DRAWN_ALONG = "drawing heights against distances along the line"


def _units_in_lengths(cloud, label: str | None = None) -> dict:
    """``cloud``'s units (reader.cloud_crs_units), its x and y in degrees refused (``label``
    names it, else its name) before a point is read."""
    crs, units = cloud_crs_units(cloud)
    refuse_angles("section", label or cloud.name, crs, units, DRAWN_ALONG, bounds=cloud.bounds)
    return units


def _region(keep: PointFilter) -> str:
    """What a section's filter keeps, as the error says no octree node meets it."""
    return "the corridor" if keep.polygon is None else "the corridor in the clip polygon"


__all__ = ["Section", "check_size", "section"]
