"""What a conversion's input files say about their coordinates, for the outputs that can hold it:
the CRS (COPC's WKT VLR, Potree's ``projection``), the LAS integer grid (scale, offset) and
whether the points carry colors (COPC point format 7 or 6). Recorded once by the read phase
in the state (``state["source"]``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import GigapointWarning, warn
from ...io import file_names, warn_mixed_crs
from ...io.crs import first_crs_wkt
from ...io.las import LasReader
from ...io.registry import reader_for
from ...io.write import file_has_color


def _warn_off_grid(grids, scale, offset) -> None:
    """Warn where LAS files' points are not on the output's grid (``scale``, ``offset``): whole
    multiples of it, counted from the offset (PDAL's offset 'auto' gives each tile its own)."""

    def steps_off(v):  # how far from a whole number of output steps, per axis
        return np.abs(v / scale - np.round(v / scale))

    off = [p for p, s, o in grids if np.any(steps_off(o - offset) > 1e-3) or np.any(steps_off(s) > 1e-3)]
    if off:
        first = Path(grids[0][0]).name
        warn(
            f"{file_names(off)}: off the LAS grid the output stores every point on (scale {', '.join(f'{v:g}' for v in scale)}, "
            f"offset {', '.join(f'{v:.15g}' for v in offset)}: {first}'s): their points move to it, by up to half a step "
            f"({float(np.max(scale)) / 2:g})",
            GigapointWarning,
        )


def input_facts(paths, one_grid: bool = False, moved_to: tuple | None = None) -> dict:
    """{crs: 'EPSG:n' or WKT or None, wkt: WKT or None, scale, offset: the LAS inputs' grid (the
    finest scale; the first file's offset) or None, has_color}. Read from headers only.
    ``one_grid``: the output holds every point as integers on that grid (Potree, COPC): a file
    on another one (an offset off it by a fraction of a step) is warned about. ``moved_to``:
    (the target CRS's WKT, the moved points' LAS grid (scale, offset) or None) where the points
    are reprojected as they are read (convert's to_crs): the CRS and grid are those, and the
    inputs' own (mixed CRSs, grids apart) nothing to warn of."""
    scale = offset = None
    has_color = None
    grids = []  # (file, scale, offset) of the LAS inputs
    for p in paths or []:
        try:
            reader = reader_for(p)
        except Exception:  # noqa: BLE001 - the read phase reports unreadable inputs itself
            reader = None
        if not isinstance(reader, LasReader):  # colors where its header says so (PLY, NPY), else assumed
            try:
                colored = True if reader is None else file_has_color(p)
            except Exception:  # noqa: BLE001 - as above
                colored = True
            has_color = bool(has_color) or colored
            continue
        info = reader.info(p)
        has_color = bool(has_color) or bool(info.get("has_color"))
        s = np.abs(np.asarray(info["scale"], np.float64))  # a negative scale (a mirrored axis) was "source scale must be positive" inside
        scale = s if scale is None else np.minimum(scale, s)
        offset = np.asarray(info["offset"], np.float64) if offset is None else offset
        grids.append((p, s, np.asarray(info["offset"], np.float64)))
    if moved_to is not None:
        crs = wkt = moved_to[0]
        scale, offset = (None, None) if moved_to[1] is None else (np.asarray(v, np.float64) for v in moved_to[1])
    else:
        crs, wkt = first_crs_wkt(paths or []) or (None, None)
        warn_mixed_crs(paths or [], then="; the output takes the first CRS named")
        if one_grid and grids:
            _warn_off_grid(grids, scale, offset)
    return {
        "crs": crs,
        "wkt": wkt,
        "scale": None if scale is None else scale.tolist(),
        "offset": None if offset is None else offset.tolist(),
        "has_color": True if has_color is None else has_color,
    }
