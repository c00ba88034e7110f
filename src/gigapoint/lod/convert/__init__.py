"""Out-of-core conversion of point clouds into a layered-point-cloud octree.

Phases (each resumable; the state is saved atomically in the output folder, ``OctreeDir.state_file``):

1. **read** (read.py): input chunks are validated, bounded and spilled to raw chunk files
   (spill.py; the input is decoded once: LAZ decoding is usually the bottleneck, so the next
   chunk is decoded in a thread while this one is spilled, prefetch.py).
2. **count** (partition.py): spilled points are counted into a 128³ grid of the octree cube.
3. **distribute** (partition.py): grid cells are merged into partitions (octree subtrees)
   holding at most what fits the memory limit; each spilled chunk is appended to its
   partitions' files, then deleted.
4. **build** (phases.py): per partition, a local octree is split until nodes hold ≤
   ``max_leaf`` points and sampled bottom-up (../build.py); the subtree's root points are
   carried up.
5. **group** and 6. **upper** (phases.py): the nodes above the partitions are sampled from the
   carried points, a group of partition roots at a time.
7. **write** (phases.py): node payloads are assembled into the output format (../writer.py,
   ../potree.py); the metadata file is written last, atomically, and only then is the working
   folder removed. The output therefore never looks complete before it is.

A builder's grown tree (seeded.py, a progressive octree's ``save``) replaces phases 1-3: its
leaves are the partitions, planned from their counts and built from their points in memory.
An input that fits the memory limit waits between phases 1-4 in memory, not in spill and
partition files (in_memory.py); the octree is the same.

A re-run after an interruption resumes where the state says (same inputs and options,
state.py), otherwise it starts clean. converter.py runs the phases in order (``convert``);
the output folder itself (kind, lock, clearing, state file) is ../octree_dir.py's. With a Dask
client (``convert(..., client=...)``) distributed.py runs the same phases as tasks on workers.
"""

from __future__ import annotations

# Imported on first use (PEP 562): the phases' modules define numba kernels (gigapoint/lod/__init__.py
# loads this package at once, so that ``gigapoint.lod.convert`` stays the function).
_LAZY = {
    "ConvertError": ("octree_dir", "ConvertError"),
    "OutputExistsError": ("octree_dir", "OutputExistsError"),
    "ConvertResult": ("convert.converter", "ConvertResult"),
    "_Converter": ("convert.converter", "_Converter"),
    "convert": ("convert.converter", "convert"),
    "DEFAULT_MAX_LEAF": ("convert.options", "DEFAULT_MAX_LEAF"),
    "FORMATS": ("convert.options", "FORMATS"),
    "parse_memory": ("convert.options", "parse_memory"),
    "_plan_groups": ("convert.partition", "plan_groups"),  # the names tests use
    "_plan_partitions": ("convert.partition", "plan_partitions"),
}


from ...core.hooks import lazy_names

__getattr__ = lazy_names(__name__, _LAZY, base="gigapoint.lod")  # (its names are in its modules and lod's)


__all__ = [
    "DEFAULT_MAX_LEAF",
    "FORMATS",
    "ConvertError",
    "ConvertResult",
    "OutputExistsError",
    "_Converter",
    "_plan_groups",
    "_plan_partitions",
    "convert",
    "parse_memory",
]
