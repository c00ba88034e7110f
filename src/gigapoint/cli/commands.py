"""Imports every command module so each registers on the app."""

from . import render_cmd  # noqa: F401
from . import bench_cmd  # noqa: F401
from . import info_cmd  # noqa: F401
from . import view_cmd  # noqa: F401
from . import convert_cmd  # noqa: F401
