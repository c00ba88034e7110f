"""The conversion's options and the sizes derived from the memory limit."""

from __future__ import annotations

import numpy as np

from ..octree_dir import ConvertError

BYTES_PER_POINT_BUILD = 220  # peak working set per point of a partition build
# Partitions above this gain nothing (every kernel is already parallel inside one) and lose a lot:
# 20 M points on the 2-core project machine convert at 1.2 M points/s as one partition, 2.5 M
# points/s in 4 M-point ones (page faults on a larger working set, cache misses in the sort).
MAX_PARTITION_POINTS = 4_000_000
# What a converting process holds besides the conversion: Python, numpy, numba, gigapoint (121 MB
# measured at the plan in `gigapoint convert`, 145 MB in a `--workers` driver, Dask loaded) and a
# margin. A constant, not the process's measured size: the plan (``partition_points``) must be
# the same wherever and whenever it is made, or the octree is not (one process against a Dask
# driver, whose size says nothing of its workers').
RUNTIME_BYTES = 192 << 20
MIN_DEFAULT_MEMORY = 256 << 20  # the default memory limit on the smallest machines
MIN_MEMORY_LIMIT = 64 << 20  # the least a conversion may be given
DEFAULT_MAX_LEAF = 20_000
FORMATS = ("gigapoint", "potree", "copc")
ENCODINGS = ("DEFAULT", "BROTLI")  # Potree's


def task_share(memory: int, tasks: int, least: int) -> int:
    """A task's memory limit where ``tasks`` tasks at once draw on ``memory``: half of it among
    them, at most a quarter each (one task: a quarter, as one process plans); ``least`` at least."""
    return max(least, min(memory // 4, memory // (2 * tasks)))


def parse_memory(value, option: str = "--memory-limit", minimum: int = MIN_MEMORY_LIMIT) -> int:
    """'4G', '512M', '2GiB', '1.5g' or a byte count -> bytes; None -> a quarter of the RAM.
    ``option``: the setting errors name; ``minimum``: the fewest bytes it may be (a conversion's 64M)."""
    if value is None:
        from ...core.chunked import physical_memory

        return task_share(physical_memory(), 1, MIN_DEFAULT_MEMORY)
    if isinstance(value, (int, np.integer)):
        n = int(value)
    else:
        s = str(value).strip().lower().removesuffix("b").removesuffix("i")
        mult = {"k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}.get(s[-1:], 1)
        try:
            n = int(float(s[:-1] if s[-1:] in "kmgt" else s) * mult)
        except (ValueError, OverflowError):  # 'abc', 'nanG'; 'infG' (an internal error before)
            raise ConvertError(f"{option}: cannot read {value!r} (use e.g. 4G, 512M)") from None
    if n < minimum:
        raise ConvertError(f"{option}: {value!r} is below the {minimum >> 20}M minimum")
    return n
