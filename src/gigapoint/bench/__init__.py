"""The brute-force render benchmark (``gigapoint bench``, benchmarks/bench_render.py).

run.py measures the demo scene (scene.py) rendered by gigapoint against two baselines in
the same run: GL_POINTS through OpenGL on the CPU (gl_baseline.py) and a naive numba loop
(naive.py); report.py reads the arguments and presents the results. The CLI imports this
package only when ``gigapoint bench`` runs (it pulls in moderngl).
"""

from .gl_baseline import GLBaseline, gl_matrix
from .naive import naive_frame, naive_matrix, naive_raster
from .report import (
    cpu_model,
    machine_pages,
    one_line_errors,
    pages_since,
    parse_count,
    parse_counts,
    parse_threads,
    print_results,
    results_table,
    run_measured,
    write_results,
)
from .run import COVERAGE_TOLERANCE, run_render_benchmark
from .scene import THROUGHPUT_DEFINITION, VIEWS, benchmark_cameras, comparison_cameras, coverage_iou, demo_cloud, relative_cloud

__all__ = [
    "COVERAGE_TOLERANCE",
    "THROUGHPUT_DEFINITION",
    "VIEWS",
    "GLBaseline",
    "benchmark_cameras",
    "comparison_cameras",
    "coverage_iou",
    "cpu_model",
    "demo_cloud",
    "gl_matrix",
    "machine_pages",
    "naive_frame",
    "naive_matrix",
    "naive_raster",
    "one_line_errors",
    "pages_since",
    "parse_count",
    "parse_counts",
    "parse_threads",
    "print_results",
    "relative_cloud",
    "results_table",
    "run_measured",
    "run_render_benchmark",
    "write_results",
]
