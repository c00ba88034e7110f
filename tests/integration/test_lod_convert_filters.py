"""Conversions read through the point filter (io/filters.py: ``classes``, ``drop_classes``,
``clip``) in one process, out of core and on Dask, and a resumed conversion never mixes points
kept by two filters (the filter is part of its fingerprint)."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, InputError
from gigapoint.io import read_chunks
from gigapoint.lod import OctreeDir, convert

CLIP = (636_500.0, 849_000.0, 637_000.0, 849_300.0)


@pytest.fixture(scope="module")
def autzen(autzen_path):
    """autzen's positions and classification as the reader gives them (the numpy reference)."""
    chunks = list(read_chunks(autzen_path))
    return np.concatenate([c.xyz for c in chunks]), np.concatenate([c.attributes["classification"] for c in chunks])


def _spill_always(monkeypatch) -> None:
    """Conversions spill their points (the out-of-core phases), however few."""
    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.in_memory"), "fits_in_memory", lambda job: False)


def _in_clip(xyz: np.ndarray) -> np.ndarray:
    return np.all((xyz[:, :2] >= CLIP[:2]) & (xyz[:, :2] <= CLIP[2:]), axis=1)


@pytest.mark.parametrize("spilled", [False, True], ids=["in-memory", "out-of-core"])
def test_a_conversion_holds_the_points_the_filter_keeps(autzen_path, autzen, tmp_path, monkeypatch, spilled):
    xyz, classification = autzen
    if spilled:
        _spill_always(monkeypatch)
    res = convert(autzen_path, tmp_path / "ground", classes=[2], chunk_size=20_000)
    assert res.points == gp.open(tmp_path / "ground").n_points == np.count_nonzero(np.isin(classification, [2])) == 26_107
    assert res.in_memory == (not spilled)
    res = convert(autzen_path, tmp_path / "clip", clip=CLIP, drop_classes=[2], chunk_size=20_000)
    assert res.points == np.count_nonzero(_in_clip(xyz) & (classification != 2)) > 0


def test_the_convert_cli_takes_the_filter_options(cli, autzen_path, autzen, tmp_path):
    _, classification = autzen
    rc, out, err = cli("convert", autzen_path, "-o", tmp_path / "oct", "--drop-classes", "2", "-q")
    assert rc == 0, err
    assert out.startswith(f"{tmp_path / 'oct'}: {np.count_nonzero(classification != 2):,} points in ")
    rc, _, err = cli("convert", autzen_path, "-o", tmp_path / "bad", "--clip", "3,0,1,1")
    assert (rc, err.strip()) == (1, "error: convert: --clip 3,0,1,1: xmin 3 is above xmax 1")
    assert not (tmp_path / "bad").exists()


def test_a_conversion_whose_filter_keeps_nothing_says_so_and_leaves_nothing(autzen_path, tmp_path):
    with pytest.raises(EmptyCloudError) as err:
        convert(autzen_path, tmp_path / "oct", classes=[6])
    assert str(err.value) == f"{autzen_path}: no point passes the filter (classes 6): 110,000 points read"
    assert not (tmp_path / "oct").exists()


def test_a_filter_is_refused_for_chunk_inputs(autzen_path, tmp_path):
    with pytest.raises(InputError) as err:
        convert(gp.open(autzen_path), tmp_path / "oct", drop_classes=[7])
    assert str(err.value) == "convert: the filter (drop classes 7) applies to the points read from files; the inputs are a cloud or PointChunks"


def test_a_conversion_resumes_only_under_the_same_filter(autzen_path, autzen, tmp_path, interrupted_read):
    _, classification = autzen
    out = tmp_path / "oct"
    opts = {"chunk_size": 20_000}  # (out of core: a resume takes the chunks spilled)
    interrupted_read(lambda: convert(autzen_path, out, classes=[1], **opts))
    assert OctreeDir(out).read_state()["chunks"] == 1  # (the two chunks' class 1 points, joined)
    res = convert(autzen_path, out, classes=[2], **opts)  # another filter: starts over, not a mix of both
    assert (res.resumed, res.points) == (False, np.count_nonzero(classification == 2))
    out = tmp_path / "again"
    interrupted_read(lambda: convert(autzen_path, out, classes=[1], **opts))
    res = convert(autzen_path, out, classes=[1], **opts)  # the same one: resumed
    assert (res.resumed, res.points) == (True, np.count_nonzero(classification == 1))
    assert gp.open(out).n_points == 83_893


def test_a_dask_conversion_filters_in_its_read_tasks(autzen_path, autzen, thread_client, tmp_path):
    xyz, classification = autzen
    res = convert(autzen_path, tmp_path / "oct", clip=CLIP, classes=[1], client=thread_client, chunk_size=20_000)
    assert res.points == gp.open(tmp_path / "oct").n_points == np.count_nonzero(_in_clip(xyz) & (classification == 1))
    with pytest.raises(EmptyCloudError) as err:
        convert(autzen_path, tmp_path / "none", classes=[6], client=thread_client, chunk_size=20_000)
    assert str(err.value) == f"{autzen_path}: no point passes the filter (classes 6): 110,000 points read"
