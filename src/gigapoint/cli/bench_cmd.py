"""`gigapoint bench`: the brute-force render benchmark with its GL_POINTS baseline."""

from __future__ import annotations

from pathlib import Path

import typer

from ..errors import GigapointError
from .app import app
from .settings_opts import named_option


@app.command()
def bench(
    points: list[str] = typer.Option(["20M", "100M"], "--points", "-n", help="Point counts of the demo scene (repeat: -n 20M -n 100M)."),
    width: int = typer.Option(1920, "--width", "-W", help="Image width in pixels."),
    height: int = typer.Option(1080, "--height", "-H", help="Image height in pixels."),
    threads: list[str] = typer.Option(["1", "all"], "--threads", help="Thread counts to measure (repeat; 'all' = every core)."),
    repeats: int = typer.Option(5, help="Timed frames per measurement (the median is reported)."),
    gl: bool = typer.Option(True, "--gl/--no-gl", help="Also time GL_POINTS through OpenGL (Mesa llvmpipe via EGL)."),
    naive: bool = typer.Option(True, "--naive/--no-naive", help="Also time a naive numba loop over the same points."),
    out: Path | None = typer.Option(None, "--out", readable=False, help="Directory for the frames as PNG and bench_render.json."),
    json_path: Path | None = typer.Option(None, "--json", readable=False, help="Where to write the JSON results (default: bench_render.json in the --out folder)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing JSON results file."),
) -> None:
    """Measure brute-force rendering (points/s) of the demo scene, overview and close-up, against GL_POINTS and a naive loop."""
    from ..bench import VIEWS, parse_count, parse_threads, print_results, run_render_benchmark, write_results
    from .output import check_output
    from .progress import err_console, progress_bar

    counts = [parse_count(p) for p in points]
    thread_counts = [parse_threads(t) for t in threads]
    target = json_path or (out / "bench_render.json" if out is not None else None)
    if target is not None:  # before any measurement: its folder was said only at the end; --json a.laz replaced the scan
        check_output(target, overwrite, suffixes={".json"})
    err = err_console()
    # the steps it reports: per point count the scene, the GL upload, and per view each thread count, the naive loop, GL
    steps = len(counts) * (1 + gl + len(VIEWS) * (len(thread_counts) + naive + gl))
    with progress_bar("bench", steps, err) as advance:
        step = iter(range(steps + 1))
        try:
            results = run_render_benchmark(
                points=counts,
                width=width,
                height=height,
                threads=thread_counts,
                repeats=repeats,
                gl=gl,
                naive=naive,
                out=out,
                progress=lambda m: advance(min(next(step, steps), steps), m),
            )
        except GigapointError as exc:  # 'image width must be ...' named no option
            raise named_option(exc, {"image width": "--width", "image height": "--height", "benchmark repeats": "--repeats"}) from None
    print_results(results)
    if target is not None:
        err.print(f"results written to {write_results(results, target)}")
