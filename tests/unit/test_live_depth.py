"""Depth images -> points with normals (live/depth.py): the compiled kernel against the numpy reference."""

from __future__ import annotations

import numpy as np
import pytest

from gigapoint.errors import InputError
from gigapoint.live import LiveCloud
from gigapoint.live.depth import TILE, depth_to_points, depth_to_points_reference, tile_order

K = (365.5, 360.0, 31.5, 23.5)


def pose_of(angle=0.4, t=(1.0, -2.0, 3.0)):
    c, s = np.cos(angle), np.sin(angle)
    p = np.eye(4)
    p[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    p[:3, 3] = t
    return p


def test_kernel_equals_reference_with_holes_nans_and_a_pose():
    rng = np.random.default_rng(1)
    d = rng.uniform(0.5, 4.0, (48, 64)).astype(np.float32)
    d[5:9, 10:20] = 0
    d[30, :] = np.nan
    d[:, 40] = -1.0
    d[0, 0] = np.inf
    xyz, nrm, rgba, pix = depth_to_points(d, K, pose_of())
    rx, rn, ridx = depth_to_points_reference(d, K, pose_of())
    assert rgba is None
    np.testing.assert_array_equal(pix, ridx)
    np.testing.assert_allclose(xyz, rx, rtol=0, atol=1e-12)
    np.testing.assert_allclose(nrm, rn, rtol=0, atol=1e-6)
    assert len(xyz) == np.count_nonzero(np.isfinite(d) & (d > 0))


def test_uint16_millimetres_and_a_3x3_matrix_and_max_depth():
    d = np.full((10, 12), 2000, np.uint16)
    d[0, 0] = 9000
    m = np.array([[K[0], 0, K[2]], [0, K[1], K[3]], [0, 0, 1]])
    xyz, _, _, pix = depth_to_points(d, m, max_depth=5.0)
    assert 0 not in pix and len(xyz) == 119
    np.testing.assert_allclose(xyz[:, 2], 2.0)
    v, u = divmod(pix[0], 12)
    np.testing.assert_allclose(xyz[0, :2], [(u - K[2]) * 2.0 / K[0], (v - K[3]) * 2.0 / K[1]])
    rx, _, _ = depth_to_points_reference(d, m, max_depth=5.0)
    np.testing.assert_allclose(xyz, rx, atol=1e-12)


def test_a_plane_facing_the_sensor_has_normals_towards_it_rotated_by_the_pose():
    d = np.full((20, 20), 3.0)
    _, nrm, _, _ = depth_to_points(d, K)
    np.testing.assert_allclose(nrm, np.tile([0.0, 0.0, -1.0], (400, 1)), atol=1e-6)
    p = pose_of(0.0)
    p[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # sensor z -> world +y: the normal (towards the sensor) -> -y
    _, nrm, _, _ = depth_to_points(d, K, p)
    np.testing.assert_allclose(nrm[0], [0.0, -1.0, 0.0], atol=1e-6)


def test_tilted_plane_normal_and_isolated_pixels_get_zero_normals():
    v, u = np.mgrid[0:30, 0:40].astype(np.float64)
    # the plane z = 2 + 0.5 x (x = (u - cx) z / fx): z = 2 / (1 - 0.5 (u - cx) / fx)
    z = 2.0 / (1.0 - 0.5 * (u - K[2]) / K[0])
    _, nrm, _, _ = depth_to_points(z, K)
    expect = np.array([0.5, 0.0, -1.0]) / np.sqrt(1.25)
    np.testing.assert_allclose(nrm, np.tile(expect, (len(nrm), 1)), atol=1e-5)
    lone = np.zeros((5, 5))
    lone[2, 2] = 1.0
    _, nrm, _, _ = depth_to_points(lone, K)
    np.testing.assert_array_equal(nrm, [[0.0, 0.0, 0.0]])


@pytest.mark.parametrize("scale", [(0.001, 0.001, 0.001), (2.0, 1.0, 0.5)], ids=["millimetres-to-metres", "non-uniform"])
def test_a_scaled_pose_gives_unit_normals_perpendicular_to_the_world_surface(scale):
    """Normals were moved by the pose's 3x3 part, as points are: a millimetre -> metre pose made
    them 0.001 long (lighting and colour_mode='normal' all but black, files saying so), a
    non-uniform scale tilted them off the surface."""
    v, u = np.mgrid[0:30, 0:40].astype(np.float64)
    z = 2.0 / (1.0 - 0.5 * (u - K[2]) / K[0])  # the sensor's plane z = 2 + 0.5 x: normal (0.5, 0, -1) towards it
    p = pose_of()
    p[:3, :3] = p[:3, :3] @ np.diag(scale)
    xyz, nrm, _, _ = depth_to_points(z, K, p)
    # the world plane: normal (0.5, 0, -1) (the sensor's) through the inverse transpose
    expect = np.array([0.5, 0.0, -1.0]) @ np.linalg.inv(p[:3, :3])
    expect /= np.linalg.norm(expect)
    np.testing.assert_allclose(nrm, np.tile(expect, (len(nrm), 1)), atol=1e-5)
    np.testing.assert_allclose((xyz - xyz[0]) @ expect, 0.0, atol=1e-9)  # (it is the world surface's normal)
    _, rn, _ = depth_to_points_reference(z, K, p)
    np.testing.assert_allclose(nrm, rn, rtol=0, atol=1e-6)
    live = LiveCloud()
    live.push(xyz, normals=np.tile([0.5, 0.0, -1.0], (len(xyz), 1)) / np.sqrt(1.25), pose=p)  # the sensor normals pushed with points (where does not matter)
    a = live.frame_points()[2]
    np.testing.assert_allclose(np.c_[a["nx"], a["ny"], a["nz"]], np.tile(expect, (len(xyz), 1)), atol=1e-5)


def test_rgb_follows_the_pixels():
    d = np.ones((4, 5), np.float32)
    d[1, 1] = 0
    rgb = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)
    _, _, rgba, pix = depth_to_points(d, K, rgb=rgb)
    np.testing.assert_array_equal(rgba[:, :3], rgb.reshape(-1, 3)[pix])
    assert (rgba[:, 3] == 255).all()


def test_float_and_16_bit_rgb_are_judged_as_pushed_colours():
    """A float image of 0..255 was taken as 0..1 (every point white), NaN and -3 clipped to black
    without a word; push judged the same colours by their range."""
    d = np.ones((4, 5), np.float32)
    rgb = np.empty((4, 5, 3))
    rgb[:] = (200.0, 100.0, 50.0)
    assert depth_to_points(d, K, rgb=rgb)[2][0].tolist() == [200, 100, 50, 255]
    assert depth_to_points(d, K, rgb=rgb / 255.0)[2][0].tolist() == [200, 100, 50, 255]
    assert depth_to_points(d, K, rgb=(rgb * 256).astype(np.uint16))[2][0].tolist() == [200, 100, 50, 255]
    rgb[2, 3] = (np.nan, 0.0, 0.0)
    with pytest.raises(InputError, match=r"^push_depth: colors must be 0..1, 0..255 or 0..65535 \(16 bits\), got nan$"):
        depth_to_points(d, K, rgb=rgb)


def test_a_depth_streams_float_colours_keep_the_range_of_its_first_frame():
    """Each frame's float image was judged by its own range: in a 0..1 stream, a frame whose max
    went just over 1.0 came out almost black ([0, 0, 1] for (0.5, 0.5, 1.025)), and in a 0..255
    stream a dark frame (all <= 1) almost white. The stream's ``scalers`` keep the first frame's
    decision, as a file's range (push_depth: the cloud's, as push's)."""
    d = np.ones((4, 5), np.float32)

    def colour(rgb, scalers):
        return depth_to_points(d, K, rgb=np.broadcast_to(rgb, (4, 5, 3)), scalers=scalers)[2][0].tolist()

    unit: dict = {}
    assert colour((0.5, 0.5, 1.0), unit) == [128, 128, 255, 255]
    assert colour((0.5, 0.5, 1.025), unit) == [128, 128, 255, 255]  # clipped, as before the range was judged
    assert colour((0.5, 0.5, 1.025), None) == [0, 0, 1, 255]  # a frame alone: 0..255
    bytes_: dict = {}
    assert colour((200.0, 100.0, 50.0), bytes_) == [200, 100, 50, 255]
    assert colour((0.9, 1.0, 1.0), bytes_) == [1, 1, 1, 255]
    live = LiveCloud()
    for rgb in ((0.5, 0.5, 1.0), (0.5, 0.5, 1.025)):
        live.push_depth(d, K, rgb=np.broadcast_to(rgb, (4, 5, 3)))
    assert np.unique(live.frame_points()[1], axis=0).tolist() == [[128, 128, 255, 255]]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"intrinsics": None}, "intrinsics are missing"),
        ({"intrinsics": (1.0, 2.0)}, "intrinsics must be"),
        ({"intrinsics": (0.0, 1.0, 1.0, 1.0)}, "fx, fy > 0"),
        ({"depth": np.ones((4, 4, 2))}, "depth must be an (H, W) image"),
        ({"depth": np.array([["a"]])}, "dtype"),
        ({"depth": np.zeros((4, 4))}, "no valid pixel"),
        ({"depth": np.full((4, 4), np.nan)}, "no valid pixel"),
        ({"pose": np.eye(3)}, "pose must be a 4x4"),
        ({"pose": np.full((4, 4), np.nan)}, "NaN"),
        ({"pose": np.diag([0.0, 0.0, 0.0, 1.0])}, "pose's 3x3 rotation part is singular (it would flatten the frame): [[0.0, 0.0, 0.0], "),  # all one point
        ({"pose": np.diag([1.0, 1.0, 0.0, 1.0])}, "pose's 3x3 rotation part is singular"),  # flat
        ({"rgb": np.zeros((3, 3, 3), np.uint8)}, "rgb must be"),
        ({"depth": [[1.0, 2.0], [3.0]]}, "depth must be an (H, W) image of numbers, got a ragged list"),  # numpy's ValueError
        ({"rgb": np.full((4, 4, 3), "a")}, "rgb must hold numbers (uint8, uint16 or float colors), got dtype <U1"),  # int()'s ValueError
        ({"rgb": np.ones((4, 4, 3), complex)}, "rgb must hold numbers (uint8, uint16 or float colors), got dtype complex128"),  # a ComplexWarning
        ({"depth_scale": -1.0}, "depth_scale"),
        ({"depth_scale": "mm"}, "depth_scale must be a positive number, got 'mm'"),  # was float()'s ValueError
        ({"depth_scale": True}, "depth_scale must be a positive number, got True"),  # was taken as 1
        ({"max_depth": -1.0}, "max_depth must be a positive number of metres or None, got -1.0"),  # was "no valid pixel"
        ({"max_depth": "far"}, "max_depth must be a positive number of metres or None, got 'far'"),
    ],
)
def test_bad_input_is_one_line(kwargs, message):
    args = {"depth": np.ones((4, 4)), "intrinsics": K, **kwargs}
    with pytest.raises(InputError) as err:
        depth_to_points(**args)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_tile_order_visits_the_tiles_in_z_order_or_the_rows_in_order():
    tiles, th, tw = tile_order(4 * TILE, 4 * TILE, True)
    assert (th, tw) == (TILE, TILE)
    r, c = tiles.T
    # 4x4 tiles: the four 2x2 blocks in Z order, each in Z order (column bit first)
    np.testing.assert_array_equal(r * 4 + c, [0, 1, 4, 5, 2, 3, 6, 7, 8, 9, 12, 13, 10, 11, 14, 15])
    tiles, th, tw = tile_order(5, 7, False)
    assert (th, tw) == (1, 7)
    np.testing.assert_array_equal(tiles, [[v, 0] for v in range(5)])
    h, w = 424, 512  # a Kinect frame: 27 x 32 tiles, the last row of tiles cut short
    tiles, _, _ = tile_order(h, w, True)
    rows, cols = -(-h // TILE), w // TILE
    np.testing.assert_array_equal(np.sort(tiles[:, 0] * cols + tiles[:, 1]), np.arange(rows * cols))  # every tile once

    def z_key(t):  # the reference: row and column bits interleaved, column first
        return sum(((int(t[1]) >> b) & 1) << (2 * b) | ((int(t[0]) >> b) & 1) << (2 * b + 1) for b in range(6))

    keys = [z_key(t) for t in tiles]
    assert keys == sorted(keys)


def test_z_order_gives_the_row_major_points_tile_by_tile():
    """The kernel visiting the image tile by tile in Z order gives the row-major points permuted
    (tiles in ``tile_order``'s order, row-major inside each), nothing else."""
    rng = np.random.default_rng(3)
    d = rng.uniform(0.5, 4.0, (3 * TILE + 5, 4 * TILE + 9)).astype(np.float32)  # partial tiles at the edges
    d[rng.random(d.shape) < 0.3] = 0  # holes
    d[20:30, 10:40] = np.nan
    rgb = rng.integers(0, 255, d.shape + (3,), dtype=np.uint8)
    rows = depth_to_points(d, K, pose_of(), rgb)
    z = depth_to_points(d, K, pose_of(), rgb, z_order=True)
    h, w = d.shape
    visit = [v * w + u for tr, tc in tile_order(h, w, True)[0] for v in range(tr * TILE, min(h, tr * TILE + TILE)) for u in range(tc * TILE, min(w, tc * TILE + TILE))]
    rank = np.empty(d.size, np.int64)
    rank[visit] = np.arange(d.size)
    perm = np.argsort(rank[rows[3]])
    for a, b in zip(z, rows):
        np.testing.assert_array_equal(a, b[perm])
    assert np.all(np.diff(rank[z[3]]) > 0)


def test_scratch_arrays_are_reused_from_frame_to_frame_and_give_the_same_points():
    """``scratch`` keeps the positions, pixel indices and metres between calls (push_depth's, one
    set per producer thread): the points equal the reference frame after frame, whatever the
    holes, and a frame of another shape gets arrays of its own."""
    rng = np.random.default_rng(2)
    scratch: dict = {}
    held = []
    for h, w in ((48, 64), (48, 64), (30, 20), (48, 64)):
        d = rng.uniform(0.5, 4.0, (h, w)).astype(np.float32)
        d[rng.random((h, w)) < 0.2] = 0
        xyz, nrm, _, pix = depth_to_points(d, K, pose_of(), scratch=scratch)
        rx, rn, ridx = depth_to_points_reference(d, K, pose_of())
        np.testing.assert_array_equal(pix, ridx)
        np.testing.assert_allclose(xyz, rx, rtol=0, atol=1e-12)
        np.testing.assert_allclose(nrm, rn, rtol=0, atol=1e-6)
        assert np.shares_memory(xyz, scratch["xyz"]) and scratch["xyz"].shape == (h * w, 3)
        held.append((scratch["xyz"], nrm))
    assert held[1][0] is held[0][0] and held[2][0] is not held[0][0]  # reused while the shape holds
    odd = {"xyz": np.zeros((48 * 64, 3), np.float32), "pix": "not an array", "z": np.zeros((64, 48))}  # replaced, not used
    xyz, _, _, pix = depth_to_points(d, K, pose_of(), scratch=odd)
    np.testing.assert_allclose(xyz, depth_to_points_reference(d, K, pose_of())[0], rtol=0, atol=1e-12)
    assert odd["xyz"].dtype == np.float64 and odd["z"].shape == (48, 64)
    assert not np.shares_memory(held[0][1], held[1][1])  # the normals stay the caller's: the frame keeps them
