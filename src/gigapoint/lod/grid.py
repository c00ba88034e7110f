"""The integer grid of the LAS-style outputs (COPC and Potree store positions as 32-bit
integers times a scale plus an offset): the inputs' own where they have one, else a fine enough one."""

from __future__ import annotations

import numpy as np

from ..io.las_fields import las_grid, warn_coarsened


def output_grid(state: dict, unsigned: bool = False, out=None) -> tuple[np.ndarray, np.ndarray]:
    """``las_grid`` of a conversion's points (its state: bounds ``lo``/``hi``, the LAS inputs'
    grid ``source``, else the chunks' own ``chunk_scale``: gp.demo's, from_arrays(scale=)).
    ``unsigned`` (Potree's, whose writer keeps integers >= 0): the offset moved to the grid line
    at or below ``lo`` (a LAS offset above some points made them negative). ``out``: the output, named
    where the inputs' scale must coarsen (``warn_coarsened``)."""
    src = state.get("source") or {}
    scale = src.get("scale")
    if scale is None and isinstance(state.get("chunk_scale"), list):
        scale = state["chunk_scale"]
    lo, hi = np.asarray(state["lo"], np.float64), np.asarray(state["hi"], np.float64)
    s, o = las_grid(lo, hi, scale, src.get("offset"), None if unsigned else out)
    if unsigned:
        s = np.maximum(s, (hi - lo) / 2**30)  # counted from lo they must fit 31 bits too
        o = o + np.floor((lo - o) / s) * s
        if out is not None and scale is not None:  # (said once, of both coarsenings)
            warn_coarsened(out, scale, s)
    return s, o
