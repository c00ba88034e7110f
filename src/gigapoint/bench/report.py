"""Reading the benchmark's arguments and presenting its results (a rich table, JSON)."""

from __future__ import annotations

import functools
import json
import math
import platform
import subprocess
import sys
from pathlib import Path

from ..atomic import atomic_bytes, folder_refusal, folders_for, refuse
from ..errors import GigapointError
from ..io.demo import MAX_DEMO_POINTS
from .scene import THROUGHPUT_DEFINITION

_SUFFIXES = {"k": 10**3, "m": 10**6, "g": 10**9, "b": 10**9}


# The command runs as the child of a small launcher, which reports the command's peak RSS: a
# process a large one starts (vfork, then exec) takes that one's high-water mark as its own
# ru_maxrss (Linux keeps it across exec), so wait4 from a benchmark that holds 1.5 GB reports
# 1.5 GB even for /bin/true; the launcher's own few MB are the floor instead.
_LAUNCHER = (
    "import os, subprocess, sys\n"
    "p = subprocess.Popen(sys.argv[2:])\n"
    "_, status, usage = os.wait4(p.pid, 0)\n"
    "open(sys.argv[1], 'w').write(str(usage.ru_maxrss))\n"
    "sys.exit(os.waitstatus_to_exitcode(status))\n"
)


def run_measured(cmd: list) -> tuple[int, bytes, bytes, float, int]:
    """Run ``cmd`` (its output captured): (exit code, stdout, stderr, wall seconds, its peak RSS
    in bytes, measured through a small launcher: see above)."""
    import sys
    import tempfile
    import time

    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "peak_kb"
        t = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", _LAUNCHER, str(report), *map(str, cmd)], capture_output=True, check=False)
        wall = time.perf_counter() - t
        peak = int(report.read_text()) * 1024 if report.is_file() else 0
    return proc.returncode, proc.stdout, proc.stderr, wall, peak


def one_line_errors(main):
    """A benchmark script's ``main(argv)``: its exit status, 0, or 1 with a GigapointError
    (bad arguments, a missing tool or device) said in one line on stderr, not a traceback."""

    @functools.wraps(main)
    def run(argv=None) -> int:
        try:
            return main(argv) or 0
        except GigapointError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1

    return run


def cpu_model() -> str:
    """The CPU's model name (``lscpu``), for every benchmark's figures: the machine changes."""
    try:
        out = subprocess.run(["lscpu"], check=False, capture_output=True, text=True).stdout
    except OSError:
        out = ""
    model = next((line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name")), "")
    return model or platform.processor() or "unknown CPU"


def machine_pages() -> tuple[int, int]:
    """(bytes of pages the kernel has handed out, bytes it has given back to a VM's host), both
    machine-wide and counted since boot (``/proc/vmstat`` pgalloc_*, free page reporting's
    ``reported_kib``; 0 where a system has neither). The difference of two readings is the new
    memory a benchmark needed: on a VM that reports free pages (this project's machines) new
    memory costs ~0.4 ms a MB in 4 KiB pages and ~2.5 ms a MB in numpy's huge pages
    (core/pages.py, docs/benchmarks.md "Huge pages"), so a run's time moves with it."""
    try:
        with open("/proc/vmstat") as fh:
            alloc = sum(int(v) for k, v in (line.split() for line in fh) if k.startswith("pgalloc_")) * 4096
    except OSError:
        alloc = 0
    try:
        with open("/sys/module/page_reporting/parameters/reported_kib") as fh:
            reported = int(fh.read()) * 1024
    except (OSError, ValueError):
        reported = 0
    return alloc, reported


def pages_since(before: tuple[int, int]) -> dict:
    """MiB of pages handed out and given back to the host since ``machine_pages()`` gave ``before``."""
    alloc, reported = machine_pages()
    return {"alloc_mib": (alloc - before[0]) / 2**20, "reported_mib": (reported - before[1]) / 2**20}


def parse_count(text, option: str = "--points") -> int:
    """'20M', '100_000_000', '1e6', '200k' -> a positive int; errors name ``option``."""
    s = str(text).strip().lower().replace("_", "").replace(",", "")
    mult = 1
    if s and s[-1] in _SUFFIXES:
        s, mult = s[:-1], _SUFFIXES[s[-1]]
    try:
        value = float(s) * mult
    except ValueError:
        raise GigapointError(f"{option}: cannot read {text!r} (use e.g. 20M, 200k, 1e6 or 5000000)") from None
    if not (math.isfinite(value) and value >= 1 and value == int(value)):
        raise GigapointError(f"{option}: need a positive whole number of points, got {text!r}")
    if value > MAX_DEMO_POINTS:  # (1e99 was said as a 100-digit count of points and of terabytes)
        raise GigapointError(f"{option}: the demo scene has at most {MAX_DEMO_POINTS:,} points, got {text!r}")
    return int(value)


def parse_counts(parser, *given: tuple[str, object]) -> list[int]:
    """``parse_count`` of each (option, text); a bad one is ``parser``'s error (an
    argparse.ArgumentParser's: the usage and one line naming the option, exit status 2), as
    argparse says any other bad option, not a traceback."""
    try:
        return [parse_count(text, option) for option, text in given]
    except GigapointError as exc:
        parser.error(str(exc))


def parse_threads(text) -> int | None:
    """'all' -> None (every core), else a positive int."""
    s = str(text).strip().lower()
    if s in ("all", "none", "0"):
        return None
    try:
        value = int(s)
    except ValueError:
        raise GigapointError(f"--threads: need a positive integer or 'all', got {text!r}") from None
    if value < 1:
        raise GigapointError(f"--threads: need a positive integer or 'all', got {text!r}")
    return value


def write_results(results: list[dict], path) -> Path:
    """Write the results as JSON (atomically), the folders missing on its way made, and return the path."""
    path = Path(path)
    refuse(path, folder_refusal(path.parent), GigapointError)
    with folders_for(path):
        return atomic_bytes(path, (json.dumps(results, indent=2) + "\n").encode())


def _mps(v: float) -> str:
    return f"{v / 1e6:,.1f} M" if math.isfinite(v) else "-"


def _short(n: int) -> str:
    """1234567 -> '1.23M', 4096 -> '4.1k'."""
    for div, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if n >= div:
            return f"{n / div:.3g}{unit}"
    return str(n)


def _render_row(table, r: dict, step: str, threads: str, note: str, culled: str = "", bits: str = "") -> None:
    """One timed frame's row: gigapoint, the naive loop or GL_POINTS."""
    table.add_row(_short(r["points"]), step, r["view"], threads, f"{r['frame_ms']:,.1f}", _mps(r["points_per_second"]), culled, bits, f"{r['coverage']:.1%}", note)


def results_table(results: list[dict]):
    """A rich Table of ``run_render_benchmark`` results."""
    from rich.table import Table

    env = next((r for r in results if r["kind"] == "environment"), {})
    table = Table(title="gigapoint brute-force render benchmark", caption=THROUGHPUT_DEFINITION)
    for col in ("points", "step", "view", "threads", "ms", "points/s", "culled", "10/20/30 bit", "coverage", "note"):
        table.add_column(col, justify="left" if col in ("step", "view", "note") else "right")
    for r in results:
        if r["kind"] in ("generate", "build"):
            if r["kind"] == "build":
                step, note = "build", f"Morton sort + batching, {r['batches']:,} batches"
            else:
                step, note = "generate", f"demo scene, median of {len(r['seconds_runs'])} after a warm-up run"
            table.add_row(_short(r["points"]), step, "", "", f"{r['seconds'] * 1e3:,.0f}", _mps(r["points_per_second"]), "", "", "", note)
        elif r["kind"] == "render" and r["renderer"] == "gigapoint":
            h = r["precision_histogram"]
            culled = f"{r['batches_culled']:,}/{r['batches_total']:,}"
            bits = "/".join(_short(h[b]) for b in ("10", "20", "30"))
            _render_row(table, r, "gigapoint", str(r["threads"]), f"raster {r['raster_ms']:,.1f} ms", culled, bits)
        elif r["kind"] == "render" and r["renderer"] == "naive":
            note = f"loop {r['raster_ms']:,.1f} ms; gigapoint / naive = {r['gigapoint_over_naive']:.2f}x; IoU {r['coverage_iou']:.2f}"
            _render_row(table, r, "naive loop", str(r["threads"]), note)
        elif r["kind"] == "render" and r["renderer"] == "gl":
            if r.get("skipped"):
                table.add_row(_short(r["points"]), "GL_POINTS", r["view"], "", "", "", "", "", "", f"skipped: {r['reason']}")
                continue
            ok = "ok" if r["coverage_matches"] else "MISMATCH"
            note = f"gigapoint ({r['gigapoint_threads']} thr) / GL = {r['gigapoint_over_gl']:.1f}x; coverage {ok}, IoU {r['coverage_iou']:.2f}"
            _render_row(table, r, "GL_POINTS", str(env.get("gl_threads", "all")), note)
    if env.get("gl_renderer"):
        table.caption += f"\nGL: {env['gl_renderer']}; CPU: {env['cpu_count']} cores, numba {env['numba']}"
    return table


def print_results(results: list[dict], console=None) -> None:
    """Print the results table (wide enough to stay readable when stdout is not a terminal)."""
    import sys

    from rich.console import Console

    if console is None:
        console = Console() if sys.stdout.isatty() else Console(width=200)
    console.print(results_table(results))


