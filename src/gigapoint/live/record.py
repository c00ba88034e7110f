"""Recording a live stream and reading it back.

A recording is a folder: ``frames/000000.npz``... one file per frame, each written atomically
(gigapoint.atomic: a reader never sees half a frame) and self-describing (its kind, pose, time
and arrays), and ``index.json`` listing them, rewritten atomically about once a second and when
the recording stops. A frame pushed as a depth image is recorded as that image and its
intrinsics (replay runs the same kernel again), one pushed as points as its sensor-frame points.
A ``clear()`` of the cloud is recorded as a frame file of kind ``clear`` (no arrays, the time of
the frame before it): the replay clears its cloud there, as the live cloud was.
"""

from __future__ import annotations

import contextlib
import json
import os
import threading
import time
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import atomic_json, atomic_open
from ..errors import GigapointWarning, InputError, counted, first_line, warn

FORMAT = "gigapoint-live-recording"
INDEX = "index.json"
FRAMES = "frames"
_NPZ_MAGIC = b"PK\x03\x04"  # a zip archive's first bytes: every frame file np.savez writes


@dataclass
class RecordedFrame:
    """One frame of a stream: points (``xyz`` in sensor coordinates) or a depth image, with its pose and time."""

    kind: str  # "points", "depth" or "clear" (the cloud cleared: LiveCloud.clear)
    time: float
    pose: np.ndarray | None = None
    xyz: np.ndarray | None = None
    rgb: np.ndarray | None = None
    normals: np.ndarray | None = None
    attributes: dict = field(default_factory=dict)
    depth: np.ndarray | None = None
    intrinsics: np.ndarray | None = None
    depth_scale: float | None = None
    max_depth: float | None = None
    origin: str | None = None  # its file or message, for a refused frame's message

    def push_into(self, live) -> int | None:
        """Push this frame into a LiveCloud (``push`` or ``push_depth``; a clear: ``clear``, None)."""
        if self.kind == "clear":
            live.clear()
            return None
        if self.kind == "depth":
            return live.push_depth(self.depth, self.intrinsics, self.pose, self.rgb, self.depth_scale, self.time, self.max_depth)
        return live.push(self.xyz, self.rgb, self.pose, self.time, self.normals, **self.attributes)


class Recorder:
    """Writes the frames a LiveCloud accepts into a recording folder (``LiveCloud.record``)."""

    def __init__(self, directory, overwrite: bool = False, index_every_s: float = 1.0):
        if not isinstance(directory, (str, os.PathLike)) or not os.fspath(directory):  # 5: a TypeError; "": the current folder
            raise InputError(f"record: the recording's folder must be a path, got {directory!r}")
        self.directory = Path(directory)
        held = is_recording(self.directory)  # by its index's format: someone's own index.json was replaced
        if held and not overwrite:
            raise InputError(f"{self.directory}: holds a recording already; pass overwrite=True to replace it")
        if self.directory.exists() and not self.directory.is_dir():
            raise InputError(f"{self.directory}: exists and is not a folder")
        if not held and self.directory.is_dir() and any(self.directory.iterdir()):  # its frames/000000.npz was replaced
            raise InputError(f"{self.directory}: holds other files, not a gigapoint recording: not overwritten; record into a new or empty folder")
        created = not self.directory.exists()
        (self.directory / FRAMES).mkdir(parents=True, exist_ok=True)
        if overwrite and held:  # a recording's frames only
            for old in (self.directory / FRAMES).glob("*.npz"):
                old.unlink()
        self.index_every_s = index_every_s
        self.entries: list[dict] = []  # the frames written, in the order they were numbered
        self._frames = 0  # of those, the frames pushed (not the clears)
        self.error: InputError | None = None  # why the recording stopped early (a full disk), else None
        self._numbered = 0
        self._last_time: float | None = None  # the newest frame's time stamp: a clear's
        self._lock = threading.Lock()
        self._written_at = 0.0
        self.started = time.time()
        try:
            atomic_json(self.directory / INDEX, self._index())
        except OSError as exc:  # (a full disk: nothing recorded yet, and no folder left to refuse a second try)
            with contextlib.suppress(OSError):
                (self.directory / FRAMES).rmdir()
                if created:
                    self.directory.rmdir()
            raise InputError(f"{self.directory}: cannot record into it: {first_line(exc)}") from None

    def _write(self, arrays: dict, kind: str, t: float) -> None:
        """Frame ``arrays`` written as the next file. A frame that cannot be written (a full disk)
        stops the recording, said once (a GigapointWarning; ``error``): the stream goes on, and
        the recording keeps the frames before it (a push raised OSError for every frame after,
        though its frame was in, and index.json listed frames never written)."""
        with self._lock:
            if self.error is not None:
                return
            k = self._numbered
            self._numbered += 1
        name = f"{FRAMES}/{k:06d}.npz"
        try:
            with atomic_open(self.directory / name) as f:
                np.savez(f, kind=np.array(kind), time=np.array(t, np.float64), **arrays)
        except OSError as exc:
            self._stop_for(exc)
            return
        with self._lock:
            self.entries.append({"file": name, "time": t, "kind": kind})
            self._frames += kind != "clear"
            self._last_time = t
        if time.monotonic() - self._written_at > self.index_every_s:
            self._write_index()

    def _stop_for(self, exc: OSError) -> None:
        with self._lock:
            if self.error is not None:
                return
            self.error = InputError(f"{self.directory}: recording stopped after {counted(self._frames, 'frame')}: {first_line(exc)}")
        warn(str(self.error), GigapointWarning)
        self._write_index()  # the frames written so far, if there is room for that

    def write_points(self, seq, xyz, rgb, pose, t, normals, attributes) -> None:
        arrays = {"xyz": np.asarray(xyz)}
        if pose is not None:
            arrays["pose"] = np.asarray(pose, np.float64)
        if rgb is not None:
            arrays["rgb"] = np.asarray(rgb)
        if normals is not None:
            arrays["normals"] = np.asarray(normals)
        for a, v in attributes.items():
            arrays[f"attr_{a}"] = np.asarray(v)
        self._write(arrays, "points", t)

    def write_depth(self, seq, depth, intrinsics, pose, rgb, depth_scale, max_depth, t) -> None:
        from .depth import parse_intrinsics

        arrays = {"depth": np.asarray(depth), "intrinsics": np.array(parse_intrinsics(intrinsics)), "pose": np.asarray(pose, np.float64)}
        if rgb is not None:
            arrays["rgb"] = np.asarray(rgb)
        arrays["depth_scale"] = np.array(np.nan if depth_scale is None else depth_scale, np.float64)
        arrays["max_depth"] = np.array(np.nan if max_depth is None else max_depth, np.float64)
        self._write(arrays, "depth", t)

    def write_clear(self) -> None:
        """The cloud was cleared (LiveCloud.clear): its frames and colour range dropped. Recorded
        at the time of the frame before it (no wait in a replay at its rate); before any frame,
        nothing to record: a replay starts from an empty cloud."""
        if self._last_time is not None:
            self._write({}, "clear", self._last_time)

    def _index(self) -> dict:
        with self._lock:
            entries = sorted(self.entries, key=lambda e: e["file"])  # (producers on several threads finish out of order)
        index = {"format": FORMAT, "version": 1, "frames": entries}
        if self.error is not None:  # (a recording cut short by a full disk looked like a whole one)
            index["stopped_early"] = str(self.error)
        return index

    def _write_index(self) -> None:
        try:
            atomic_json(self.directory / INDEX, self._index())
        except OSError as exc:  # the last index written stays; a replay also finds the frames written after it
            if self.error is None:
                self._stop_for(exc)
            return
        self._written_at = time.monotonic()

    def stop(self) -> None:
        self._write_index()

    @property
    def n_frames(self) -> int:
        return self._frames


def _opt(z, name):
    if name not in z:
        return None
    v = float(z[name])
    return None if np.isnan(v) else v


def read_frame(path: Path) -> RecordedFrame:
    """One recorded frame (an npz written by Recorder); one missing, or no frame, a one-line InputError."""
    try:
        with open(path, "rb") as f:
            # another file (notes, an .npy): numpy's reason was a pickle's ("allow_pickle=False"), of no frame
            if f.read(len(_NPZ_MAGIC)) != _NPZ_MAGIC:
                raise InputError(f"{path}: not a recorded frame (not an NPZ archive, which a recording writes)")
            f.seek(0)
            with np.load(f, allow_pickle=False) as z:
                frame = _frame_of(path, z)
                frame.origin = str(path)
                return frame
    except FileNotFoundError:  # (a file the index lists, deleted since: it was skipped without a word)
        raise InputError(f"{path}: no such file") from None
    except (OSError, ValueError, TypeError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:  # a truncated or damaged npz (TypeError: a time of several values)
        raise InputError(f"{path}: not a recorded frame ({first_line(exc)})") from None


def _frame_of(path: Path, z) -> RecordedFrame:
    """The frame an open NPZ archive ``z`` of ``path`` holds."""
    if "kind" not in z.files or "time" not in z.files:  # another NPZ archive (its own arrays, objects among them)
        raise InputError(f"{path}: not a recorded frame (an NPZ archive without a frame's kind and time)")
    kind = str(z["kind"])
    t = float(z["time"])
    if kind == "clear":
        return RecordedFrame("clear", t)
    pose = z.get("pose", None)
    rgb = z.get("rgb", None)
    if kind == "depth":
        return RecordedFrame("depth", t, pose, rgb=rgb, depth=z["depth"], intrinsics=z["intrinsics"],
                             depth_scale=_opt(z, "depth_scale"), max_depth=_opt(z, "max_depth"))  # fmt: skip
    if kind != "points":
        raise InputError(f"{path}: unknown frame kind {kind!r} (points, depth or clear)")
    attrs = {k[5:]: z[k] for k in z.files if k.startswith("attr_")}
    return RecordedFrame("points", t, pose, xyz=z["xyz"], rgb=rgb, normals=z.get("normals", None), attributes=attrs)


def _frame_files(directory: Path) -> list[Path]:
    """The frame files in a recording's frames/ folder, in name order (their order)."""
    return sorted((directory / FRAMES).glob("[0-9]*.npz"))


def _read_index(directory: Path) -> dict:
    """A recording's index.json, read; a one-line InputError where there is none, or it is not
    a recording's (its ``format``). An index that is not JSON (cut short by a crash, edited by
    hand) beside frame files stands for an index of no frames, its ``damaged`` saying why
    (recording_files then plays every frame file): refused whole, the frames were lost."""
    index = directory / INDEX
    if not directory.exists():
        raise InputError(f"{directory}: no such folder (a live recording: a folder with {INDEX})")
    if not index.is_file():
        raise InputError(f"{directory}: not a live recording (no {INDEX})")
    try:
        meta = json.loads(index.read_text())
    except OSError as exc:
        raise InputError(f"{index}: unreadable ({exc})") from None
    except ValueError as exc:  # not JSON (UnicodeDecodeError among them)
        if not _frame_files(directory):
            raise InputError(f"{index}: unreadable ({first_line(exc)})") from None
        return {"format": FORMAT, "frames": [], "damaged": first_line(exc)}
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InputError(f"{index}: not a gigapoint live recording index")
    return meta


def recording_files(directory) -> list[Path]:
    """The frame files of a recording, in order: index.json's (a missing one too: read_frame
    refuses it, and the replay counts it, as a damaged one), then any written after it."""
    directory = Path(directory)
    index = directory / INDEX
    meta = _read_index(directory)
    if "damaged" in meta:
        warn(f"{index}: damaged, not JSON ({meta['damaged']}): the frame files in {directory / FRAMES} are replayed without it, in name order", GigapointWarning)
    entries = meta.get("frames", [])
    if not isinstance(entries, list):  # (7 was a TypeError)
        raise InputError(f"{index}: damaged: its frames are not a list")
    # an entry that is not a relative name inside the recording (5 was a TypeError; "/etc/hostname" was read) is left out,
    # judged by its name, not a resolve (a stat a component) for each of thousands of frames
    named = [Path(e["file"]) for e in entries if isinstance(e, dict) and isinstance(e.get("file"), str)]
    listed = [directory / f for f in named if not f.is_absolute() and ".." not in f.parts]
    seen = {p.name for p in listed}
    later = [p for p in _frame_files(directory) if p.name not in seen]
    return listed + later


def stopped_early(directory) -> str | None:
    """Why a recording stopped before its stream did (a full disk), as its index says, else None."""
    why = _read_index(Path(directory)).get("stopped_early")
    return why if isinstance(why, str) else None


def is_recording(path) -> bool:
    """Whether ``path`` is a recording's folder: its index.json is a recording's (its ``format``),
    not anyone's index.json, or is damaged (not JSON) beside frame files."""
    try:
        _read_index(Path(path))
    except InputError:
        return False
    return True
