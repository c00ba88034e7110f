"""What a map product (`gigapoint render --gsd`, `gigapoint change`, gigapoint.orthophoto,
Change.write_geotiff) writes beside its image and its surface model so that a GIS places them on
its map: an ESRI world file (the pixel grid) and a .prj (the cloud's CRS as WKT); a .tif or .tiff
is a GeoTIFF besides, the same grid and CRS in its own tags (``geotiff_tags``). ``map_writes``
gives all of a product's files; ``write_map`` writes them, all or none, for the Python API."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..atomic import atomic_bytes, refuse_named_twice, write_failure, write_together
from ..errors import GigapointError, GigapointWarning, warn
from ..io import EPSG_LENGTH_UNITS, crs_wkt, horizontal_epsg, vertical_crs
from ..io.crs import angular_across
from .camera import Camera
from .image_files import IMAGE_SUFFIXES, check_image_fits, check_output, save_heights, save_image

# ESRI's names: the image suffix's first and last letters and a 'w'; .wld, which GDAL and QGIS
# read beside any image, for the others
WORLD_FILE_SUFFIXES = {".png": ".pgw", ".jpg": ".jgw", ".jpeg": ".jgw", ".tif": ".tfw", ".tiff": ".tfw"}


def map_image(image: np.ndarray, empty: np.ndarray) -> np.ndarray:
    """A top-down render's (H, W, 4) image as a map holds it: pixels no point reached (``empty``,
    ``Frame.index < 0``) transparent, alpha 0, their colour the background's. An opaque
    background read as imagery (GIS software, ``--colorize`` from it) coloured points black."""
    image = image.copy()
    image[np.asarray(empty, bool), 3] = 0
    return image


def world_file_path(image: Path) -> Path:
    """The world file beside ``image`` (ortho.png -> ortho.pgw)."""
    return image.with_suffix(WORLD_FILE_SUFFIXES.get(image.suffix.lower(), ".wld"))


def georef_paths(images) -> list[Path]:
    """The world files and .prj files beside ``images`` (None: not written), each once: ortho.png
    and ortho.tif share ortho.prj, which holds the one CRS both are in."""
    paths: list[Path] = []
    for image in filter(None, images):
        for side in (world_file_path(Path(image)), Path(image).with_suffix(".prj")):
            if all(side.resolve() != p.resolve() for p in paths):
                paths.append(side)
    return paths


def world_file_text(camera: Camera) -> str:
    """The six lines of ``camera``'s world file (Camera.world_file), to 15 significant digits:
    float64's rounding noise (0.49999999999999994) left out."""
    return "".join(f"{v:.15g}\n" for v in camera.world_file())


def write_world_file(camera: Camera, path: Path) -> None:
    """``camera``'s world file as ``path`` (world_file_path of its image), atomically."""
    atomic_bytes(path, world_file_text(camera).encode())


def write_prj(wkt: str, path: Path) -> None:
    """``wkt`` as the .prj ``path``, atomically."""
    atomic_bytes(path, wkt.encode())


def no_prj_reason(crs: str | None) -> str:
    """Why no .prj is written: the inputs name no CRS, or only an EPSG code whose WKT needs pyproj."""
    if crs is None:
        return "no .prj written: the inputs name no CRS"
    return f"no .prj written: the inputs name their CRS only as {crs}, and its WKT needs pyproj (pip install pyproj)"


def georef_writes(camera: Camera, images, crs: str | None, wkt: str | None, units: dict) -> tuple[list, list[str]]:
    """What georeferences ``images`` (None: not written) drawn through ``camera``: the (path,
    save) writes of their world files and .prj files (``georef_paths``; no .prj without a WKT),
    and the notes to print (why no .prj, a GeoTIFF whose keys name no CRS)."""
    images = [Path(image) for image in images if image is not None]
    writes = [(world_file_path(image), lambda p: write_world_file(camera, p)) for image in images]
    notes = [] if wkt else [no_prj_reason(crs)]
    if wkt:
        writes += [(p, lambda p: write_prj(wkt, p)) for p in georef_paths(images) if p.suffix == ".prj"]
    return writes, notes + geotiff_notes(images, crs, wkt, units)


GEOTIFF_SUFFIXES = {".tif", ".tiff"}
#: GeoTIFF's TIFF tags and their TIFF types (3 SHORT, 12 DOUBLE, 2 ASCII); GDAL_NODATA is GDAL's
MODEL_PIXEL_SCALE, MODEL_TIEPOINT, GEO_KEY_DIRECTORY, GEO_DOUBLE_PARAMS, GEO_ASCII_PARAMS, GDAL_NODATA = 33550, 33922, 34735, 34736, 34737, 42113
TAG_TYPES = {MODEL_PIXEL_SCALE: 12, MODEL_TIEPOINT: 12, GEO_KEY_DIRECTORY: 3, GEO_DOUBLE_PARAMS: 12, GEO_ASCII_PARAMS: 2, GDAL_NODATA: 2}
#: GeoKeys written (GeoTIFF 1.0 names), and their values
MODEL_TYPE, RASTER_TYPE, GEOGRAPHIC_TYPE, PROJECTED_CS_TYPE, PCS_CITATION, LINEAR_UNITS, LINEAR_UNIT_SIZE = 1024, 1025, 2048, 3072, 3073, 3076, 3077
PROJECTED, GEOGRAPHIC, USER_DEFINED, PIXEL_IS_AREA = 1, 2, 32767, 1
#: GeoTIFF 1.1's keys of a vertical CRS (VerticalGeoKey: its EPSG code), which a file holding them
#: says it follows by its key directory's minor revision 1 (as GDAL writes it)
VERTICAL, VERTICAL_CITATION, VERTICAL_UNITS = 4096, 4097, 4099
#: GDAL reads a user-defined CRS's WKT from PCSCitationGeoKey after this prefix (ArcGIS's), into a
#: buffer of 2 400 characters: a longer one would be cut, so it is not written there
ESRI_PE_PREFIX, GDAL_CITATION_MAX = "ESRI PE String = ", 2399


def geotiff_tags(camera: Camera, crs: str | None, wkt: str | None, units: dict, nodata: bool = False):
    """The GeoTIFF tags (a Pillow ImageFileDirectory_v2, for ``save(tiffinfo=)``) of ``camera``'s
    image (``Camera.top_down``): its grid, and where ``crs`` is known (lod.reader.cloud_crs,
    ``units`` its cloud_units) its GeoKeys (``geo_keys``); ``nodata``: NaN marks empty pixels (a DSM)."""
    from PIL.TiffImagePlugin import ImageFileDirectory_v2

    size, _, _, minus_size, x, y = camera.world_file()
    # the world file names the centre of pixel (0, 0); the tiepoint, with RasterPixelIsArea, its
    # upper-left corner: half a pixel left and up
    values = {MODEL_PIXEL_SCALE: (size, -minus_size, 0.0), MODEL_TIEPOINT: (0.0, 0.0, 0.0, x - size / 2, y - minus_size / 2, 0.0)}
    keys, doubles, text = geo_keys(crs, wkt, units), [], ""
    if keys:
        revision = 1 if VERTICAL in keys else 0
        directory = [1, 1, revision, len(keys)]  # KeyDirectoryVersion, KeyRevision 1.0 or 1.1, then the keys by id
        for key, value in sorted(keys.items()):
            if isinstance(value, float):
                directory += [key, GEO_DOUBLE_PARAMS, 1, len(doubles)]
                doubles.append(value)
            elif isinstance(value, str):  # ASCII params end with '|'
                directory += [key, GEO_ASCII_PARAMS, len(value) + 1, len(text)]
                text += value + "|"
            else:
                directory += [key, 0, 1, value]
        values[GEO_KEY_DIRECTORY] = tuple(directory)
    if doubles:
        values[GEO_DOUBLE_PARAMS] = tuple(doubles)
    if text:
        values[GEO_ASCII_PARAMS] = text
    if nodata:
        values[GDAL_NODATA] = "nan"
    tags = ImageFileDirectory_v2()
    for tag, value in values.items():
        tags[tag] = value
        tags.tagtype[tag] = TAG_TYPES[tag]
    return tags


def geo_keys(crs: str | None, wkt: str | None, units: dict) -> dict:
    """The GeoKeys ({key: value}) naming ``crs``: its horizontal part's (``horizontal_keys``) and,
    where it has one, its vertical part's (``vertical_keys``: a DSM's heights' datum and unit); {}
    where the horizontal part cannot be named (no CRS, a WKT that GDAL would cut)."""
    keys = horizontal_keys(crs, wkt, units)
    return {**keys, **vertical_keys(crs, units)} if keys else {}


def horizontal_keys(crs: str | None, wkt: str | None, units: dict) -> dict:
    """The GeoKeys of ``crs``'s map grid: its horizontal part's EPSG code (io.horizontal_epsg) and
    linear unit, else its ``wkt`` as an ESRI PE string, which GDAL reads; {} without a CRS, or
    with a WKT that GDAL would cut."""
    horizontal = units.get("horizontal")
    code = horizontal_epsg(crs)
    if code is not None and angular_across(units) is not None:  # an angle: geographic
        return {MODEL_TYPE: GEOGRAPHIC, RASTER_TYPE: PIXEL_IS_AREA, GEOGRAPHIC_TYPE: code}
    if code is not None:  # (an 'EPSG:n' whose units are unknown, pyproj missing, is taken to be projected)
        return {MODEL_TYPE: PROJECTED, RASTER_TYPE: PIXEL_IS_AREA, PROJECTED_CS_TYPE: code, **linear_unit_keys(horizontal)}
    if wkt and len(ESRI_PE_PREFIX + wkt) <= GDAL_CITATION_MAX:
        # GDAL reads the citation only where the model type is user-defined (neither projected nor geographic)
        return {MODEL_TYPE: USER_DEFINED, RASTER_TYPE: PIXEL_IS_AREA, PCS_CITATION: ESRI_PE_PREFIX + wkt, **linear_unit_keys(horizontal)}
    return {}


def vertical_keys(crs: str | None, units: dict) -> dict:
    """GeoTIFF 1.1's keys of ``crs``'s vertical part (io.vertical_crs: NAVD88 height of
    EPSG:26910+5703), so that a GIS knows what a DSM's heights are measured from and in: its EPSG
    code, else user-defined with its name as citation; its unit's EPSG code (GeoTIFF has no key
    for another's size), the one ``units`` (io.crs_units) name where they name one (a LAS file's
    VerticalUnitsGeoKey: its own word), else the vertical CRS's. A projected CRS without a vertical
    part whose heights' unit is named all the same (VerticalUnitsGeoKey beside a user-defined
    VerticalCSTypeGeoKey) has a user-defined one in that unit; {} where neither is named."""
    vertical = vertical_crs(crs)
    named_unit = None if units.get("vertical_assumed", True) else units.get("vertical")
    if vertical is None:  # (a 3D geographic CRS's ellipsoidal heights are its own: no vertical CRS)
        horizontal = units.get("horizontal")
        code = length_unit_code(named_unit) if horizontal is not None and horizontal["metres"] is not None else None
        return {VERTICAL: USER_DEFINED, VERTICAL_UNITS: code} if code else {}
    keys = {VERTICAL: vertical["epsg"]} if vertical["epsg"] else {VERTICAL: USER_DEFINED, VERTICAL_CITATION: vertical["name"]}
    unit = length_unit_code(named_unit or vertical["unit"])
    return {**keys, VERTICAL_UNITS: unit} if unit else keys


def linear_unit_keys(unit: dict | None) -> dict:
    """ProjLinearUnitsGeoKey of a length unit (io.crs_units'): its EPSG code, else user-defined
    with its size in metres; {} where it is unknown or an angle."""
    if unit is None or unit["metres"] is None:
        return {}
    code = length_unit_code(unit)
    return {LINEAR_UNITS: code} if code else {LINEAR_UNITS: USER_DEFINED, LINEAR_UNIT_SIZE: float(unit["metres"])}


def length_unit_code(unit: dict | None) -> int | None:
    """The EPSG code of a length unit (io.crs_units'; io.EPSG_LENGTH_UNITS: metre, foot, US survey
    foot) by its size; None for another, an unknown one or an angle."""
    if unit is None or unit["metres"] is None:
        return None
    return next((c for c, (_, metres) in EPSG_LENGTH_UNITS.items() if math.isclose(metres, unit["metres"], rel_tol=1e-9)), None)


def geotiff_notes(images, crs: str | None, wkt: str | None, units: dict) -> list[str]:
    """Which of ``images`` (None: not written) are GeoTIFFs whose keys name no CRS although the
    cloud has one (a WKT too long for them; their .prj has it): a line each."""
    if not crs or horizontal_keys(crs, wkt, units):
        return []
    tiffs = [image for image in filter(None, images) if Path(image).suffix.lower() in GEOTIFF_SUFFIXES]
    return [f"{image}: its GeoTIFF keys name no CRS (its WKT is longer than GDAL reads from them); the .prj beside it has it" for image in tiffs]


def raster_writes(camera: Camera, crs: str | None, wkt: str | None, units: dict, rasters) -> list:
    """The (path, save) writes of ``rasters``, (path, array) pairs drawn through ``camera`` (path
    None: not written): an (H, W) array is a surface model (float32 heights, NaN where empty),
    an (H, W, 4) one an image; a .tif of either a GeoTIFF (``geotiff_tags``)."""
    writes = []
    for path, array in rasters:
        if path is None:
            continue
        if np.ndim(array) == 2:
            writes.append((Path(path), lambda p, a=array: save_heights(a, p, geotiff_tags(camera, crs, wkt, units, nodata=True))))
        else:
            writes.append((Path(path), lambda p, a=array: save_image(a, p, geotiff_tags(camera, crs, wkt, units))))
    return writes


def write_map(camera: Camera, crs: str | None, units: dict, rasters, overwrite: bool = False) -> list[Path]:
    """``rasters`` ((path, array) pairs: ``raster_writes``) written with their world files and
    .prj files, all or none (atomic.write_together), as the CLI writes them; returns the paths
    written. Each is checked first: its type (a surface model is a .tif), an existing file
    refused without ``overwrite``. A .prj that holds this very CRS already (an earlier product of
    the same map beside it: change.tif, then change.png) is kept; with no CRS to write, one
    there is removed with ``overwrite`` (``write_map_files``). Why no .prj is written, a GeoTIFF
    names no CRS, or a .prj was removed, is a GigapointWarning. (The CLI checked the paths before
    reading the survey; checked again here, a few stats, for the Python callers.)"""
    rasters = [(Path(path), array) for path, array in rasters if path is not None]
    wkt = crs_wkt(crs)
    for path, array in rasters:
        check_output(path, overwrite, GEOTIFF_SUFFIXES if np.ndim(array) == 2 else IMAGE_SUFFIXES)
        check_image_fits(path, camera.width, camera.height)
    images = [path for path, _ in rasters]
    check_world_files_apart(images)
    side_writes, notes, stale = checked_side_writes(camera, images, crs, wkt, units, overwrite)
    written = write_map_files([(path, _said(path, save)) for path, save in raster_writes(camera, crs, wkt, units, rasters) + side_writes], stale)
    for note in notes:
        warn(note, GigapointWarning)
    return written


def _said(path: Path, save):
    """``save``, its OSError (a full disk, a folder not writable after all: PIL's and rasterio's
    "[Errno 13] Permission denied" came raw through gp.orthophoto) a one-line GigapointError naming ``path``."""

    def save_or_say(target):
        try:
            save(target)
        except OSError as exc:
            raise GigapointError(f"{path}: not written ({write_failure(exc)}); none of the map's files was left") from None

    return save_or_say


def check_world_files_apart(images) -> None:
    """A one-line error where two of ``images`` (None: not written) are one file, or their world
    files are (ortho.tif and ortho.tiff: one ortho.tfw, the second written over the first)."""
    images = [Path(image) for image in images if image is not None]
    refuse_named_twice(images + [world_file_path(image) for image in images], GigapointError)  # (each .prj once: georef_paths)


def check_side_outputs(images, overwrite: bool) -> list[Path]:
    """Before the cloud is read: ``images`` (None: not written) apart with their world files
    (``check_world_files_apart``), and the world files and .prj files beside them
    (``georef_paths``), each refused like the image where it exists without ``overwrite``, but
    an existing .prj: it may hold this very CRS (``checked_side_writes`` judges it once the CRS
    is known). Returns them."""
    check_world_files_apart(images)
    paths = georef_paths(images)
    for side in paths:
        if side.suffix != ".prj" or not side.exists():
            check_output(side, overwrite, suffixes=None)
    return paths


def checked_side_writes(camera: Camera, images, crs: str | None, wkt: str | None, units: dict, overwrite: bool) -> tuple[list, list[str], list[Path]]:
    """Once the CRS is known: ``georef_writes`` of ``images`` less a .prj that holds ``wkt``
    already (``unheld_side_writes``), each path they write, and with no WKT a .prj beside
    ``images`` (``stale_side_files``), refused where it exists without ``overwrite``: a user's world
    file or .prj is not replaced without asking. Returns the writes, the notes (to say once the
    map is written: a stale .prj's removal among them), and those stale .prj files, which
    ``write_map_files`` removes once the map is written."""
    side_writes, notes = georef_writes(camera, images, crs, wkt, units)
    left = _left_beside(images, [path for path, _ in side_writes])
    for prj in _prjs_of_other_maps(left, images):  # neither removed (that map's) nor left (said of this one)
        raise GigapointError(f"{prj}: holds the CRS of the map beside it ({_other_world_files(prj, images)[0].name}), which these inputs do not name: write this map under another name")
    stale = left  # (stale_side_files': none is another map's, refused above)
    side_writes = unheld_side_writes(side_writes, wkt)
    for path in [path for path, _ in side_writes] + stale:
        check_output(path, overwrite, suffixes=None)
    return side_writes, notes + stale_notes(stale), stale


def unheld_side_writes(side_writes, wkt: str | None) -> list:
    """``side_writes`` (georef_writes') less a .prj that holds ``wkt`` already: an earlier product
    of the same map beside it (change.tif, then change.png) keeps it, neither refused nor rewritten."""
    return [(path, save) for path, save in side_writes if not _holds(path, wkt)]


def stale_side_files(images, written) -> list[Path]:
    """Each existing world file and .prj beside ``images`` (``georef_paths``) that is not among
    the ``written`` ones: an earlier map's (its .prj where this one names no CRS, both where
    this image is no map: render without --gsd), left describing this one. A .prj another map
    of the stem still uses (ortho.tif's ortho.tfw beside it) is not one: it is that map's."""
    left = _left_beside(images, written)
    kept = _prjs_of_other_maps(left, images)
    return [path for path in left if path not in kept]


def check_plain_image(image, overwrite: bool) -> list[Path]:
    """Before anything is drawn: the world file and .prj an earlier map left beside ``image``, an
    image drawn as no map (render without --gsd; ``stale_side_files``), which would place it on
    that map's grid. Refused without ``overwrite`` (nothing is removed without asking), else
    returned: ``write_map_files`` removes them once the image is written, whether it replaces the
    map's image or that was removed before. A .prj with no world file beside it is left alone."""
    stale = stale_side_files([image], written=[])
    if all(path.suffix == ".prj" for path in stale):  # a .prj alone places nothing (and may be a shapefile's)
        return []
    if not overwrite:
        them = "it" if len(stale) == 1 else "them"
        raise GigapointError(
            f"{', '.join(map(str, stale))}: an earlier map's georeferencing, which would place {Path(image).name} (no map: no --gsd) on its grid; "
            f"remove {them}, or pass overwrite=True to remove {them} once the image is written"
        )
    return stale


def _other_world_files(prj: Path, images) -> list[Path]:
    """The world files beside ``prj`` (any image type's of its stem) but those of ``images``:
    another map's, which shares the .prj (ortho.tif's ortho.tfw beside ortho.png's)."""
    ours = {world_file_path(Path(image)).resolve() for image in filter(None, images)}
    sides = sorted({*WORLD_FILE_SUFFIXES.values(), ".wld"})
    return [w for w in (prj.with_suffix(s) for s in sides) if w.exists() and w.resolve() not in ours]


def _left_beside(images, written) -> list[Path]:
    """The existing world files and .prj files beside ``images`` (``georef_paths``) not among ``written``."""
    written = {Path(path).resolve() for path in written}
    return [path for path in georef_paths(images) if path.exists() and path.resolve() not in written]


def _prjs_of_other_maps(left, images) -> list[Path]:
    """The .prj files among ``left`` (``_left_beside``) that another map of the stem uses
    (``_other_world_files``)."""
    return [path for path in left if path.suffix == ".prj" and _other_world_files(path, images)]


def stale_notes(stale, map_drawn: bool = True) -> list[str]:
    """What is said of ``stale`` (``stale_side_files``) removed: beside a map, a line for each
    .prj of a CRS its inputs do not name; beside an image drawn as no map (render without
    --gsd), one line for its world file and .prj."""
    if map_drawn:
        return [f"removed {path}: an earlier map's CRS, which these inputs do not name" for path in stale]
    return [f"removed {', '.join(map(str, stale))}: an earlier map's georeferencing; this image is no map (no --gsd)"] if stale else []


def write_map_files(writes, stale) -> list[Path]:
    """A map's ``writes`` (its rasters' and ``checked_side_writes``' (path, save) pairs) written
    all or none (atomic.write_together), then the ``stale`` files (``stale_side_files``) removed: an
    earlier map's CRS left beside a map that names none, its world file beside a plain image. Returns the paths written."""
    written = write_together(writes)
    for path in stale:
        path.unlink(missing_ok=True)
    return written


def _holds(path: Path, wkt: str | None) -> bool:
    """Whether ``path`` is a .prj holding ``wkt`` already."""
    return bool(wkt) and path.suffix == ".prj" and path.is_file() and path.read_bytes() == wkt.encode()
