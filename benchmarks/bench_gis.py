"""gigapoint's GIS commands against PDAL's on the same file, in the same run: whole-process wall
time of the commands a user types, alternating gigapoint and PDAL round by round, medians of R
rounds, peak RSS of both, and a check that each pair's outputs agree.

    .venv/bin/python benchmarks/bench_gis.py [--points 20M] [--rounds 3] [--formats las,laz] [--jobs filter,thin,tile,stats,dtm,copy,reproject,ground,colorize,noise] [--input FILE.las] [--workdir DIR] [--pdal pdal]

Smoke check (under a minute with PDAL installed): ``--points 200000 --rounds 1``.

The input is the demo town's first N points as a LAS 1.2 file (point format 3, 0.001 scale:
bench_convert.write_las) and a LAZ copy of it (``--formats``), or ``--input`` an existing LAS
file (its LAZ copy written beside it in the work folder). The pairs (``{in}`` the LAS or LAZ file):

    filter  gigapoint convert {in} -o ground.laz --classes 2
            pdal translate {in} ground.laz -f filters.range --filters.range.limits="Classification[2:2]"
    thin    gigapoint convert {in} -o thin.laz --thin 1
            pdal translate {in} thin.laz -f filters.voxeldownsize --filters.voxeldownsize.cell=1
                 --filters.voxeldownsize.mode=first
            (both keep the first point of each 1-unit cube; gigapoint's cubes are anchored at 0,
            PDAL's at the first point less half a cell: the counts differ a little, both shown)
    tile    gigapoint tile {in} --size 500 -o tiles/
            pdal tile {in} "tiles/out_#.laz" --length 500 --origin_x 0 --origin_y 0
            (PDAL's tile grid starts at the first point unless told; at 0 the grids are the same)
    stats   gigapoint info --stats {in} --json
            pdal info --stats {in}
    dtm     gigapoint render {in} -o o.png --classes 2 --gsd 1 --depth-out dtm.tif --size-mode fixed --point-size 1
            pdal pipeline dtm.json: the file, filters.range Classification[2:2], writers.gdal
            (output_type max, resolution 1, binmode: a cell's points only, float32) on
            gigapoint's grid (edges on whole multiples of the gsd: origin_x/origin_y/width/height)
    copy    gigapoint convert {in} -o copy.las
            pdal translate {in} copy.las
            (the baseline of reproject: the same read and write without the transform)
    reproject  gigapoint convert {in} -o utm.las --from-crs EPSG:2992 --to-crs EPSG:32610
            pdal translate {in} utm.las reprojection --filters.reprojection.in_srs=EPSG:2992
                 --filters.reprojection.out_srs=EPSG:32610
            (the demo town, which names no CRS, taken as Oregon Lambert in feet, as autzen is,
            into UTM 10N metres; the check: the largest distance between the two files' points)
    ground  gigapoint classify {in} -o smrf.laz --ground
            pdal translate {in} smrf.laz smrf
            (SMRF with both tools' defaults, in the file's units: PDAL takes them as they are, metres
            or not; the check: agreement of their class 2, point by point, and Cohen's kappa. Needs a
            PDAL with filters.smrf: --jobs without ground for one that lacks it)
    colorize  gigapoint convert {in} -o colored.las --colorize ortho.tif
            pdal translate {in} colored.las colorization --filters.colorization.raster=ortho.tif
                 --filters.colorization.dimensions=Red:1:257,Green:2:257,Blue:3:257
            (ortho.tif: an 8-bit RGB GeoTIFF over the file's extent, ORTHO_PIXELS on its long
            side, in 512-pixel tiles, written once into the work folder; like the points, it
            names no CRS; PDAL's scale 257 is gigapoint's 8 -> 16 bits; compare with copy; the
            check: the share of points whose colours are the same in both files)
    noise   gigapoint classify {in} -o noise.laz --noise --step 4 --isolated 5
            pdal translate {in} noise.laz outlier --filters.outlier.method=radius
                 --filters.outlier.radius=4 --filters.outlier.min_k=6
            (lasnoise's rule against PDAL's radius outlier filter: at most 5 other points in the
            27 cells of 4 units around a point's, against at most 5 others within 4 units of it
            (PDAL: noise where the radius search, the point included, finds min_k or fewer):
            neighbourhoods alike, not the same; the check: both tools' class 7, point by point.
            Needs a PDAL with filters.outlier)

Each command runs once on a 20 000-point file first (numba's cache filled: JIT compile time
excluded; PDAL's libraries loaded once), then R rounds of the pairs in turn, gigapoint first in
odd rounds and PDAL first in even ones. Times include start-up (the Python interpreter and its
imports; PDAL's plugin scan): they are what a user waits for. The machine may be shared:
compare the ratios, measured side by side, rather than absolute times.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_convert import write_las, write_laz  # a sibling script: its folder is sys.path[0]

from gigapoint.bench import run_measured
from gigapoint.bench.report import cpu_model, parse_counts

JOBS = ("filter", "thin", "tile", "stats", "dtm", "copy", "reproject", "ground", "colorize", "noise")
#: the PDAL stage a job needs beyond the core ones (builds without PROJ, GDAL or some filters lack them)
PDAL_STAGE = {"reproject": "filters.reprojection", "ground": "filters.smrf", "colorize": "filters.colorization", "noise": "filters.outlier"}
#: reproject's CRSs: Oregon Lambert (NAD83, international feet; autzen's) -> WGS 84 / UTM 10N (metres)
FROM_CRS, TO_CRS = "EPSG:2992", "EPSG:32610"
GSD = 1.0
TILE = 500.0
SPACING = 1.0
#: pixels along the long side of colorize's orthophoto
ORTHO_PIXELS = 8192
#: each point in its own pixel (the exact one-pixel render), as PDAL's binmode puts it in its own
#: cell; render's default (adaptive) draws points as large as their spacing: a surface with no gaps
DTM_POINTS = ("--size-mode", "fixed", "--point-size", "1")


def gp_cmd(*args) -> list[str]:
    return [sys.executable, "-m", "gigapoint.cli", *map(str, args)]


def dtm_grid(las: Path, gsd: float) -> tuple[float, float, int, int]:
    """(origin_x, origin_y, width, height) of gigapoint's top-down grid of the ground points
    (camera.Camera.top_down over the bounds of the class 2 points it renders: pixel edges on
    whole multiples of the gsd; asked of top_down itself, whose margins a copy here missed)."""
    import laspy

    from gigapoint import Camera

    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    with laspy.open(str(las)) as f:
        for pts in f.chunk_iterator(2_000_000):
            ground = np.asarray(pts.classification) == 2
            if ground.any():
                x, y = np.asarray(pts.x)[ground], np.asarray(pts.y)[ground]
                lo = np.minimum(lo, [x.min(), y.min()])
                hi = np.maximum(hi, [x.max(), y.max()])
    cam = Camera.top_down(((lo[0], lo[1], 0.0), (hi[0], hi[1], 0.0)), gsd)
    _, _, _, _, centre_x, centre_y = cam.world_file()  # of the upper-left pixel
    # edges are whole multiples of the gsd: rounded, the sums above leave no float residue
    left, top = round(centre_x / gsd - 0.5) * gsd, round(centre_y / gsd + 0.5) * gsd
    return left, top - cam.height * gsd, cam.width, cam.height


def write_ortho(las: Path, path: Path) -> Path:
    """An 8-bit RGB GeoTIFF over ``las``'s header extent (``ORTHO_PIXELS`` along its long side,
    tiled), of a pattern whose neighbouring pixels differ, naming no CRS (as the demo town)."""
    import laspy
    import rasterio
    from rasterio.transform import from_origin

    with laspy.open(str(las)) as f:
        lo, hi = f.header.mins, f.header.maxs
    pixel = max(hi[0] - lo[0], hi[1] - lo[1]) / (ORTHO_PIXELS - 1)
    width, height = (int((hi[k] - lo[k]) / pixel) + 2 for k in (0, 1))
    profile = {"driver": "GTiff", "width": width, "height": height, "count": 3, "dtype": "uint8", "tiled": True, "blockxsize": 512,
               "blockysize": 512, "transform": from_origin(lo[0] - pixel / 2, hi[1] + pixel / 2, pixel, pixel)}  # fmt: skip
    with rasterio.open(path, "w", **profile) as ds:
        for top in range(0, height, 512):
            rows, cols = np.mgrid[top : min(top + 512, height), 0:width]
            window = rasterio.windows.Window(0, top, width, rows.shape[0])
            ds.write(np.stack([(cols * 3) % 256, (rows * 5) % 256, (cols + 2 * rows) % 256]).astype(np.uint8), window=window)
    return path


def commands(job: str, inp: Path, out: Path, pdal: str, grid, ortho: Path | None = None) -> tuple[list[str], list[str]]:
    """(gigapoint's command, PDAL's) for ``job`` on ``inp``, writing under ``out`` (``ortho``: colorize's raster)."""
    if job == "filter":
        return (
            gp_cmd("convert", inp, "-o", out / "gp_ground.laz", "--classes", "2", "--quiet"),
            [pdal, "translate", str(inp), str(out / "pdal_ground.laz"), "-f", "filters.range", "--filters.range.limits=Classification[2:2]"],
        )
    if job == "thin":
        return (
            gp_cmd("convert", inp, "-o", out / "gp_thin.laz", "--thin", SPACING, "--quiet"),
            [pdal, "translate", str(inp), str(out / "pdal_thin.laz"), "-f", "filters.voxeldownsize",
             f"--filters.voxeldownsize.cell={SPACING}", "--filters.voxeldownsize.mode=first"],
        )
    if job == "tile":
        (out / "pdal_tiles").mkdir(exist_ok=True)
        return (
            gp_cmd("tile", inp, "--size", TILE, "-o", out / "gp_tiles", "--quiet"),
            [pdal, "tile", str(inp), str(out / "pdal_tiles" / "out_#.laz"), "--length", str(TILE), "--origin_x", "0", "--origin_y", "0"],
        )
    if job == "stats":
        return gp_cmd("info", "--stats", inp, "--json"), [pdal, "info", "--stats", str(inp)]
    if job == "dtm":
        ox, oy, w, h = grid
        pipeline = [
            str(inp),
            {"type": "filters.range", "limits": "Classification[2:2]"},
            {"type": "writers.gdal", "filename": str(out / "pdal_dtm.tif"), "output_type": "max", "resolution": GSD,
             "binmode": True, "data_type": "float32", "origin_x": ox, "origin_y": oy, "width": w, "height": h},
        ]
        spec = out / "dtm.json"
        spec.write_text(json.dumps(pipeline))
        return (
            gp_cmd("render", inp, "-o", out / "gp_ortho.png", "--classes", "2", "--gsd", GSD, "--depth-out", out / "gp_dtm.tif", *DTM_POINTS),
            [pdal, "pipeline", str(spec)],
        )
    if job == "copy":
        return gp_cmd("convert", inp, "-o", out / "gp_copy.las", "--quiet"), [pdal, "translate", str(inp), str(out / "pdal_copy.las")]
    if job == "reproject":
        return (
            gp_cmd("convert", inp, "-o", out / "gp_utm.las", "--from-crs", FROM_CRS, "--to-crs", TO_CRS, "--quiet"),
            [pdal, "translate", str(inp), str(out / "pdal_utm.las"), "reprojection",
             f"--filters.reprojection.in_srs={FROM_CRS}", f"--filters.reprojection.out_srs={TO_CRS}"],
        )
    if job == "ground":
        return (
            gp_cmd("classify", inp, "-o", out / "gp_smrf.laz", "--ground", "--quiet"),
            [pdal, "translate", str(inp), str(out / "pdal_smrf.laz"), "smrf"],
        )
    if job == "colorize":
        return (
            gp_cmd("convert", inp, "-o", out / "gp_colored.las", "--colorize", ortho, "--quiet"),
            [pdal, "translate", str(inp), str(out / "pdal_colored.las"), "colorization", f"--filters.colorization.raster={ortho}",
             "--filters.colorization.dimensions=Red:1:257,Green:2:257,Blue:3:257"],
        )
    if job == "noise":
        return (
            gp_cmd("classify", inp, "-o", out / "gp_noise.laz", "--noise", "--step", "4", "--isolated", "5", "--quiet"),
            [pdal, "translate", str(inp), str(out / "pdal_noise.laz"), "outlier", "--filters.outlier.method=radius",
             "--filters.outlier.radius=4", "--filters.outlier.min_k=6"],
        )
    raise ValueError(job)


def clean(out: Path) -> None:
    """The last run's outputs removed (neither tool overwrites by default)."""
    for p in out.iterdir():
        if p.name == "dtm.json":
            continue
        shutil.rmtree(p) if p.is_dir() else p.unlink()


def run(cmd: list[str]) -> tuple[float, int, bytes]:
    code, stdout, err, wall, peak = run_measured(cmd)
    if code != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({code}): {err.decode(errors='replace')[-2000:]}")
    return wall, peak, stdout


def las_count(path: Path) -> int:
    import laspy

    with laspy.open(str(path)) as f:
        return int(f.header.point_count)


def tiles_count(folder: Path) -> tuple[int, int]:
    files = sorted(p for p in folder.iterdir() if p.suffix in (".las", ".laz"))
    return len(files), sum(las_count(p) for p in files)


def compare_dtm(gp_tif: Path, pdal_tif: Path) -> dict:
    """Both DTMs' heights on the same cells: cells with a height in both, in one only, and how
    far apart the shared ones are (max heights of the same points: 0 but for points on a cell
    edge, which gigapoint puts in the row above, PDAL below)."""
    import rasterio

    with rasterio.open(gp_tif) as a, rasterio.open(pdal_tif) as b:
        ga, gb = a.transform, b.transform
        za, zb = a.read(1).astype(np.float64), b.read(1).astype(np.float64)
        nb = b.nodata
    if za.shape != zb.shape or not np.allclose(tuple(ga)[:6], tuple(gb)[:6]):
        return {"same_grid": False, "gigapoint": f"{za.shape} {tuple(ga)[:6]}", "pdal": f"{zb.shape} {tuple(gb)[:6]}"}
    va = np.isfinite(za)
    vb = np.isfinite(zb) & ((zb != nb) if nb is not None else True)
    both = va & vb
    d = np.abs(za[both] - zb[both])
    return {
        "same_grid": True,
        "cells": int(za.size),
        "both": int(both.sum()),
        "gigapoint_only": int((va & ~vb).sum()),
        "pdal_only": int((vb & ~va).sum()),
        "equal_within_1mm": round(float((d <= 0.0015).mean()) if d.size else 1.0, 5),
        "max_abs_diff": round(float(d.max()) if d.size else 0.0, 3),
    }


def check(job: str, out: Path, gp_stdout: bytes, pdal_stdout: bytes, n: int) -> dict:
    """What the pair's outputs say (counts), and whether they agree where they should."""
    if job == "filter":
        a, b = las_count(out / "gp_ground.laz"), las_count(out / "pdal_ground.laz")
        return {"gigapoint_points": a, "pdal_points": b, "agree": a == b}
    if job == "thin":
        a, b = las_count(out / "gp_thin.laz"), las_count(out / "pdal_thin.laz")
        return {"gigapoint_points": a, "pdal_points": b, "ratio": round(a / b, 4), "agree": "by rule (grid origins differ)"}
    if job == "tile":
        (ta, a), (tb, b) = tiles_count(out / "gp_tiles"), tiles_count(out / "pdal_tiles")
        return {"gigapoint_tiles": ta, "pdal_tiles": tb, "gigapoint_points": a, "pdal_points": b, "agree": a == b == n and ta == tb}
    if job == "stats":
        g = json.loads(gp_stdout)
        p = json.loads(pdal_stdout)
        pst = {s["name"]: s for s in p["stats"]["statistic"]}
        pb = [[pst[d]["minimum"] for d in "XYZ"], [pst[d]["maximum"] for d in "XYZ"]]
        gb = [g["bounds"]["min"], g["bounds"]["max"]]
        same_bounds = bool(np.allclose(gb, pb, atol=1e-6))
        return {"gigapoint_points": g["point_count"], "pdal_points": pst["X"]["count"], "same_bounds": same_bounds,
                "agree": g["point_count"] == pst["X"]["count"] == n and same_bounds}
    if job == "dtm":
        r = compare_dtm(out / "gp_dtm.tif", out / "pdal_dtm.tif")
        # (a point on a row's edge: gigapoint's cell above it, PDAL's below; a few in 10^4 cells)
        r["agree"] = bool(r.get("same_grid") and r["gigapoint_only"] + r["pdal_only"] <= 0.002 * r["both"] and r["equal_within_1mm"] > 0.99)
        return r
    if job == "copy":
        a, b = las_count(out / "gp_copy.las"), las_count(out / "pdal_copy.las")
        return {"gigapoint_points": a, "pdal_points": b, "agree": a == b == n}
    if job == "reproject":
        return compare_points(out / "gp_utm.las", out / "pdal_utm.las", n)
    if job == "ground":
        return compare_ground(out / "gp_smrf.laz", out / "pdal_smrf.laz")
    if job == "colorize":
        return compare_colors(out / "gp_colored.las", out / "pdal_colored.las", n)
    if job == "noise":
        return compare_noise(out / "gp_noise.laz", out / "pdal_noise.laz")
    raise ValueError(job)


def compare_points(a: Path, b: Path, n: int) -> dict:
    """Both files' points in order: the largest distance between the same point in each (PDAL
    writes a 0.01 grid by default: up to 0.005 per axis of it), and the grids they chose."""
    import laspy

    with laspy.open(str(a)) as fa, laspy.open(str(b)) as fb:
        far = 0.0
        for pa, pb in zip(fa.chunk_iterator(1_000_000), fb.chunk_iterator(1_000_000)):
            d = np.stack([np.asarray(pa[k]) - np.asarray(pb[k]) for k in "xyz"], axis=1)
            far = max(far, float(np.abs(d).max()))
        scales = [list(fa.header.scales), list(fb.header.scales)]
        counts = [int(fa.header.point_count), int(fb.header.point_count)]
    return {"points": counts, "max_abs_diff": round(far, 4), "scales": scales, "agree": counts == [n, n] and far <= 0.01}


def compare_ground(gp_laz: Path, pdal_laz: Path) -> dict:
    """Both classifications' ground (class 2), point by point (both tools write the points in
    the input's order): how many each finds, the share of points they agree on, Cohen's kappa."""
    import laspy

    a, b = (np.asarray(laspy.read(str(p)).classification) == 2 for p in (gp_laz, pdal_laz))
    if len(a) != len(b):
        return {"gigapoint_points": len(a), "pdal_points": len(b), "agree": False}
    agree = float((a == b).mean())
    chance = a.mean() * b.mean() + (1 - a.mean()) * (1 - b.mean())
    kappa = (agree - chance) / (1 - chance) if chance < 1 else 1.0
    return {"gigapoint_ground": int(a.sum()), "pdal_ground": int(b.sum()), "agreement": round(agree, 4), "kappa": round(float(kappa), 4), "agree": "by measure"}


def compare_colors(a: Path, b: Path, n: int) -> dict:
    """The share of points (in order) whose red, green and blue are the same in both files."""
    import laspy

    with laspy.open(str(a)) as fa, laspy.open(str(b)) as fb:
        same = 0
        for pa, pb in zip(fa.chunk_iterator(1_000_000), fb.chunk_iterator(1_000_000)):
            same += int(np.all([np.asarray(pa[c]) == np.asarray(pb[c]) for c in ("red", "green", "blue")], axis=0).sum())
        counts = [int(fa.header.point_count), int(fb.header.point_count)]
    return {"points": counts, "same_colour": round(same / max(n, 1), 5), "agree": counts == [n, n] and same == n}


def compare_noise(gp_laz: Path, pdal_laz: Path) -> dict:
    """Both tools' noise (class 7), point by point (in the input's order): how many each flags, how many both do."""
    import laspy

    a, b = (np.asarray(laspy.read(str(p)).classification) == 7 for p in (gp_laz, pdal_laz))
    if len(a) != len(b):
        return {"gigapoint_points": len(a), "pdal_points": len(b), "agree": False}
    return {"gigapoint_noise": int(a.sum()), "pdal_noise": int(b.sum()), "both": int((a & b).sum()), "agree": "by measure"}


WARM = """
import json, sys
from gigapoint.cli import main
for argv in json.loads(sys.argv[1]):
    if main(argv):
        raise SystemExit(f"warm-up failed: {argv}")
"""


def warm_up(jobs, inputs, out, pdal, grid, ortho) -> None:
    """Every gigapoint command once on the 20 000-point files, in one process (numba's cache
    filled: JIT compile time excluded; one interpreter start instead of one a command), and
    PDAL's once on the LAS one (its libraries and plugins read from disk)."""
    argvs = []
    for fmt, (_, warm) in inputs.items():
        for job in jobs:
            sub = out / f"warm_{fmt}_{job}"
            sub.mkdir()
            gcmd, pcmd = commands(job, warm, sub, pdal, grid, ortho)
            argvs.append(gcmd[3:])  # less python -m gigapoint.cli
            if fmt == next(iter(inputs)):
                run(pcmd)
    code, _, err, _, _ = run_measured([sys.executable, "-c", WARM, json.dumps(argvs)])
    if code != 0:
        raise SystemExit(f"warm-up failed ({code}): {err.decode(errors='replace')[-2000:]}")
    clean(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", default="20M", help="points of the generated demo file (20M, 5M, 200000)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--formats", default="las,laz", help="input formats to measure: las, laz or both")
    ap.add_argument("--jobs", default=",".join(JOBS))
    ap.add_argument("--input", default=None, help="an existing LAS file instead of the demo town")
    ap.add_argument("--workdir", default=None, help="keep the input files here (reused by later runs)")
    ap.add_argument("--pdal", default=shutil.which("pdal") or "pdal")
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    a = ap.parse_args(argv)
    (n_demo,) = parse_counts(ap, ("--points", a.points))
    jobs = [j for j in a.jobs.split(",") if j]
    if bad := set(jobs) - set(JOBS):
        raise SystemExit(f"unknown jobs {sorted(bad)}; choose from {JOBS}")
    if shutil.which(a.pdal) is None:
        raise SystemExit(f"no PDAL at {a.pdal!r} (--pdal PATH)")
    drivers = os.popen(f"{a.pdal} --drivers 2>/dev/null").read()
    lacking = [job for job in jobs if PDAL_STAGE.get(job, "filters.range") not in drivers]
    if lacking and a.jobs != ",".join(JOBS):  # (asked for by name: say why not rather than leave it out)
        raise SystemExit(f"{a.pdal} has no {', '.join(PDAL_STAGE[j] for j in lacking)}; leave out {', '.join(lacking)} (--jobs)")
    for job in lacking:  # (the default set: each job this PDAL build cannot run is left out, said once)
        print(f"{job}: left out, {a.pdal} has no {PDAL_STAGE[job]}", file=sys.stderr)
    jobs = [j for j in jobs if j not in lacking]
    work = Path(a.workdir) if a.workdir else Path(tempfile.mkdtemp(prefix="bench_gis_"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        if a.input:
            las = Path(a.input)
        else:
            las = work / f"demo_{n_demo}.las"
            if not las.exists():
                t = time.perf_counter()
                write_las(las, n_demo)
                print(f"wrote {las} in {time.perf_counter() - t:.1f} s", file=sys.stderr)
        n = las_count(las)
        warm = work / "warm.las"
        if not warm.exists():
            write_las(warm, 20_000)
        inputs = {}
        for fmt in a.formats.split(","):
            if fmt == "las":
                inputs["las"] = (las, warm)
            elif fmt == "laz":
                laz, warm_laz = work / (las.stem + ".laz"), work / "warm.laz"
                for src, dst in ((las, laz), (warm, warm_laz)):
                    if not dst.exists():
                        write_laz(src, dst)
                inputs["laz"] = (laz, warm_laz)
            else:
                raise SystemExit(f"--formats: las or laz, got {fmt!r}")
        found = re.search(r"pdal (\S+)", os.popen(f"{a.pdal} --version 2>/dev/null").read())
        print(f"{n:,} points, {a.rounds} rounds, {cpu_model()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}, "
              f"PDAL {found.group(1) if found else '?'}", file=sys.stderr)
        out = work / "out"
        out.mkdir(exist_ok=True)
        ortho = work / "ortho.tif"
        if "colorize" in jobs and not ortho.exists():
            write_ortho(las, ortho)
        warm_up(jobs, inputs, out, a.pdal, dtm_grid(warm, GSD), ortho)
        grid = dtm_grid(las, GSD) if "dtm" in jobs else None
        rows = []
        for fmt, (inp, _) in inputs.items():
            for job in jobs:
                times: dict[str, list[float]] = {"gigapoint": [], "pdal": []}
                peaks: dict[str, list[int]] = {"gigapoint": [], "pdal": []}
                verdict = None
                for r in range(a.rounds):
                    clean(out)
                    gcmd, pcmd = commands(job, inp, out, a.pdal, grid, ortho)
                    order = [("gigapoint", gcmd), ("pdal", pcmd)]
                    if r % 2:
                        order.reverse()
                    stdout = {}
                    for tool, cmd in order:
                        wall, peak, stdout[tool] = run(cmd)
                        times[tool].append(wall)
                        peaks[tool].append(peak)
                    if verdict is None:
                        verdict = check(job, out, stdout["gigapoint"], stdout["pdal"], n)
                g, p = statistics.median(times["gigapoint"]), statistics.median(times["pdal"])
                row = {
                    "input": fmt, "job": job, "points": n,
                    "gigapoint_s": round(g, 3), "pdal_s": round(p, 3),
                    "gigapoint_mpts_s": round(n / g / 1e6, 2), "pdal_mpts_s": round(n / p / 1e6, 2),
                    "pdal_over_gigapoint": round(p / g, 2),  # > 1: gigapoint faster
                    "gigapoint_rss_mib": round(max(peaks["gigapoint"]) / 2**20), "pdal_rss_mib": round(max(peaks["pdal"]) / 2**20),
                    "gigapoint_runs_s": [round(t, 2) for t in times["gigapoint"]], "pdal_runs_s": [round(t, 2) for t in times["pdal"]],
                    "check": verdict,
                }
                rows.append(row)
                print(json.dumps(row), flush=True)
        print(f"load average at the end {os.getloadavg()[0]:.2f}", file=sys.stderr)
        print_table(rows)
        if a.json:
            Path(a.json).write_text(json.dumps(rows, indent=1))
    finally:
        if not a.workdir:
            shutil.rmtree(work, ignore_errors=True)
    return 0


def print_table(rows: list[dict]) -> None:
    print()
    print("| input | job | gigapoint s (M pts/s) | PDAL s (M pts/s) | PDAL / gigapoint | peak RSS MiB gigapoint / PDAL | check |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        c = {k: v for k, v in r["check"].items() if k != "agree"}
        print(f"| {r['input']} | {r['job']} | {r['gigapoint_s']:.2f} ({r['gigapoint_mpts_s']}) | {r['pdal_s']:.2f} ({r['pdal_mpts_s']}) | "
              f"{r['pdal_over_gigapoint']:.2f}x | {r['gigapoint_rss_mib']} / {r['pdal_rss_mib']} | {r['check']['agree']}: {json.dumps(c)} |")


if __name__ == "__main__":
    raise SystemExit(main())
