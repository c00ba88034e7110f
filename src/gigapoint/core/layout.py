"""Binary layouts shared by every backend, defined once as numpy dtypes.

The wgpu backend derives its WGSL structs from these; never re-type them by hand.
"""

from __future__ import annotations

import numpy as np

#: Points per batch (the 2022 paper: 128 threads x 80 points).
BATCH_SIZE = 10_240

#: Bits per axis of a batch-relative fixed-point coordinate, and per precision word.
COORD_BITS = 30
WORD_BITS = 10
WORD_MASK = (1 << WORD_BITS) - 1

#: One record per batch (or LOD node): which consecutive points it holds and their box.
BATCH_DTYPE = np.dtype(
    [
        ("first", "<u8"),  # index of the first point in the point buffers
        ("count", "<u4"),  # number of points
        ("level", "<i4"),  # LOD level (0 for unstructured clouds)
        ("bbox_min", "<f8", (3,)),
        ("bbox_max", "<f8", (3,)),
    ]
)

#: Visibility buffer: float32 depth bits << 32 | point index; all ones = empty.
EMPTY_PIXEL = np.uint64(0xFFFFFFFFFFFFFFFF)

#: Precisions a batch can be drawn with (bits per axis).
PRECISIONS = (10, 20, 30)

#: The 2022 paper's rule: a batch spanning fewer pixels than half a 10-bit grid uses 10 bits.
PRECISION_THRESHOLD_PX = 500.0

#: The compact layout (core/compact.py): one record per batch beside BATCH_DTYPE. ``ext_first`` is
#: the first u64 word of the batch's extension bit stream; ``code`` = e_x | e_y << 8 | e_z << 16,
#: the bits per axis a point holds there (0..19: a grid-aligned batch of 10 + e bits an axis;
#: 20 on every axis: a wide batch, today's medium and high words).
PACK_DTYPE = np.dtype([("ext_first", "<u8"), ("code", "<u4"), ("_pad", "<u4")])

#: Fewest bits an axis of a compact batch has (its box is 2^bits source steps): the low word's.
COMPACT_MIN_BITS = 10

#: Extension bits an axis of a wide batch holds (medium and high words: 2 x 10).
EXT_FULL_BITS = 20

#: how a PointCloud holds its colours (``build_cloud``'s ``colors``; here, numba-free: the CLI's options check them)
COLOR_FORMATS = ("auto", "rgba", "rgb565", "palette")
