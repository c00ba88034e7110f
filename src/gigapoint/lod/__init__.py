"""Level of detail: out-of-core octree conversion, Potree 2.0 interop and LOD rendering."""

from .convert import ConvertError, ConvertResult, OutputExistsError, convert, parse_memory
from .store import Arena, OctreeCloud, is_octree_dir, open_octree

__all__ = [
    "Arena",
    "ConvertError",
    "ConvertResult",
    "OctreeCloud",
    "OutputExistsError",
    "convert",
    "is_octree_dir",
    "open_octree",
    "parse_memory",
]
