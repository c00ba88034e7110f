"""Live sources (live/sources.py), recording and replay (live/record.py), pushed frames (live/wire.py),
on small files written with the libraries themselves (plyfile, pypcd4, Pillow, rosbags)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from gigapoint.errors import GigapointError, InputError
from gigapoint.live import LiveCloud
from gigapoint.live.record import RecordedFrame, is_recording, recording_files
from gigapoint.live.sources import (
    BagSource,
    FramesDir,
    Player,
    ReplaySource,
    SyntheticSensor,
    TumSequence,
    open_source,
    quaternion_pose,
)
from gigapoint.live.wire import decode_frame, encode_frame


def sorted_rows(a):
    a = np.asarray(a, np.float64)
    return a[np.lexsort(a.T[::-1])]


def cloud_points(live):
    return sorted_rows(live.frame_points()[0])


def patch(k, n=500):
    rng = np.random.default_rng(k)
    return rng.uniform(-2, 2, (n, 3)).astype(np.float32) + np.float32(k), rng.integers(0, 255, (n, 3), dtype=np.uint8)


# ---------------------------------------------------------------------- synthetic sensor
def test_synthetic_sensor_is_deterministic_and_sees_the_town():
    a = SyntheticSensor(n_frames=3, scene_points=200_000)
    b = SyntheticSensor(n_frames=3, scene_points=200_000)
    fa, fb = a.render(2), b.render(2)
    np.testing.assert_array_equal(fa.depth, fb.depth)
    np.testing.assert_array_equal(fa.rgb, fb.rgb)
    np.testing.assert_array_equal(fa.pose, fb.pose)
    assert fa.depth.shape == (424, 512) and (fa.depth > 0).mean() > 0.5
    assert not np.array_equal(a.render(0).depth, fa.depth)  # it moves
    live = LiveCloud(keep=3)
    Player(a, live, rate=None).run()
    assert live.n_frames == 3 and live.n_points > 3 * 100_000
    lo, hi = live.bounds
    assert (lo > -50).all() and (hi[:2] < 1050).all()  # inside the demo town


# ---------------------------------------------------------------------- folders of frames
def test_frames_dir_reads_ply_pcd_npy_in_name_order(tmp_path):
    from plyfile import PlyData, PlyElement

    pypcd4 = pytest.importorskip("pypcd4")
    xyz0, rgb0 = patch(0)
    v = np.empty(len(xyz0), [("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for k, a in enumerate("xyz"):
        v[a] = xyz0[:, k]
    for k, a in enumerate(("red", "green", "blue")):
        v[a] = rgb0[:, k]
    PlyData([PlyElement.describe(v, "vertex")]).write(str(tmp_path / "000.ply"))
    xyz1, rgb1 = patch(1)
    packed = pypcd4.PointCloud.encode_rgb(rgb1)
    pc = pypcd4.PointCloud.from_xyzrgb_points(np.column_stack([xyz1, packed.astype(np.float32)]))
    pc.save(tmp_path / "001.pcd")
    xyz2, _ = patch(2)
    np.save(tmp_path / "002.npy", xyz2)
    (tmp_path / "notes.txt").write_text("not a frame")
    src = open_source(tmp_path)
    assert isinstance(src, FramesDir) and [p.name for p in src.files] == ["000.ply", "001.pcd", "002.npy"]
    frames = list(src.frames())
    np.testing.assert_allclose(frames[0].xyz, xyz0)
    np.testing.assert_array_equal(frames[0].rgb, rgb0)
    np.testing.assert_allclose(frames[1].xyz, xyz1)
    np.testing.assert_array_equal(frames[1].rgb, rgb1)
    np.testing.assert_allclose(frames[2].xyz, xyz2)
    live = LiveCloud(keep=10)
    player = Player(src, live, rate=None)
    player.run()
    assert live.n_frames == 3 and player.errors == 0


def test_a_bad_file_in_a_frames_dir_is_skipped_with_a_message(tmp_path):
    np.save(tmp_path / "a.npy", patch(0)[0])
    (tmp_path / "b.ply").write_bytes(b"ply\nformat garbage\n")
    np.save(tmp_path / "c.npy", np.zeros((4, 2)))
    np.save(tmp_path / "d.npy", patch(3)[0])
    live = LiveCloud()
    player = Player(FramesDir(tmp_path), live, rate=None)
    player.run()
    assert player.frames == 2 and player.errors == 2 and live.n_frames == 2
    assert "c.npy" in live.stats.last_error and "\n" not in live.stats.last_error


def test_pcl_colours_read_right_from_ascii_pcd_and_rgba_fields(tmp_path):
    """PCL writes a float rgb field of an ASCII PCD as the integer of its 32 bits (0xFFRRGGBB:
    alpha 255), which were read as the float's bits: every colour wrong. An rgba field
    (PointXYZRGBA, in PCD files and PointCloud2 messages) was not read at all: no colours; and
    a big-endian PointCloud2's packed colours were byte-swapped."""
    pytest.importorskip("pypcd4")
    from gigapoint.live.sources import pointcloud2_arrays, read_points_file

    rgb = np.array([[255, 0, 0], [0, 255, 0], [10, 49, 51], [0, 0, 0]], np.uint8)
    bits = (0xFF << 24) | (rgb[:, 0].astype(np.uint64) << 16) | (rgb[:, 1].astype(np.uint64) << 8) | rgb[:, 2]
    head = "VERSION 0.7\nFIELDS x y z {0}\nSIZE 4 4 4 4\nTYPE F F F {1}\nCOUNT 1 1 1 1\nWIDTH 4\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\nDATA ascii\n"
    rows = "".join(f"{k} 1 2 {b}\n" for k, b in enumerate(bits.tolist()))
    for name, kind in (("rgb", "F"), ("rgba", "U")):
        (tmp_path / f"{name}.pcd").write_text("# .PCD v0.7 - Point Cloud Data file format\n" + head.format(name, kind) + rows)
        xyz, got = read_points_file(tmp_path / f"{name}.pcd")
        np.testing.assert_array_equal(xyz[:, 0], [0, 1, 2, 3])
        np.testing.assert_array_equal(got, rgb)
    typesys = pytest.importorskip("rosbags.typesys")
    msg = _pointcloud2(typesys.get_typestore(typesys.Stores.ROS2_HUMBLE), patch(0, 4)[0], rgb, 0, False)
    msg.fields[-1].name = "rgba"  # PointXYZRGBA's field
    np.testing.assert_array_equal(pointcloud2_arrays(msg)[1], rgb)
    # a big-endian message: its packed colours were read byte-swapped ((16, 32, 48) as (48, 32, 16))
    big = np.zeros(4, [("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("pad", ">f4"), ("rgba", ">u4")])
    big["x"], big["rgba"] = [0, 1, 2, 3], bits
    msg.is_bigendian, msg.data = True, big.view(np.uint8)
    xyz, got = pointcloud2_arrays(msg)
    np.testing.assert_array_equal(xyz[:, 0], [0, 1, 2, 3])
    np.testing.assert_array_equal(got, rgb)



def test_an_ascii_pcd_frame_is_read_once(tmp_path, monkeypatch):
    """pypcd4 parses the file's bytes, and PCL's integer colours are taken from those same bytes
    (the file was read a second time for them)."""
    pytest.importorskip("pypcd4")
    import builtins
    import io

    from gigapoint.live.sources import read_points_file

    path = tmp_path / "a.pcd"
    path.write_text("FIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n0 1 2 4278190335\n3 4 5 4294901760\n")
    real, opened = builtins.open, []

    def counting(file, *args, **kwargs):
        opened.append(file)
        return real(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", counting)  # pypcd4's open
    monkeypatch.setattr(io, "open", counting)  # pathlib's
    xyz, rgb = read_points_file(path)
    monkeypatch.undo()
    assert [str(f) for f in opened].count(str(path)) == 1
    np.testing.assert_array_equal(xyz, [[0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(rgb, [[0, 0, 255], [255, 0, 0]])

def test_a_frame_the_cloud_refuses_is_said_with_its_file_or_message(tmp_path):
    """A frame read fine but refused by push (every point NaN: an organised PCL cloud that saw
    nothing; an empty PointCloud2) was said as "live: push: ...", naming no file or message."""
    np.save(tmp_path / "a.npy", patch(0)[0])
    np.save(tmp_path / "b.npy", np.full((4, 3), np.nan))
    live = LiveCloud()
    player = Player(FramesDir(tmp_path), live, rate=None)
    player.run()
    assert player.frames == 1 and player.errors == 1 and live.stats.frames_rejected == 1
    assert live.stats.last_error == f"{tmp_path / 'b.npy'}: live: push: none of the frame's 4 points is valid (NaN, inf or beyond ±1e+12)"
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(tmp_path / "bag", version=8) as writer:
        conn = writer.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=typestore)
        for k, n in enumerate((0, 5)):
            msg = _pointcloud2(typestore, *patch(k, n), 10**9, False)
            writer.write(conn, 10**9 + k, typestore.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
    Player(BagSource(tmp_path / "bag"), live, rate=None).run()
    assert live.stats.last_error == f"{tmp_path / 'bag'}: message at {10**9}: live: push: the frame has no points" and live.n_frames == 2


@pytest.mark.parametrize("fps", [0, -10.0, float("nan"), "10"])
def test_a_frame_rate_that_is_not_a_positive_number_is_refused_at_once(tmp_path, fps):
    """fps=0 was a ZeroDivisionError in the player's thread, reported only as "the stream
    stopped"; "10" a ValueError; -10 and NaN played every frame at once."""
    np.save(tmp_path / "a.npy", patch(0)[0])
    with pytest.raises(InputError, match=f"^{re.escape(str(tmp_path))}: fps must be a positive number of frames a second, got {re.escape(repr(fps))}$"):
        FramesDir(tmp_path, fps=fps)
    with pytest.raises(InputError, match=r"^synthetic sensor \(512x424, demo town\): fps must be a positive number"):
        SyntheticSensor(n_frames=1, fps=fps, scene_points=10)


# ---------------------------------------------------------------------- TUM RGB-D
def test_tum_sequence_pairs_depth_rgb_and_poses(tmp_path):
    from PIL import Image

    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    h, w = 24, 32
    depth_lines, rgb_lines, gt_lines = [], [], []
    poses = {}
    for k in range(3):
        t = 1305031102.0 + 0.1 * k
        d = np.full((h, w), 5000 * (1 + k), np.uint16)  # (1 + k) metres at 5000 units a metre
        d[0, :] = 0
        Image.fromarray(d).save(tmp_path / "depth" / f"{t:.6f}.png")
        Image.fromarray(np.full((h, w, 3), 50 * k, np.uint8)).save(tmp_path / "rgb" / f"{t + 0.004:.6f}.png")
        depth_lines.append(f"{t:.6f} depth/{t:.6f}.png")
        rgb_lines.append(f"{t + 0.004:.6f} rgb/{t + 0.004:.6f}.png")
        q = (0.0, 0.0, np.sin(0.1 * k), np.cos(0.1 * k))
        gt_lines.append(f"{t + 0.001:.4f} {k} 2 3 {q[0]} {q[1]} {q[2]} {q[3]}")
        poses[k] = quaternion_pose((k, 2, 3), q)
    (tmp_path / "depth.txt").write_text("# depth maps\n" + "\n".join(depth_lines) + "\n")
    (tmp_path / "rgb.txt").write_text("# color images\n" + "\n".join(rgb_lines) + "\n")
    (tmp_path / "groundtruth.txt").write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(gt_lines) + "\n")
    src = open_source(tmp_path)
    assert isinstance(src, TumSequence)
    frames = list(src.frames())
    assert len(frames) == 3
    np.testing.assert_allclose(frames[1].pose, poses[1])
    assert np.allclose(frames[2].rgb, 100)
    live = LiveCloud(keep=3)
    Player(src, live, rate=None).run()
    assert live.n_points == 3 * (h - 1) * w
    # frame 1: a plane at 2 m in front of the sensor, moved by its pose
    f = live.frames[1]
    xyz = live.frame_points([f])[0]
    cam = (xyz - poses[1][:3, 3]) @ poses[1][:3, :3]
    np.testing.assert_allclose(cam[:, 2], 2.0, atol=1e-5)
    rz = np.array([[np.cos(0.2), -np.sin(0.2), 0], [np.sin(0.2), np.cos(0.2), 0], [0, 0, 1]])  # qz = sin(0.1): 0.2 rad about z
    np.testing.assert_allclose(poses[1][:3, :3], rz, atol=1e-12)


def test_tum_association_file(tmp_path):
    from PIL import Image

    (tmp_path / "depth").mkdir()
    (tmp_path / "rgb").mkdir()
    Image.fromarray(np.full((8, 8), 5000, np.uint16)).save(tmp_path / "depth" / "a.png")
    Image.fromarray(np.full((8, 8, 3), 9, np.uint8)).save(tmp_path / "rgb" / "a.png")
    (tmp_path / "associations.txt").write_text("1.000 rgb/a.png 1.010 depth/a.png\n")
    (tmp_path / "groundtruth.txt").write_text("1.01 0 0 0 0 0 0 1\n")
    frames = list(TumSequence(tmp_path).frames())
    assert len(frames) == 1 and frames[0].time == pytest.approx(1.01) and frames[0].rgb[0, 0, 0] == 9


def test_tum_images_pillow_cannot_read_are_refused_naming_them_and_the_rest_play(tmp_path):
    """A depth PNG whose IHDR length is damaged made Pillow raise ValueError ("Truncated IHDR
    chunk"), which ended the replay (found by a fuzzer); an unreadable colour image was reported
    as its depth image."""
    from PIL import Image

    (tmp_path / "depth").mkdir()
    (tmp_path / "rgb").mkdir()
    for k in range(3):
        Image.fromarray(np.full((8, 8), 5000, np.uint16)).save(tmp_path / "depth" / f"{k}.png")
        Image.fromarray(np.full((8, 8, 3), 9, np.uint8)).save(tmp_path / "rgb" / f"{k}.png")
    damaged = bytearray((tmp_path / "depth" / "0.png").read_bytes())
    damaged[8:12] = (5).to_bytes(4, "big")  # the IHDR chunk's length
    (tmp_path / "depth" / "0.png").write_bytes(bytes(damaged))
    (tmp_path / "rgb" / "1.png").write_bytes(b"not a png")
    (tmp_path / "depth.txt").write_text("".join(f"{k}.0 depth/{k}.png\n" for k in range(3)))
    (tmp_path / "rgb.txt").write_text("".join(f"{k}.0 rgb/{k}.png\n" for k in range(3)))
    n, errors = _played(TumSequence(tmp_path))
    assert n == 64  # the third frame
    assert [e.split(":")[0] for e in errors] == [str(tmp_path / "depth" / "0.png"), str(tmp_path / "rgb" / "1.png")]
    assert all("unreadable image" in e and "\n" not in e for e in errors)


def _tum(tmp_path, depth_txt="1.0 depth/a.png\n", gt="1.0 0 0 0 0 0 0 1\n"):
    from PIL import Image

    (tmp_path / "depth").mkdir(exist_ok=True)
    Image.fromarray(np.full((8, 8), 5000, np.uint16)).save(tmp_path / "depth" / "a.png")
    (tmp_path / "depth.txt").write_text(depth_txt)
    (tmp_path / "groundtruth.txt").unlink(missing_ok=True)
    if gt is not None:
        (tmp_path / "groundtruth.txt").write_text(gt)
    return tmp_path


def _played(source) -> tuple[int, list[str]]:
    live = LiveCloud()
    player = Player(source, live, rate=None)
    player.run()
    return live.n_points, [str(f) for f in source.frames() if isinstance(f, GigapointError)]


def test_a_tum_sequence_without_poses_plays_in_the_sensors_frame_and_bad_lists_are_one_line(tmp_path):
    """Without groundtruth.txt every frame was skipped (nothing played, without a word), as when
    no frame had a pose near its time; a depth.txt line 'abc ...' was float()'s ValueError, a
    line of one column an IndexError, a quaternion of zeros or a NaN translation named no file,
    a list of no image played nothing."""
    seq = _tum(tmp_path, gt=None)
    assert _played(TumSequence(seq)) == (64, [])  # one 8x8 plane, where the sensor saw it
    live = LiveCloud()
    Player(TumSequence(seq), live, rate=None).run()
    np.testing.assert_allclose(live.frame_points()[0][:, 2], 1.0, atol=1e-6)  # 5000 units: 1 m in front of it
    _tum(tmp_path, gt="100.0 0 0 0 0 0 0 1\n")
    assert _played(TumSequence(seq)) == (
        0, [f"{seq / 'groundtruth.txt'}: no depth image has a pose within 20 ms of its time stamp: nothing to place"]
    )
    for depth_txt, gt, problem in (
        ("abc depth/a.png\n", None, "depth.txt: lines must be 'timestamp file'"),
        ("1.0\n", None, "depth.txt: lines must be 'timestamp file'"),
        ("# none\n", None, ": a TUM RGB-D sequence that lists no depth image"),
        ("1.0 depth/a.png\n", "1.0 0 0 0 0 0 0 0\n", "groundtruth.txt: quaternion ['0', '0', '0', '0'] is not a rotation"),
        ("1.0 depth/a.png\n", "1.0 nan 0 0 0 0 0 1\n", "groundtruth.txt: translation ['nan', '0', '0'] is not finite"),
    ):
        _tum(tmp_path, depth_txt, gt)
        with pytest.raises(InputError, match=f"^{re.escape(str(tmp_path))}.*{re.escape(problem)}$"):
            TumSequence(seq)
    for name in ("groundtruth.txt", "depth.txt"):  # a byte of binary junk: a UnicodeDecodeError, a traceback (found by a fuzzer)
        _tum(tmp_path)
        (seq / name).write_bytes(b"1.0 depth/a.png 0 0 \xd0 0 0 1\n")
        with pytest.raises(InputError, match=f"^{re.escape(str(seq / name))}: not a readable text file \\('utf-8' codec can't decode"):
            TumSequence(seq)


# ---------------------------------------------------------------------- ROS bags
def _pointcloud2(typestore, xyz, rgb, stamp_ns, ros1):
    PointCloud2 = typestore.types["sensor_msgs/msg/PointCloud2"]
    PointField = typestore.types["sensor_msgs/msg/PointField"]
    Header = typestore.types["std_msgs/msg/Header"]
    Time = typestore.types["builtin_interfaces/msg/Time"]
    rec = np.zeros(len(xyz), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("pad", "<f4"), ("rgb", "<u4")])
    rec["x"], rec["y"], rec["z"] = xyz.T
    rec["rgb"] = (rgb[:, 0].astype(np.uint32) << 16) | (rgb[:, 1].astype(np.uint32) << 8) | rgb[:, 2]
    fields = [PointField(name=n, offset=o, datatype=7, count=1) for n, o in (("x", 0), ("y", 4), ("z", 8))]
    fields.append(PointField(name="rgb", offset=16, datatype=6, count=1))
    extra = {"seq": 0} if ros1 else {}
    header = Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id="lidar", **extra)
    return PointCloud2(header=header, height=1, width=len(xyz), fields=fields, is_bigendian=False, point_step=20,
                       row_step=20 * len(xyz), data=rec.view(np.uint8).reshape(-1), is_dense=True)  # fmt: skip


def _write_bag(path, ros1: bool):
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    String = typestore.types["std_msgs/msg/String"]
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import Writer

        writer = Writer(path, version=8)
    sent = []
    with writer:
        conn = writer.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=typestore)
        chat = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=typestore)
        ser = typestore.serialize_ros1 if ros1 else typestore.serialize_cdr
        for k in range(3):
            xyz, rgb = patch(10 + k, n=300)
            t = 1_700_000_000_000_000_000 + k * 100_000_000
            msg = _pointcloud2(typestore, xyz, rgb, t, ros1)
            writer.write(conn, t, ser(msg, "sensor_msgs/msg/PointCloud2"))
            writer.write(chat, t, ser(String(data="hello"), "std_msgs/msg/String"))
            sent.append((xyz, rgb, t))
    return sent


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_bags_with_pointcloud2(tmp_path, ros1):
    pytest.importorskip("rosbags")
    path = tmp_path / ("run.bag" if ros1 else "run")
    sent = _write_bag(path, ros1)
    src = open_source(path)
    assert isinstance(src, BagSource)
    frames = list(src.frames())
    assert len(frames) == 3  # the String messages on /chatter are not frames
    for f, (xyz, rgb, t) in zip(frames, sent):
        np.testing.assert_allclose(f.xyz, xyz)
        np.testing.assert_array_equal(f.rgb, rgb)
        assert f.time == pytest.approx(t * 1e-9)
    live = LiveCloud(keep=5)
    Player(src, live, rate=None).run()
    assert live.n_frames == 3 and live.n_points == 900
    with pytest.raises(InputError, match="holds std_msgs/msg/String, not sensor_msgs/PointCloud2"):
        list(BagSource(path, topic="/chatter").frames())
    with pytest.raises(InputError, match="no topic '/nope'"):
        list(BagSource(path, topic="/nope").frames())


def test_a_file_that_is_not_a_bag(tmp_path):
    pytest.importorskip("rosbags")
    bad = tmp_path / "x.bag"
    bad.write_bytes(b"#ROSBAG V2.0\nnonsense")
    with pytest.raises(InputError, match="not a readable ROS bag"):
        list(BagSource(bad).frames())


# ---------------------------------------------------------------------- recording and replay
def test_a_replay_equals_the_recorded_frames(tmp_path):
    live = LiveCloud(keep=10)
    rec = live.record(tmp_path / "rec")
    for k in range(3):
        xyz, rgb = patch(k)
        pose = np.eye(4)
        pose[:3, 3] = [k, 10, 0]
        live.push(xyz, rgb, pose=pose, time=100.0 + 0.5 * k, intensity=np.arange(len(xyz), dtype=np.uint16))
    d = np.full((6, 8), 1500, np.uint16)
    d[2, 3] = 0
    live.push_depth(d, (5.0, 5.0, 3.5, 2.5), time=102.0)
    with pytest.raises(InputError):
        live.push(np.zeros((3, 2)))  # refused: not recorded
    live.stop_recording()
    assert rec.n_frames == 4
    index = json.loads((tmp_path / "rec" / "index.json").read_text())
    assert [e["kind"] for e in index["frames"]] == ["points"] * 3 + ["depth"]
    assert [e["time"] for e in index["frames"]] == [100.0, 100.5, 101.0, 102.0]
    src = open_source(tmp_path / "rec")
    assert isinstance(src, ReplaySource)
    again = LiveCloud(keep=10)
    Player(src, again, rate=None).run()
    assert again.n_frames == 4 and [f.time for f in again.frames] == [100.0, 100.5, 101.0, 102.0]
    np.testing.assert_array_equal(cloud_points(again), cloud_points(live))
    np.testing.assert_array_equal(sorted(again.frame_points()[2]["intensity"]), sorted(live.frame_points()[2]["intensity"]))
    with pytest.raises(InputError, match="holds a recording already"):
        live.record(tmp_path / "rec")


def test_a_depth_frame_is_recorded_with_its_own_time_while_another_producer_pushes(tmp_path):
    """push_depth recorded the cloud's last time stamp: a frame another producer pushed
    between its push and its recording gave the depth frame that frame's time (replayed there)."""
    import threading

    live = LiveCloud()
    live.record(tmp_path / "rec")
    commit, others = live._commit_pending, []

    def another_producer_meanwhile():
        commit()
        if not others:
            others.append(threading.Thread(target=live.push, args=(np.zeros((4, 3)),), kwargs={"time": 99.0}))
            others[0].start()
            others[0].join()

    live._commit_pending = another_producer_meanwhile
    live.push_depth(np.ones((2, 2)), (1, 1, 1, 1), time=3.0)
    live.stop_recording()
    index = json.loads((tmp_path / "rec" / "index.json").read_text())
    assert sorted((e["kind"], e["time"]) for e in index["frames"]) == [("depth", 3.0), ("points", 99.0)]


def test_recording_into_the_recording_being_replayed_is_refused_and_it_is_kept(tmp_path):
    """Recording a replay into its own folder with overwrite=True deleted the recording's frames
    before the player read them: nothing played, 0 frames recorded, the recording lost."""
    live = LiveCloud()
    live.record(tmp_path / "rec")
    for k in range(3):
        live.push(*patch(k), time=0.1 * k)
    live.stop_recording()
    before = sorted(p.name for p in (tmp_path / "rec" / "frames").iterdir())
    again = LiveCloud()
    player = Player(ReplaySource(tmp_path / "rec"), again, rate=None)
    with pytest.raises(InputError, match=r"rec/?: the recording being replayed \(recording into it would delete its frames\); record into another folder"):
        again.record(str(tmp_path / "rec") + "/", overwrite=True)
    assert again.recorder is None
    assert sorted(p.name for p in (tmp_path / "rec" / "frames").iterdir()) == before == ["000000.npz", "000001.npz", "000002.npz"]
    player.run()
    assert again.n_frames == 3 and player.errors == 0
    again.record(tmp_path / "copy").stop()  # another folder: recorded as usual


def test_replay_plays_at_the_recorded_rate_and_a_frame_written_after_the_index_is_found(tmp_path):
    import time

    live = LiveCloud()
    live.record(tmp_path / "rec").index_every_s = 0.0  # the index rewritten after every frame
    live.push(patch(0)[0], time=5.0)
    live.push(patch(1)[0], time=5.3)
    live.recorder.index_every_s = 1e9  # the index stops being rewritten: the last frame is only on disk
    live.push(patch(2)[0], time=5.6)
    assert len(json.loads((tmp_path / "rec" / "index.json").read_text())["frames"]) == 2
    assert len(recording_files(tmp_path / "rec")) == 3
    again = LiveCloud()
    t0 = time.perf_counter()
    Player(ReplaySource(tmp_path / "rec"), again, rate=2.0).run()
    assert again.n_frames == 3 and time.perf_counter() - t0 >= 0.29  # 0.6 s of stream at twice its rate


def _recorded(folder, times) -> LiveCloud:
    """A cloud (keep=10) that recorded into ``folder`` one ``patch(k)`` frame at each of
    ``times``, its recording stopped."""
    live = LiveCloud(keep=10)
    live.record(folder)
    for k, t in enumerate(times):
        live.push(patch(k)[0], time=float(t))
    live.stop_recording()
    return live


def test_a_damaged_frame_of_a_recording_is_refused_and_the_rest_play(tmp_path):
    """A truncated or overwritten frame file ended the replay: BadZipFile was not one of the
    errors read_frame turned into its one line, so the stream stopped there."""
    _recorded(tmp_path / "rec", range(5))
    files = recording_files(tmp_path / "rec")
    with open(files[1], "r+b") as f:
        f.truncate(50)
    with open(files[3], "r+b") as f:
        f.seek(100)
        f.write(bytes(range(256)) * 2)
    with np.load(files[4]) as z:  # a time of two values: float()'s TypeError stopped the replay (found by a fuzzer)
        np.savez(files[4], **dict(z, time=np.array([4.0, 5.0])))
    frames = list(ReplaySource(tmp_path / "rec").frames())
    assert [type(f).__name__ for f in frames] == ["RecordedFrame", "InputError", "RecordedFrame", "InputError", "InputError"]
    assert str(frames[1]).startswith(f"{files[1]}: not a recorded frame (") and "\n" not in str(frames[3])
    again = LiveCloud(keep=10)
    player = Player(ReplaySource(tmp_path / "rec"), again, rate=None)
    player.run()
    assert player.error is None and player.errors == 3 and [f.time for f in again.frames] == [0.0, 2.0]


def test_a_frame_file_the_index_lists_but_missing_is_refused_as_a_damaged_one_is(tmp_path):
    """A frame file listed in index.json and deleted since was skipped without a word: not in
    stats.frames_rejected, no last_error, where a damaged one was counted and said."""
    _recorded(tmp_path / "rec", range(4))
    files = recording_files(tmp_path / "rec")
    files[1].unlink()
    with open(files[2], "r+b") as f:
        f.truncate(50)
    again = LiveCloud(keep=10)
    player = Player(ReplaySource(tmp_path / "rec"), again, rate=None)
    player.run()
    assert player.error is None and player.errors == 2 and again.stats.frames_rejected == 2 and [f.time for f in again.frames] == [0.0, 3.0]
    frames = list(ReplaySource(tmp_path / "rec").frames())
    assert [type(f).__name__ for f in frames] == ["RecordedFrame", "InputError", "InputError", "RecordedFrame"]
    assert str(frames[1]) == f"{files[1]}: no such file"
    files[3].unlink()  # the last one: the error the HUD shows last
    again = LiveCloud(keep=10)
    Player(ReplaySource(tmp_path / "rec"), again, rate=None).run()
    assert again.stats.frames_rejected == 3 and again.stats.last_error == f"{files[3]}: no such file"


def test_a_junk_file_among_a_recordings_frames_is_said_to_be_no_frame(tmp_path):
    """Files in frames/ that a recording did not write were reported with numpy's reasons: a
    note or an .npy of objects with its pickle message ("This file contains pickled (object)
    data...", "Object arrays cannot be loaded when allow_pickle=False"), an NPZ of one's own
    with "'kind is not a file in the archive'"; the frames around them play."""
    _recorded(tmp_path / "rec", range(2))
    frames = tmp_path / "rec" / "frames"
    (frames / "000005.npz").write_text("my notes on this take\n")
    np.save(frames / "000006.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    (frames / "000006.npy").rename(frames / "000006.npz")
    np.savez(frames / "000007.npz", labels=np.array([{"a": 1}], dtype=object))
    got = list(ReplaySource(tmp_path / "rec").frames())
    assert [f.time for f in got[:2]] == [0.0, 1.0]
    no_archive = "not a recorded frame (not an NPZ archive, which a recording writes)"
    assert [str(e) for e in got[2:]] == [
        f"{frames / '000005.npz'}: {no_archive}",
        f"{frames / '000006.npz'}: {no_archive}",
        f"{frames / '000007.npz'}: not a recorded frame (an NPZ archive without a frame's kind and time)",
    ]


def test_a_damaged_index_reads_only_its_own_frames_and_a_leap_in_time_is_not_waited_for(tmp_path):
    """A recording's index.json whose frame entry was not a file name (5) or whose frames were
    not a list was a TypeError; an entry naming a file outside the recording (/etc/hostname)
    was read as a frame. A frame stamped 1e12 s after the last stalled the replay for good."""
    import time

    _recorded(tmp_path / "rec", (0.0, 0.1, 1e12, 1e12 + 0.1))
    index = tmp_path / "rec" / "index.json"
    meta = json.loads(index.read_text())
    outside = tmp_path / "outside.npz"
    np.savez(outside, kind="points", time=0.5, xyz=np.zeros((3, 3)))
    index.write_text(json.dumps({**meta, "frames": [{"file": 5}, {"file": str(outside)}, {"file": "../outside.npz"}] + meta["frames"]}))
    assert recording_files(tmp_path / "rec") == [tmp_path / "rec" / e["file"] for e in meta["frames"]]
    again = LiveCloud(keep=10)
    player = Player(ReplaySource(tmp_path / "rec"), again, rate=1.0).start()
    t0 = time.perf_counter()
    assert player.join(timeout=30), "the replay stalled at the leap"
    assert time.perf_counter() - t0 < 5 and player.errors == 0 and [f.time for f in again.frames] == [0.0, 0.1, 1e12, 1e12 + 0.1]
    assert re.fullmatch(r".*rec: the time stamps jump 1,000,000,000,000 s ahead at frame 2: played on at once", again.stats.last_error)
    index.write_text(json.dumps({**meta, "frames": 7}))
    with pytest.raises(InputError, match=r"index.json: damaged: its frames are not a list$"):
        ReplaySource(tmp_path / "rec")


def test_a_replay_clears_where_the_recorded_cloud_was_cleared(tmp_path):
    """clear() dropped the live cloud's frames and colour range, but the recording did not mark
    it: the replay kept the frames before the clear and their 0..1 range, so the 0..255 frames
    after it read as white."""
    live = LiveCloud(keep=10)
    rec = live.record(tmp_path / "rec")
    for k in range(2):
        live.push(patch(k)[0], rgb=np.full((500, 3), 0.5), time=float(k))
    live.clear()
    high = patch(7)[0] + np.float32(10.0)  # another height and colour range
    live.push(high, rgb=np.full((500, 3), 100.0), time=2.0)
    live.stop_recording()
    again = LiveCloud(keep=10)
    player = Player(ReplaySource(tmp_path / "rec"), again, rate=None)
    player.run()
    assert player.errors == 0 and player.frames == 3
    assert [f.time for f in again.frames] == [f.time for f in live.frames] == [2.0]
    np.testing.assert_array_equal(cloud_points(again), cloud_points(live))
    assert np.unique(again.frame_points()[1], axis=0).tolist() == np.unique(live.frame_points()[1], axis=0).tolist() == [[100, 100, 100, 255]]
    np.testing.assert_array_equal(again.bounds, live.bounds)
    assert rec.n_frames == 3  # the clear is marked in the index, and is no frame
    kinds = [e["kind"] for e in json.loads((tmp_path / "rec" / "index.json").read_text())["frames"]]
    assert kinds == ["points", "points", "clear", "points"]


def test_a_recording_whose_index_is_not_json_replays_its_frame_files_with_one_warning(tmp_path):
    """An index.json that is not JSON (cut short by a crash, edited by hand) refused the whole
    recording ("unreadable"), though frames/ held every frame; a folder with no frame files, and
    one whose index.json is someone's own JSON, are still no recording."""
    from gigapoint.errors import GigapointWarning

    live = _recorded(tmp_path / "rec", range(3))
    index = tmp_path / "rec" / "index.json"
    index.write_text(index.read_text()[:40])  # cut short
    assert is_recording(tmp_path / "rec")
    with pytest.warns(GigapointWarning) as seen:
        source = open_source(tmp_path / "rec")
    assert isinstance(source, ReplaySource)
    said = [str(w.message) for w in seen]
    assert len(said) == 1 and re.fullmatch(
        rf"{re.escape(str(index))}: damaged, not JSON \(.+\): the frame files in {re.escape(str(tmp_path / 'rec' / 'frames'))} are replayed without it, in name order",
        said[0],
    )
    again = LiveCloud(keep=10)
    player = Player(source, again, rate=None)
    player.run()
    assert player.errors == 0 and [f.time for f in again.frames] == [0.0, 1.0, 2.0]
    np.testing.assert_array_equal(cloud_points(again), cloud_points(live))
    with pytest.raises(InputError, match=r"holds a recording already; pass overwrite=True to replace it$"):
        LiveCloud().record(tmp_path / "rec")  # its frames are not recorded over unasked
    index.write_text('{"pages": [1, 2, 3]}')  # someone's own index.json beside frame files
    assert not is_recording(tmp_path / "rec")
    with pytest.raises(InputError, match=r"index.json: not a gigapoint live recording index$"):
        ReplaySource(tmp_path / "rec")
    index.write_text("{not json")
    for f in (tmp_path / "rec" / "frames").iterdir():
        f.unlink()
    assert not is_recording(tmp_path / "rec")
    with pytest.raises(InputError, match=r"index.json: unreadable \(Expecting property name enclosed in double quotes: line 1 column 2 \(char 1\)\)$"):
        ReplaySource(tmp_path / "rec")


def test_a_folder_with_someones_own_index_json_is_no_recording_and_is_not_overwritten(tmp_path):
    """A recording is known by its index.json's format: a folder holding only a user's own
    index.json counted as one, so overwrite=True replaced that file with a recording's."""
    theirs = tmp_path / "mine"
    theirs.mkdir()
    (theirs / "index.json").write_text('{"pages": [1, 2, 3]}')
    assert not is_recording(theirs)
    live = LiveCloud()
    for overwrite in (False, True):
        not_ours = rf"^{re.escape(str(theirs))}: holds other files, not a gigapoint recording: not overwritten; record into a new or empty folder$"
        with pytest.raises(InputError, match=not_ours):
            live.record(theirs, overwrite=overwrite)
    assert sorted(p.name for p in theirs.iterdir()) == ["index.json"] and json.loads((theirs / "index.json").read_text()) == {"pages": [1, 2, 3]}
    live.record(tmp_path / "rec")  # a recording's own folder is one, and is replaced when asked
    live.push(np.zeros((2, 3)), time=1.0)
    live.stop_recording()
    assert is_recording(tmp_path / "rec")
    LiveCloud().record(tmp_path / "rec", overwrite=True).stop()
    assert json.loads((tmp_path / "rec" / "index.json").read_text())["frames"] == []


def test_recording_into_an_odd_folder(tmp_path, monkeypatch):
    """record(5) was a TypeError, record("") recorded into the current folder; overwrite=True
    deleted the .npz files of a frames/ folder that held no recording, and a folder of other
    files (a Potree octree, someone's frames/000000.npz) was recorded into, its files replaced."""
    live = LiveCloud()
    monkeypatch.chdir(tmp_path)
    for bad in (5, ""):
        with pytest.raises(InputError, match=rf"^record: the recording's folder must be a path, got {re.escape(repr(bad))}$"):
            live.record(bad)
    assert not list(tmp_path.iterdir())
    mine = tmp_path / "work" / "frames"
    mine.mkdir(parents=True)
    np.savez(mine / "000000.npz", a=np.arange(3))
    for overwrite in (False, True):
        with pytest.raises(InputError, match=rf"^{re.escape(str(tmp_path / 'work'))}: holds other files, not a gigapoint recording: not overwritten; record into a new or empty folder$"):
            live.record(tmp_path / "work", overwrite=overwrite)
    assert sorted(p.name for p in (tmp_path / "work").rglob("*")) == ["000000.npz", "frames"]
    np.testing.assert_array_equal(np.load(mine / "000000.npz")["a"], np.arange(3))
    (tmp_path / "empty").mkdir()
    live.record(tmp_path / "empty")  # an empty folder is fine
    live.push(np.zeros((2, 3)))
    live.stop_recording()
    assert (tmp_path / "empty" / "index.json").exists()


def _fill_disk_after(monkeypatch, frames: int) -> list:
    """A disk that fills after ``frames`` frame files: np.savez of the recorder raises ENOSPC
    from then on; the list counts the writes tried."""
    import errno

    from gigapoint.live import record as rec_module

    savez, calls = np.savez, []

    def filling(f, **arrays):
        calls.append(1)
        if len(calls) > frames:
            raise OSError(errno.ENOSPC, "No space left on device")
        savez(f, **arrays)

    monkeypatch.setattr(rec_module.np, "savez", filling)
    return calls


def test_a_full_disk_stops_the_recording_once_and_the_stream_goes_on(tmp_path, monkeypatch):
    """Frame 5 cannot be written (a full disk): every push after raised OSError although its
    frame was in, and index.json listed 40 frames of which 5 existed. Now the recording stops
    with one warning, the pushes go on, and the recording replays the 5 frames written."""
    import errno
    import warnings

    from gigapoint.errors import GigapointWarning
    from gigapoint.live import record as rec_module
    from gigapoint.live.record import read_frame

    live = LiveCloud()
    rec = live.record(tmp_path / "rec")
    savez = np.savez  # (the real one: put back below)
    calls = _fill_disk_after(monkeypatch, 5)
    frames = [patch(k, 50)[0] for k in range(40)]
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        for xyz in frames:
            live.push(xyz)
    said = [str(w.message) for w in seen if issubclass(w.category, GigapointWarning)]
    assert said == [f"{tmp_path / 'rec'}: recording stopped after 5 frames: [Errno 28] No space left on device: '{tmp_path / 'rec' / 'frames' / '000005.npz'}'"]
    assert live.n_points == 40 * 50 and len(calls) == 6  # every frame drawn; no write tried after the failure
    live.stop_recording()
    monkeypatch.setattr(rec_module.np, "savez", savez)
    files = recording_files(tmp_path / "rec")
    assert [f.name for f in files] == [f"{k:06d}.npz" for k in range(5)] and rec.n_frames == 5
    assert len(json.loads((tmp_path / "rec" / "index.json").read_text())["frames"]) == 5
    for k, f in enumerate(files):
        np.testing.assert_array_equal(read_frame(f).xyz, frames[k])
    assert not [p for p in (tmp_path / "rec" / "frames").iterdir() if p.name.startswith(".")]  # no temporary left
    # a replay plays the 5 frames and then says the recording was cut short (it looked whole)
    replay = LiveCloud()
    player = Player(ReplaySource(tmp_path / "rec"), replay, rate=None)
    player.run()
    assert player.frames == 5 and replay.n_points == 5 * 50
    assert replay.stats.last_error == f"{tmp_path / 'rec'}: the recording ends early: {said[0]}"

    def no_room(path, obj, **kw):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    json_writer = rec_module.atomic_json
    monkeypatch.setattr(rec_module, "atomic_json", no_room)  # not even the index: refused in one line, nothing left behind
    with pytest.raises(InputError, match=rf"^{re.escape(str(tmp_path / 'new'))}: cannot record into it: \[Errno 28\] No space left on device"):
        live.record(tmp_path / "new")
    assert not (tmp_path / "new").exists()
    monkeypatch.setattr(rec_module, "atomic_json", json_writer)
    live.record(tmp_path / "new")  # once there is room
    live.stop_recording()
    assert (tmp_path / "new" / "index.json").is_file()


def test_a_recording_stopped_after_a_clear_counts_its_frames_not_the_clear(tmp_path, monkeypatch):
    """push, clear(), push, then a full disk: said 'stopped after 3 frames' (the clear's file
    counted) while n_frames was 2."""
    import warnings

    from gigapoint.errors import GigapointWarning

    live = LiveCloud()
    rec = live.record(tmp_path / "rec")
    _fill_disk_after(monkeypatch, 3)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        live.push(patch(0, 10)[0])
        live.clear()
        live.push(patch(1, 10)[0])
        live.push(patch(2, 10)[0])
    said = [str(w.message) for w in seen if issubclass(w.category, GigapointWarning)]
    assert said == [f"{tmp_path / 'rec'}: recording stopped after 2 frames: [Errno 28] No space left on device: '{tmp_path / 'rec' / 'frames' / '000003.npz'}'"]
    assert rec.n_frames == 2
    live.stop_recording()


def test_a_recording_stopped_after_one_frame_says_1_frame(tmp_path, monkeypatch):
    """A full disk at the second frame said 'stopped after 1 frames'."""
    import warnings

    from gigapoint.errors import GigapointWarning

    live = LiveCloud()
    live.record(tmp_path / "rec")
    _fill_disk_after(monkeypatch, 1)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        live.push(patch(0, 10)[0])
        live.push(patch(1, 10)[0])
    said = [str(w.message) for w in seen if issubclass(w.category, GigapointWarning)]
    assert said == [f"{tmp_path / 'rec'}: recording stopped after 1 frame: [Errno 28] No space left on device: '{tmp_path / 'rec' / 'frames' / '000001.npz'}'"]
    live.stop_recording()


def test_not_a_recording(tmp_path):
    with pytest.raises(InputError, match="not a live recording"):
        ReplaySource(tmp_path)
    with pytest.raises(InputError, match=r"missing: no such folder \(a live recording: a folder with index.json\)$"):
        ReplaySource(tmp_path / "missing")  # said "not a live recording (no index.json)"
    with pytest.raises(InputError, match="no such file"):
        open_source(tmp_path / "missing")


# ---------------------------------------------------------------------- pushed frames (wire format)
def test_wire_round_trip_and_malformed_messages():
    xyz, rgb = patch(4)
    pose = np.eye(4)
    pose[0, 3] = 3
    f = decode_frame(encode_frame("points", xyz=xyz, rgb=rgb, pose=pose, time=1.5))
    np.testing.assert_array_equal(f.xyz, xyz)
    np.testing.assert_array_equal(f.rgb, rgb)
    np.testing.assert_array_equal(f.pose, pose)
    assert f.time == 1.5
    d = decode_frame(encode_frame("depth", depth=np.ones((3, 4), np.uint16), intrinsics=(1, 1, 1, 1), depth_scale=0.01))
    assert d.kind == "depth" and d.depth_scale == 0.01
    good = encode_frame("points", xyz=xyz)
    bad = [
        b"nope",
        good[:-5],  # cut short mid-frame
        good + b"xx",
        encode_frame("mesh", xyz=xyz),
        encode_frame("points", rgb=rgb),
        encode_frame("points", xyz=xyz, depth=np.ones(3)),
        b"GPL1" + (5).to_bytes(4, "little") + b"{oops",
        "text",
    ]
    for shape in ([2**62, 4], [1e20, 3], [0, 2**63]):  # numpy's int64 product wrapped or overflowed: a ValueError, the producer's connection lost
        head = json.dumps({"type": "points", "arrays": [{"name": "xyz", "dtype": "<f8", "shape": shape}]}).encode()
        bad.append(b"GPL1" + len(head).to_bytes(4, "little") + head + bytes(24))
    for message in bad:
        with pytest.raises(InputError) as err:
            decode_frame(message)
        assert "\n" not in str(err.value) and str(err.value).startswith("push:")
    live = LiveCloud()
    with pytest.raises(GigapointError, match="intrinsics are missing"):
        decode_frame(encode_frame("depth", depth=np.ones((3, 4), np.uint16))).push_into(live)
    RecordedFrame("points", 0.0, None, xyz=xyz).push_into(live)
    assert live.n_frames == 1


def test_a_source_that_breaks_stops_the_player_with_one_line():
    from gigapoint.live.sources import Source

    class Broken(Source):
        name = "broken"

        def frames(self):
            yield RecordedFrame("points", 0.0, None, xyz=np.zeros((3, 3)))
            raise ZeroDivisionError("boom\nmore")

    live = LiveCloud()
    player = Player(Broken(), live, rate=None)
    player.run()
    assert live.n_frames == 1 and player.done.is_set()
    assert str(player.error) == "broken: the stream stopped (ZeroDivisionError: boom)"


@pytest.mark.parametrize(("kw", "problem"), [
    ({"rate": 0}, "rate must be a positive number (times the stream's speed) or None (as fast as frames come), got 0"),
    ({"rate": -2.0}, "rate must be a positive number (times the stream's speed) or None (as fast as frames come), got -2.0"),
    ({"rate": float("nan")}, "rate must be a positive number (times the stream's speed) or None (as fast as frames come), got nan"),
    ({"rate": "fast"}, "rate must be a positive number (times the stream's speed) or None (as fast as frames come), got 'fast'"),
    ({"loop": "no"}, "loop must be True or False, got 'no'"),
])  # fmt: skip
def test_a_player_refuses_odd_rates_in_one_line(kw, problem):
    """rate 0, -2 and NaN played as fast as frames came, without a word; 'fast' stopped the
    stream at its second frame with a TypeError; loop='no' looped."""
    from gigapoint.live.sources import Source

    class Nothing(Source):
        name = "nothing"

        def frames(self):
            return iter(())

    live = LiveCloud()
    with pytest.raises(InputError, match=re.escape(problem)):
        Player(Nothing(), live, **kw)
    assert live.player is None


@pytest.mark.parametrize("then", ["join", "snapshot", "close"])
def test_a_warning_on_the_player_s_thread_reaches_the_caller_at_its_next_call(tmp_path, then):
    """The cloud's "frames arrive faster" (said by the push of the player's thread) went through
    Python's machinery from that thread: past the caller's catch, at any moment. Now kept, as the
    player's errors are, and issued by ``player.join`` (or the cloud's snapshot, save, close) at the caller's line."""
    import warnings

    from gigapoint.errors import GigapointWarning

    for k in range(3):
        np.save(tmp_path / f"{k}.npy", patch(k)[0])
    live = LiveCloud(keep=1, name="cam")
    with warnings.catch_warnings(record=True) as meanwhile:
        warnings.simplefilter("always")
        with live.reading():  # the lock held: frames wait for it, the oldest dropped
            player = Player(FramesDir(tmp_path), live, rate=None).start()
            assert player.done.wait(30)
    assert meanwhile == [] and live.stats.frames_dropped == 2 and len(live.warnings) == 1
    with pytest.warns(GigapointWarning, match="^cam: frames arrive faster than they are copied into the ring") as caught:
        {"join": player.join, "snapshot": live.snapshot, "close": live.close}[then]()
    assert [w.filename for w in caught] == [__file__]
    live.close()
