"""Damaged inputs, made by a seeded mutator: every point file and octree opened, read and drawn
either works or fails with one line naming the file (a GigapointError), never another exception.

Random byte flips, zeroed runs and truncations of small NPY, NPZ, PLY (binary and ASCII), XYZ,
CSV, LAS and LAZ files; of one file of gigapoint, Potree and COPC octrees; and random values
put into their metadata's JSON. Each mutation is drawn from a fixed seed, so a failure names a
case that repeats. Defects this found, each a traceback before: a garbled NPY header (numpy's
tokenize.TokenError), an NPZ member's damaged zip header, a garbled array header in an octree
folder, a COPC/EPT/Potree scale of 2e277 drawn as NaN, an octree's field dtypes or attributes of
the wrong kind, a Potree metadata without its position attribute.
"""

from __future__ import annotations

import copy
import json
import random
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointError
from gigapoint.io import file_info
from gigapoint.lod import convert

pytestmark = pytest.mark.timeout(600)

MUTATIONS = 24  # a format and octree kind (the fuzzer that found the defects ran 150 a format, seeds 1-21)


def _mutated(data: bytes, rng: random.Random) -> bytes:
    """Bytes flipped, zeroed or cut, mostly near the start (where the headers are)."""
    d = bytearray(data)
    region = min(len(d), rng.choice([64, 256, 1024, len(d)]))
    kind = rng.choice(["flip", "trunc", "zero"])
    if kind == "flip":
        for _ in range(rng.randint(1, 8)):
            d[rng.randrange(region)] = rng.randrange(256)
    elif kind == "trunc":
        d = d[: rng.randrange(1, len(d))]
    else:
        i = rng.randrange(region)
        d[i : i + 16] = bytes(len(d[i : i + 16]))
    return bytes(d)


def _fails_in_one_line_or_works(path: Path, action) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            action(path)
        except GigapointError as exc:
            msg = str(exc)
            assert "\n" not in msg and str(path) in msg, msg


def _draw(path: Path) -> None:
    cloud = gp.open(path)
    gp.render(cloud, width=48, height=32)


def _write_point_files(folder: Path) -> list[Path]:
    import laspy
    from plyfile import PlyData, PlyElement

    xyz, rgba, _ = gp.demo_arrays(600, seed=1)
    np.save(folder / "a.npy", xyz)
    np.savez(folder / "a.npz", xyz=xyz, rgb=rgba[:, :3])
    v = np.zeros(len(xyz), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    v["x"], v["y"], v["z"] = xyz.T
    v["red"], v["green"], v["blue"] = rgba[:, :3].T
    PlyData([PlyElement.describe(v, "vertex")], text=False).write(str(folder / "b.ply"))
    PlyData([PlyElement.describe(v[:200], "vertex")], text=True).write(str(folder / "t.ply"))
    np.savetxt(folder / "a.xyz", xyz[:300], fmt="%.3f")
    rows = [f"{a:.3f},{b:.3f},{c:.3f},{r},{g},{bb}" for (a, b, c), (r, g, bb, _) in zip(xyz[:300], rgba[:300])]
    (folder / "a.csv").write_text("x,y,z,r,g,b\n" + "\n".join(rows) + "\n")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.write(str(folder / "a.las"))
    las.write(str(folder / "a.laz"))
    return sorted(p for p in folder.iterdir() if p.is_file())


def test_damaged_point_files_fail_in_one_line(tmp_path):
    seeds = tmp_path / "seeds"
    seeds.mkdir()
    rng = random.Random(11)
    for src in _write_point_files(seeds):
        for k in range(MUTATIONS):
            path = tmp_path / f"m{k}_{src.name}"
            path.write_bytes(_mutated(src.read_bytes(), rng))
            _fails_in_one_line_or_works(path, gp.open)
            _fails_in_one_line_or_works(path, file_info)
            _fails_in_one_line_or_works(path, lambda p: gp.open(p, progressive=True).wait(timeout=60))


@pytest.fixture(scope="module")
def octrees(tmp_path_factory):
    base = tmp_path_factory.mktemp("octrees")
    xyz, rgba, attrs = gp.demo_arrays(20_000, seed=2)
    src = gp.from_arrays(xyz, rgba, **attrs)
    out = {}
    for fmt, name in (("gigapoint", "g"), ("potree", "p"), ("copc", "c.copc.laz")):
        convert(src.chunks(), base / name, format=fmt, max_leaf=2_000)
        out[fmt] = base / name
    return out


@pytest.mark.parametrize("fmt", ["gigapoint", "potree", "copc"])
def test_damaged_octrees_fail_in_one_line(octrees, tmp_path, fmt):
    rng = random.Random({"gigapoint": 1, "potree": 2, "copc": 3}[fmt])
    src = octrees[fmt]
    for k in range(MUTATIONS):
        path = tmp_path / f"m{k}_{src.name}"
        if src.is_dir():
            shutil.copytree(src, path)
            target = rng.choice(sorted(p for p in path.rglob("*") if p.is_file()))
        else:
            shutil.copy(src, path)
            target = path
        target.write_bytes(_mutated(target.read_bytes(), rng))
        _fails_in_one_line_or_works(path, _draw)


_VALUES = [None, -1, 0, 1, 2.5, 1e308, -1e308, "x", "", [], {}, True, [1, 2], [0, 0, 0], [1e308] * 3, {"a": 1}, 2**63, "u0"]


def _json_mutated(doc, rng: random.Random):
    """One value somewhere in the document replaced by an odd one (or its key removed)."""
    doc = copy.deepcopy(doc)

    def places(node, at=()):
        yield at
        items = node.items() if isinstance(node, dict) else enumerate(node[:6]) if isinstance(node, list) else ()
        for k, v in items:
            yield from places(v, (*at, k))

    at = rng.choice([p for p in places(doc) if p])
    parent = doc
    for k in at[:-1]:
        parent = parent[k]
    if isinstance(parent, dict) and rng.random() < 0.25:
        del parent[at[-1]]
    else:
        parent[at[-1]] = rng.choice(_VALUES)
    return doc


@pytest.mark.parametrize("fmt, meta_name", [("gigapoint", "octree.json"), ("potree", "metadata.json")])
def test_odd_octree_metadata_fails_in_one_line(octrees, tmp_path, fmt, meta_name):
    rng = random.Random(7)
    doc = json.loads((octrees[fmt] / meta_name).read_text())
    for k in range(3 * MUTATIONS):
        path = shutil.copytree(octrees[fmt], tmp_path / f"m{k}")
        (path / meta_name).write_text(json.dumps(_json_mutated(doc, rng)))
        _fails_in_one_line_or_works(path, _draw)
