"""Converting (or opening) many small tiles against one file of the same points: what each input file costs.

    .venv/bin/python benchmarks/bench_many_tiles.py                  # 2 000 tiles of 50 points
    .venv/bin/python benchmarks/bench_many_tiles.py --tiles 4000 --points 100 --memory-limit 64M
    .venv/bin/python benchmarks/bench_many_tiles.py --open           # gigapoint.open of the tiles, plain and progressive
    .venv/bin/python benchmarks/bench_many_tiles.py --open --format las

The demo town's points, cut into ``--tiles`` NPY (or ``--format las``: LAS 1.2, millimetres) files of ``--points`` each and saved once
more as one NPY file; both converted with ``gigapoint.convert`` in this process, alternately
(``--rounds``, medians; the first, numba's warm-up, a round of its own, not counted), held in
memory or, with a small ``--memory-limit``, spilled. Reported: seconds, points/s and the tiles'
time over the one file's: a cost that grows faster than the tiles (the state's fingerprint of
every tile written with each tile's chunk, a bincount of 8^7 cells a chunk, a listing of the
spill folder a chunk) shows as a ratio that grows with ``--tiles``. With ``--open`` the tiles
are opened instead: ``gigapoint.open`` as one plain cloud against a progressive octree loaded
to the end (``wait``), alternately.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from gigapoint.bench import cpu_model
from gigapoint.io import demo_arrays
from gigapoint.lod import convert


def _timed(inputs, out: Path, memory_limit) -> float:
    t = time.perf_counter()
    convert(inputs, out, memory_limit=memory_limit)
    return time.perf_counter() - t


def _opened(tiles: Path, progressive: bool) -> float:
    import gigapoint

    t = time.perf_counter()
    cloud = gigapoint.open(tiles, progressive=progressive)
    if progressive:
        cloud.wait()
        cloud.close()
    return time.perf_counter() - t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tiles", type=int, default=2000)
    ap.add_argument("--points", type=int, default=50, help="points a tile")
    ap.add_argument("--memory-limit", default=None, help="e.g. 64M: spilled; default: held in memory")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--open", action="store_true", help="time gigapoint.open of the tiles, plain and progressive, instead")
    ap.add_argument("--format", choices=("npy", "las"), default="npy", help="the tiles' (and the one file's) format")
    args = ap.parse_args(argv)
    xyz, _, _ = demo_arrays(args.tiles * args.points, seed=3)
    with tempfile.TemporaryDirectory() as tmp:
        tiles, one = Path(tmp) / "tiles", Path(tmp) / "one"
        tiles.mkdir()
        one.mkdir()
        for k in range(args.tiles):
            _write(tiles / f"t{k:06d}.{args.format}", xyz[k * args.points : (k + 1) * args.points])
        _write(one / f"all.{args.format}", xyz)
        if args.open:
            return _compare_opens(tiles, args)
        _timed([one], Path(tmp) / "warm", args.memory_limit)  # numba's compile: not counted
        times: dict[str, list[float]] = {"tiles": [], "one file": []}
        for r in range(args.rounds):
            times["tiles"].append(_timed([tiles], Path(tmp) / f"t{r}", args.memory_limit))
            times["one file"].append(_timed([one], Path(tmp) / f"o{r}", args.memory_limit))
    n = len(xyz)
    print(f"{cpu_model()}; {args.tiles:,} tiles of {args.points} points ({n:,}), {'memory limit ' + args.memory_limit if args.memory_limit else 'held in memory'}")
    med = _medians(times, n)
    print(f"  tiles / one file: {med['tiles'] / med['one file']:.1f}x, {(med['tiles'] - med['one file']) / args.tiles * 1e3:.2f} ms a tile")
    return 0


def _write(path: Path, xyz: np.ndarray) -> None:
    if path.suffix == ".npy":
        np.save(path, xyz)
        return
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.write(str(path))


def _medians(times: dict[str, list[float]], n: int) -> dict[str, float]:
    """Each way's median seconds, printed with its points/s."""
    med = {k: statistics.median(v) for k, v in times.items()}
    for k, s in med.items():
        print(f"  {k:11s} {s:6.2f} s (median of {len(times[k])}), {n / s / 1e6:.3f} M points/s")
    return med


def _compare_opens(tiles: Path, args) -> int:
    _opened(tiles, True)  # numba's compile: not counted
    times: dict[str, list[float]] = {"plain": [], "progressive": []}
    for _ in range(args.rounds):
        times["plain"].append(_opened(tiles, False))
        times["progressive"].append(_opened(tiles, True))
    n = args.tiles * args.points
    print(f"{cpu_model()}; gigapoint.open of {args.tiles:,} {args.format.upper()} tiles of {args.points} points ({n:,})")
    med = _medians(times, n)
    print(f"  progressive / plain: {med['progressive'] / med['plain']:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
