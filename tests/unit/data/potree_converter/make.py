"""Remakes this folder's fixture: town.laz (1200 points of gigapoint's demo town: 16-bit colours,
a fifth of them dark (channels under 256), LAS's signed scan angle rank, extra bytes with a
space in a name), then PotreeConverter 2.1.1's octrees of it:

    PYTHONPATH=src python tests/unit/data/potree_converter/make.py
    PotreeConverter tests/unit/data/potree_converter/town.laz -o tests/unit/data/potree_converter/town_BROTLI --encoding BROTLI
    PotreeConverter tests/unit/data/potree_converter/town.laz -o tests/unit/data/potree_converter/town_DEFAULT --encoding DEFAULT

(log.txt removed from both.)"""

from pathlib import Path

import laspy
import numpy as np

from gigapoint.io import demo_arrays

n = 1200
xyz, rgba, attrs = demo_arrays(n, seed=3)
rng = np.random.default_rng(3)
h = laspy.LasHeader(point_format=3, version="1.2")
h.scales, h.offsets = [0.01, 0.01, 0.01], np.floor(xyz.min(0))
for name, t in (("height above ground", "f4"), ("tilt", "i2"), ("quality", "u1")):
    h.add_extra_dim(laspy.ExtraBytesParams(name, t))
las = laspy.LasData(h)
las.x, las.y, las.z = xyz.T
c16 = rgba[:, :3].astype(np.uint16) * 257
c16[rng.random(n) < 0.2] = rng.integers(0, 256, (1, 3))
las.red, las.green, las.blue = c16.T
las.intensity, las.classification = attrs["intensity"], attrs["classification"]
las.return_number, las.number_of_returns = rng.integers(1, 4, n), np.full(n, 3)
las.user_data, las.point_source_id = rng.integers(0, 255, n), rng.integers(0, 60000, n)
las.gps_time = rng.uniform(0, 1e5, n)
las.scan_angle_rank = rng.integers(-90, 90, n)
las["height above ground"] = rng.uniform(-5, 50, n).astype(np.float32)
las["tilt"], las["quality"] = rng.integers(-30000, 30000, n), rng.integers(0, 255, n)
las.write(Path(__file__).with_name("town.laz"))
