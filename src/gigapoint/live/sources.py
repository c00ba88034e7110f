"""Streams of frames for a LiveCloud, and the Player that feeds one into it at the stream's rate.

Every source yields ``RecordedFrame``s (record.py: points in sensor coordinates or a depth
image, with a pose and a time stamp):

- ``SyntheticSensor``: a deterministic depth sensor (512x424, Kinect v2 intrinsics) flying
  through the demo town (io/demo.py): each frame is the town's points projected into a
  z-buffer from a pose that is a pure function of the frame number;
- ``FramesDir``: a folder of point files (PLY through plyfile, PCD through pypcd4, NPY);
- ``TumSequence``: a TUM RGB-D sequence (``rgb/`` and ``depth/`` PNGs, ``rgb.txt``,
  ``depth.txt``, an optional association file, ``groundtruth.txt`` poses);
- ``BagSource``: ``sensor_msgs/PointCloud2`` messages of a ROS 1 ``.bag`` or a ROS 2 bag
  folder, through rosbags;
- ``ReplaySource``: a recording made by ``LiveCloud.record``.

``open_source(spec)`` picks one; ``Player(source, live).start()`` plays it from a thread. A
bad frame (one-line GigapointError) is counted and skipped: the stream goes on.
"""

from __future__ import annotations

import io
import math
import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numba import njit

from ..errors import GigapointError, InputError, check_switch, first_line, is_real, keep_warnings
from ..io._base import unpack_rgb
from ..io.http import as_url, shown_url
from .record import RecordedFrame, is_recording, read_frame, recording_files, stopped_early

KINECT_V2 = (365.5, 365.5, 256.0, 212.0)  # fx, fy, cx, cy of a Kinect v2's 512x424 depth camera
TUM_DEFAULT = (525.0, 525.0, 319.5, 239.5)  # the TUM benchmark's default (ROS) intrinsics
TUM_DEPTH_SCALE = 1.0 / 5000.0  # TUM depth PNGs: 5000 units a metre


class Source:
    """A stream of frames (``frames()``); ``name`` for messages."""

    name = "source"
    rate_hz: float | None = None  # frames per second when frames carry no useful time stamps

    def frames(self) -> Iterator[RecordedFrame]:
        raise NotImplementedError

    def __iter__(self):
        return self.frames()


# ---------------------------------------------------------------------- the synthetic sensor
@njit(cache=True)
def project_depth(xyz, rgba, world_to_cam, fx, fy, cx, cy, spacing, max_depth, depth, rgb):
    """Z-buffer the points into ``depth`` (float32 metres, 0 = nothing) and ``rgb``: each point a
    square splat of the size its spacing has at its distance (so a sampled surface closes)."""
    h, w = depth.shape
    for v in range(h):
        for u in range(w):
            depth[v, u] = np.inf
    for i in range(xyz.shape[0]):
        x = world_to_cam[0, 0] * xyz[i, 0] + world_to_cam[0, 1] * xyz[i, 1] + world_to_cam[0, 2] * xyz[i, 2] + world_to_cam[0, 3]
        y = world_to_cam[1, 0] * xyz[i, 0] + world_to_cam[1, 1] * xyz[i, 1] + world_to_cam[1, 2] * xyz[i, 2] + world_to_cam[1, 3]
        z = world_to_cam[2, 0] * xyz[i, 0] + world_to_cam[2, 1] * xyz[i, 1] + world_to_cam[2, 2] * xyz[i, 2] + world_to_cam[2, 3]
        if z < 0.5 or z > max_depth:
            continue
        pu = fx * x / z + cx
        pv = fy * y / z + cy
        r = min(int(0.6 * fx * spacing / z), 6)
        iu = math.floor(pu)
        iv = math.floor(pv)
        if iu + r < 0 or iu - r >= w or iv + r < 0 or iv - r >= h:
            continue
        zf = np.float32(z)
        for vv in range(max(iv - r, 0), min(iv + r + 1, h)):
            for uu in range(max(iu - r, 0), min(iu + r + 1, w)):
                if zf < depth[vv, uu]:
                    depth[vv, uu] = zf
                    for c in range(3):
                        rgb[vv, uu, c] = rgba[i, c]
    for v in range(h):
        for u in range(w):
            if depth[v, u] == np.inf:
                depth[v, u] = 0.0


def look_pose(eye, forward) -> np.ndarray:
    """Sensor -> world 4x4 of a camera at ``eye`` looking along ``forward`` (OpenCV axes: x right,
    y down, z forward; world z up)."""
    f = np.asarray(forward, np.float64)
    f = f / np.linalg.norm(f)
    right = np.cross(f, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(f, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, down, f, eye
    return pose


def _frame_rate(where: str, fps) -> float:
    """``fps`` as a positive float: 0 was a ZeroDivisionError in the player's thread ("the stream
    stopped"), "10" a ValueError, -10 and NaN played every frame at once."""
    if not (is_real(fps) and fps > 0):
        raise InputError(f"{where}: fps must be a positive number of frames a second, got {fps!r}")
    return float(fps)


class SyntheticSensor(Source):
    """A depth camera circling the demo town at ``altitude`` metres, ``fps`` frames a second
    (frame k's pose and image are pure functions of k and ``seed``: deterministic)."""

    def __init__(self, n_frames: int | None = None, fps: float = 30.0, width: int = 512, height: int = 424, scene_points: int = 1_000_000,
                 seed: int = 0, altitude: float = 60.0, radius: float = 300.0, speed: float = 12.0, max_depth: float = 300.0):  # fmt: skip
        if n_frames is not None and n_frames < 0:
            raise InputError(f"synthetic sensor: n_frames must be >= 0, got {n_frames}")
        self.name = f"synthetic sensor ({width}x{height}, demo town)"
        self.n_frames, self.rate_hz, self.width, self.height = n_frames, _frame_rate(self.name, fps), int(width), int(height)
        self.altitude, self.radius, self.speed, self.max_depth = altitude, radius, speed, max_depth
        s = width / 512.0
        self.intrinsics = (KINECT_V2[0] * s, KINECT_V2[1] * s, (width - 1) / 2.0, (height - 1) / 2.0)
        from ..io.demo import SCENE_SIZE, demo_arrays

        self.centre = np.array([SCENE_SIZE / 2, SCENE_SIZE / 2])
        self.xyz, self.rgba, _ = demo_arrays(scene_points, seed)
        self.spacing = SCENE_SIZE / math.sqrt(max(scene_points, 1))

    def pose(self, k: int) -> np.ndarray:
        t = k / self.rate_hz
        a = t * self.speed / self.radius  # around the centre at ``speed`` m/s
        eye = np.array([*(self.centre + self.radius * np.array([math.cos(a), math.sin(a)])), self.altitude])
        heading = np.array([-math.sin(a), math.cos(a)])
        forward = np.array([*(heading * math.cos(math.radians(35))), -math.sin(math.radians(35))])  # 35 degrees down
        return look_pose(eye, forward)

    def render(self, k: int) -> RecordedFrame:
        pose = self.pose(k)
        depth = np.empty((self.height, self.width), np.float32)
        rgb = np.zeros((self.height, self.width, 3), np.uint8)
        fx, fy, cx, cy = self.intrinsics
        project_depth(self.xyz, self.rgba, np.linalg.inv(pose), fx, fy, cx, cy, self.spacing, self.max_depth, depth, rgb)
        return RecordedFrame("depth", k / self.rate_hz, pose, rgb=rgb, depth=depth, intrinsics=np.array(self.intrinsics), depth_scale=1.0)

    def frames(self):
        k = 0
        while self.n_frames is None or k < self.n_frames:
            yield self.render(k)
            k += 1


# ---------------------------------------------------------------------- folders of frames
FRAME_SUFFIXES = (".ply", ".pcd", ".npy")


def _xyz_rgb_of_table(path, names, column):
    lower = {n.lower(): n for n in names}
    if not all(a in lower for a in "xyz"):
        raise InputError(f"{path}: no x, y, z fields (has {', '.join(names)})")
    xyz = np.stack([np.asarray(column(lower[a]), np.float64) for a in "xyz"], axis=1)
    rgb = None
    for r, g, b in (("red", "green", "blue"), ("r", "g", "b")):
        if all(c in lower for c in (r, g, b)):
            rgb = np.stack([np.asarray(column(lower[c])) for c in (r, g, b)], axis=1)
            break
    name = lower.get("rgb", lower.get("rgba"))  # PCL's packed float/u32 rgb, or rgba (PointXYZRGBA: its colour was dropped)
    if rgb is None and name is not None:
        rgb = unpack_rgb(column(name))
    return xyz, rgb


def _pcl_ascii_colors(data: bytes, names: list[str], arr: np.ndarray) -> np.ndarray | None:
    """The packed colours of an ASCII PCD's float ``rgb``/``rgba`` field as PCL writes them, or
    None: PCL writes that float's 32 bits as an integer there (pcd_io.cpp: a colour's bits can
    be a NaN), which pypcd4 reads as a float32 number (rounding 0xFFRRGGBB), and its bits were
    every colour wrong. Integers are read again exactly from the column of the file's ``data``."""
    name = next((n for n in names if n.lower() in ("rgb", "rgba")), None)
    if name is None or arr.dtype[name].kind != "f" or not len(arr):
        return None
    lines = data.splitlines()
    data = next((k for k, line in enumerate(lines) if line.startswith(b"DATA")), None)
    if data is None or lines[data].split()[1:] != [b"ascii"]:
        return None
    values = np.loadtxt(lines[data + 1 :], usecols=names.index(name), dtype=np.float64, ndmin=1)
    if not ((values >= 0) & (values < 2**32) & (values == np.round(values))).all():
        return None  # the float's own values (a NaN or a fraction: not PCL's integers)
    return values.astype(np.uint32)


def read_points_file(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(xyz, rgb or None) of one frame file: PLY (plyfile), PCD (pypcd4), NPY ((N, 3|6) or structured)."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".ply":
            from plyfile import PlyData

            v = PlyData.read(str(path))["vertex"].data
            return _xyz_rgb_of_table(path, list(v.dtype.names), lambda n: v[n])
        if suffix == ".pcd":
            try:
                from pypcd4 import PointCloud
            except ImportError:
                raise InputError(f"{path}: reading PCD needs pypcd4 (pip install 'gigapoint[live]')") from None
            data = path.read_bytes()  # read once: pypcd4 parses it, and an ASCII file's colours are taken from it again
            arr = PointCloud.from_fileobj(io.BytesIO(data)).pc_data
            names = list(arr.dtype.names)
            ints = _pcl_ascii_colors(data, names, arr)
            return _xyz_rgb_of_table(path, names, lambda n: ints if ints is not None and n.lower() in ("rgb", "rgba") else arr[n])
        if suffix == ".npy":
            a = np.load(path, allow_pickle=False)
            if a.dtype.names:
                return _xyz_rgb_of_table(path, list(a.dtype.names), lambda n: a[n])
            if a.ndim == 2 and a.shape[1] in (3, 6) and a.dtype.kind in "uif":
                return a[:, :3].astype(np.float64), (a[:, 3:6] if a.shape[1] == 6 else None)
            raise InputError(f"{path}: an NPY frame must be (N, 3), (N, 6) or a structured array with x, y, z; got {a.shape} {a.dtype}")
    except GigapointError:
        raise
    except Exception as exc:  # noqa: BLE001 - a library's error on a bad file: one line naming it
        raise InputError(f"{path}: unreadable {suffix[1:].upper()} frame ({first_line(exc)})") from None
    raise InputError(f"{path}: not a frame file ({', '.join(FRAME_SUFFIXES)})")


class FramesDir(Source):
    """Every .ply/.pcd/.npy file of a folder, in name order, one frame each, at ``fps``."""

    def __init__(self, path, fps: float = 10.0):
        self.path = Path(path)
        self.name = str(self.path)
        self.rate_hz = _frame_rate(self.name, fps)
        self.files = sorted(p for p in self.path.iterdir() if p.suffix.lower() in FRAME_SUFFIXES and p.is_file())
        if not self.files:
            raise InputError(f"{self.path}: no frame files ({', '.join(FRAME_SUFFIXES)})")

    def frames(self):
        for k, p in enumerate(self.files):
            try:
                xyz, rgb = read_points_file(p)
            except GigapointError as exc:
                yield exc  # the Player counts it and goes on
                continue
            yield RecordedFrame("points", k / self.rate_hz, None, xyz=xyz, rgb=rgb, origin=str(p))


# ---------------------------------------------------------------------- TUM RGB-D
def _stamped_lines(path: Path) -> list[list[str]]:
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:  # (a byte of binary junk in groundtruth.txt was a UnicodeDecodeError, a traceback)
        raise InputError(f"{path}: not a readable text file ({first_line(exc)})") from None
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            out.append(line.split())
    return out


def _timed_files(path: Path) -> list[tuple[float, str]]:
    """(time, file) of each line of a TUM list (``rgb.txt``, ``depth.txt``)."""
    try:
        return [(float(r[0]), r[1]) for r in _stamped_lines(path)]
    except (ValueError, IndexError):  # ("abc" was float()'s ValueError, a line of one column an IndexError)
        raise InputError(f"{path}: lines must be 'timestamp file'") from None


def quaternion_pose(t, q) -> np.ndarray:
    """4x4 from a translation and a unit quaternion (qx, qy, qz, qw)."""
    x, y, z, w = (float(v) for v in q)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if n == 0 or not math.isfinite(n):
        raise InputError(f"quaternion {q} is not a rotation")
    x, y, z, w = x / n, y / n, z / n, w / n
    pose = np.eye(4)
    pose[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    pose[:3, 3] = [float(v) for v in t]
    if not np.isfinite(pose[:3, 3]).all():  # (NaN was refused frame by frame, naming no file)
        raise InputError(f"translation {list(t)} is not finite")
    return pose


def _image(path: Path, mode: str | None = None) -> np.ndarray:
    """An image file's pixels (``mode``: Pillow's conversion first); a file Pillow cannot read is
    a one-line InputError naming it. Pillow raises OSError, ValueError ("Truncated IHDR chunk"),
    SyntaxError or DecompressionBombError on bad files (the ValueError stopped a TUM replay; an
    unreadable colour image was reported as its depth image)."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert(mode) if mode else im)
    except Exception as exc:  # noqa: BLE001 - Pillow's errors on a bad file: one line naming it
        raise InputError(f"{path}: unreadable image ({first_line(exc)})") from None


def _nearest(times: np.ndarray, t: float, limit: float) -> int | None:
    if not len(times):
        return None
    k = int(np.searchsorted(times, t))
    best = min((j for j in (k - 1, k) if 0 <= j < len(times)), key=lambda j: abs(times[j] - t))
    return best if abs(times[best] - t) <= limit else None


class TumSequence(Source):
    """A TUM RGB-D sequence folder: depth (and rgb) PNGs paired by an association file
    (``associations.txt``/``associate.txt``: ``t_rgb rgb/... t_depth depth/...``) or by nearest
    time stamps (within 20 ms), posed by ``groundtruth.txt`` (``t tx ty tz qx qy qz qw``, the
    nearest within 20 ms; frames without a pose are skipped, and if every frame is, that is
    one error at the end). Without ``groundtruth.txt`` the frames are drawn where the sensor
    saw them (its own frame: a camera that stood still)."""

    def __init__(self, path, intrinsics=TUM_DEFAULT, depth_scale: float = TUM_DEPTH_SCALE, max_dt: float = 0.02):
        self.path = Path(path)
        self.name = str(self.path)
        self.intrinsics, self.depth_scale, self.max_dt = intrinsics, depth_scale, max_dt
        pairs = self._pairs()
        gt = self.gt_file = self.path / "groundtruth.txt"
        self.posed = gt.is_file()  # (without it every frame was skipped: nothing played, without a word)
        rows = _stamped_lines(gt) if self.posed else []
        try:
            self.gt_times = np.array([float(r[0]) for r in rows])
            self.gt_poses = [quaternion_pose(r[1:4], r[4:8]) for r in rows]
        except (ValueError, IndexError):
            raise InputError(f"{gt}: lines must be 'timestamp tx ty tz qx qy qz qw'") from None
        except InputError as exc:  # (a quaternion of zeros: the message named no file)
            raise InputError(f"{gt}: {exc}") from None
        if not pairs:
            raise InputError(f"{self.path}: a TUM RGB-D sequence that lists no depth image")
        self.pairs = pairs

    def _pairs(self) -> list[tuple[float, str, str | None]]:
        for name in ("associations.txt", "associate.txt", "association.txt"):
            f = self.path / name
            if f.is_file():
                try:
                    rows = _stamped_lines(f)
                    return [(float(r[2]), r[3], r[1]) if r[1].startswith("rgb") else (float(r[0]), r[1], r[3]) for r in rows]
                except (ValueError, IndexError):
                    raise InputError(f"{f}: lines must be 'time rgb/file time depth/file'") from None
        depth_txt = self.path / "depth.txt"
        if not depth_txt.is_file():
            raise InputError(f"{self.path}: not a TUM RGB-D sequence (no depth.txt or association file)")
        depth = _timed_files(depth_txt)
        rgb_txt = self.path / "rgb.txt"
        rgb = _timed_files(rgb_txt) if rgb_txt.is_file() else []
        rgb_times = np.array([t for t, _ in rgb])
        out = []
        for t, f in depth:
            k = _nearest(rgb_times, t, self.max_dt)
            out.append((t, f, rgb[k][1] if k is not None else None))
        return out

    def frames(self):
        posed = 0
        for t, depth_file, rgb_file in self.pairs:
            k = _nearest(self.gt_times, t, self.max_dt) if self.posed else None
            if k is None and self.posed:
                continue
            posed += 1
            try:
                depth = _image(self.path / depth_file)
                rgb = _image(self.path / rgb_file, "RGB") if rgb_file else None
            except InputError as exc:
                yield exc
                continue
            if rgb is not None and rgb.shape[:2] != depth.shape[:2]:
                rgb = None
            yield RecordedFrame("depth", t, self.gt_poses[k] if k is not None else None, rgb=rgb, depth=depth,
                                intrinsics=np.array(self.intrinsics, np.float64), depth_scale=self.depth_scale,
                                origin=str(self.path / depth_file))  # fmt: skip
        if not posed:
            yield InputError(f"{self.gt_file}: no depth image has a pose within {self.max_dt * 1000:g} ms of its time stamp: nothing to place")


# ---------------------------------------------------------------------- ROS bags
_PF_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}  # sensor_msgs/PointField datatypes


def pointcloud2_arrays(msg) -> tuple[np.ndarray, np.ndarray | None]:
    """(xyz float64 (N, 3), rgb uint8 (N, 3) or None) of a sensor_msgs/PointCloud2 message."""
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if f.datatype not in _PF_TYPES:
            raise InputError(f"PointCloud2 field {f.name!r}: unknown datatype {f.datatype}")
        if f.count != 1:
            continue
        names.append(f.name)
        formats.append((">" if msg.is_bigendian else "<") + _PF_TYPES[f.datatype])
        offsets.append(f.offset)
    step = int(msg.point_step)
    n = int(msg.width) * int(msg.height)
    data = np.asarray(msg.data, np.uint8)
    if step <= 0 or len(data) < n * step or (msg.height > 1 and msg.row_step * msg.height > len(data)):
        raise InputError(f"PointCloud2: {len(data)} data bytes for {n} points of {step} bytes")
    try:
        dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    except ValueError as exc:
        raise InputError(f"PointCloud2: bad field layout ({exc})") from None
    if msg.height > 1 and msg.row_step != msg.width * step:
        rows = data[: msg.row_step * msg.height].reshape(msg.height, msg.row_step)[:, : msg.width * step]
        data = np.ascontiguousarray(rows).reshape(-1)
    arr = np.frombuffer(data[: n * step].tobytes(), dtype)
    xyz, rgb = _xyz_rgb_of_table("PointCloud2", names, lambda k: arr[k])
    return xyz, rgb


class BagSource(Source):
    """``sensor_msgs/PointCloud2`` messages of a ROS 1 bag file or ROS 2 bag folder (rosbags), on
    ``topic`` (default: every PointCloud2 topic). Time stamps from the message headers."""

    POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"

    def __init__(self, path, topic: str | None = None):
        try:
            from rosbags.highlevel import AnyReader  # noqa: F401
        except ImportError:
            raise InputError(f"{path}: reading ROS bags needs rosbags (pip install 'gigapoint[live]')") from None
        self.path = Path(path)
        self.name = str(self.path)
        self.topic = topic

    def frames(self):
        from rosbags.highlevel import AnyReader

        try:
            reader = AnyReader([self.path])
            reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags' own errors: one line naming the bag
            raise InputError(f"{self.path}: not a readable ROS bag ({first_line(exc)})") from None
        try:
            conns = [c for c in reader.connections if self.topic is None or c.topic == self.topic]
            if self.topic is not None and not conns:
                raise InputError(f"{self.path}: no topic {self.topic!r} (has {', '.join(sorted({c.topic for c in reader.connections}))})")
            for c in conns:
                if c.msgtype != self.POINTCLOUD2 and self.topic is not None:
                    raise InputError(f"{self.path}: topic {c.topic} holds {c.msgtype}, not sensor_msgs/PointCloud2")
            clouds = [c for c in conns if c.msgtype == self.POINTCLOUD2]
            if not clouds:
                raise InputError(f"{self.path}: no sensor_msgs/PointCloud2 messages")
            for conn, stamp, raw in reader.messages(connections=clouds):
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                    xyz, rgb = pointcloud2_arrays(msg)
                    t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
                    if t == 0:
                        t = stamp * 1e-9
                except GigapointError as exc:
                    yield InputError(f"{self.path}: message at {stamp}: {exc}")
                    continue
                except Exception as exc:  # noqa: BLE001
                    yield InputError(f"{self.path}: message at {stamp} is not a PointCloud2 ({first_line(exc)})")
                    continue
                yield RecordedFrame("points", t, None, xyz=xyz, rgb=rgb, origin=f"{self.path}: message at {stamp}")
        finally:
            reader.close()


# ---------------------------------------------------------------------- recordings
class ReplaySource(Source):
    """A recording made by ``LiveCloud.record`` (record.py), frame by frame with its times."""

    def __init__(self, path):
        self.path = Path(path)
        self.name = str(self.path)
        self.files = recording_files(self.path)
        self.stopped_early = stopped_early(self.path)

    def frames(self):
        for p in self.files:
            try:
                yield read_frame(p)
            except GigapointError as exc:
                yield exc
        if self.stopped_early:  # said once its frames are played, as a bad frame is (the HUD's last line)
            yield InputError(f"{self.path}: the recording ends early: {self.stopped_early}")


def open_source(spec, **options) -> Source:
    """A source from a name or path: ``demo``/``synthetic`` (the synthetic sensor), a recording
    folder, a ROS bag (``.bag`` file or a folder with ``metadata.yaml``), a TUM RGB-D sequence
    folder, or a folder of frame files."""
    if str(spec) in ("demo", "synthetic"):
        return SyntheticSensor(**options)
    if not isinstance(spec, str | os.PathLike) or not os.fspath(spec).strip():  # "" played the current folder's files; 5 was a TypeError
        raise InputError(f"live: a source is demo, a recording, a bag, a TUM sequence or a folder of frames, got {spec!r}")
    if as_url(spec) is not None:  # (said as 'http:/host/x.bag: no such file')
        raise InputError(f"{shown_url(spec)}: live sources are read from this machine's files, not from URLs")
    path = Path(spec)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder (a live source: demo, a recording, a bag, a TUM sequence or a folder of frames)")
    if path.is_dir() and is_recording(path):
        return ReplaySource(path)
    if path.suffix == ".bag" or path.suffix == ".mcap" or (path.is_dir() and (path / "metadata.yaml").is_file()):
        return BagSource(path, **options)
    if path.is_dir() and any((path / n).is_file() for n in ("depth.txt", "associations.txt", "associate.txt")):
        return TumSequence(path, **options)
    if path.is_dir():
        return FramesDir(path, **options)
    raise InputError(f"{path}: not a live source (a recording, a .bag, a TUM sequence or a folder of frames)")


MAX_WAIT_S = 60.0  # the longest pause between two frames a Player keeps: a longer one is played on at once, and said


class Player:
    """Plays a source into a LiveCloud from a thread, at the stream's rate (``rate`` times its
    time stamps; None: as fast as frames come). Bad frames are counted and skipped; a pause of
    more than MAX_WAIT_S between two frames is not waited for (the HUD says so)."""

    def __init__(self, source: Source, live, rate: float | None = 1.0, loop: bool = False):
        # 0, -2 and NaN played as fast as frames came, without a word; "fast" broke the stream at its second frame
        if rate is not None and not (is_real(rate) and rate > 0):
            raise InputError(f"{source.name}: Player: rate must be a positive number (times the stream's speed) or None (as fast as frames come), got {rate!r}")
        check_switch("loop", loop, f"{source.name}: Player")  # "no" looped
        self.source, self.live, self.rate, self.loop = source, live, rate, loop
        self.frames = 0
        self.errors = 0
        self.error: GigapointError | None = None  # the error that ended the stream (not a bad frame)
        self.done = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run_keeping, name="gigapoint-live-player", daemon=True)
        live.player = self

    def start(self) -> Player:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def join(self, timeout: float | None = None) -> bool:
        """Until the stream ends (True) or ``timeout`` passes; issues the warnings its thread kept."""
        done = self.done.wait(timeout)
        self.live.warnings.issue()
        return done

    def run(self) -> None:
        """Play in this thread."""
        self._run()

    def _run_keeping(self) -> None:
        # its thread's warnings (a frame's, the cloud's "frames arrive faster") kept, as its errors are, for
        # the user's thread: join, the cloud's snapshot, save and close issue them (Python's filters and
        # catches are process-wide: issued here, they escaped a caller's catch and printed at any moment)
        keep_warnings(self.live.warnings)
        self._run()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self._play_once()
                if not self.loop:
                    break
        except GigapointError as exc:
            self.error = exc
            self.live.stats.last_error = str(exc)
        except Exception as exc:  # noqa: BLE001 - a reader's bug or a library's error must not end the thread silently
            self.error = GigapointError(f"{self.source.name}: the stream stopped ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})")
            self.live.stats.last_error = str(self.error)
        finally:
            self.done.set()

    def _play_once(self) -> None:
        t0_wall = t0_stream = last_stamp = None
        for k, frame in enumerate(self.source.frames()):
            if self._stop.is_set():
                return
            if isinstance(frame, GigapointError):
                self.errors += 1
                self.live.refused(frame)
                continue
            if self.rate:
                stamp = frame.time if self.source.rate_hz is None else k / self.source.rate_hz
                if t0_wall is not None and (stamp - last_stamp) / self.rate > MAX_WAIT_S:
                    # a clock reset or a damaged stamp: a frame 1e12 s on stalled the stream for good, without a word
                    self.live.stats.last_error = f"{self.source.name}: the time stamps jump {stamp - last_stamp:,.0f} s ahead at frame {k}: played on at once"
                    t0_wall = None
                if t0_wall is None:
                    t0_wall, t0_stream = time.perf_counter(), stamp
                last_stamp = stamp
                wait = (stamp - t0_stream) / self.rate - (time.perf_counter() - t0_wall)
                if wait > 0 and self._stop.wait(wait):
                    return
            try:
                frame.push_into(self.live)
                self.frames += frame.kind != "clear"  # (a clear is no frame)
            except GigapointError as exc:
                self.errors += 1  # counted by the cloud too (stats.frames_rejected)
                # which file or message (the cloud's message named only itself: "live: push: the frame has no points")
                self.live.stats.last_error = f"{frame.origin or f'{self.source.name}: frame {k}'}: {exc}"
