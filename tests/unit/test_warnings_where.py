"""gigapoint's warnings name the user's line (a notebook cell, a script), whatever way inside
gigapoint they arose: they named gigapoint's own lines (``renderer.py:78`` and the source line
``warnings.warn(f"{cloud.name}: ...")`` under it in a notebook)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointWarning
from gigapoint.viewer.session import view_frame


def away_from(cloud) -> gp.Camera:
    lo, hi = cloud.bounds
    eye = hi + 10 * (hi - lo)
    return gp.Camera.look_at(eye, eye + (hi - lo), width=64, height=48)  # looking away from the points


def test_an_empty_view_is_warned_of_at_the_callers_line():
    cloud = gp.demo(2_000)
    for draw in (gp.render, gp.render_frame):
        with pytest.warns(GigapointWarning, match="no point is in view") as caught:
            draw(cloud, away_from(cloud))
        assert [w.filename for w in caught] == [__file__]


def test_a_readers_warning_is_at_the_callers_line(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("x,y,z,label\n1,2,3,tree\n4,5,6,rock\n")
    with pytest.warns(GigapointWarning, match="hold text, not numbers") as caught:
        cloud = gp.open(path)
    assert cloud.n_points == 2 and [w.filename for w in caught] == [__file__]


def test_the_viewer_does_not_say_an_empty_view():
    cloud = gp.demo(2_000)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frame = view_frame(cloud, away_from(cloud), gp.RenderSettings())
    assert frame.stats.visible_pixels == 0 and caught == []
    assert np.count_nonzero(view_frame(cloud, gp.Camera.fit_cloud(cloud, width=64, height=48), gp.RenderSettings()).image[..., 3])
