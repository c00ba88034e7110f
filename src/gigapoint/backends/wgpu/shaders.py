"""Loads the WGSL passes shipped in shaders/: generated structs first, then includes expanded.

A pass file names shared code with a line ``//! include common.wgsl``; the loader inserts
that file there (once), so shared functions live in one file and are never copied.
"""

from __future__ import annotations

import re
from functools import cache
from importlib import resources

from .layout import wgsl_structs

_INCLUDE = re.compile(r"^//! include (\S+)\s*$", re.MULTILINE)

#: The passes, one file each.
PASSES = ("raster64", "raster_depth", "raster_index", "clear", "resolve")


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
    return wgsl_structs() + "\n" + _expand(_read(f"{pass_name}.wgsl"), set())
