"""io/ply.py's numba kernel (apart, so that reading a PLY header imports no numba)."""

from __future__ import annotations

from numba import njit


@njit(cache=True)
def _records_end(data, pos, count, len_bytes, len_signed, sizes, least, big_endian):
    """Where ``count`` binary records that start at ``pos`` end, or -1 where they run past the end of
    ``data`` (uint8) or a list is shorter than ``least[j]``. Property j is ``sizes[j]`` bytes, or with
    ``len_bytes[j]`` > 0 a list: a length field of that many bytes, then that many items of ``sizes[j]``
    bytes (lists make records' sizes vary)."""
    end = len(data)
    for _ in range(count):
        for j in range(len(sizes)):
            n = len_bytes[j]
            if n == 0:
                pos += sizes[j]
                continue
            if pos + n > end:
                return -1
            length = 0
            for b in range(n):
                length = (length << 8) | data[pos + (b if big_endian else n - 1 - b)]
            if (len_signed[j] and length >= 1 << (8 * n - 1)) or length < least[j]:
                return -1  # a negative length; a face of fewer than 3 corners
            pos += n + length * sizes[j]
        if pos > end:
            return -1
    return pos
