"""What a conversion's input files say about their coordinates, for the outputs that can hold it:
the CRS (COPC's WKT VLR, Potree's ``projection``), the LAS integer grid (scale, offset) and
whether the points carry colors (COPC point format 7 or 6). Recorded once by the read phase
in the state (``state["source"]``)."""

from __future__ import annotations

import numpy as np

from ...errors import GigapointWarning, warn
from ...io.las import LasReader, read_las_header
from ...io.registry import reader_for
from ..copc import wkt_of


def _wkt_of(text: str | None) -> str | None:
    """WKT of the LAS reader's CRS: an 'EPSG:n' through pyproj when it is installed (else None);
    any other is WKT already (one found in an EVLR, where copc-lib writes it)."""
    if not text or not text.upper().startswith("EPSG:"):
        return text or None
    try:
        import pyproj

        return pyproj.CRS.from_user_input(text).to_wkt()
    except Exception:  # noqa: BLE001 - pyproj missing or the code unknown: no WKT
        return None


def input_facts(paths) -> dict:
    """{crs: 'EPSG:n' or WKT or None, wkt: WKT or None, scale, offset: the LAS inputs' grid (the
    finest scale; the first file's offset) or None, has_color}. Read from headers only."""
    crs = wkt = scale = offset = None
    has_color = None
    crs_seen = set()
    for p in paths or []:
        try:
            reader = reader_for(p)
        except Exception:  # noqa: BLE001 - the read phase reports unreadable inputs itself
            reader = None
        if not isinstance(reader, LasReader):  # colors where its header says so (PLY, NPY), else assumed
            try:
                colored = True if reader is None else reader.header(p).get("has_color", True)
            except Exception:  # noqa: BLE001 - as above
                colored = True
            has_color = bool(has_color) or colored
            continue
        info = reader.info(p)
        has_color = bool(has_color) or bool(info.get("has_color"))
        s = np.abs(np.asarray(info["scale"], np.float64))  # a negative scale (a mirrored axis) was "source scale must be positive" inside
        scale = s if scale is None else np.minimum(scale, s)
        offset = np.asarray(info["offset"], np.float64) if offset is None else offset
        text = info.get("crs")
        if text:
            crs_seen.add(text)
            if crs is None:
                crs = text
                wkt = wkt_of(read_las_header(p).vlrs) or _wkt_of(text)  # the header's VLRs: the first CRS's file only
    if len(crs_seen) > 1:
        warn(
            f"the inputs have {len(crs_seen)} different CRSs; the output takes the first ({crs[:60]})", GigapointWarning
        )
    return {
        "crs": crs,
        "wkt": wkt,
        "scale": None if scale is None else scale.tolist(),
        "offset": None if offset is None else offset.tolist(),
        "has_color": True if has_color is None else has_color,
    }
