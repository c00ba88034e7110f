"""Loads the WGSL passes shipped in shaders/: generated structs and constants first, then
includes expanded.

A pass file names shared code with a line ``//! include common.wgsl``; the loader inserts
that file there (once), so shared functions live in one file and are never copied.
"""

from __future__ import annotations

import re
from functools import cache
from importlib import resources

import numpy as np

from ...render import params
from .layout import wgsl_structs

_INCLUDE = re.compile(r"^//! include (\S+)\s*$", re.MULTILINE)

#: The passes, one file each.
PASSES = (
    "raster64", "raster_depth", "raster_index", "clear", "resolve",
    "hqs_accumulate", "hqs_resolve", "fill_holes", "log_depth", "edl", "lighting",
    "transparency_accumulate", "transparency_gather", "transparency_resolve",
)  # fmt: skip


def constants() -> dict[str, np.float32]:
    """float32 constants the shaders share with the CPU kernels (render/params.py: EDL's fast log2 / exp2)."""
    out = {"LOG2_C1": params.LOG2_C1, "LOG2_C3": params.LOG2_C3, "LOG2_C5": params.LOG2_C5, "LOG2_C7": params.LOG2_C7}
    out.update({f"EXP2_C{k + 1}": c for k, c in enumerate(params.EXP2_C)})
    out["EDL_EMPTY_RESPONSE"] = params.EDL_EMPTY_RESPONSE
    return {k: np.float32(v) for k, v in out.items()}


def integer_constants() -> dict[str, int]:
    """u32 constants the shaders share with the CPU kernels (render/params.py: transparency's)."""
    return {"TR_LAYERS": params.TR_LAYERS, "TR_COUNT_BITS": params.TR_COUNT_BITS, "TR_REVEAL_BITS": params.TR_REVEAL_BITS}


def wgsl_constants() -> str:
    """``const NAME: f32 = ...;`` lines; the decimal text is the float32 value exactly (repr of
    the float64 holding it), so the shader gets the same bits."""
    lines = ["// generated from gigapoint.render.params by gigapoint.backends.wgpu.shaders; do not edit"]
    lines += [f"const {k}: f32 = {float(v)!r};" for k, v in constants().items()]
    lines += [f"const {k}: u32 = {int(v)}u;" for k, v in integer_constants().items()]
    return "\n".join(lines) + "\n"


def _read(name: str) -> str:
    return resources.files(__package__).joinpath("shaders").joinpath(name).read_text(encoding="utf-8")


def _expand(text: str, seen: set[str]) -> str:
    def include(match: re.Match) -> str:
        name = match.group(1)
        if name in seen:
            return f"// {name}: already included\n"
        seen.add(name)
        return f"// ---- {name} ----\n" + _expand(_read(name), seen) + f"// ---- end of {name} ----\n"

    return _INCLUDE.sub(include, text)


@cache
def shader_source(pass_name: str) -> str:
    """Complete WGSL text of one pass (``raster64``, ``clear``...)."""
    if pass_name not in PASSES:
        raise KeyError(f"no shader pass {pass_name!r}; known: {', '.join(PASSES)}")
    return wgsl_structs() + "\n" + wgsl_constants() + "\n" + _expand(_read(f"{pass_name}.wgsl"), set())
