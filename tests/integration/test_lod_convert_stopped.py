"""A conversion stopped by a bad input (a truncated file) says why, and what to do, in its error,
in `info`, in gp.open's warning and in the viewer's status line: a rerun with that file unchanged
stops the same way (it had said "run `gigapoint convert` again to resume it")."""

from __future__ import annotations

import importlib
import json

import pytest

import gigapoint as gp
from gigapoint.cli import main
from gigapoint.errors import GigapointWarning, InputError
from gigapoint.lod import OctreeDir, convert
from gigapoint.lod.convert import hooks
from gigapoint.lod.octree_dir import RESUME_HINT
from gigapoint.viewer.watch import preview_note

OPTS = {"max_leaf": 3_000, "partition_points": 25_000, "chunk_size": 40_000}
AGAIN = "run it again once that file is whole, or without it: it starts over"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, las_writer):
    """A whole LAS file and one cut short (its header claims 30 000 points)."""
    d = tmp_path_factory.mktemp("las")
    whole, cut = las_writer(d / "a.las", 30_000, seed=1), d / "cut.las"
    cut.write_bytes(las_writer(d / "b.las", 30_000, seed=2).read_bytes()[:300_000])
    return whole, cut


def _cause(cut) -> str:
    return (
        f"{cut}: truncated LAS file: the header claims 30,000 points (1,020,000 bytes) but only 299,773 bytes of point data "
        "follow (room for 8,816 points); `gigapoint view` shows the points before the cut (gigapoint.open(..., progressive=True))"
    )


def test_a_conversion_stopped_by_a_truncated_input_says_why_and_what_to_do(inputs, tmp_path, capsys):
    whole, cut = inputs
    out = tmp_path / "oct"
    for _ in range(2):  # the rerun with the same (cut) file stops the same way
        with pytest.raises(InputError) as err:
            convert([whole, cut], out, **OPTS)
        assert str(err.value) == f"{_cause(cut)}; the conversion to {out} stopped unfinished: {AGAIN}"
    assert json.loads((out / ".partial" / "state.json").read_text())["stopped_by"] == _cause(cut)
    assert OctreeDir(out).resume_hint == f"{_cause(cut)}; {AGAIN}"
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    assert f"\n  state:       stopped: {_cause(cut)}; {AGAIN}\n" in capsys.readouterr().out
    with pytest.warns(GigapointWarning) as caught:
        gp.open(out)
    assert str(caught[0].message) == f"{out}: conversion not finished (30,000 points read); showing its preview; it has stopped: {_cause(cut)}; {AGAIN}"
    assert preview_note(OctreeDir(out)) == f"preview: 30,000 points read, 30,000 shown; conversion stopped ({_cause(cut)}; {AGAIN})"
    res = convert([whole], out, **OPTS)  # without it: a fresh conversion of the whole file
    assert (res.points, res.resumed) == (30_000, False)


def test_a_resumed_run_forgets_the_cause_that_stopped_the_last_one(inputs, tmp_path, monkeypatch):
    """The same inputs read this time (a cause that went away): killed later, it resumes as any run.
    Out of core: the resumed run goes on from the saved state (one in memory reads from the start)."""
    whole, _ = inputs
    out = tmp_path / "oct"
    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.in_memory"), "fits_in_memory", lambda job: False)
    read = importlib.import_module("gigapoint.lod.convert.read")
    real = read._read_chunks
    other = whole.with_name("b.las")

    def fails(path, size):
        if path == other:
            raise InputError(f"{path}: cannot read it (test)")
        return real(path, size)

    monkeypatch.setattr(read, "_read_chunks", fails)
    with pytest.raises(InputError) as err:
        convert([whole, other], out, **OPTS)
    assert str(err.value) == f"{other}: cannot read it (test); the conversion to {out} stopped unfinished: {AGAIN}"
    assert OctreeDir(out).resume_hint == f"{other}: cannot read it (test); {AGAIN}"
    monkeypatch.setattr(read, "_read_chunks", real)

    def stop(done):
        raise KeyboardInterrupt("test")

    monkeypatch.setattr(hooks, "after_partition_built", stop)
    with pytest.raises(KeyboardInterrupt):
        convert([whole, other], out, **OPTS)
    assert "stopped_by" not in OctreeDir(out).read_state() and OctreeDir(out).resume_hint == RESUME_HINT


def test_info_of_a_copc_output_stopped_by_a_truncated_input_says_why(inputs, tmp_path, capsys):
    """The COPC file is not there yet: info named its work folder and said to resume it."""
    whole, cut = inputs
    out = tmp_path / "o.copc.laz"
    with pytest.raises(InputError):
        convert([whole, cut], out, **OPTS)
    capsys.readouterr()
    assert main(["info", str(out)]) == 1
    assert capsys.readouterr().err == (
        f"error: {out}: no such file yet: a conversion to it is unfinished (its work folder {out}.work is there); {_cause(cut)}; {AGAIN}\n"
    )
