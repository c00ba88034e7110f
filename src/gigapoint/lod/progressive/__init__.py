"""Progressive LOD: an octree built while points arrive and drawn at any moment (SimLOD)."""

from .loader import Loader, demo_sources, file_sources, memory_limit_bytes, open_progressive, open_sized
from .octree import CHUNK, MAX_LEAF, ProgressiveOctree

__all__ = ["CHUNK", "MAX_LEAF", "Loader", "ProgressiveOctree", "demo_sources", "file_sources", "memory_limit_bytes", "open_progressive", "open_sized"]
