"""numba's cache of gigapoint's kernels where it cannot be written (core/kernel_cache.py): a
read-only install run with a read-only or unset HOME, NUMBA_CACHE_DIR a file, a full disk while
numba saves. Each runs, compiled in memory, with one warning; a writable cache is used as before."""

from __future__ import annotations

import os
import resource
import shutil
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import gigapoint
from gigapoint.core.morton import morton_codes

AUTZEN = Path(__file__).parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"
SRC = Path(gigapoint.__file__).parents[1]
XYZ = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [3.5, 0.5, 2.5]])
# one small kernel compiled (or loaded) in a fresh process: its codes, then its cache hits
SCRIPT = (
    "import numpy as np; from gigapoint.core.morton import morton_codes; "
    f"c = morton_codes(np.array({XYZ.tolist()}), np.zeros(3), 4.0); "
    "print(c.tolist()); print(sum(morton_codes.stats.cache_hits.values()))"
)
CODES = morton_codes(XYZ, np.zeros(3), 4.0).tolist()
UNCACHED = "numba can write its cache nowhere"


def _chmod_tree(root: Path, writable: bool) -> None:
    for folder, dirs, files in os.walk(root):
        for name in [folder, *(os.path.join(folder, f) for f in files)]:
            mode = os.stat(name).st_mode
            os.chmod(name, mode | stat.S_IWUSR if writable else mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))


@pytest.fixture(scope="module")
def read_only():
    """A copy of the package in a read-only folder (as in a system site-packages or an image),
    a read-only home, and a writable output folder; run as an unprivileged user (root writes
    anywhere): skipped where the machine cannot drop privileges."""
    root = Path(tempfile.mkdtemp(prefix="gp-ro-"))
    os.chmod(root, 0o755)  # (the unprivileged user reaches the folders in it)
    shutil.copytree(SRC / "gigapoint", root / "site" / "gigapoint", ignore=shutil.ignore_patterns("__pycache__"))
    (root / "home").mkdir()
    (root / "out").mkdir()
    os.chmod(root / "out", 0o777)
    _chmod_tree(root / "site", writable=False)
    _chmod_tree(root / "home", writable=False)
    prefix = []
    if os.geteuid() == 0:
        prefix = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]
        probe = subprocess.run([*prefix, sys.executable, "-c", "import numba"], capture_output=True) if shutil.which("setpriv") else None
        if probe is None or probe.returncode != 0:
            shutil.rmtree(root)
            pytest.skip("cannot run Python as an unprivileged user here (setpriv to uid 65534)")
    yield root, prefix
    _chmod_tree(root, writable=True)
    shutil.rmtree(root)


def _run_read_only(read_only, args, home=True, **env):
    root, prefix = read_only
    base = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "PYTHONPATH": str(root / "site")}
    if home:
        base["HOME"] = str(root / "home")
    return subprocess.run([*prefix, sys.executable, *args], env={**base, **env}, cwd=root / "out", capture_output=True, text=True, timeout=600)


def test_cli_renders_from_a_read_only_install_with_one_warning(read_only):
    """Before: a traceback at import ("cannot cache function '_decode_all': no locator available")."""
    out = read_only[0] / "out" / "a.png"
    r = _run_read_only(read_only, ["-m", "gigapoint.cli", "render", str(AUTZEN), "-o", str(out), "-W", "64", "-H", "48"])
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    folders = f"{read_only[0] / 'site' / 'gigapoint' / 'core' / '__pycache__'}, the user's cache folder"
    assert [line for line in lines if UNCACHED in line] == [
        f"warning: {UNCACHED} ({folders}): gigapoint's kernels compile in memory on every run, which takes a while; set NUMBA_CACHE_DIR to a writable folder to keep them"
    ]
    assert "Traceback" not in r.stderr
    assert Image.open(out).size == (64, 48)


@pytest.mark.parametrize("cache_dir", ["file", "missing"])
def test_import_without_home_and_an_unusable_cache_dir(read_only, cache_dir):
    """HOME unset; NUMBA_CACHE_DIR a file, or a missing folder in a read-only one: the kernel
    runs, and the one warning names NUMBA_CACHE_DIR."""
    root = read_only[0]
    path = root / "site" / "gigapoint" / "__init__.py" if cache_dir == "file" else root / "site" / "missing"
    r = _run_read_only(read_only, ["-c", SCRIPT], home=False, NUMBA_CACHE_DIR=str(path))
    assert r.returncode == 0, r.stderr
    assert r.stdout == f"{CODES}\n0\n"
    assert r.stderr.count("GigapointWarning") == 1 and f"GigapointWarning: {UNCACHED} (NUMBA_CACHE_DIR={path}, " in r.stderr


def _run_with_cache(cache_dir: Path, max_file_bytes: int | None = None):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir), "PYTHONPATH": str(SRC)}
    limit = None if max_file_bytes is None else lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (max_file_bytes, max_file_bytes))
    return subprocess.run([sys.executable, "-c", SCRIPT], env=env, preexec_fn=limit, capture_output=True, text=True, timeout=600)


def test_full_disk_while_numba_saves_runs_the_kernel_with_one_warning(tmp_path):
    """Before: the kernel's first call raised "OSError: [Errno 27] File too large" (the CLI: "error: File too large")."""
    r = _run_with_cache(tmp_path / "cache", max_file_bytes=2048)  # the index (~1.7 kB) fits, the compiled kernel not
    assert r.returncode == 0, r.stderr
    assert r.stdout == f"{CODES}\n0\n"
    assert r.stderr.count("GigapointWarning") == 1
    assert f"numba could not save a compiled kernel in {tmp_path / 'cache'}" in r.stderr and "(File too large)" in r.stderr


def test_a_writable_cache_is_written_and_loaded_as_before(tmp_path):
    first, second = _run_with_cache(tmp_path), _run_with_cache(tmp_path)
    assert (first.returncode, second.returncode) == (0, 0), first.stderr + second.stderr
    assert (first.stdout, second.stdout) == (f"{CODES}\n0\n", f"{CODES}\n1\n")  # compiled, then loaded from the cache
    assert "Warning" not in first.stderr + second.stderr
    assert len(list(tmp_path.glob("*/morton.morton_codes-*.nbc"))) == 1
