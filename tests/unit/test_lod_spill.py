"""Spill files of positions as a LAS file stores them (lod/convert/spill.py): int32 X, Y, Z and the
file's scale and offset, decoded back to the float64 positions bit for bit, or float64 when they
would not be."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gigapoint.core.chunk import PointChunk
from gigapoint.lod.convert.read import spill_chunk
from gigapoint.lod.convert.spill import decode_xyz, encode_xyz, load_raw_chunk, raw_chunk_files, raw_xyz_code


def _las_positions(ints: np.ndarray, code: np.ndarray) -> np.ndarray:
    """What io/las.py's reader computes from record integers: float64(int) * scale + offset."""
    return ints.astype(np.float64) * code[:3] + code[3:]


@pytest.mark.parametrize(
    "code",
    [
        [0.001, 0.001, 0.001, 0.0, 0.0, 0.0],
        [0.01, 0.01, 0.0025, 485_000.0, 4_420_000.0, -12.5],
        [0.00025, 1e-7, 0.003, 123_456.789, -0.1, 7.0],
    ],
)
def test_positions_of_las_integers_come_back_bit_for_bit(code):
    code = np.array(code)
    rng = np.random.default_rng(3)
    ints = rng.integers(-(2**31), 2**31 - 1, (50_000, 3), dtype=np.int64).astype(np.int32)
    ints[:3] = [[-(2**31), 0, 2**31 - 1], [1, -1, 0], [0, 0, 0]]
    xyz = _las_positions(ints, code)
    enc = encode_xyz(xyz, code)
    assert enc is not None and enc.dtype == np.int32
    np.testing.assert_array_equal(enc, ints)
    dec = decode_xyz(enc, code)
    assert dec.dtype == np.float64 and dec.tobytes() == xyz.tobytes()
    out = np.empty((len(xyz) + 4, 3))
    decode_xyz(enc, code, out[2 : 2 + len(xyz)])  # into a slice of a larger array
    assert out[2 : 2 + len(xyz)].tobytes() == xyz.tobytes()


def test_positions_off_the_grid_stay_float():
    code = np.array([0.001, 0.001, 0.001, 0.0, 0.0, 0.0])
    good = _las_positions(np.arange(30, dtype=np.int32).reshape(10, 3), code)
    assert encode_xyz(good, code) is not None
    for bad in (0.0005, 1e-12, 3e6, -3e6, np.nextafter(0.001, 1.0)):  # between two integers, beyond int32, one ulp off
        xyz = good.copy()
        xyz[7, 1] = bad
        assert encode_xyz(xyz, code) is None, bad
    xyz = good.copy()
    xyz[0, 0] = -0.0  # decodes to +0.0: not the same bits
    assert encode_xyz(xyz, code) is None
    assert encode_xyz(np.empty((0, 3)), code).shape == (0, 3)


def test_a_spilled_chunk_keeps_int32_positions_and_loads_as_float(tmp_path: Path):
    code = np.array([0.01, 0.01, 0.01, 1000.0, 2000.0, 3.0])
    ints = np.arange(3000, dtype=np.int32).reshape(1000, 3)
    xyz = _las_positions(ints, code)
    rgba = np.full((1000, 4), 200, np.uint8)
    chunk = PointChunk(xyz, rgba, {"intensity": np.arange(1000, dtype=np.uint16)})
    spill_chunk(tmp_path, 4, chunk, code)
    np.testing.assert_array_equal(raw_xyz_code(tmp_path, 4), code)
    kept = load_raw_chunk(tmp_path, 4, ["intensity"], decode=False)
    assert kept["xyz"].dtype == np.int32
    np.testing.assert_array_equal(kept["xyz"], ints)
    loaded = load_raw_chunk(tmp_path, 4, ["intensity"])
    assert loaded["xyz"].dtype == np.float64 and loaded["xyz"].tobytes() == xyz.tobytes()
    assert {p.name for p in raw_chunk_files(tmp_path, 4)} >= {"c000004.xyz.npy", "c000004.xyzcode.npy"}
    # positions the code cannot give back: the chunk is spilled as float64, without a code
    xyz[5, 2] += 0.004
    spill_chunk(tmp_path, 5, PointChunk(xyz, rgba, {}), code)
    assert raw_xyz_code(tmp_path, 5) is None
    assert load_raw_chunk(tmp_path, 5, [], decode=False)["xyz"].tobytes() == xyz.tobytes()
    # without a code (the single-process converter), float64 as before
    spill_chunk(tmp_path, 6, PointChunk(_las_positions(ints, code), rgba, {}))
    assert raw_xyz_code(tmp_path, 6) is None and load_raw_chunk(tmp_path, 6, [])["xyz"].dtype == np.float64


def test_a_constant_attribute_is_spilled_as_its_value_alone(tmp_path: Path):
    """An attribute every point of a chunk holds one value of (a LAS file's flags, its user_data)
    is spilled as that value, not a point at a time, and loads as the values it was. One value
    is bit for bit: a -0.0 among 0.0 keeps the values a point at a time."""
    xyz = np.arange(3000, dtype=np.float64).reshape(1000, 3)
    rgba = np.full((1000, 4), 200, np.uint8)
    height = np.zeros(1000)
    height[7] = -0.0
    attrs = {"flags": np.zeros(1000, np.uint8), "gps": np.full(1000, 2.5), "intensity": np.arange(1000, dtype=np.uint16), "height": height}
    spill_chunk(tmp_path, 3, PointChunk(xyz, rgba, attrs))
    sizes = {p.name.split(".", 1)[1]: p.stat().st_size for p in raw_chunk_files(tmp_path, 3)}
    assert set(sizes) == {"xyz.npy", "rgba.npy", "const.flags.npy", "const.gps.npy", "attr.intensity.npy", "attr.height.npy"}
    header = sizes["const.flags.npy"] - 1  # (one uint8)
    assert sizes["const.gps.npy"] == header + 8 and sizes["attr.intensity.npy"] == header + 2000 and sizes["attr.height.npy"] == header + 8000
    loaded = load_raw_chunk(tmp_path, 3, list(attrs))
    for a, v in attrs.items():
        assert loaded["attr." + a].dtype == v.dtype and loaded["attr." + a].tobytes() == v.tobytes(), a
