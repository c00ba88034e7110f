"""Copies the PDAL test datasets used by tests/unit/test_ept_interop.py from a PDAL checkout
(``python make.py PDAL/test/data``) and derives the two small ellipsoid datasets (README.md)."""

import io
import json
import shutil
import sys
from pathlib import Path

import zstandard

src, here = Path(sys.argv[1]), Path(__file__).resolve().parent
COPIED = [
    "ept/1.2-with-color", "ept/bad-pointcount/laszip", "ept/bcbf", "ept/ellipsoid-nopoints",
    "ept/lone-star-laszip/ept.json", "ept/lone-star-laszip/ept-hierarchy",
    "ept/lone-star-laszip/ept-data/3-5-4-3.laz", "ept/lone-star-laszip/ept-data/3-5-4-4.laz",
    "ept/lone-star-invalid-tile/ept.json", "ept/lone-star-invalid-tile/ept-hierarchy",
    "ept/lone-star-invalid-tile/ept-data/2-2-2-2.laz",
    "copc/1.2-with-color.copc.laz", "tindex/autzen_clip_native.copc.laz", "tindex/autzen_clip_4326.copc.laz",
]  # fmt: skip
for rel in COPIED:
    to = here / rel.split("/", 1)[1]
    to.parent.mkdir(parents=True, exist_ok=True)
    (shutil.copytree if (src / rel).is_dir() else shutil.copy)(src / rel, to)

# ellipsoid-zstandard's one node (1.6 MB) thinned to every 50th record: as zstandard and as binary
zst = src / "ept/ellipsoid-zstandard"
raw = zstandard.ZstdDecompressor().stream_reader(io.BytesIO((zst / "ept-data/0-0-0-0.zst").read_bytes())).read()
meta = json.loads((zst / "ept.json").read_text())
size = sum(d["size"] for d in meta["schema"])
recs = b"".join(raw[i : i + size] for i in range(0, len(raw), 50 * size))
n = len(recs) // size
for kind, data in (("zstandard", zstandard.ZstdCompressor(level=19).compress(recs)), ("binary", recs)):
    d = here / f"ellipsoid-{kind}-2k"
    (d / "ept-data").mkdir(parents=True, exist_ok=True)
    (d / "ept-hierarchy").mkdir(exist_ok=True)
    (d / "ept.json").write_text(json.dumps({**meta, "points": n, "dataType": kind}, indent=2) + "\n")
    (d / "ept-hierarchy/0-0-0-0.json").write_text(json.dumps({"0-0-0-0": n}) + "\n")
    (d / "ept-data" / ("0-0-0-0.zst" if kind == "zstandard" else "0-0-0-0.bin")).write_bytes(data)
