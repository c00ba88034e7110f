"""Imports every command module so each registers on the app."""

from . import (
    bench_cmd,  # noqa: F401
    compile_cmd,  # noqa: F401
    convert_cmd,  # noqa: F401
    info_cmd,  # noqa: F401
    render_cmd,  # noqa: F401
    section_cmd,  # noqa: F401
    tile_cmd,  # noqa: F401
    view_cmd,  # noqa: F401
)
