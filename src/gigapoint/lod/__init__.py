"""Level of detail: out-of-core octree conversion, Potree 2.0 interop and LOD rendering.

octree_dir.py owns an octree folder's layout; convert/ makes one, writer.py and potree.py
write it, store.py (gigapoint), potree.py and preview.py read it, reader.py opens any kind.
copc.py and ept.py read COPC files and EPT datasets (local or over HTTP) as octrees
(voxel_octree.py), copc_write.py writes COPC.
"""

from __future__ import annotations

# Imported on first use (PEP 562): most of lod's modules define numba kernels; ``gigapoint
# info`` of a point file asks only whether it is an octree (reader.py's ``is_lod_source``).
_LAZY = {
    "ConvertError": "convert",
    "ConvertResult": "convert",
    "OutputExistsError": "convert",
    "convert": "convert",
    "parse_memory": "convert",
    "CopcCloud": "copc",
    "open_copc": "copc",
    "write_copc": "copc_write",
    "EptCloud": "ept",
    "open_ept": "ept",
    "OctreeDir": "octree_dir",
    "is_local_copc": "reader",
    "is_lod_source": "reader",
    "is_octree_dir": "reader",
    "octree_info": "reader",
    "open_octree": "reader",
    "Arena": "store",
    "OctreeCloud": "store",
}


from ..core.hooks import lazy_names

__getattr__ = lazy_names(__name__, _LAZY)


# the subpackage loaded now (cheap: its names are lazy), so that no later import of it makes
# ``gigapoint.lod.convert`` the package: it is the function (``_LAZY``), as it was
import importlib as _importlib

_importlib.import_module(f"{__name__}.convert")  # (``from . import convert`` would ask __getattr__ for the function)
del globals()["convert"]  # (the import bound the package to the name)


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
    "is_local_copc",
    "is_lod_source",
    "is_octree_dir",
    "octree_info",
    "open_copc",
    "open_ept",
    "open_octree",
    "parse_memory",
    "write_copc",
]
