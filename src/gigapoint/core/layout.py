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
