"""A viewable preview of a conversion while it runs.

PotreeConverter shows nothing until it has finished. gigapoint's read phase keeps a uniform
subsample of every point read so far (every ``stride``-th valid point, the stride doubling
whenever the sample outgrows its target) and writes it atomically into the conversion's
working folder (``OctreeDir.preview``) after the first chunk and then every few seconds.
``gigapoint render OUT`` / ``view OUT`` / ``gp.open(OUT)`` draw it, with a warning, until the
octree is complete; the viewer swaps in the octree when it appears (viewer/watch.py).
"""

from __future__ import annotations

import time
import zipfile
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from ..atomic import atomic_open
from ..core.cloud import PointCloud
from ..errors import GigapointWarning, InputError, warn
from ..io import open_cloud
from .octree_dir import OctreeDir

PREVIEW_BYTES_PER_POINT = 48  # xyz, rgba and a few attributes, held twice while a file is written
MAX_PREVIEW_POINTS = 2_000_000  # renders brute force in a few ms: enough to look at, cheap to write
MIN_PREVIEW_POINTS = 50_000


def preview_points(memory_limit: int) -> int:
    """Sample size for a conversion under ``memory_limit`` bytes (~2 % of it)."""
    return int(min(MAX_PREVIEW_POINTS, max(MIN_PREVIEW_POINTS, memory_limit // 50 // PREVIEW_BYTES_PER_POINT)))


class PreviewSampler:
    """Every ``stride``-th valid point of the input, in input order, written out now and then.

    With the input's point count known up front the stride is fixed (``total // target``);
    otherwise it starts at 1 and doubles, keeping every other kept point, whenever the
    sample exceeds ``target``. Either way the sample is a uniform thinning of all that was
    read, so the preview covers what is read so far evenly, and the whole input at the end.
    """

    def __init__(self, path: Path, target: int, total: int | None, interval_s: float = 2.0):
        self.path = Path(path)
        self.target = max(1, int(target))
        self.stride = max(1, int(total) // self.target) if total else 1
        self.seen = 0  # valid points offered so far (the global index of the next one)
        self.parts: list[dict] = []
        self.held = 0
        self.interval_s = interval_s
        self.last_write = -np.inf
        self.write_seconds = 0.0
        self.dirty = False

    def resume(self, seen: int, stride: int) -> None:
        """Continue a sample written by an interrupted run (its file is loaded, its stride kept)."""
        try:
            with np.load(self.path) as z:
                part = {k if k in ("xyz", "rgba") else "attr." + k: z[k] for k in z.files}
        except (OSError, ValueError, KeyError, zipfile.BadZipFile):  # missing or unreadable: start the sample afresh
            return
        if "xyz" not in part or "rgba" not in part:
            return
        self.parts, self.held = [part], len(part["xyz"])
        self.seen, self.stride = int(seen), max(1, int(stride))

    def add(self, xyz: np.ndarray, rgba_u32: np.ndarray, attributes: dict) -> None:
        """Offer one chunk's valid points (float64 xyz, u32 RGBA, 1-D attributes)."""
        n = len(xyz)
        first = (-self.seen) % self.stride  # the chunk's first point whose global index is a multiple
        self.seen += n
        if first >= n:
            return
        pick = slice(first, None, self.stride)
        part = {"xyz": np.array(xyz[pick]), "rgba": np.array(rgba_u32[pick]).view(np.uint8).reshape(-1, 4)}
        for a, v in attributes.items():
            part["attr." + a] = np.array(v[pick])
        self.parts.append(part)
        self.held += len(part["xyz"])
        self.dirty = True
        while self.held > self.target:  # kept indices are multiples of stride: [::2] keeps those of 2·stride
            self.stride *= 2
            merged = self._merged()
            self.parts = [{k: v[::2] for k, v in merged.items()}]
            self.held = len(self.parts[0]["xyz"])

    def _merged(self) -> dict:
        if len(self.parts) > 1:  # attributes only some chunks have are dropped, as the conversion does
            common = set.intersection(*(set(p) for p in self.parts))
            self.parts = [{k: np.concatenate([p[k] for p in self.parts]) for k in self.parts[0] if k in common}]
        return self.parts[0]

    def maybe_write(self, force: bool = False) -> bool:
        """Write the sample if it changed and enough time passed (always after the first chunk).

        The pause between writes is at least 40x the last write's duration, so writing costs
        the conversion at most ~2.5 %.
        """
        now = time.perf_counter()
        due = now - self.last_write >= max(self.interval_s, 40 * self.write_seconds)  # -inf before the first write
        if not self.dirty or not (due or force) or self.held == 0:
            return False
        merged = self._merged()
        arrays = {"xyz": merged["xyz"], "rgba": merged["rgba"]}
        arrays.update({k.removeprefix("attr."): v for k, v in merged.items() if k.startswith("attr.")})
        with atomic_open(self.path) as f:  # readers see the old preview or the new one, never a torn file
            np.savez(f, **arrays)
        self.write_seconds = time.perf_counter() - now
        self.last_write = now
        self.dirty = False
        return True


@dataclass(repr=False)
class ConversionPreview(PointCloud):
    """The preview of an unfinished conversion (``open_preview``): a PointCloud of every
    ``stride``-th point read so far, which knows the octree folder it stands in for, so that
    the viewer follows the conversion to its finished octree (viewer/watch.py)."""

    octree_dir: OctreeDir = field(kw_only=True)


def open_preview(octree_dir) -> ConversionPreview:
    """The preview of an unfinished conversion into ``octree_dir`` (an OctreeDir or a path), with
    a warning saying so."""
    d = OctreeDir(octree_dir)
    out = d.path
    if not d.preview.is_file():
        raise InputError(f"{out}: conversion not finished and no preview written yet ({d.resume_hint})")
    s = d.status()
    read = f"{s['points']:,} of {s['total']:,} points read" if s.get("total") else f"{s.get('points', 0):,} points read"
    if s.get("phase") not in (None, "read"):
        read = f"all {s['points']:,} points read, now in phase {s['phase']}"
    stopped = f"; it has stopped: {d.resume_hint}" if s.get("running") is False else ""
    warn(f"{out}: conversion not finished ({read}); showing its preview{stopped}", GigapointWarning)
    cloud = open_cloud(d.preview, name=out.name)
    return ConversionPreview(**{f.name: getattr(cloud, f.name) for f in fields(PointCloud) if f.init}, octree_dir=d)


def wait_for_preview(out, timeout_s: float = 60.0, poll_s: float = 0.25) -> bool:
    """For an unfinished conversion into ``out`` that has not written its preview yet (its first
    second or so): wait until the preview or the finished octree appears. False on timeout, or
    at once when no conversion is running (one killed before its first preview)."""
    d = OctreeDir(out)
    deadline = time.monotonic() + timeout_s
    while d.awaiting_preview:
        if time.monotonic() >= deadline or d.running is False:
            return False
        time.sleep(poll_s)
    return True


def awaiting_preview(path) -> bool:
    """``path`` is an unfinished conversion that has no preview yet."""
    return OctreeDir(path).awaiting_preview
