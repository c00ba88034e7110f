"""Remakes this folder's fixtures: COPC files of a 20 000-point sample of the shared autzen_trim.laz
written by copc-lib (RockRobotic's C++ library, PyPI ``copclib``; 2.6.3 made these), in the layouts
its writer offers, for tests/unit/test_copc_interop.py (which needs no copclib):

    pip install copclib
    python tests/unit/data/copclib/make.py

- one_page.copc.laz: format 7 (16-bit RGB), WKT, every node in the root hierarchy page.
- shared_keys.copc.laz: format 7, nested pages the way copclib's AddNode(key, points, page_key) makes
  them: a node at depth 2 or deeper in the page of its parent (pages in pages). A page's
  key is a node too: the parent page lists that key twice, its entry (points) and the pointer
  (count -1) to the page, which holds the nodes below it only.
- own_pages.copc.laz: format 6 (no colour), each depth-1 node in a page of its own with its subtree
  (its entry in the page, only the pointer in the root page: PDAL/untwine's way); a cube with room
  around the points (offset, twice as big).
- nir_extra.copc.laz: format 8 (8-bit values in the 16-bit colour fields, as autzen has; NIR)
  with two extra-byte fields (copclib's EbVlr(2): FIELD_0, FIELD_1, unsigned char); no root
  node (the hierarchy starts at depth 1), nodes written deepest first, and copclib's extended
  stats (VLRs copc 10000 and rock_robotic 10001, between the info VLR and the others).

copclib writes the points first (in AddNode's order), then each hierarchy page as an EVLR of its
own (copc 1000, the page's key as description), child pages before their parents, the root page
last but one; the WKT goes into an EVLR too (LASF_Projection 2112), the last one. nodes.json: the
nodes (d-x-y-z: points) and pages copclib's reader finds in each file.
"""

import json
from pathlib import Path

import copclib as c
import laspy
import numpy as np

HERE = Path(__file__).resolve().parent
AUTZEN = HERE.parents[3] / ".." / "shared" / "data" / "autzen_trim.laz"
N, CAP, DEPTH = 20_000, 1_500, 4  # points, points a node keeps before its children take the rest, deepest level

src = laspy.read(AUTZEN)
keep = np.arange(40_000, 40_000 + N)  # a run of the file (scan order): it compresses as the file does
pts = src.points[keep]
WKT = src.header.vlrs.get("WktCoordinateSystemVlr")[0].string.strip("\0")


def octree(xyz, cmin, edge, cap=CAP, depth=DEPTH, first=0):
    """{(d, x, y, z): point indices}: each node keeps ``cap`` points of its cube (in a seeded random
    order) from level ``first`` down, the deepest level keeps the rest."""
    rest = np.random.default_rng(1).permutation(len(xyz))
    nodes = {}
    for d in range(first, depth + 1):
        cell = np.clip(((xyz[rest] - cmin) / edge * 2**d).astype(np.int64), 0, 2**d - 1)
        flat = (cell[:, 0] << 2 * d) | (cell[:, 1] << d) | cell[:, 2]
        order = np.argsort(flat, kind="stable")
        f = flat[order]
        rank = np.arange(len(f)) - np.searchsorted(f, f)
        take = np.ones(len(f), bool) if d == depth else rank < cap
        for k in np.unique(f[take]):
            sel = order[take & (f == k)]
            nodes[(d, int(k >> 2 * d), int((k >> d) & (2**d - 1)), int(k & (2**d - 1)))] = np.sort(rest[sel])  # in file order: it compresses
        taken = np.zeros(len(rest), bool)
        taken[order[take]] = True
        rest = rest[~taken]
    assert sum(len(v) for v in nodes.values()) == len(xyz)
    return nodes


def ancestor(key, depth):
    d, x, y, z = key
    s = d - depth
    return (depth, x >> s, y >> s, z >> s)


def write(name, fmt, offset, pad, page_of, eb=0, first=0, deepest_first=False):
    scale = np.array(src.header.scales)
    lh = laspy.LasHeader(point_format=fmt, version="1.4")
    for i in range(eb):
        lh.add_extra_dim(laspy.ExtraBytesParams(f"FIELD_{i}", "u1"))
    lh.scales, lh.offsets = scale, offset
    rec = laspy.ScaleAwarePointRecord.zeros(N, header=lh)
    rec.x, rec.y, rec.z = pts.x, pts.y, pts.z
    for f in ("intensity", "classification", "return_number", "number_of_returns", "user_data", "point_source_id", "gps_time"):
        rec[f] = pts[f]
    rec.scan_angle = np.rint(np.asarray(pts.scan_angle_rank) / 0.006).astype(np.int16)
    rec.scan_direction_flag, rec.edge_of_flight_line = pts.scan_direction_flag, pts.edge_of_flight_line
    if fmt >= 7:
        k = 257 if fmt == 7 else 1
        rec.red, rec.green, rec.blue = (np.asarray(pts[b]) * k for b in ("red", "green", "blue"))
    if fmt == 8:
        rec.nir = np.asarray(pts.intensity).astype(np.int64) * 3 % 65536
    for i in range(eb):
        rec[f"FIELD_{i}"] = (np.asarray(pts.intensity) >> (4 * i)) % 251
    xyz = np.stack([rec.x, rec.y, rec.z], 1)
    lo, hi = xyz.min(0), xyz.max(0)
    edge = float((hi - lo).max()) * pad
    cmin = lo - (edge - (hi - lo)) / 2  # the points in the middle of the cube
    nodes = octree(xyz, cmin, edge, first=first)
    cfg = c.CopcConfigWriter(fmt, c.Vector3(*scale), c.Vector3(*offset), WKT if fmt == 7 else "", c.EbVlr(eb), eb > 0)  # extents VLR
    w = c.FileWriter(str(HERE / name), cfg)
    h, info = w.copc_config.las_header, w.copc_config.copc_info
    info.center_x, info.center_y, info.center_z = (cmin + edge / 2).tolist()
    info.halfsize, info.spacing = edge / 2, edge / 2 / 64
    h.min, h.max = c.Vector3(*lo), c.Vector3(*hi)
    for key in sorted(nodes, key=lambda k: (-k[0] if deepest_first else k[0], k)):
        raw = np.ascontiguousarray(rec.array[nodes[key]]).tobytes()
        w.AddNode(c.VoxelKey(*key), c.VectorChar(memoryview(raw).cast("b")), c.VoxelKey(*page_of(key)))
    w.Close()
    r = c.FileReader(str(HERE / name))
    assert sum(n.point_count for n in r.GetAllNodes()) == N
    pages = [f"{k.d}-{k.x}-{k.y}-{k.z}" for k in r.GetPageList()]
    found = {f"{n.key.d}-{n.key.x}-{n.key.y}-{n.key.z}": n.point_count for n in r.GetAllNodes()}
    MANIFEST[name] = {"nodes": dict(sorted(found.items())), "pages": sorted(pages)}
    print(f"{name}: {(HERE / name).stat().st_size:,} bytes, {len(nodes)} nodes, {len(pages)} pages")


MANIFEST = {}  # what copclib's reader finds in each file: nodes.json
root = (0, 0, 0, 0)
write("one_page.copc.laz", 7, [0.0, 0.0, 0.0], 1.0, lambda k: root)
write("shared_keys.copc.laz", 7, [636000.0, 849000.0, 0.0], 1.0, lambda k: root if k[0] < 2 else ancestor(k, k[0] - 1))
write("own_pages.copc.laz", 6, [636500.25, 849200.5, 400.0], 2.0, lambda k: root if k[0] == 0 else ancestor(k, 1))
write("nir_extra.copc.laz", 8, [637000.0, 849000.0, 500.0], 1.0, lambda k: root, eb=2, first=1, deepest_first=True)
(HERE / "nodes.json").write_text(json.dumps(MANIFEST, indent=1) + "\n")
