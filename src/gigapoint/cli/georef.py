"""What `gigapoint render --gsd` writes beside its image and its surface model so that a GIS
places them on its map: an ESRI world file (the pixel grid) and a .prj (the cloud's CRS as WKT)."""

from __future__ import annotations

from pathlib import Path

from ..atomic import atomic_bytes
from ..render import Camera

# ESRI's names: the image suffix's first and last letters and a 'w'; .wld, which GDAL and QGIS
# read beside any image, for the others
WORLD_FILE_SUFFIXES = {".png": ".pgw", ".jpg": ".jgw", ".jpeg": ".jgw", ".tif": ".tfw", ".tiff": ".tfw"}


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
