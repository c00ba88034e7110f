"""A new user's command line (the audit of fix-audit-cli): unreadable inputs and unwritable
folders told in one line, no image left without the depth asked for beside it, hints a shell can
run, options named in their errors."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from gigapoint.cli import main

SIZE = ["-W", "64", "-H", "48", "--backend", "cpu"]


def run(capsys, *args):
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def cloud_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("in") / "cloud.npy"
    np.save(path, np.random.default_rng(0).random((3000, 3)) * 10)
    return path


def unprivileged(*args, timeout=120) -> subprocess.CompletedProcess:
    """``gigapoint ARGS`` in a process that file permissions apply to: root (CI, containers)
    reads a chmod 000 file anyway, so as root without the capabilities that bypass them."""
    cmd = [sys.executable, "-m", "gigapoint.cli", *map(str, args)]
    if os.geteuid() == 0:
        drop = ["setpriv", "--inh-caps=-dac_override,-dac_read_search", "--bounding-set=-dac_override,-dac_read_search"]
        if shutil.which("setpriv") is None or subprocess.run([*drop, "true"], capture_output=True).returncode != 0:
            pytest.skip("root, and setpriv cannot drop the capabilities that bypass file permissions")
        cmd = drop + cmd
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def test_an_unreadable_input_is_one_line_for_every_command(cloud_file, tmp_path):
    """typer's own check answered a chmod 000 file with a usage message and 'Invalid value for
    'inputs': path ... is not readable' (three lines, exit 2)."""
    locked = tmp_path / "locked.npy"
    shutil.copyfile(cloud_file, locked)
    locked.chmod(0)
    for args in (["render", locked, "-o", tmp_path / "x.png"], ["info", locked], ["convert", locked, "-o", tmp_path / "oct"], ["view", locked, "--no-browser"]):
        done = unprivileged(*args)
        assert (done.returncode, done.stderr) == (1, f"error: {locked}: permission denied\n"), args
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "oct").exists()
