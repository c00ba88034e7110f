"""Writing images and surface models safely: never over a user's file without overwrite, never
half-written (each file atomic; ``atomic.write_together`` for several). The CLI and the Python
map products (gigapoint.orthophoto, Change.write_geotiff) write through these, byte for byte alike."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..atomic import atomic_npy, atomic_write, folders_for, output_file_refusal, refuse
from ..errors import GigapointError, GigapointWarning, warn

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".webp", ".tif", ".tiff", ".bmp"}
NO_ALPHA_SUFFIXES = {".jpg", ".jpeg", ".bmp"}  # images written as RGB: their alpha dropped
WEBP_MAX_SIDE = 16_383  # libwebp's limit (an image may be 16 384 wide): its "encoding error" came once the render was done


def check_output(path, overwrite: bool, suffixes=IMAGE_SUFFIXES) -> Path:
    """``path`` validated as an output before any work is done (the CLI says ``overwrite=True`` as
    --overwrite: cli.PYTHON_HINTS). Folders missing on its way are not refused:
    the writers below and ``atomic.write_together`` make them just before writing."""
    path = Path(path)
    refuse(path, output_file_refusal(path, overwrite, "an output file", suffixes), GigapointError)
    return path


def check_image_fits(path, width: int, height: int) -> None:
    """A one-line error, before anything is drawn, where ``path``'s format cannot hold a
    ``width`` x ``height`` image."""
    path = Path(path)
    if path.suffix.lower() == ".webp" and max(width, height) > WEBP_MAX_SIDE:
        raise GigapointError(f"{path}: a WebP image is at most {WEBP_MAX_SIDE:,} pixels a side, this one would be {width}x{height}; write .png or .tif")


def warn_alpha_dropped(path, background_alpha: int, also_opaque=()) -> None:
    """A background less than opaque (``#rrggbbaa``: its alpha ``background_alpha``) written where
    the file holds no alpha (JPEG, BMP; ``also_opaque``: more suffixes, a video's): said once,
    naming the file (it came out opaque without a word). render and section say it alike."""
    path = Path(path)
    if background_alpha < 255 and path.suffix.lower() in NO_ALPHA_SUFFIXES | set(also_opaque):
        warn(f"{path}: a {path.suffix[1:].upper()} file holds no alpha: the background's alpha {background_alpha} is written opaque", GigapointWarning)


def save_image(image: np.ndarray, path, tiff_tags=None) -> None:
    """Write an (H, W, 4) uint8 image; formats without alpha get RGB. Atomic, its missing folders
    made. ``tiff_tags`` (a Pillow ImageFileDirectory_v2: georef.geotiff_tags) are added to a .tif's, not to others."""
    from PIL import Image

    path = Path(path)
    fmt = {".jpg": "JPEG", ".jpeg": "JPEG", ".tif": "TIFF", ".tiff": "TIFF"}.get(path.suffix.lower())
    img = Image.fromarray(image)
    if path.suffix.lower() in NO_ALPHA_SUFFIXES:
        img = img.convert("RGB")
    # PNG at zlib level 1: the default (6) took 0.3 s of a 1.8 s first render of 1 M points and its
    # files of renders (flat background) were larger, not smaller (docs/benchmarks.md, CLI first render)
    options = {"compress_level": 1} if path.suffix.lower() == ".png" else {}
    if fmt == "TIFF" and tiff_tags is not None:
        options["tiffinfo"] = tiff_tags
    with folders_for(path):
        atomic_write(path, lambda tmp: img.save(tmp, format=fmt or path.suffix[1:].upper(), **options))


def save_array(array: np.ndarray, path) -> None:
    """Write an array as .npy (depth, point index). Atomic, its missing folders made."""
    with folders_for(path):
        atomic_npy(path, array)


def save_heights(heights: np.ndarray, path, tiff_tags=None) -> None:
    """Write (H, W) heights (NaN: no point) as a float32 TIFF (Pillow's mode 'F'), with
    ``tiff_tags`` (a GeoTIFF's: georef.geotiff_tags): a surface model a GIS places. Atomic."""
    from PIL import Image

    img = Image.fromarray(np.ascontiguousarray(heights, np.float32))  # float32: mode F
    with folders_for(path):
        atomic_write(path, lambda tmp: img.save(tmp, format="TIFF", **({"tiffinfo": tiff_tags} if tiff_tags is not None else {})))
