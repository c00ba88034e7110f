"""Viewer camera moves (orbit parameters), message validation and the introspected settings schema."""

from __future__ import annotations

import dataclasses
import enum
import json
import math
from typing import Literal

import numpy as np
import pytest

from gigapoint import Camera, RenderSettings
from gigapoint.viewer import protocol as P
from gigapoint.viewer.session import FRAME_BUDGET_S, SCALES, ScaleControl
from gigapoint.viewer.state import OrbitState

BOUNDS = (np.array([637000.0, 4850000.0, 10.0]), np.array([637100.0, 4850080.0, 40.0]))


def pixel(cam: Camera, point) -> np.ndarray:
    x, y, w, _ = cam.screen_rows() @ np.append(np.asarray(point, np.float64), 1.0)
    return np.array([x / w, y / w])


def state() -> OrbitState:
    return OrbitState.fit(BOUNDS, view="iso", width=800, height=600)


def test_fit_matches_camera_fit():
    s = state()
    cam = Camera.fit(BOUNDS, view="iso", width=800, height=600)
    np.testing.assert_allclose(s.camera(800, 600).eye, cam.eye, rtol=0, atol=1e-6)
    np.testing.assert_allclose(s.target, cam.target)
    for view in ("top", "front", "side"):
        s = OrbitState.fit(BOUNDS, view=view, width=800, height=600)
        c = Camera.fit(BOUNDS, view=view, width=800, height=600)
        np.testing.assert_allclose(s.eye, c.eye, atol=1e-6)


def test_orbit_keeps_target_and_distance_and_clamps_pitch():
    s = state()
    t0, d0 = s.target.copy(), s.distance
    s.orbit(30.0, 10.0)
    np.testing.assert_array_equal(s.target, t0)
    assert np.linalg.norm(s.eye - s.target) == pytest.approx(d0)
    assert s.yaw == pytest.approx(-135.0 + 30.0)
    s.orbit(0.0, 500.0)
    assert s.pitch == 90.0
    s.camera(64, 64)  # straight down is a valid camera


def test_look_keeps_the_eye():
    s = state()
    eye = s.eye.copy()
    s.look(25.0, -10.0)
    np.testing.assert_allclose(s.eye, eye, atol=1e-6)
    assert s.yaw == pytest.approx(-110.0)


def test_pan_moves_the_scene_with_the_cursor():
    s = state()
    h = 600
    before = pixel(s.camera(800, h), s.target)
    anchor = s.target.copy()
    s.pan(0.1, -0.05)  # drag right by 0.1 and up by 0.05 view heights
    after = pixel(s.camera(800, h), anchor)
    np.testing.assert_allclose(after - before, [0.1 * h, -0.05 * h], atol=1e-6)


def test_zoom_to_cursor_keeps_the_anchor_pixel():
    s = state()
    cam = s.camera(800, 600)
    anchor = np.array([637020.0, 4850010.0, 12.0])
    before = pixel(cam, anchor)
    d0 = s.distance
    s.zoom(0.5, anchor)
    assert s.distance == pytest.approx(d0 * 0.5)
    np.testing.assert_allclose(pixel(s.camera(800, 600), anchor), before, atol=1e-6)
    s.zoom(1e-30)  # clamped, never zero
    assert s.distance > 0


def test_move_translates_eye_and_target():
    s = state()
    eye, target = s.eye.copy(), s.target.copy()
    right, _, fwd = s.basis()
    s.move(5.0, 2.0, 1.0)
    delta = fwd * 5 + right * 2 + np.array([0, 0, 1.0])
    np.testing.assert_allclose(s.target, target + delta, atol=1e-6)
    np.testing.assert_allclose(s.eye, eye + delta, atol=1e-6)


def test_set_pivot_keeps_eye():
    s = state()
    eye = s.eye.copy()
    p = np.array([637012.5, 4850044.25, 20.0])
    s.set_pivot(p)
    np.testing.assert_array_equal(s.target, p)
    np.testing.assert_allclose(s.eye, eye, atol=1e-6)
    np.testing.assert_allclose(pixel(s.camera(800, 600), p), [400, 300], atol=1e-6)


@pytest.mark.parametrize(
    "text",
    [
        "{not json",
        "[]",
        '"text"',
        "42",
        '{"type": 5}',
        '{"type": "launch_missiles"}',
        '{"no": "type"}',
        "[" * 100_000,
        "x" * (P.MAX_MESSAGE + 1),
    ],
)
def test_parse_message_rejects(text):
    with pytest.raises(P.ProtocolError):
        P.parse_message(text)


def test_parse_message_rejects_bytes_and_accepts_known():
    with pytest.raises(P.ProtocolError, match="binary"):
        P.parse_message(b'{"type": "ping"}')
    assert P.parse_message('{"type": "ping", "t": 1}') == {"type": "ping", "t": 1}


@pytest.mark.parametrize("value", [float("nan"), float("inf"), "1", True, None, 1e12])
def test_number_rejects(value):
    with pytest.raises(P.ProtocolError):
        P.number({"type": "t", "k": value}, "k", -1e9, 1e9)


def test_schema_covers_every_render_setting():
    schema = {d["name"]: d for d in P.settings_schema()}
    names = [f.name for f in dataclasses.fields(RenderSettings)]
    assert set(schema) == set(names)  # every current field is editable from the panel
    assert schema["background"]["kind"] == "color"
    assert schema["adaptive_precision"]["kind"] == "bool"
    assert schema["backend"]["kind"] == "enum" and {"auto", "cpu"} <= set(schema["backend"]["choices"])
    assert schema["threads"]["kind"] == "int" and schema["threads"]["nullable"]
    assert schema["precision_threshold_px"]["kind"] == "float"
    json.dumps(P.settings_schema())  # goes over the wire as it is


def test_schema_follows_fields_added_later():
    class Mode(enum.Enum):
        A = "a"
        B = "b"

    @dataclasses.dataclass(frozen=True)
    class Extended(RenderSettings):
        sparkle: bool = False
        mode: Mode = Mode.A
        shape: Literal["dot", "star"] = "dot"
        budget: int = dataclasses.field(default=5, metadata={"min": 1, "max": 10})
        tint_color: tuple[int, int, int] = (1, 2, 3)
        hidden: float = dataclasses.field(default=1.0, metadata={"viewer": False})

    schema = {d["name"]: d for d in P.settings_schema(Extended)}
    assert schema["sparkle"]["kind"] == "bool"
    assert schema["mode"] == {**schema["mode"], "kind": "enum", "choices": ["a", "b"]}
    assert schema["shape"]["choices"] == ["dot", "star"]
    assert (schema["budget"]["kind"], schema["budget"]["min"], schema["budget"]["max"]) == ("int", 1, 10)
    assert schema["tint_color"]["kind"] == "color"
    assert "hidden" not in schema
    s = P.apply_settings(Extended(), {"sparkle": True, "shape": "star", "budget": 7.0})
    assert (s.sparkle, s.shape, s.budget) == (True, "star", 7) and isinstance(s.budget, int)


@pytest.mark.parametrize(
    "values, match",
    [
        ({"adaptive_precision": "yes"}, "true or false"),
        ({"precision_threshold_px": -1}, "precision_threshold_px"),
        ({"precision_threshold_px": 1e12}, "range|in \\["),
        ({"threads": 2.5}, "integer"),
        ({"backend": "quantum"}, "one of"),
        ({"no_such_field": 1}, "unknown field"),
        ({"background": "not-a-color"}, "color"),
        ({}, "non-empty"),
        ([1, 2], "non-empty"),
    ],
)
def test_apply_settings_rejects(values, match):
    with pytest.raises(P.ProtocolError, match=match):
        P.apply_settings(RenderSettings(), values)


def test_apply_settings_accepts_and_round_trips():
    s = P.apply_settings(RenderSettings(), {"background": [255, 255, 255, 255], "adaptive_precision": False, "threads": None})
    assert s.background == (255, 255, 255, 255) and s.adaptive_precision is False
    values = P.settings_values(s)
    assert values["background"] == [255, 255, 255, 255]
    assert P.apply_settings(RenderSettings(), values) == s  # what the server sends can be sent back


def test_the_automatic_ipd_round_trips_through_the_viewer():
    """ipd None (auto, the 1/30 rule) is shown as an empty field and sent back as null."""
    field = next(d for d in P.settings_schema(RenderSettings) if d["name"] == "ipd")
    assert (field["kind"], field["nullable"], field["min"]) == ("float", True, 0.0)
    assert "1/30" in field["help"]
    assert P.settings_values(RenderSettings())["ipd"] is None
    s = P.apply_settings(RenderSettings(), {"ipd": 0.1})
    assert s.ipd == 0.1 and P.settings_values(s)["ipd"] == 0.1
    assert P.apply_settings(s, {"ipd": None}).ipd is None
    assert P.apply_settings(RenderSettings(), P.settings_values(s)) == s
    with pytest.raises(P.ProtocolError, match=r"^settings: ipd must be a number in \[0, 2e\+12\], got -1"):
        P.apply_settings(RenderSettings(), {"ipd": -1})


def test_point_budget_1e12_is_rejected_when_present():
    if "point_budget" not in {f.name for f in dataclasses.fields(RenderSettings)}:
        pytest.skip("RenderSettings has no point_budget yet")
    with pytest.raises(P.ProtocolError):
        P.apply_settings(RenderSettings(), {"point_budget": 1e12})


def test_frame_packing_round_trip():
    header = {"frame": 3, "stats": {"x": float("nan"), "y": np.float32(1.5)}}
    h, body = P.unpack_frame(P.pack_frame(header, b"\xff\xd8jpeg"))
    assert h == {"frame": 3, "stats": {"x": "nan", "y": 1.5}} and body == b"\xff\xd8jpeg"


def test_scale_control_adapts_to_frame_time():
    c = ScaleControl(level=0)
    c.record(0, FRAME_BUDGET_S * 3)  # too slow at full resolution: go coarser
    assert c.scale() == 2
    for _ in range(5):
        c.record(1, FRAME_BUDGET_S * 2)
    assert c.scale() == 4
    for _ in range(60):  # slow old measurements fade, so finer levels are retried
        c.record(2, FRAME_BUDGET_S * 0.05)  # far under budget: the finer level's (old) time decides
        c.record(c.level, FRAME_BUDGET_S * 0.05)
    assert c.scale() == 1
    c = ScaleControl(level=len(SCALES) - 1)
    c.record(c.level, 10.0)
    assert c.scale() == SCALES[-1]
    assert math.isfinite(c.times[c.level])


def test_moving_budget_caps_points_from_the_measured_rate(monkeypatch, demo_small):
    import gigapoint as gp
    from gigapoint.viewer import session as S

    b = S.MovingBudget()
    base = gp.RenderSettings(point_budget=5_000_000)
    assert b.settings_for(base) is base  # nothing measured yet: draw everything
    b.record(100_000_000, 1.0)  # 100 M points/s
    s = b.settings_for(base)
    assert s.max_points == int(100_000_000 * S.MOVING_RENDER_S) and s.point_budget == min(5_000_000, s.max_points)
    b.record(10_000_000, 1.0)  # the machine got slower: the cap follows
    assert b.points() < s.max_points
    b.record(0, 0.0)  # empty frames are ignored
    b.rate = 10.0
    assert b.points() == S.MIN_MOVING_POINTS
    # a moving frame of a plain cloud under the cap draws about that many points
    monkeypatch.setattr(S, "MIN_MOVING_POINTS", 1)
    b.rate = 50_000 / S.MOVING_RENDER_S
    cam = gp.Camera.fit(demo_small.bounds, view="iso", width=96, height=64)
    frame = gp.render_frame(demo_small, cam, b.settings_for(gp.RenderSettings(backend="cpu")))
    assert 40_000 < frame.stats.points_processed <= 50_000
