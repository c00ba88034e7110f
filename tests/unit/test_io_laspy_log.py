"""What laspy reports through Python's ``logging`` about a file it reads (a VLR it cannot parse:
"Failed to parse ... GeoKeyDirectoryVlr ...") is a gigapoint warning naming the file, once an
operation: it was lost (laspy's NullHandler), or with logging configured printed without the
file's name, from whichever thread read it, once per open."""

from __future__ import annotations

import logging

import laspy
import numpy as np
import pytest

import gigapoint as gp
from gigapoint.cli import main

#: laspy's words on the damaged record (after "FILE: laspy: ")
FAILED_TO_PARSE = "Failed to parse <class 'laspy.vlrs.known.GeoKeyDirectoryVlr'>: Buffer size too small (3 instead of at least 8 bytes)"


def write_damaged_geokeys(path, n=2000):
    """A LAS 1.2 file whose GeoKeyDirectory VLR is damaged: 3 bytes, where its own header alone
    is 8 (laspy parses it on every open and logs its failure; gigapoint's reading of the CRS
    skips it: no CRS)."""
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [0.0] * 3
    header.vlrs.append(laspy.VLR("LASF_Projection", 34735, "GeoKeyDirectoryTag", b"\x01\x00\x01"))
    las = laspy.LasData(header)
    t = np.arange(n, dtype=np.float64)
    las.x, las.y, las.z = t * 0.5, t % 40, t % 7
    las.write(str(path))
    return path


@pytest.fixture
def damaged(tmp_path):
    return write_damaged_geokeys(tmp_path / "damaged.las")


def laspy_warnings(record) -> list[str]:
    return [str(w.message) for w in record if "laspy:" in str(w.message)]


def test_plain_and_progressive_opens_warn_once_naming_the_file(damaged, recwarn, capfd):
    cloud = gp.open(damaged)
    assert cloud.n_points == 2000
    assert laspy_warnings(recwarn) == [f"{damaged}: laspy: {FAILED_TO_PARSE}"]
    recwarn.clear()
    progressive = gp.open(damaged, progressive=True)
    assert progressive.wait(timeout=120)  # (the loader's thread kept the warning: its wait issues it)
    assert progressive.n_points == 2000
    assert laspy_warnings(recwarn) == [f"{damaged}: laspy: {FAILED_TO_PARSE}"]
    assert all(issubclass(w.category, gp.GigapointWarning) for w in recwarn)
    assert "Failed to parse" not in capfd.readouterr().err


def test_each_file_of_a_folder_is_named_in_its_own_warning(tmp_path, recwarn):
    folder = tmp_path / "tiles"
    folder.mkdir()
    files = [write_damaged_geokeys(folder / f"t{i}.las") for i in range(2)]
    assert gp.open(folder).n_points == 4000
    assert sorted(laspy_warnings(recwarn)) == [f"{f}: laspy: {FAILED_TO_PARSE}" for f in files]


def test_info_on_the_command_line_says_it_once_on_stderr(damaged, capfd):
    assert main(["info", str(damaged)]) == 0
    err = capfd.readouterr().err
    assert err == f"warning: {damaged}: laspy: {FAILED_TO_PARSE}\n"


def test_convert_warns_once(damaged, tmp_path, recwarn, capfd):
    gp.convert(damaged, tmp_path / "octree")  # (the file read by the read phase's threads, its header by several steps)
    assert laspy_warnings(recwarn) == [f"{damaged}: laspy: {FAILED_TO_PARSE}"]
    assert "Failed to parse" not in capfd.readouterr().err


def test_a_users_own_logging_still_gets_laspys_records(damaged, caplog, recwarn):
    """A handler the user configured (caplog's, on the root logger) gets laspy's record as
    before: gigapoint's warning is added, nothing taken away."""
    with caplog.at_level(logging.WARNING):
        gp.open(damaged)
    assert [(r.name, r.getMessage()) for r in caplog.records] == [("laspy.vlrs.known", FAILED_TO_PARSE)]
    assert laspy_warnings(recwarn) == [f"{damaged}: laspy: {FAILED_TO_PARSE}"]


def test_laspy_used_outside_gigapoints_reading_is_left_to_logging(damaged, recwarn, caplog):
    """The user's own laspy call (not a file gigapoint reads): no gigapoint warning, laspy's record
    as logging routes it."""
    with caplog.at_level(logging.WARNING):
        gp.open(damaged)  # (gigapoint's handler in place)
        caplog.clear()
        recwarn.clear()
        laspy.read(str(damaged))
    assert laspy_warnings(recwarn) == []
    assert [r.getMessage() for r in caplog.records] == [FAILED_TO_PARSE]


@pytest.mark.filterwarnings("error::gigapoint.GigapointWarning")
def test_made_an_error_by_the_users_filters_it_is_the_warning_not_damage(damaged):
    """Under ``-W error`` the warning is raised from inside laspy: it is the error, as any
    gigapoint warning, not "truncated or corrupt LAS point data (...)" around it."""
    for read in (lambda: gp.open(damaged), lambda: gp.io.file_info(damaged)):
        with pytest.raises(gp.GigapointWarning) as err:
            read()
        assert str(err.value) == f"{damaged}: laspy: {FAILED_TO_PARSE}"
