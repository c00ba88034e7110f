"""Gap filling of top-down rasters (``Camera.top_down``): a surface model's NaN pixels and an
orthophoto's empty ones, as a post-pass on the finished image (the raster kernels never see it).

Heights are interpolated linearly (a TIN, as surveyors fill a DTM): scipy's Delaunay
triangulation of the drawn pixels that border an empty one (the interior of a drawn area adds
nothing to a hole but triangles), then each empty pixel takes the plane of the triangle it lies
in. A plane is kept exactly, a value never leaves the range of its triangle's corners, and
nothing outside the drawn pixels' convex hull (the data's footprint) is filled: linear
interpolation does not extrapolate. ``max_distance`` bounds it further to pixels within that
many pixels of a drawn one (gdal_fillnodata's -md): speckle closes, a building's hole in a
ground model keeps its middle. (Nearest value + smoothing was the other choice: it steps at
the Voronoi edges in the middle of a hole and does not keep a slope.)

Colours are not interpolated across a hole (that would invent imagery): ``fill_colors`` gives an
empty pixel within ``max_distance`` of a drawn one, inside the footprint, the nearest drawn colour.

``fill_everywhere`` is the fast fill for rasters that are models, not pictures (ground
classification's DEMs, survey/ground.py): every NaN cell, inside the hull or not, by pull-push (a
mip-map interpolation: the known cells averaged down a pyramid of halved rasters with their
weights, then each level's empty cells blended from the bilinearly read coarser one on the way
back up; first order: a plane kept). It is O(cells) and in numba (raster_fill_kernels.py): a
million-cell raster 40 % empty in ~0.4 s where the TIN took 12-50 s of classify's, smooth over a
large gap and exact on the known cells. It is not linear interpolation: over a curved hole it
bends near the TIN's values, not on them, and it fills outside the data's hull too, so render's
``--fill-nodata`` keeps ``fill_heights``, whose tests pin the TIN's values.
"""

from __future__ import annotations

import numpy as np

from ..errors import GigapointError, check_whole


def require_scipy(what: str = "filling empty pixels") -> None:
    """A one-line error naming the extra to install where scipy is missing."""
    try:
        import scipy.ndimage
        import scipy.spatial  # noqa: F401
    except ImportError:
        raise GigapointError(f"{what} needs scipy (pip install 'gigapoint[quality]')") from None


def check_max_distance(where: str, max_distance) -> int | None:
    """``max_distance`` (whole pixels, >= 1) or None (every hole inside the footprint); anything
    else a one-line error."""
    return None if max_distance is None else check_whole(where, "max_distance", max_distance, 1, unit=" pixels")


def _pixels(mask: np.ndarray) -> np.ndarray:
    """(row, column) of ``mask``'s true pixels as float64 points."""
    return np.argwhere(mask).astype(np.float64)


def _to_fill(valid: np.ndarray, max_distance: int | None):
    """(empty pixels to fill (K, 2) rows/columns, the Delaunay triangulation of the drawn pixels
    bordering empty ones, those pixels' mask): empty pixels inside the drawn pixels' convex hull,
    within ``max_distance`` of a drawn one if given. None where nothing can be filled."""
    from scipy import ndimage
    from scipy.spatial import Delaunay, QhullError

    empty = ~valid
    if not empty.any() or valid.sum() < 3:
        return None
    # a drawn pixel with an empty neighbour, or on the image's edge: the hull's corners are among them
    border = valid & ndimage.binary_dilation(np.pad(empty, 1, constant_values=True), np.ones((3, 3), bool))[1:-1, 1:-1]
    candidates = empty
    if max_distance is not None:
        candidates = empty & (ndimage.distance_transform_edt(empty) <= max_distance)
    targets = _pixels(candidates)
    try:
        tri = Delaunay(_pixels(border))
    except QhullError:  # the drawn pixels on one line: a footprint of no area
        return None
    # no brute-force fallback: pixels on a lattice lie on the triangles' edges, and scipy's
    # fallback searched every triangle for each (20 s against 2 ms for a 100 x 150 raster half
    # empty, the same pixels found: a scattered DTM's, a ground classification's min-z raster)
    inside = tri.find_simplex(targets, bruteforce=False) >= 0
    return targets[inside].astype(np.intp), tri, border


def fill_heights(heights: np.ndarray, max_distance: int | None = None) -> np.ndarray:
    """A copy of the (H, W) ``heights`` (a DSM/DTM: ``Camera.heights``, NaN where no point) whose
    NaN pixels inside the data's footprint (the convex hull of the non-NaN pixels) are linearly
    interpolated from the surrounding ones; ``max_distance``: only those within that many pixels
    of a non-NaN pixel. Pixels outside the footprint stay NaN. Needs scipy."""
    require_scipy("fill_heights")
    from scipy.interpolate import LinearNDInterpolator

    max_distance = check_max_distance("fill_heights", max_distance)
    heights = np.asarray(heights)
    if heights.ndim != 2:
        raise GigapointError(f"fill_heights takes an (H, W) array of heights, got shape {heights.shape}")
    filled = heights.copy()
    found = _to_fill(~np.isnan(heights), max_distance)
    if found is None:
        return filled
    targets, tri, border = found
    values = LinearNDInterpolator(tri, heights[border].astype(np.float64))(targets.astype(np.float64))
    filled[targets[:, 0], targets[:, 1]] = values
    return filled


def fill_colors(image: np.ndarray, empty: np.ndarray, max_distance: int) -> np.ndarray:
    """A copy of the (H, W, C) ``image`` whose ``empty`` pixels (``Frame.index < 0``) within
    ``max_distance`` pixels of a drawn one, inside the drawn pixels' convex hull, take the nearest
    drawn pixel's colour. Needs scipy."""
    require_scipy("fill_colors")
    from scipy import ndimage

    max_distance = check_max_distance("fill_colors", max_distance)
    if max_distance is None:  # a colour smeared across a whole building would be invented imagery
        raise GigapointError("fill_colors needs a max_distance in pixels: colours are filled only near drawn pixels")
    image, empty = np.asarray(image), np.asarray(empty, bool)
    if empty.shape != image.shape[:2]:
        raise GigapointError(f"fill_colors: empty's shape {empty.shape} is not the image's {image.shape[:2]}")
    filled = image.copy()
    found = _to_fill(~empty, max_distance)
    if found is None:
        return filled
    targets = found[0]
    _, (near_rows, near_cols) = ndimage.distance_transform_edt(empty, return_indices=True)
    rows, cols = targets[:, 0], targets[:, 1]
    filled[rows, cols] = image[near_rows[rows, cols], near_cols[rows, cols]]
    return filled


def fill_map(image: np.ndarray, empty: np.ndarray, heights: np.ndarray | None, max_distance: int | None):
    """A top-down render's orthophoto and surface model (None: none) with their empty pixels
    filled (``render --gsd --fill-nodata``, gigapoint.orthophoto): the heights within
    ``max_distance`` (None: every hole inside the footprint), the colours of ``empty`` pixels
    only within ``max_distance`` (None: not at all; colours are not invented across a hole)."""
    if max_distance is not None:
        image = fill_colors(image, empty, max_distance)
    if heights is not None:
        heights = fill_heights(heights, max_distance)
    return image, heights


def _pull_push(raster: np.ndarray, known: np.ndarray) -> np.ndarray:
    """``raster`` (float64) with its cells not ``known`` filled by pull-push; some cell known."""
    from .raster_fill_kernels import pulled, pushed  # (numba: not at import, as the CLI's --help needs none)

    levels = [(np.where(known, raster, 0.0), known.astype(np.float64))]
    while levels[-1][0].size > 1:
        levels.append(pulled(*levels[-1]))
    for (values, weights), (coarse, _) in zip(levels[-2::-1], levels[:0:-1]):
        pushed(values, weights, coarse)
    return levels[0][0]


def _known_slopes(raster: np.ndarray, known: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """(the rise per cell along ``axis``, where it is known): between the two known neighbours of
    a cell (a central difference), or one known neighbour and the cell itself."""
    ahead, behind = np.roll(raster, -1, axis), np.roll(raster, 1, axis)
    has_ahead, has_behind = np.roll(known, -1, axis), np.roll(known, 1, axis)
    edge = [slice(None)] * 2
    edge[axis] = -1
    has_ahead[tuple(edge)] = False  # (np.roll wraps around: the far edge is no neighbour)
    edge[axis] = 0
    has_behind[tuple(edge)] = False
    ahead = np.where(has_ahead, ahead, raster)
    behind = np.where(has_behind, behind, raster)
    steps = has_ahead.astype(np.float64) + has_behind
    slopes = np.where(known & (steps > 0), (ahead - behind) / np.maximum(steps, 1), 0.0)
    return slopes, known & (steps > 0)


def fill_everywhere(raster: np.ndarray) -> np.ndarray:
    """A float64 copy of the (H, W) ``raster`` with every NaN cell filled by pull-push (see the
    module's notes): known cells as they were, a gap smoothly from the cells around it. All NaN
    stays all NaN.

    First order: pull-push alone averages a gap's value from the cells around it as if they lay
    at the gap's centre, and a hole in a slope comes back sagged (2 units in a 15 x 20 hole of a
    slope 0.76 a cell). So the cells' positions and the known slopes are filled alongside, and
    each filled value is moved from where its data lay to the cell along the filled slope: a
    plane is kept exactly."""
    raster = np.asarray(raster, np.float64)
    if raster.ndim != 2:
        raise GigapointError(f"fill_everywhere takes an (H, W) raster, got shape {raster.shape}")
    known = ~np.isnan(raster)
    if known.all() or not known.any():
        return raster.copy()
    rows, cols = np.indices(raster.shape, dtype=np.float64)
    filled = _pull_push(raster, known)
    for axis, at in ((0, rows), (1, cols)):
        slopes, slope_known = _known_slopes(raster, known, axis)
        if slope_known.any():
            filled += _pull_push(slopes, slope_known) * (at - _pull_push(at, known))
    return filled
