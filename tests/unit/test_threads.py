"""numba's threading layer and thread counts (core/threads.py)."""

from __future__ import annotations

import os
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
    "from gigapoint.core.threads import threads_spin\n"
    "print(numba.threading_layer(), threads_spin())\n"
)


def _layer(**env) -> str:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER") and k != "OMP_WAIT_POLICY"}
    run = subprocess.run([sys.executable, "-c", _LAYER], env={**clean, **env}, capture_output=True, text=True, timeout=300)
    return run.stdout.strip() if run.returncode == 0 else f"failed: {run.stderr.strip().splitlines()[-1:]}"


def test_openmp_is_numbas_layer_unless_the_user_chose_one():
    """numba loads TBB before OpenMP where both are installed, and on TBB small kernels slowed
    down as a process went on: gigapoint puts OpenMP first where it loads; a layer the user
    names is the one loaded."""
    if _layer(NUMBA_THREADING_LAYER="omp") != "omp True":
        pytest.skip("no OpenMP runtime loads here")
    assert _layer() == "omp True"  # OpenMP's default: idle threads spin a while
    assert _layer(OMP_WAIT_POLICY="PASSIVE") == "omp False"
    assert _layer(NUMBA_THREADING_LAYER="workqueue") == "workqueue False"
    assert _layer(NUMBA_THREADING_LAYER_PRIORITY="workqueue omp tbb") == "workqueue False"


def test_a_block_runs_on_the_threads_asked_and_gives_the_count_back(monkeypatch):
    before = numba.get_num_threads()
    with numba_threads(1):
        assert numba.get_num_threads() == 1
    assert numba.get_num_threads() == before
    with pytest.raises(ValueError, match="boom"), numba_threads(1):
        raise ValueError("boom")
    assert numba.get_num_threads() == before
    for spin in (False, True):
        monkeypatch.setattr(threads, "threads_spin", lambda spin=spin: spin)
        with threads_for(SMALL_BATCH - 1):
            assert numba.get_num_threads() == 1
        with threads_for(SMALL_BATCH - 1, when_spinning=False):
            assert numba.get_num_threads() == (before if spin else 1)
        with threads_for(SMALL_BATCH):
            assert numba.get_num_threads() == before
