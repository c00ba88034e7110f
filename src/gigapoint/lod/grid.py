"""The integer grid of the LAS-style outputs (COPC and Potree store positions as 32-bit
integers times a scale plus an offset): the inputs' own where they have one, else a fine enough one."""

from __future__ import annotations

import numpy as np

_INT32 = (-(2**31), 2**31 - 1)


def default_step(lo, hi) -> float:
    """The grid step for points that came without one (float positions): a millimetre, finer for
    a cloud under 65.5 m across (at least 65 536 steps across it: a 10 cm object kept its shape,
    not 100 mm-steps), and never below what float64 tells apart at its coordinates (2e-15 of
    them: ~8 of its steps) or 1 nm."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    extent = float(np.max(hi - lo))
    return max(min(0.001, extent / 2**16), 2e-15 * max(1.0, float(np.abs(lo).max()), float(np.abs(hi).max())), 1e-9)


def las_grid(lo, hi, scale=None, offset=None) -> tuple[np.ndarray, np.ndarray]:
    """(scale, offset) per axis of 32-bit integers for points within [lo, hi]: the input's when
    both are given and the points fit on them; else ``scale`` (a grid the points lie on, from 0:
    the offset a multiple of it) or ``default_step``, coarser where the extent needs it, from
    the grid line at or below ``lo``."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    if scale is not None and offset is not None:
        s, o = np.asarray(scale, np.float64), np.asarray(offset, np.float64)
        if np.all(s > 0) and np.all((lo - o) / s > _INT32[0] + 1) and np.all((hi - o) / s < _INT32[1] - 1):
            return s, o
    s = np.broadcast_to(np.asarray(scale, np.float64), (3,)) if scale is not None else np.full(3, default_step(lo, hi))
    s = np.maximum(s, (hi - lo) / 2**30)
    o = np.floor(lo / s) * s
    return s, o


def output_grid(state: dict, unsigned: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``las_grid`` of a conversion's points (its state: bounds ``lo``/``hi``, the LAS inputs'
    grid ``source``, else the chunks' own ``chunk_scale``: gp.demo's, from_arrays(scale=)).
    ``unsigned`` (Potree's, whose writer keeps integers >= 0): the offset moved to the grid line
    at or below ``lo`` (a LAS offset above some points made them negative)."""
    src = state.get("source") or {}
    scale = src.get("scale")
    if scale is None and isinstance(state.get("chunk_scale"), list):
        scale = state["chunk_scale"]
    lo, hi = np.asarray(state["lo"], np.float64), np.asarray(state["hi"], np.float64)
    s, o = las_grid(lo, hi, scale, src.get("offset"))
    if unsigned:
        s = np.maximum(s, (hi - lo) / 2**30)  # counted from lo they must fit 31 bits too
        o = o + np.floor((lo - o) / s) * s
    return s, o
