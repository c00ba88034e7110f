"""gigapoint as a notebook (IPython/Jupyter) shows it: errors, images and names."""

from __future__ import annotations

import pytest

import gigapoint as gp


@pytest.fixture(scope="module")
def shell():
    """An in-process IPython shell: what runs a notebook's cells in a Jupyter kernel."""
    interactiveshell = pytest.importorskip("IPython.core.interactiveshell")
    sh = interactiveshell.InteractiveShell.instance()
    sh.run_cell("import gigapoint as gp")
    return sh


def test_a_gigapoint_error_in_a_cell_is_one_line(shell, capsys, tmp_path):
    """A user's mistake (a missing file) showed a 38-line traceback through gigapoint's internals."""
    missing = tmp_path / "missing.laz"
    result = shell.run_cell(f"gp.open({str(missing)!r})")
    assert isinstance(result.error_in_exec, gp.GigapointError)
    assert capsys.readouterr().out.strip().splitlines() == [f"InputError: {missing}: no such file"]
    result = shell.run_cell("gp.render(gp.demo(1000), width=0)")
    assert capsys.readouterr().out.strip().splitlines() == ["CameraError: image width must be an integer in 1..16384, got 0"]
    result = shell.run_cell("1 / 0")  # other errors keep their traceback
    assert "ZeroDivisionError" in capsys.readouterr().out and isinstance(result.error_in_exec, ZeroDivisionError)
