"""Level of detail: out-of-core octree conversion, Potree 2.0 interop and LOD rendering.

octree_dir.py owns an octree folder's layout; convert/ makes one, writer.py and potree.py
write it, store.py (gigapoint), potree.py and preview.py read it, reader.py opens any kind.
copc.py and ept.py read COPC files and EPT datasets (local or over HTTP) as octrees
(voxel_octree.py), copc_write.py writes COPC.
"""

from .convert import ConvertError, ConvertResult, OutputExistsError, convert, parse_memory
from .copc import CopcCloud, open_copc
from .copc_write import write_copc
from .ept import EptCloud, open_ept
from .octree_dir import OctreeDir
from .reader import is_lod_source, is_octree_dir, octree_info, open_octree
from .store import Arena, OctreeCloud

__all__ = [
    "Arena",
    "ConvertError",
    "ConvertResult",
    "CopcCloud",
    "EptCloud",
    "OctreeCloud",
    "OctreeDir",
    "OutputExistsError",
    "convert",
    "is_lod_source",
    "is_octree_dir",
    "octree_info",
    "open_copc",
    "open_ept",
    "open_octree",
    "parse_memory",
    "write_copc",
]
