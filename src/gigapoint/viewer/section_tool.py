"""The viewer's section tool (Potree's profile tool): a cross-section along two picked points.

The session picks the two points as the measuring tool does (world points through the last
frame's visibility buffer) and draws the line into each frame (measure.draw, in its own
colour); the section itself (``gigapoint.section``, survey/section.py) is computed off the
render loop (``Session._compute_section``'s thread) and sent as a PNG of the panel's size with
its numbers. Which points: a cloud held in memory (a PointCloud) gives its own; an LOD octree
(converted, COPC, EPT, Potree, local or over HTTP; a progressive one) those of the nodes that
meet the corridor, at every level (lod/query.py): they hold every point once (a COPC file or
EPT dataset through a reader of its own, apart from the frames'). Classes hidden in the Classes
panel are left out (the section is of what the view shows, as the volume tool's volume), and
the section is drawn again when they change.
"""

from __future__ import annotations

import base64
import tempfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..core.chunk import PointChunk
from ..core.cloud import PointCloud, build_cloud
from ..errors import GigapointError
from ..io.http import LocalFile
from ..lod.query import is_octree
from ..lod.voxel_octree import VoxelOctree
from ..render.frame import encode_image
from ..survey.section import Section, section
from . import protocol as P

COLOR = (0, 229, 255)  # cyan: the section's line, apart from the measuring tool's yellow
MAX_POINTS = 5_000_000  # a corridor holding more is thinned to every k-th point (drawn and written)
MAX_IMAGE_SIDE = 2048  # pixels of the panel's image


def parse(msg: dict) -> dict:
    """The checked values of a section message: ``points`` (two [x, y, z]), ``width`` (> 0), ``size`` ([w, h]); those given."""
    out = {}
    if "points" in msg:
        points = msg["points"]
        if not isinstance(points, list) or len(points) != 2:
            raise P.ProtocolError("section: points must be a list of two points [x, y, z]")
        out["points"] = [P.vec3({"type": "section", "point": p}, "point") for p in points]
        if out["points"][0][:2] == out["points"][1][:2]:
            raise P.ProtocolError("section: the two points are at the same x, y: the line has no length")
    if "width" in msg:
        width = P.number(msg, "width", 0, P.MAX_ABS_COORD)
        if width <= 0:
            raise P.ProtocolError("section: width must be above 0")
        out["width"] = width
    if "size" in msg:
        size = msg["size"]
        if not isinstance(size, list) or len(size) != 2:
            raise P.ProtocolError("section: size must be [width, height] in pixels")
        out["size"] = [P.integer({"type": "section", "size": v}, "size", 8, MAX_IMAGE_SIDE) for v in size]
    return out


def own_reader_source(cloud: VoxelOctree) -> str:
    """The path or URL of a COPC file or EPT dataset, for a reader of its own: the frames' reads
    change the viewer's octree's pages and nodes as they go."""
    return cloud.source.path if isinstance(cloud.source, LocalFile) else cloud.source.url


def section_of(cloud, line, width, hidden_classes=()) -> Section:
    """``gigapoint.section`` of what the viewer shows: the cloud's points in memory, an octree's
    from the nodes meeting the corridor, but those of ``hidden_classes``; a one-line
    GigapointError for any other cloud."""
    dropped = list(hidden_classes) or None
    if isinstance(cloud, VoxelOctree):
        return section(own_reader_source(cloud), line, width, drop_classes=dropped)
    if isinstance(cloud, PointCloud) or is_octree(cloud):
        return section(cloud, line, width, drop_classes=dropped)
    raise GigapointError(f"{cloud.name}: sections need the points in memory or an LOD octree; this cloud is neither (view the point files instead)")


def every_kth(chunks: Iterable[PointChunk], limit: int, total: int | None = None) -> tuple[list[PointChunk], int, int]:
    """(the rows of ``chunks`` thinned to every k-th, the first included: at most ``limit``; the
    rows seen; k). ``total``, the rows there are where known: k = total / limit (rounded up) from
    the start. Without it k starts at 1 and doubles whenever more than ``limit`` rows are held
    (every other row held is dropped): a stream of any length is read holding at most ``limit``
    rows and a chunk."""
    step = 1 if total is None else max(1, -(-total // limit))
    held: list[tuple[int, PointChunk]] = []  # (its first row's number in the stream, a chunk's rows numbered a multiple of step)
    n_held = seen = 0

    def halved(first: int, part: PointChunk) -> tuple[int, PointChunk]:
        """Of ``part``'s rows (every step/2-th from row ``first``) those numbered a multiple of step."""
        odd = first % step != 0
        return first + odd * step // 2, part.subset(np.arange(int(odd), len(part), 2))

    for chunk in chunks:
        first = -(-seen // step) * step  # the chunk's first row numbered a multiple of step
        part = chunk if step == 1 else chunk.subset(np.arange(first - seen, len(chunk), step))
        seen += len(chunk)
        if len(part):
            held.append((first, part))
            n_held += len(part)
        while n_held > limit:
            step *= 2
            held = [(first, part) for first, part in (halved(*kept) for kept in held) if len(part)]
            n_held = sum(len(part) for _, part in held)
    return [part for _, part in held], seen, step


def capped(cut: Section, limit: int) -> tuple[Section, str]:
    """``cut`` with at most ``limit`` points (every k-th row of the corridor: the image and the CSV
    stay quick to make), and the line that says so ("" when nothing was left out)."""
    n = cut.cloud.n_points
    if n <= limit:
        return cut, ""
    kept, _, step = every_kth(cut.cloud.chunks(), limit, total=n)
    thinned = build_cloud(kept, name=cut.cloud.name, colors="rgba")
    return Section(thinned, cut.line, cut.width, cut.units), f"{n:,} points in the corridor: 1 point in {step} shown (at most {limit:,}); narrow or shorten it for all"


def default_width(bounds) -> float:
    """The width offered first: 1/50 of the cloud's larger horizontal side, to 2 significant digits."""
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    side = float(max(hi[0] - lo[0], hi[1] - lo[1]))
    return float(f"{side / 50:.2g}") if side > 0 else 1.0


def summary(cut: Section, units, note: str) -> dict:
    """The section's numbers, as the panel shows them (in the cloud's ``units``)."""
    return {
        "count": int(cut.cloud.n_points),
        "length": cut.length,
        "width": cut.width,
        "line": list(cut.line),
        "distance": [float(cut.distance.min()), float(cut.distance.max())],
        "z": [float(cut.z.min()), float(cut.z.max())],
        "units": units,
        "message": note,
    }


def image_url(image: np.ndarray) -> str:
    """A PNG data URL of ``image`` (what the panel's <img> shows)."""
    return "data:image/png;base64," + base64.b64encode(encode_image(image, "PNG")).decode("ascii")


def csv_bytes(cut: Section) -> bytes:
    """The rows as ``Section.write_csv`` writes them."""
    with tempfile.TemporaryDirectory(prefix="gigapoint-section-") as tmp:
        path = Path(tmp) / "section.csv"
        cut.write_csv(path)
        return path.read_bytes()
