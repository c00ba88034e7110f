"""Checks of the options of the commands that draw on a ground grid (`render --gsd`, `change`):
the gsd and --fill-nodata, told in one line before anything is read."""

from __future__ import annotations

import math

from ..errors import GigapointError, number_text
from ..render.camera import MAX_GSD
from ..render.raster_fill import require_scipy

#: --all-points (`change`, `volume`): an LOD octree read whole, not down to the levels the gsd needs
ALL_POINTS_HELP = (
    "An LOD octree's every node read, not only its levels down to points a quarter of a pixel apart "
    "(those give each pixel the highest of a sample of its points: on a roof's edge or a tree's crown up to that spacing lower)."
)

#: --all-points/--levels-only (`volume`): every node by default (volumes are paid by the cubic metre)
VOLUME_POINTS_HELP = (
    "An LOD octree's every node near the piles read (the default), or with --levels-only its levels down to points a quarter "
    "of a pixel apart: faster, and each pixel the highest of a sample, so a pile's volume comes out a little low."
)


def check_gsd_value(gsd: float) -> None:
    """A one-line error for a --gsd that is no size."""
    if not (math.isfinite(gsd) and 0 < gsd <= MAX_GSD):
        raise GigapointError(f"--gsd must be a number > 0 and at most {MAX_GSD:g} (cloud units per pixel), got {number_text(gsd)}")


def check_fill_nodata(text: str | None, gsd, depth_out) -> int | None:
    """--fill-nodata's pixels (None: 'all', every hole inside the footprint), checked before
    anything is read: a one-line error for a value that is neither, for a use without --gsd, and
    for 'all' without --depth-out (the orthophoto's colours are filled only within N pixels)."""
    if text is None:
        return None
    if gsd is None:
        raise GigapointError("--fill-nodata: an option of --gsd (it fills the orthophoto and the surface model of a top-down render)")
    distance = None if text.strip().lower() == "all" else int(text) if text.strip().isdigit() else 0
    if distance == 0:
        raise GigapointError(f"--fill-nodata must be 'all' or a whole number of pixels >= 1, got {text!r}")
    if distance is None and depth_out is None:
        raise GigapointError("--fill-nodata all fills the surface model: give --depth-out too (the orthophoto is filled only within N pixels: --fill-nodata N)")
    require_scipy("--fill-nodata")
    return distance
