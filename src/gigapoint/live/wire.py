"""Frames pushed into a running viewer from another process, over the viewer's ``/push`` WebSocket.

A message is binary: ``b"GPL1"``, a u32 little-endian header length, a JSON header, then the
arrays' raw bytes one after the other. The header says the frame's kind (``points`` or
``depth``), each array's dtype and shape (whole numbers; in order, each array once), and the
pose (16 numbers, row-major), time, intrinsics ((fx, fy, cx, cy), or a 3x3 matrix: 9 numbers
row-major or nested) and depth scale. ``decode_frame`` checks every part against the bytes it
got and raises a one-line InputError on anything else (the server answers it and keeps the
stream going). ``PushClient`` (websockets' sync client) sends frames and reads each answer.
"""

from __future__ import annotations

import json
import math
import struct

import numpy as np

from ..errors import GigapointError, InputError, first_line
from .record import RecordedFrame

MAGIC = b"GPL1"
MAX_PUSH_BYTES = 64 << 20  # one pushed frame (a 512x424 float32 depth image is 0.9 MB; 1 M float32 points 12 MB)
_DTYPES = {"<f4", "<f8", "<u1", "<u2", "<u4", "<i1", "<i2", "<i4", "|u1", "|i1", "<u8", "<i8"}
_ARRAYS = {"points": ("xyz", "rgb", "normals"), "depth": ("depth", "rgb")}


def encode_frame(kind: str = "points", *, pose=None, time=None, intrinsics=None, depth_scale=None, max_depth=None, **arrays) -> bytes:
    """One push message: ``kind`` 'points' (xyz, rgb, normals) or 'depth' (depth, rgb, intrinsics)."""
    header: dict = {"type": kind, "arrays": []}
    if pose is not None:
        header["pose"] = np.asarray(pose, np.float64).reshape(-1).tolist()
    for key, value in (("time", time), ("depth_scale", depth_scale), ("max_depth", max_depth)):
        if value is not None:
            header[key] = float(value)
    if intrinsics is not None:
        header["intrinsics"] = np.asarray(intrinsics, np.float64).reshape(-1).tolist()
    blobs = []
    for name, a in arrays.items():
        if a is None:
            continue
        a = np.ascontiguousarray(a)
        header["arrays"].append({"name": name, "dtype": a.dtype.str, "shape": list(a.shape)})
        blobs.append(a.tobytes())
    head = json.dumps(header, separators=(",", ":")).encode()
    return MAGIC + struct.pack("<I", len(head)) + head + b"".join(blobs)


def decode_frame(data: bytes) -> RecordedFrame:
    """The frame of one push message; InputError (one line) when it is malformed."""
    if not isinstance(data, bytes | bytearray):
        raise InputError("push: frames are binary messages (b'GPL1' + header length + JSON header + arrays)")
    if len(data) > MAX_PUSH_BYTES:
        raise InputError(f"push: a frame of {len(data):,} bytes exceeds the limit of {MAX_PUSH_BYTES:,}")
    if len(data) < 8 or data[:4] != MAGIC:
        raise InputError("push: not a frame message (it must start with b'GPL1')")
    (n,) = struct.unpack("<I", data[4:8])
    if 8 + n > len(data):
        raise InputError(f"push: header of {n} bytes runs past the message's {len(data)}")
    try:
        header = json.loads(data[8 : 8 + n])
    except (ValueError, RecursionError):
        raise InputError("push: the header is not JSON") from None
    if not isinstance(header, dict):
        raise InputError("push: the header must be a JSON object")
    kind = header.get("type")
    if not isinstance(kind, str) or kind not in _ARRAYS:  # (a list: unhashable, an internal error)
        raise InputError(f"push: unknown frame type {str(kind)[:30]!r} (points or depth)")
    arrays, offset = {}, 8 + n
    specs = header.get("arrays")
    if not isinstance(specs, list) or len(specs) > 8:
        raise InputError("push: 'arrays' must be a list of {name, dtype, shape}")
    for spec in specs:
        try:
            name, dtype, shape = spec["name"], spec["dtype"], spec["shape"]
        except (TypeError, KeyError):
            raise InputError("push: each array needs a name, a dtype and a shape") from None
        if not isinstance(name, str) or not isinstance(dtype, str):  # (lists: unhashable)
            raise InputError("push: each array's name and dtype must be strings")
        if name not in _ARRAYS[kind]:
            raise InputError(f"push: a {kind} frame has no array {str(name)[:30]!r} (only {', '.join(_ARRAYS[kind])})")
        if name in arrays:  # a second xyz replaced the first, without a word
            raise InputError(f"push: array {name} is given twice")
        if not isinstance(shape, list) or not all(isinstance(s, int) and not isinstance(s, bool) for s in shape):
            # (int() read a shape of [2.5, 3] as [2, 3] and true as 1: the bytes were split otherwise than the producer meant)
            raise InputError(f"push: array {name}: shape must be a list of whole numbers, got {str(shape)[:60]}")
        shape = tuple(shape)
        if dtype not in _DTYPES or len(shape) > 3 or any(not 0 <= s <= MAX_PUSH_BYTES for s in shape):
            raise InputError(f"push: array {name}: unsupported dtype {str(dtype)[:10]!r} or shape {str(shape)[:60]}")
        count = math.prod(shape)  # Python's integers: numpy's int64 product of [2**62, 4] wrapped to 0 (a ValueError, the connection lost)
        size = count * np.dtype(dtype).itemsize
        if offset + size > len(data):
            raise InputError(f"push: array {name} ({size:,} bytes) runs past the end of the message (a frame cut short)")
        arrays[name] = np.frombuffer(data, dtype, count, offset).reshape(shape)
        offset += size
    if offset != len(data):
        raise InputError(f"push: {len(data) - offset} bytes after the last array")
    pose = None
    if "pose" in header:
        try:
            pose = np.asarray(header["pose"], np.float64).reshape(4, 4)
        except (TypeError, ValueError, OverflowError):  # JSON integers have no bound: 10**400 overflows a float
            raise InputError("push: 'pose' must be 16 numbers (a 4x4 matrix, row-major)") from None
    try:
        t = float(header["time"]) if "time" in header else None
        scale = float(header["depth_scale"]) if "depth_scale" in header else None
        max_depth = float(header["max_depth"]) if "max_depth" in header else None
        intrinsics = header.get("intrinsics")
        if intrinsics is not None:
            intrinsics = np.asarray(intrinsics, np.float64)
            if intrinsics.size == 9:  # a 3x3 camera matrix, row-major (encode_frame sends it flat): push_depth refused its 9 numbers
                intrinsics = intrinsics.reshape(3, 3)
    except (TypeError, ValueError, OverflowError):
        raise InputError("push: time, depth_scale, max_depth and intrinsics must be numbers") from None
    if kind == "depth":
        if "depth" not in arrays:
            raise InputError("push: a depth frame needs a 'depth' array")
        return RecordedFrame("depth", t, pose, rgb=arrays.get("rgb"), depth=arrays["depth"], intrinsics=intrinsics,
                             depth_scale=scale, max_depth=max_depth)  # fmt: skip
    if "xyz" not in arrays:
        raise InputError("push: a points frame needs an 'xyz' array")
    return RecordedFrame("points", t, pose, xyz=arrays["xyz"], rgb=arrays.get("rgb"), normals=arrays.get("normals"))


class PushClient:
    """Pushes frames into a running viewer (``gigapoint view --live ...`` printed its push URL and token)."""

    def __init__(self, url: str, token: str, timeout: float = 10.0):
        try:
            from websockets.sync.client import connect
        except ImportError:
            raise GigapointError("pushing frames needs websockets (pip install 'gigapoint[viewer]')") from None
        base, _, query = url.partition("?")  # the page's token= (a server off loopback wants it) is kept
        base = base.rstrip("/").removesuffix("/push")
        query = "&".join(q for q in query.split("&") if q and not q.startswith("push_token="))
        ws_url = base.replace("http://", "ws://").replace("https://", "wss://") + "/push?" + (query + "&" if query else "") + f"push_token={token}"
        try:
            self._connection = connect(ws_url, max_size=1 << 20, open_timeout=timeout)
            self.ws = self._connection.__enter__()  # websockets >= 15 wants it entered as a context
        except Exception as exc:  # noqa: BLE001 - refused handshake (wrong token), no server...
            raise GigapointError(f"push: {base} refused the connection ({first_line(exc)})") from None
        self.timeout = timeout

    def send(self, message: bytes) -> dict:
        """Send one encoded frame; returns the viewer's answer ({'type': 'ack', 'seq': ...} or {'type': 'error', ...})."""
        self.ws.send(message)
        return json.loads(self.ws.recv(self.timeout))

    def push(self, xyz, rgb=None, pose=None, time=None, normals=None) -> dict:
        return self.send(encode_frame("points", xyz=xyz, rgb=rgb, normals=normals, pose=pose, time=time))

    def push_depth(self, depth, intrinsics, pose=None, rgb=None, depth_scale=None, time=None) -> dict:
        return self.send(encode_frame("depth", depth=depth, rgb=rgb, intrinsics=intrinsics, pose=pose, time=time, depth_scale=depth_scale))

    def close(self) -> None:
        self._connection.__exit__(None, None, None)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
