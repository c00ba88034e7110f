"""numba's threading layer and thread counts (core/threads.py)."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import numba
import pytest

from gigapoint.core import threads
from gigapoint.core.threads import SMALL_BATCH, numba_threads, threads_for

_LAYER = (
    "import sys, numpy as np, gigapoint, numba\n"
    "from gigapoint.core.morton import morton_codes\n"
    "morton_codes(np.zeros((10, 3)), np.zeros(3), 1.0)\n"  # a parallel kernel: numba loads its layer
    "from gigapoint.core.threads import threads_awake\n"
    "print(numba.threading_layer(), threads_awake())\n"
    "import os\n"  # where the library named LIBRARY was loaded from
    "lib = os.environ.get('LIBRARY')\n"
    "lib and print(next(os.path.realpath(l.split()[-1]) for l in open('/proc/self/maps') if l.rstrip().endswith(lib)))\n"
)


def _layer(**env) -> str:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER") and k != "OMP_WAIT_POLICY"}
    run = subprocess.run([sys.executable, "-c", _LAYER], env={**clean, **env}, capture_output=True, text=True, timeout=300)
    return run.stdout.strip() if run.returncode == 0 else f"failed: {run.stderr.strip().splitlines()[-1:]}"


def _wheel_tbb_expected() -> bool:
    """The platforms pyproject.toml names the ``tbb`` wheel a dependency for."""
    return (sys.platform, platform.machine()) in {("linux", "x86_64"), ("win32", "AMD64")}


def test_tbb_of_its_wheel_is_numbas_layer_else_openmp_unless_the_user_chose_one():
    """With the tbb wheel (a dependency where PyPI has one) numba runs on its TBB, loaded by
    path from the environment; without it, OpenMP before an older system TBB (on Debian's 2021.8
    small kernels slowed down as a process went on); a layer the user names is the one loaded."""
    if _wheel_tbb_expected():
        assert threads.wheel_tbb_library(), "the tbb wheel (a dependency here) is not installed"
    default = "tbb True" if threads.wheel_tbb_library() else "omp True"  # idle threads take up work at once (OpenMP's spin a while by default)
    assert _layer() == default
    if default.startswith("tbb") and sys.platform == "linux":  # the wheel's library, also where the user named TBB (not a system one)
        wheel = os.path.realpath(threads.wheel_tbb_library())
        for env in ({}, {"NUMBA_THREADING_LAYER": "tbb"}):
            assert _layer(**env, LIBRARY="libtbb.so.12").endswith(wheel)
    if _layer(NUMBA_THREADING_LAYER="omp") != "omp True":
        pytest.skip("no OpenMP runtime loads here")
    assert _layer(NUMBA_THREADING_LAYER="omp", OMP_WAIT_POLICY="PASSIVE") == "omp False"
    assert _layer(NUMBA_THREADING_LAYER="workqueue") == "workqueue False"
    assert _layer(NUMBA_THREADING_LAYER_PRIORITY="workqueue omp tbb") == "workqueue False"


_FORKED = (
    "import os, numpy as np, gigapoint as gp, numba\n"
    "cloud = gp.demo(20_000)\n"
    "image = gp.render(cloud, width=160, height=120)\n"
    "pid = os.fork()\n"
    "if pid == 0:\n"
    "    os._exit(0 if np.array_equal(gp.render(cloud, width=160, height=120), image) else 3)\n"
    "print(numba.threading_layer(), os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]))\n"
)


@pytest.mark.skipif(sys.platform == "win32", reason="no fork() on Windows")
def test_a_process_forked_after_drawing_draws_the_same_image():
    """multiprocessing's default start on Linux (before Python 3.14) forks: on TBB the child draws
    as its parent; GNU OpenMP terminates it ("fork() called from a process already using GNU OpenMP")."""
    if not threads.wheel_tbb_library():
        pytest.skip("no tbb wheel here: numba runs on OpenMP, which is not fork-safe")
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER")}
    run = subprocess.run([sys.executable, "-c", _FORKED], env=clean, capture_output=True, text=True, timeout=300)
    assert run.stdout.strip() == "tbb 0", run.stderr[-800:]


def test_a_block_runs_on_the_threads_asked_and_gives_the_count_back(monkeypatch):
    before = numba.get_num_threads()
    with numba_threads(1):
        assert numba.get_num_threads() == 1
    assert numba.get_num_threads() == before
    with pytest.raises(ValueError, match="boom"), numba_threads(1):
        raise ValueError("boom")
    assert numba.get_num_threads() == before
    for awake in (False, True):
        monkeypatch.setattr(threads, "threads_awake", lambda awake=awake: awake)
        with threads_for(SMALL_BATCH - 1):
            assert numba.get_num_threads() == 1
        with threads_for(SMALL_BATCH - 1, when_awake=False):
            assert numba.get_num_threads() == (before if awake else 1)
        with threads_for(SMALL_BATCH):
            assert numba.get_num_threads() == before


_KERNEL_FIRST = (
    "import os, numba, numpy as np\n"
    "@numba.njit(parallel=True)\n"
    "def bump(a):\n"
    "    for i in numba.prange(len(a)):\n"
    "        a[i] += 1\n"
    "bump(np.zeros(10))\n"  # numba loads its layer before gigapoint is imported
    "import gigapoint as gp\n"
    "from gigapoint.core import threads\n"
    "tbbs = {os.path.realpath(l.split()[-1]) for l in open('/proc/self/maps') if 'libtbb.so' in l}\n"
    "print(threads.load_wheel_tbb(), len(tbbs) <= 1, gp.render(gp.demo(2000), width=32, height=24).shape)\n"
)


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc/self/maps")
def test_a_layer_numba_loaded_before_gigapoint_is_kept_and_no_second_tbb_is_loaded():
    """A program that ran a parallel kernel before importing gigapoint has numba's layer (perhaps
    a system TBB) loaded: gigapoint loads no second TBB beside it, and draws."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER")}
    run = subprocess.run([sys.executable, "-c", _KERNEL_FIRST], env=clean, capture_output=True, text=True, timeout=300)
    assert run.stdout.strip() == "False True (24, 32, 4)", run.stderr[-800:]


_BLAS = """
import sys, numpy as np, numba
from gigapoint.core.threads import skip_blas_check
skip_blas_check()
from gigapoint.core.morton import morton_codes
morton_codes(np.zeros((10, 3)), np.zeros(3), 1.0)
first = "scipy.linalg" in sys.modules
a, v = np.arange(7.0), np.array([1.0, -2.0, 0.5])
conv = numba.njit(lambda a, v: np.convolve(a, v))(a, v)
assert np.allclose(conv, np.convolve(a, v))
try:
    import scipy.linalg  # noqa: F401
except ImportError:
    print(first, "no scipy")
else:
    dot = numba.njit(lambda a, b: np.dot(a, b))(np.ones((3, 4)), np.ones((4, 2)))
    assert np.allclose(dot, 4.0)
    print(first, "dot")
"""


def test_the_cli_runs_kernels_without_scipys_blas_and_numba_still_computes():
    """skip_blas_check (cli.main): a kernel call imports no scipy.linalg (0.26 s), and numba's
    convolution (its own loop then) and np.dot (scipy's BLAS, imported when compiled) still
    give numpy's results."""
    run = subprocess.run([sys.executable, "-c", _BLAS], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split()[0] == "False"


def test_a_cli_render_imports_no_scipy_linalg(tmp_path):
    code = (
        "import sys\nfrom gigapoint.cli import main\n"
        f"assert main(['demo', '-n', '20000', '-o', {str(tmp_path / 'a.png')!r}, '-W', '64', '--height', '48']) == 0\n"
        "print('scipy.linalg' in sys.modules)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split()[-1] == "False" and (tmp_path / "a.png").exists()
