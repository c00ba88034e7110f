"""Level of detail: out-of-core octree conversion, Potree 2.0 interop and LOD rendering.

octree_dir.py owns an octree folder's layout; convert/ makes one, writer.py and potree.py
write it, store.py (gigapoint), potree.py and preview.py read it, reader.py opens any kind.
"""

from .convert import ConvertError, ConvertResult, OutputExistsError, convert, parse_memory
from .octree_dir import OctreeDir
from .reader import is_octree_dir, octree_info, open_octree
from .store import Arena, OctreeCloud

__all__ = [
    "Arena",
    "ConvertError",
    "ConvertResult",
    "OctreeCloud",
    "OctreeDir",
    "OutputExistsError",
    "convert",
    "is_octree_dir",
    "octree_info",
    "open_octree",
    "parse_memory",
]
