"""How soon ``gigapoint.open(path, progressive=True)`` returns, and when the octree is loaded, for
one NPY and one LAS file of the same points.

    .venv/bin/python benchmarks/bench_open_returns.py --points 20000000

``open`` should return at once and leave the reading to its loader: a reader's ``info()`` of an
NPY file reads every point (its bounds), which ``open`` once did first. Medians of ``--rounds``
(numba's compile before, not counted).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

import gigapoint as gp
from gigapoint.bench import cpu_model


def _timed(path: Path) -> tuple[float, float]:
    t = time.perf_counter()
    cloud = gp.open(path, progressive=True)
    returned = time.perf_counter() - t
    cloud.wait()
    loaded = time.perf_counter() - t
    cloud.close()
    return returned, loaded


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=20_000_000)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    xyz, rgba, _ = gp.demo_arrays(args.points, seed=1)
    with tempfile.TemporaryDirectory() as tmp:
        npy, las = Path(tmp) / "points.npy", Path(tmp) / "points.las"
        np.save(npy, xyz)
        import laspy

        header = laspy.LasHeader(point_format=2, version="1.2")
        header.scales, header.offsets = [0.001] * 3, [0.0] * 3
        data = laspy.LasData(header)
        data.x, data.y, data.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        data.red, data.green, data.blue = (rgba[:, k].astype(np.uint16) * 257 for k in range(3))
        data.write(str(las))
        del xyz, rgba, data
        for path in (npy, las):  # numba's compile: not counted (a LAS load compiles kernels of its own)
            _timed(path)
        print(f"{cpu_model()}; {args.points:,} points, medians of {args.rounds}")
        for path in (npy, las):
            runs = [_timed(path) for _ in range(args.rounds)]
            returned, loaded = (statistics.median(r[k] for r in runs) for k in (0, 1))
            print(f"  {path.suffix[1:].upper()}: open returned in {returned * 1e3:8.1f} ms, loaded in {loaded:6.2f} s ({args.points / loaded / 1e6:.2f} M points/s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
