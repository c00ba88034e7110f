"""First render through the CLI: `gigapoint render FILE.las -o out.png` of a 1 M point file, a
fresh process each time, on a warm numba cache (issue #2 asks for under 2 s).

    .venv/bin/python benchmarks/bench_cli.py [--points 1000000] [--runs 7]

One unmeasured run first fills numba's cache. Then, alternating run by run so that the shared
machine's drift hits all of them alike:
- ``gigapoint``: the console script as installed (``gigapoint.cli:run``);
- ``main()`` + normal exit: the same command through ``sys.exit(main())``, i.e. with the
  interpreter's teardown that ``run`` skips;
- ``import``: ``import gigapoint.cli`` alone, the floor of any command.
Reported: the median and fastest wall time of each, and points/s of the first.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_convert import demo_las_in


def timed(cmd: list[str]) -> float:
    t = time.perf_counter()
    proc = subprocess.run(cmd, check=False, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    dt = time.perf_counter() - t
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr.strip()}")
    return dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--workdir", default=None, help="keep the LAS file and the images here")
    ap.add_argument("--json", default=None, help="also write the results here")
    a = ap.parse_args()
    work, las = demo_las_in(a.workdir, a.points, "bench_cli_")
    script = Path(sys.executable).with_name("gigapoint")
    console = [str(script)] if script.exists() else [sys.executable, "-m", "gigapoint.cli"]
    args = ["render", str(las), "-o", str(work / "out.png"), "--overwrite"]
    commands = {
        "gigapoint": console + args,
        "main() + normal exit": [sys.executable, "-c", "import sys; from gigapoint.cli import main; sys.exit(main(sys.argv[1:]))", *args],
        "import": [sys.executable, "-c", "import gigapoint.cli"],
    }
    try:
        timed(commands["gigapoint"])  # fills numba's cache (not measured)
        times: dict[str, list[float]] = {name: [] for name in commands}
        for _ in range(a.runs):
            for name, cmd in commands.items():
                times[name].append(timed(cmd))
    finally:
        if not a.workdir:
            shutil.rmtree(work, ignore_errors=True)
    results = []
    for name, ts in times.items():
        med = float(np.median(ts))
        row = {"command": name, "median_s": med, "best_s": min(ts), "runs": len(ts)}
        if name != "import":
            row["points_per_s"] = a.points / med
        results.append(row)
        pps = f", {a.points / med / 1e6:.2f} M points/s" if name != "import" else ""
        print(f"{name:22s} median {med:.3f} s, best {min(ts):.3f} s{pps}")
    print(f"{a.points:,} points, {a.runs} runs each, alternating (issue #2: under 2 s for 1 M points)")
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
