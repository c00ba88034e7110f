"""Attributes held in their real range (core/attributes.py, issue #22): every point reads back
exactly, in its own dtype, through ``cloud.attributes``, ``point_info``, attribute colouring and
the chunked build; the bytes reported are the packed ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.core import PointChunk, build_cloud
from gigapoint.core.attributes import Attributes, Packed, encode, fits, holder_for, pack, repacked, resized, stored, widened
from gigapoint.core.chunked import build_cloud_chunked

AUTZEN = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"
UTM = np.array([636_000.0, 5_012_000.0, 120.0])


def edge_attributes(rng, n) -> dict[str, np.ndarray]:
    """Constant, full u16 range, negative ranges, wide ranges, floats exact and not in float32."""
    full16 = rng.integers(0, 65536, n).astype(np.uint16)
    full16[:2] = [0, 65535]
    return {
        "constant": np.full(n, 7326, np.uint16),
        "zero": np.zeros(n, np.int32),
        "full_u16": full16,
        "intensity": rng.integers(1200, 1400, n).astype(np.uint16),  # 200 values: u8 + 1200
        "negative": rng.integers(-300, -100, n).astype(np.int16),  # u8 - 300
        "negative32": rng.integers(-70_000, -10_000, n).astype(np.int32),  # u16 - 70 000
        "signed8": rng.integers(-128, 128, n).astype(np.int8),  # already narrowest
        "i64_near_max": (np.iinfo(np.int64).max - rng.integers(0, 1000, n)).astype(np.int64),
        "i64_span": np.where(rng.random(n) < 0.5, np.iinfo(np.int64).min, np.iinfo(np.int64).max).astype(np.int64),
        "u64_high": (np.uint64(2**63) + rng.integers(0, 70_000, n).astype(np.uint64)),
        "u32_wide": rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32),
        "f64_exact": rng.integers(-1000, 1000, n) / 4.0,  # quarters: exact in float32
        "f64_gps": 245_385.0 + rng.random(n),  # not in float32
        "f64_constant": np.full(n, 245_385.123),  # a GPS time no one set: one value
        "f64_negative_zero": np.full(n, -0.0),  # bit for bit: not +0.0
        "f32": rng.random(n).astype(np.float32),
        "flag": rng.random(n) < 0.5,
        "normal": rng.normal(size=(n, 3)).astype(np.float32),
    }


HELD = {  # what each is held in: packed dtype (None: no array), or unpacked
    "constant": None, "zero": None, "full_u16": "unpacked", "intensity": np.uint8, "negative": np.uint8, "negative32": np.uint16,
    "signed8": "unpacked", "i64_near_max": np.uint16, "i64_span": "unpacked", "u64_high": np.uint32, "u32_wide": "unpacked",
    "f64_exact": np.float32, "f64_gps": "unpacked", "f64_constant": None, "f64_negative_zero": None, "f32": "unpacked", "flag": "unpacked", "normal": "unpacked",
}  # fmt: skip


def test_pack_round_trips_every_value_and_picks_the_narrowest(rng):
    values = edge_attributes(rng, 5000)
    for name, v in values.items():
        held = pack(v)
        if HELD[name] == "unpacked":
            assert held is v, name
            continue
        assert isinstance(held, Packed), name
        assert (held.stored is None) if HELD[name] is None else (held.stored.dtype == HELD[name]), name
        back = held.decode()
        assert back.dtype == v.dtype, name
        assert np.array_equal(back.view(np.uint8), v.view(np.uint8)), name  # bit for bit
        idx = rng.integers(0, len(v), 50)
        assert np.array_equal(held.decode(idx), v[idx]), name


@pytest.mark.parametrize("order", ["as given", "ascending"])
def test_a_holder_filled_batch_by_batch_keeps_every_value_and_widens_rarely(rng, order):
    """An arena filled as points come (the progressive octree's pool): the holder the first batch
    suggests, widened (its entries so far copied) where a batch does not fit, stores every value
    bit for bit; ramps widen a few times, not once a batch; ``repacked`` then narrows to the
    real range and ``resized`` keeps the entries."""
    n, batch = 6000, 500
    values = edge_attributes(rng, n)
    values["ramp_u16"] = (np.arange(n) // 10).astype(np.uint16)  # 0..599: one value, a byte, then its dtype
    values["ramp_i32"] = (np.arange(n) - 70_000).astype(np.int32)
    values["later_gps"] = np.where(np.arange(n) < 2000, 5.0, 245_385.0 + rng.random(n))  # one value, then many
    for name, v in values.items():
        if order == "ascending" and v.ndim == 1 and v.dtype != bool:
            v = np.sort(v)
        held, used, widenings = holder_for(v[:batch], n), 0, 0
        for s in range(0, n, batch):
            part = v[s : s + batch]
            if not fits(held, part):
                held, widenings = widened(held, part, used), widenings + 1
            into = stored(held)
            if into is not None:
                into[used : used + len(part)] = encode(held, part)
            used += len(part)
        got = held.decode() if isinstance(held, Packed) else held
        assert got.dtype == v.dtype and got.tobytes() == v.tobytes(), name
        assert widenings <= 3, (name, widenings)
        tight = repacked(held)
        assert (tight.decode() if isinstance(tight, Packed) else tight).tobytes() == v.tobytes(), name
        if name in HELD and HELD[name] != "unpacked":  # as pack holds all of them at once
            assert isinstance(tight, Packed) and (tight.stored is None if HELD[name] is None else tight.stored.dtype == HELD[name]), name
        longer = resized(held, n + 10)
        assert (longer.decode() if isinstance(longer, Packed) else longer)[:n].tobytes() == v.tobytes(), name
    assert holder_for(np.full(10, 7, np.uint16), 4) == Packed(None, 7, np.dtype(np.uint16), 4)
    middle = holder_for(np.array([1000, 1100], np.int32), 4)  # the range in the middle of a byte: room either side
    assert middle.stored.dtype == np.uint8 and fits(middle, np.array([950, 1150], np.int32))
    assert not fits(middle, np.array([1000, 1300], np.int32))
    assert holder_for(np.array([0, 10], np.uint16), 4).offset == 0  # not below the dtype's range
    assert not fits(holder_for(np.full(3, 0.0), 4), np.full(3, -0.0))  # bit for bit


def test_float_packing_is_bit_exact():
    v = np.array([0.5, -0.0, np.nan, np.inf, 1e-40])  # 1e-40: a float32 subnormal, not the same float64
    assert pack(v) is v
    nan = np.full(3, np.nan)
    assert pack(nan).stored is not None  # a NaN's payload is not kept as a constant: float32 keeps it (or it stays)
    mixed = np.array([0.0, -0.0, 0.0])  # equal, but not bit for bit
    assert np.array_equal(pack(mixed).decode().view(np.uint64), mixed.view(np.uint64))
    w = np.array([0.5, -0.0, np.inf, -2.0**-130])
    back = pack(w).decode()
    assert np.array_equal(back.view(np.uint64), w.view(np.uint64))


@pytest.mark.parametrize("chunked", [False, True])
def test_a_utm_cloud_reads_back_every_point(rng, chunked, tmp_path):
    n = 40_000
    xyz = UTM + rng.integers(0, 200_000, (n, 3)) * 0.01
    rgba = np.full((n, 4), 255, np.uint8)
    attrs = edge_attributes(rng, n)
    chunks = [PointChunk(xyz[s : s + 10_000], rgba[s : s + 10_000], {k: v[s : s + 10_000] for k, v in attrs.items()}, scale=(0.01,) * 3)
              for s in range(0, n, 10_000)]  # fmt: skip
    if chunked:
        cloud = build_cloud_chunked(lambda: chunks, batch_size=1000, partition_points=7_000, tmpdir=tmp_path)
    else:
        cloud = build_cloud(chunks, batch_size=1000)
    exact = build_cloud(chunks, batch_size=1000, layout="words")  # the same Morton order
    order = match_points(cloud.positions(), xyz)
    for name, v in attrs.items():
        got = cloud.attributes[name]
        assert got.dtype == v.dtype and got.shape == v.shape, name
        assert np.array_equal(got.view(np.uint8), v[order].view(np.uint8)), name
        assert cloud.attributes.held_dtype(name) == exact.attributes.held_dtype(name)
    held = sum(pack(v).nbytes if isinstance(pack(v), Packed) else v.nbytes for v in attrs.values())
    assert cloud.memory()["attributes"] == held < sum(v.nbytes for v in attrs.values())
    for i in rng.integers(0, n, 20):
        info = cloud.point_info(int(i))
        for name, v in attrs.items():
            assert info[name] == v[order[i]].tolist(), name


def match_points(decoded: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """For each decoded position, the index of its source point (positions are distinct here)."""
    key = lambda p: np.round((p - UTM) / 0.01).astype(np.int64)
    a, b = key(decoded), key(xyz)
    ia, ib = np.lexsort(a.T), np.lexsort(b.T)
    assert np.array_equal(a[ia], b[ib])
    order = np.empty(len(a), np.int64)
    order[ia] = ib
    return order


@pytest.mark.skipif(not AUTZEN.exists(), reason="autzen_trim.laz not present")
def test_autzen_attributes_read_back_exactly():
    import laspy

    las = laspy.read(str(AUTZEN))
    cloud = gp.open(AUTZEN)
    names = ("intensity", "classification", "return_number", "number_of_returns", "point_source_id", "gps_time")
    source = {k: np.asarray(las[k]) for k in names}
    xyz = np.stack([las.x, las.y, las.z], 1)
    got_xyz = cloud.positions()
    key = lambda p: np.round(p / 0.01).astype(np.int64)
    a, b = key(got_xyz), key(xyz)
    # autzen_trim holds a few points twice at one position: compare sorted (position, attributes) rows
    rows_got = np.column_stack([a, *(cloud.attributes[k].astype(np.float64) for k in names)])
    rows_src = np.column_stack([b, *(source[k].astype(np.float64) for k in names)])
    np.testing.assert_array_equal(rows_got[np.lexsort(rows_got.T[::-1])], rows_src[np.lexsort(rows_src.T[::-1])])
    for k in names:
        assert cloud.attributes[k].dtype == gp.open(AUTZEN, layout="words").attributes[k].dtype
    mem = cloud.memory()
    assert mem["attributes"] < sum(np.asarray(las[k]).nbytes for k in cloud.attributes)
    assert mem["attributes"] == sum(cloud.attributes.nbytes_of(k) for k in cloud.attributes)


def test_colour_modes_and_later_attributes():
    """Attribute colouring reads the packed values back (same image as from plain arrays); an
    attribute stored later (estimated normals) is packed too."""
    from gigapoint.render.colors import point_colors

    rng = np.random.default_rng(3)
    n = 5000
    xyz = UTM + rng.integers(0, 3000, (n, 3)) * 0.01
    attrs = {"intensity": rng.integers(3000, 3100, n).astype(np.uint16), "classification": rng.integers(2, 7, n).astype(np.uint8)}
    cloud = build_cloud([PointChunk(xyz, None, attrs, scale=(0.01,) * 3)])
    assert cloud.attributes.held_dtype("intensity") == "uint16 in uint8 + 3000"
    plain = gp.PointCloud(cloud.batches, cloud.low, cloud.med, cloud.high, cloud.color, {k: cloud.attributes[k] for k in cloud.attributes},
                          ext=cloud.ext, packing=cloud.packing, data_bounds=cloud.data_bounds)  # fmt: skip
    assert plain.attributes.nbytes == 3 * n
    for mode in ("intensity", "classification"):
        s = gp.RenderSettings(color_mode=mode)
        np.testing.assert_array_equal(point_colors(cloud, s), point_colors(plain, s))
    cloud.attributes["later"] = np.full(n, 9, np.int64)
    assert cloud.attributes.nbytes_of("later") == 0 and cloud.attributes["later"].tolist() == [9] * n
    del cloud.attributes["later"]
    assert "later" not in cloud.attributes and isinstance(cloud.attributes, Attributes)


@pytest.mark.skipif(not AUTZEN.exists(), reason="autzen_trim.laz not present")
def test_info_shows_the_packed_sizes(capsys):
    import json

    from gigapoint.cli import main

    assert main(["info", "--memory", "--json", str(AUTZEN)]) == 0
    row = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")][-1]
    n = row["n_points"]
    held = row["attributes"]
    assert held["point_source_id"] == {"bytes": 0, "held": "uint16 constant 7326"}
    assert held["intensity"]["held"].startswith("uint16 in uint8") and held["intensity"]["bytes"] == n
    # the scan fields: one byte each where they vary, nothing where constant (withheld, synthetic...)
    assert held["scan_angle_rank"]["bytes"] == held["user_data"]["bytes"] == n and held["synthetic"] == {"bytes": 0, "held": "uint8 constant 0"}
    assert row["memory"]["attributes"] == sum(v["bytes"] for v in held.values()) < 18 * n
    assert main(["info", "--memory", str(AUTZEN)]) == 0
    out = capsys.readouterr().out
    assert "attributes held: intensity 1.00 (uint16 in uint8)" in out and "point_source_id 0.00 (uint16 constant 7326)" in out
