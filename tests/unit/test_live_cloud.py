"""LiveCloud (live/cloud.py): the ring of frames, poses, bad frames, decay, threads, snapshots, saving."""

from __future__ import annotations

import re
import threading
import time
from functools import partial

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import InputError
from gigapoint.live import LiveCloud


def frame(k: int, n: int | None = None, seed: int = 0):
    """Frame k: a small random patch of n points (sizes differ frame to frame), colored by k."""
    rng = np.random.default_rng(seed + k)
    n = n or 3000 + 137 * k
    xyz = rng.uniform(-1, 1, (n, 3)) * [5, 4, 1] + [k, 0, 0]
    rgb = np.zeros((n, 3), np.uint8)
    rgb[:] = (40 + 20 * k % 200, 100, 200)
    return xyz, rgb


def pose_of(k: int) -> np.ndarray:
    a = 0.1 * k
    p = np.eye(4)
    p[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    p[:3, 3] = [100.0 + k, -50.0, 7.0]
    return p


def sorted_rows(a):
    a = np.asarray(a, np.float64)
    return a[np.lexsort(a.T[::-1])]


def assert_same_points(got, want, tol):
    """The same set of points within ``tol``: one to one, each nearest to its own."""
    from scipy.spatial import cKDTree

    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    assert got.shape == want.shape
    dist, idx = cKDTree(want).query(got)
    assert dist.max() <= tol
    assert len(np.unique(idx)) == len(want)


def test_ring_keeps_the_last_frames_transformed_by_their_poses():
    live = LiveCloud(keep=3)
    pushed = []
    for k in range(5):
        xyz, rgb = frame(k)
        live.push(xyz, rgb, pose=pose_of(k), time=10.0 + k)
        pushed.append(xyz @ pose_of(k)[:3, :3].T + pose_of(k)[:3, 3])
    assert live.n_frames == 3 and [f.seq for f in live.frames] == [2, 3, 4]
    assert [f.time for f in live.frames] == [12.0, 13.0, 14.0]
    assert live.n_points == sum(len(p) for p in pushed[2:])
    xyz, rgba, attrs = live.frame_points()
    assert_same_points(xyz, np.concatenate(pushed[2:]), 1e-6)  # 30-bit positions in boxes of ~10 m
    lo, hi = live.bounds
    np.testing.assert_allclose(lo, np.concatenate(pushed[2:]).min(axis=0))
    np.testing.assert_allclose(hi, np.concatenate(pushed[2:]).max(axis=0))
    assert set(attrs) == {"nx", "ny", "nz"}


def test_chunks_are_reused_so_memory_stays_flat():
    live = LiveCloud(keep=4)
    for k in range(6):
        live.push(*frame(k % 3, n=25_000))
    buffers = live.buffers()
    for k in range(60):
        live.push(*frame(k % 3, n=25_000))
    assert live.buffers() is buffers  # no growth: the frames' chunks were reused
    assert int((buffers.batches["count"] > 0).sum()) == 4 * 3  # 4 frames of 3 batches of <= 10 240 points


def test_one_frame_draws_exactly_as_the_same_points_as_a_plain_cloud():
    xyz, rgb = frame(1, n=20_000)
    live = LiveCloud(keep=2)
    live.push(xyz, rgb)
    plain = gp.from_arrays(xyz, rgb)
    cam = gp.Camera.fit(plain.bounds, view="iso", width=160, height=120)
    a = gp.render_frame(live, cam, gp.RenderSettings(size_mode="fixed"))
    b = gp.render_frame(plain, cam, gp.RenderSettings(size_mode="fixed"))
    np.testing.assert_array_equal(a.image, b.image)
    assert a.stats.points_processed == 20_000
    i = int(a.index[a.index >= 0][0])
    info = a.point_info(i)
    assert info["source"] == "live frame" and info["rgba"] == b.point_info(int(b.index[a.index == i][0]))["rgba"]


def test_frames_culled_outside_the_view_and_dropped_frames_not_drawn():
    live = LiveCloud(keep=2)
    live.push(*frame(0, n=5000))
    far = frame(0, n=5000)[0] + [1000, 0, 0]
    live.push(far)
    cam = gp.Camera.fit((np.array([-6.0, -5, -2]), np.array([6.0, 5, 2])), view="top", width=100, height=100)
    f = gp.render_frame(live, cam, gp.RenderSettings(size_mode="fixed"))
    assert f.stats.points_processed == 5000  # the far frame's batches are culled
    live.push(far + [0, 0, 1])  # the first frame leaves the ring
    with pytest.warns(gp.GigapointWarning):
        f = gp.render_frame(live, cam, gp.RenderSettings(size_mode="fixed"))
    assert f.stats.visible_pixels == 0


@pytest.mark.parametrize(
    ("args", "kwargs", "message"),
    [
        ((np.zeros((5, 2)),), {}, "shape (N, 3)"),
        ((np.zeros((0, 3)),), {}, "no points"),
        ((np.array([["a", "b", "c"]]),), {}, "numbers"),
        ((np.full((4, 3), np.nan),), {}, "none of the frame's 4 points is valid"),
        ((np.zeros((4, 3)), np.zeros((3, 3), np.uint8)), {}, "rgb has 3 rows"),
        ((np.zeros((4, 3)),), {"pose": np.eye(3)}, "pose must be a 4x4"),
        ((np.zeros((4, 3)),), {"intensity": np.zeros(3)}, "attribute 'intensity'"),
        ((np.zeros((4, 3)),), {"nx": np.zeros(4)}, "reserved"),
        ((np.zeros((4, 3)),), {"normals": np.zeros((4, 2))}, "normals must be"),
        # the dtype was left out: "must be (N, 3) numbers like xyz (4, 3), got shape (4, 3)" named no problem
        ((np.zeros((4, 3)),), {"normals": np.zeros((4, 3), np.uint8)}, "live: push: normals must be (4, 3) floats or signed integers, got shape (4, 3) dtype uint8"),
        ((np.zeros((4, 3)),), {"time": float("nan")}, "time must be"),
        ((np.zeros((4, 3)),), {"time": "a"}, "live: push: time must be a finite number of seconds, got 'a'"),  # float()'s ValueError
        ((np.zeros((2, 3)),), {"a": [[1], [2, 3]]}, "live: push: attribute 'a' must be an array of numbers, got a ragged list"),  # numpy's ValueError
        ((np.zeros((2, 3)),), {"normals": [[1], [2, 3]]}, "live: push: normals must be an array of numbers, got a ragged list"),
        ((np.zeros((2, 3)), [[1], [2, 3]]), {}, "live: push: colors must have shape (N, 3) or (N, 4), got a ragged list"),  # numpy's message
    ],
)
def test_a_bad_frame_is_one_line_and_the_stream_goes_on(args, kwargs, message):
    live = LiveCloud(keep=5)
    live.push(*frame(0))
    before = (live.n_points, live.buffers().version)
    with pytest.raises(InputError) as err:
        live.push(*args, **kwargs)
    assert message in str(err.value) and "\n" not in str(err.value)
    assert (live.n_points, live.buffers().version) == before  # nothing of it landed
    assert live.stats.frames_rejected == 1 and live.stats.last_error == str(err.value)
    live.push(*frame(1))
    assert live.n_frames == 2


def test_bad_depth_frames_are_refused_and_the_stream_goes_on():
    live = LiveCloud(name="cam1")
    with pytest.raises(InputError, match="^cam1: push_depth: intrinsics are missing"):  # (the cloud named: several may refuse)
        live.push_depth(np.ones((4, 4)), None)
    with pytest.raises(InputError, match=r"^cam1: push_depth: intrinsics must be a 3x3 matrix or \(fx, fy, cx, cy\), got tuple$"):
        live.push_depth(np.ones((4, 4)), (True, True, 1, 1))  # (was fx = fy = 1)
    with pytest.raises(InputError, match="no valid pixel"):
        live.push_depth(np.zeros((4, 4), np.uint16), (1, 1, 2, 2))
    with pytest.raises(InputError, match=r"^cam1: push_depth: a 8192x4097 depth image is more than a sensor's 33,554,432 pixels; push it in tiles$"):
        live.push_depth(np.zeros((4097, 8192), np.uint16), (1, 1, 2, 2))  # 20000 x 20000 ran the machine out of memory
    live.push_depth(np.full((4, 4), 1000, np.uint16), (1, 1, 2, 2))
    assert live.n_points == 16 and live.stats.frames_rejected == 4
    np.testing.assert_allclose(live.frame_points()[0][:, 2], 1.0, atol=1e-6)


@pytest.mark.parametrize("chunk", [0, -5, 2.5, 10**12])
def test_a_chunk_size_it_cannot_hold_is_refused_at_once(chunk):
    """0 was a ZeroDivisionError at the first push, -5 numpy's ValueError, 10**12 a MemoryError
    of 116 TiB, 2.5 read as 2."""
    with pytest.raises(InputError, match=rf"^live: chunk must be an integer from 1 to 1,048,576 points, got {chunk!r}$"):
        LiveCloud(chunk=chunk)


@pytest.mark.parametrize(
    ("kw", "problem"),
    [
        ({"keep": True}, "live: keep must be an integer >= 1, got True"),  # taken as 1
        ({"keep": 0}, "live: keep must be an integer >= 1, got 0"),
        ({"decay": "abc"}, "live: decay must be a positive number of seconds or None, got 'abc'"),  # a ValueError
        ({"decay": -1.0}, "live: decay must be a positive number of seconds or None, got -1.0"),
        ({"fade": "no"}, "live: fade must be True or False, got 'no'"),  # taken as true
        ({"name": 5}, "live: name must be a string, got 5"),
        # a ValueError from reshape, or accepted and failing at the first snapshot ("cube must have a finite origin")
        ({"bounds": ([0, 0], [1, 1])}, "live: bounds must be (min, max): two (x, y, z) of finite numbers with min <= max, got ([0, 0], [1, 1])"),
        ({"bounds": "ab"}, "live: bounds must be (min, max): two (x, y, z) of finite numbers with min <= max, got 'ab'"),
        ({"bounds": ([0, 0, np.nan], [1, 1, 1])}, "live: bounds must be (min, max): two (x, y, z) of finite numbers with min <= max, got ([0, 0, nan], [1, 1, 1])"),
        ({"bounds": ([1, 1, 1], [0, 0, 0])}, "live: bounds must be (min, max): two (x, y, z) of finite numbers with min <= max, got ([1, 1, 1], [0, 0, 0])"),
        ({"clock": 5}, "live: clock must be a function giving seconds (a finite number), got 5"),  # "'int' object is not callable"
        ({"clock": str}, "live: clock must be a function giving seconds (a finite number), got <class 'str'>"),  # a TypeError at the first push
        ({"clock": partial(float, "nan")}, "live: clock must be a function giving seconds (a finite number), got functools.partial(<class 'float'>, 'nan')"),  # never decayed
    ],
)
def test_odd_live_cloud_settings_are_refused_in_one_line(kw, problem):
    with pytest.raises(InputError, match=f"^{re.escape(problem)}$"):
        LiveCloud(**kw)


def test_nan_points_inside_a_frame_are_dropped():
    live = LiveCloud()
    xyz, rgb = frame(0, n=100)
    xyz[::10] = np.nan
    live.push(xyz, rgb)
    assert live.n_points == 90


def test_decay_drops_old_frames_and_fades_the_rest():
    now = [0.0]
    live = LiveCloud(keep=100, decay=2.0, clock=lambda: now[0])
    live.push(*frame(0, n=2000))
    now[0] = 1.5
    live.push(*frame(1, n=2000))
    cam = gp.Camera.fit(live.bounds, view="top", width=64, height=64)
    view = cam.view(live.bounds)
    with live.reading():
        draw = live.prepare(view, gp.RenderSettings())
    alpha = dict(zip(draw.selection.ids.tolist(), draw.alpha.tolist()))
    first, second = live.frames[0].chunks[0], live.frames[1].chunks[0]
    assert alpha[first] == pytest.approx(1 - 1.5 / 2) and alpha[second] == pytest.approx(1.0)
    now[0] = 2.5  # the first frame is 2.5 s old: gone at the next frame
    with live.reading():
        draw = live.prepare(view, gp.RenderSettings())
    assert live.n_frames == 1 and first not in draw.selection.ids.tolist()
    assert draw.alpha.tolist() == pytest.approx([1 - 1.0 / 2.0])
    np.testing.assert_allclose(live.fade_alpha(np.array([2.5, 0.5, np.nan], np.float32)), [1.0, 0.0, 1.0])


def test_a_snapshot_leaves_out_frames_that_decayed_since_the_last_push_or_drawn_frame():
    """Frames left the ring by decay only at a push or a drawn frame: a program that snapshotted
    after its stream paused froze frames that had faded out (3 000 points, not 2 000 of the frame
    still shown), and frame_points gave them."""
    now = [0.0]
    live = LiveCloud(decay=1.0, clock=lambda: now[0])
    live.push(*frame(0, n=1000))
    now[0] = 0.8
    live.push(*frame(1, n=2000))
    now[0] = 1.5  # the first frame has faded out; nothing pushed or drawn since
    assert len(live.frame_points()[0]) == 2000
    assert live.snapshot() == 2000 and live.snapshots.n_points == 2000 and live.n_frames == 1
    now[0] = 2.0  # the second one too
    assert live.snapshot() == 0 and live.n_points == 2000


def test_a_paused_stream_counts_and_frames_only_what_has_not_decayed():
    """n_points, len, bounds, repr and the HUD counted frames that had faded out until the next
    push, drawn frame or snapshot: a paused stream with decay=1 s showed its old count forever.
    And they took the frame's lock: asked by every rendered frame and the viewer's watcher up to
    120 times a second, each counted as a frame drawn (writers took their turn behind them,
    builders saw frames being drawn)."""
    now = [0.0]
    live = LiveCloud(decay=1.0, clock=lambda: now[0])
    live.push(np.full((1000, 3), -50.0))
    now[0] = 0.8
    live.push(np.full((2000, 3), 7.0))
    now[0] = 1.5  # the first frame has faded out; nothing pushed or drawn since
    assert live.lock.builder_turn(0) == (0, False)  # (frames drawn so far, whether frames are being drawn)
    assert live.n_points == 2000 and len(live) == 2000 and live.n_frames == 1
    lo, hi = live.bounds
    assert lo.tolist() == [7.0, 7.0, 7.0] and hi.tolist() == [7.0, 7.0, 7.0]
    assert repr(live) == "LiveCloud('live', 1 of 100 frames, 2,000 live points)"
    assert ", 1 frames, 2,000 live points" in live.hud()
    assert live.lock.builder_turn(0) == (0, False)  # (the queries counted no frame)
    assert len(live.frame_points()[0]) == 2000  # reads the ring's points as a frame does: counted
    assert live.lock.builder_turn(0) == (1, True)
    now[0] = 2.0  # the second one too: nothing left (a unit box to look at)
    assert len(live) == 0 and repr(live) == "LiveCloud('live', 0 of 100 frames, 0 live points)"
    assert [b.tolist() for b in live.bounds] == [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]
    assert ", 0 frames, 0 live points" in live.hud()


def test_a_frame_decay_seconds_old_is_gone_as_its_fade_is_zero():
    """Expiry took a frame out only when older than ``decay`` while its fade reached 0 at
    ``decay``: a frame exactly ``decay`` seconds old was drawn at alpha 0 yet counted by
    n_points, bounds and the HUD."""
    now = [0.0]
    live = LiveCloud(decay=1.0, clock=lambda: now[0])
    now[0] = 0.5
    live.push(np.full((1000, 3), 7.0))
    view = gp.Camera.fit(([0.0] * 3, [10.0] * 3), view="top", width=32, height=32).view(live.bounds)
    now[0] = 1.5 - 2**-10  # just under 1 s old: faint, counted and drawn
    assert live.n_points == 1000 and live.bounds[0].tolist() == [7.0, 7.0, 7.0] and ", 1 frames, 1,000 live points" in live.hud()
    with live.reading():
        draw = live.prepare(view, gp.RenderSettings())
    assert draw.alpha.tolist() == [2**-10]
    now[0] = 1.5  # exactly 1 s old: alpha 0, so gone
    assert live.n_points == 0 and live.n_frames == 0 and ", 0 frames, 0 live points" in live.hud()
    assert [b.tolist() for b in live.bounds] == [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]
    with live.reading():
        draw = live.prepare(view, gp.RenderSettings())
    assert len(draw.selection.ids) == 0


def test_float_colours_keep_the_range_of_the_first_coloured_frame():
    """Each push judged its float colours by their own range: in a 0..1 stream, a frame that
    overshot to 1.025 was read as 0..255 (almost black beside its neighbours), and in a 0..255
    stream a dark frame (all <= 1) as 0..1 (almost white). A cloud decides once, as a file."""
    xyz = frame(0)[0]

    def pushed_colour(live, rgb):
        live.push(xyz, rgb=np.tile(rgb, (len(xyz), 1)))
        return live.frame_points([live.frames[-1]])[1][0].tolist()

    unit = LiveCloud()
    assert pushed_colour(unit, (0.5, 0.5, 1.0)) == [128, 128, 255, 255]
    assert pushed_colour(unit, (0.5, 0.5, 1.025)) == [128, 128, 255, 255]  # clipped (alone: [0, 0, 1, 255])
    assert pushed_colour(unit, np.array([200, 100, 50])) == [200, 100, 50, 255]  # integers keep their own range
    bytes_ = LiveCloud()
    assert pushed_colour(bytes_, (200.0, 100.0, 50.0)) == [200, 100, 50, 255]
    assert pushed_colour(bytes_, (0.9, 1.0, 1.0)) == [1, 1, 1, 255]  # a dark 0..255 frame (alone: [230, 255, 255, 255])
    with pytest.raises(InputError, match=r"^live: push: colors must be 0..1, 0..255 or 0..65535 \(16 bits\), got -0.5$"):
        pushed_colour(unit, (0.5, -0.5, 1.0))  # still refused


@pytest.mark.parametrize(
    "bad",
    [
        lambda live, rgb: live.push(np.zeros((4, 3)), rgb=rgb, label=np.zeros(5, np.uint8)),  # an attribute of the wrong length
        lambda live, rgb: live.push(np.zeros((4, 3)), rgb=rgb, normals=np.ones((3, 3))),
        lambda live, rgb: live.push(np.zeros((4, 3)), rgb=rgb, time=float("nan")),
        lambda live, rgb: live.push(np.full((4, 3), np.nan), rgb=rgb),  # no valid point
        lambda live, rgb: live.push(np.zeros((5, 3)), rgb=rgb),  # 4 colours for 5 points
        lambda live, rgb: live.push(np.zeros((4, 3)), rgb=rgb, label=np.full(4, 1000)),  # the first frame's uint8 cannot hold it
        lambda live, rgb: live.push_depth(np.zeros((2, 2)), (1, 1, 1, 1), rgb=rgb.reshape(2, 2, 3)),  # no valid pixel
        lambda live, rgb: live.push_depth(np.ones((2, 2)), (1, 1, 1, 1), rgb=rgb.reshape(2, 2, 3), time=float("inf")),
    ],
)
def test_a_refused_frame_does_not_decide_the_streams_colour_range(bad):
    """A frame's float colours decided the stream's range before its other checks: a 0..255
    frame refused for a bad attribute, time or no valid point made the 0..1 stream after it
    black (0.5 read as 0..255)."""
    live = LiveCloud()
    live.push(np.zeros((4, 3)), label=np.zeros(4, np.uint8))
    with pytest.raises(InputError):
        bad(live, np.full((4, 3), 200.0))
    live.push(np.ones((4, 3)), rgb=np.full((4, 3), 0.5), label=np.zeros(4, np.uint8))
    assert live.frame_points([live.frames[-1]])[1][0].tolist() == [128, 128, 128, 255]


def test_a_producer_judging_colours_while_another_decides_a_range_is_not_broken(monkeypatch):
    """_trial_colors iterated the stream's colour ranges without the pending lock: a producer
    whose frame decided a new kind (16-bit colours) meanwhile raised "dictionary changed size
    during iteration" in the other producer's push. The copy hook lets the second producer run
    inside the first one's iteration (waiting for it at most a second: it waits on the lock)."""
    import types

    import gigapoint.live.cloud as live_cloud

    live = LiveCloud()
    live.push(np.zeros((4, 3)), rgb=np.full((4, 3), 0.5))  # decides the float range
    other = threading.Thread(target=lambda: live.push(np.zeros((4, 3)), rgb=np.full((4, 3), 200, np.uint16)))
    real_copy = live_cloud.copy.copy

    def copy_while_another_pushes(x):
        if not other.is_alive() and other.ident is None:
            other.start()
            other.join(timeout=1.0)
        return real_copy(x)

    monkeypatch.setattr(live_cloud, "copy", types.SimpleNamespace(copy=copy_while_another_pushes))
    live.push(np.zeros((4, 3)), rgb=np.full((4, 3), 0.5))
    other.join()
    firsts = sorted(live.frame_points([f])[1][0].tolist() for f in live.frames)
    assert firsts == [[128, 128, 128, 255]] * 2 + [[200, 200, 200, 255]]


def test_clear_starts_a_stream_that_decides_its_own_colour_range():
    """clear() drops every frame but kept the colour range: a 0..255 float stream after a
    cleared 0..1 one was read as 0..1 (every point white)."""
    live = LiveCloud()
    live.push(np.zeros((4, 3)), rgb=np.full((4, 3), 0.5))
    live.clear()
    live.push(np.zeros((4, 3)), rgb=np.full((4, 3), 200.0))
    assert live.frame_points()[1][0].tolist() == [200, 200, 200, 255]
    live.push(np.zeros((4, 3)), rgb=np.full((4, 3), 0.9))  # the new stream's range holds: a dark 0..255 frame
    assert live.frame_points([live.frames[-1]])[1][0].tolist() == [1, 1, 1, 255]


def test_the_huds_frames_per_second_reads_the_clouds_clock():
    """Arrivals were stamped, and frames/s read, with the real clock beside the cloud's
    ``clock=``: ten frames pushed a fake 0.1 s apart (at once in real time) read ~10^5 frames/s,
    and a stream the fake clock had left 5 s behind still read as running."""
    now = [100.0]
    live = LiveCloud(clock=lambda: now[0])
    for _ in range(10):
        live.push(np.zeros((4, 3)))
        now[0] += 0.1
    assert live.stats.frames_per_second() == pytest.approx(10.0)
    assert live.hud().startswith("live: 10.0 frames/s in, 10 frames")
    now[0] += 5.0  # nothing since: the stream stopped
    assert live.hud().startswith("live: 0.0 frames/s in, 10 frames")


def test_without_decay_no_alpha_is_given():
    live = LiveCloud()
    live.push(*frame(0))
    cam = gp.Camera.fit(live.bounds, view="top", width=64, height=64)
    with live.reading():
        draw = live.prepare(cam.view(live.bounds), gp.RenderSettings())
    assert getattr(draw, "alpha", None) is None


@pytest.mark.filterwarnings("ignore:live. frames arrive faster")  # (two producers may outpace the copies: frames dropped unseen)
def test_producers_push_while_frames_render_and_no_frame_is_torn():
    live = LiveCloud(keep=4)
    sizes = {k: 4000 + 311 * k for k in range(40)}
    stop = threading.Event()
    errors = []

    def produce(offset):
        try:
            for k in range(offset, 40, 2):
                live.push(*frame(k % 5, n=sizes[k]))
        except Exception as exc:  # noqa: BLE001
            errors.append(exc)

    threads = [threading.Thread(target=produce, args=(o,)) for o in (0, 1)]
    for t in threads:
        t.start()
    cam = gp.Camera.fit((np.array([-6.0, -5, -2]), np.array([10.0, 5, 2])), view="top", width=96, height=96)
    seen = 0
    while any(t.is_alive() for t in threads) or not seen:
        with live.reading():
            draw = live.prepare(cam.view(live.bounds), gp.RenderSettings(frustum_culling=False))
            drawn = int(draw.points.batches["count"][draw.selection.ids].sum())
            frames = list(live.frames)
        assert drawn == sum(f.n_points for f in frames)  # whole frames only
        assert drawn == sum(sizes[f.seq] for f in frames) or len({f.seq for f in frames}) == len(frames)
        seen += 1
    stop.set()
    for t in threads:
        t.join()
    assert not errors and live.stats.frames_in + live.stats.frames_dropped == 40 and live.n_frames == 4  # every frame landed or was dropped unseen


def test_snapshot_holds_the_pushed_points_transformed_by_their_poses_and_draws_with_the_ring():
    live = LiveCloud(keep=2)
    want = []
    for k in range(2):
        xyz, rgb = frame(k, n=4000)
        live.push(xyz, rgb, pose=pose_of(k))
        want.append(xyz @ pose_of(k)[:3, :3].T + pose_of(k)[:3, 3])
    assert live.snapshot() == 8000
    got = np.concatenate([c.xyz for c in live.snapshots.chunks()])
    assert_same_points(got, np.concatenate(want), 1e-5)
    live.clear()
    assert live.n_frames == 0 and live.n_points == 8000
    cam = gp.Camera.fit(live.bounds, view="top", width=80, height=80)
    f = gp.render_frame(live, cam, gp.RenderSettings(size_mode="fixed"))
    assert f.stats.visible_pixels > 0
    i = int(f.index[f.index >= 0][0])
    assert f.point_info(i)["source"] == "snapshot"
    live.push(*frame(5, n=3000), pose=pose_of(5))  # live frames and snapshots in one pass
    f2 = gp.render_frame(live, cam, gp.RenderSettings(size_mode="fixed"))
    assert f2.stats.points_processed >= 3000 + 8000


def test_snapshots_with_and_without_normals_keep_the_first_snapshots_attributes():
    """The snapshot octree's attributes are its first snapshot's: normals=False, then True adds
    the points without their normals (the octree refuses attributes outside its set)."""
    live = LiveCloud(keep=1)
    live.push(*frame(0, n=2000))
    assert live.snapshot(normals=False) == 2000
    first = set(live.snapshots.attribute_names)
    assert "normal" not in first
    live.push(*frame(1, n=3000))
    assert live.snapshot(normals=True) == 3000
    assert live.snapshots.n_points == 5000 and set(live.snapshots.attribute_names) == first


@pytest.mark.parametrize("suffix", [".las", ".laz", ".ply"])
def test_save_writes_the_snapshots(tmp_path, suffix):
    live = LiveCloud()
    xyz, rgb = frame(2, n=5000)
    live.push(xyz, rgb, pose=pose_of(2))
    with pytest.raises(InputError, match="no snapshot"):
        live.save(tmp_path / f"a{suffix}")
    live.snapshot()
    out = tmp_path / f"a{suffix}"
    assert live.save(out) == 5000
    back = gp.open(out)
    assert back.n_points == 5000
    assert_same_points(back.positions(), xyz @ pose_of(2)[:3, :3].T + pose_of(2)[:3, 3], 2e-3)  # LAS: millimetres
    with pytest.raises(InputError, match="exists"):
        live.save(out)
    (tmp_path / f"d{suffix}").mkdir()  # a folder of that name: overwrite=True was os.replace's IsADirectoryError
    with pytest.raises(InputError, match=f"d{suffix}: is a directory, not a {suffix[1:].upper()} file; not replaced$"):
        live.save(tmp_path / f"d{suffix}", overwrite=True)
    assert (tmp_path / f"d{suffix}").is_dir()


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_save_puts_las_attributes_in_their_fields_and_others_in_extra_bytes(tmp_path, suffix):
    """Pushed attributes LAS has a field for go to it (clipped to its range, as the COPC writer
    does); they were declared as extra bytes of the same name too, and laspy refused the file
    ("field 'intensity' occurs more than once"); others are extra bytes."""
    import laspy

    live = LiveCloud()
    xyz, rgb = frame(2, n=3000)
    n = len(xyz)
    intensity = np.arange(n, dtype=np.uint16)
    height = np.linspace(0, 1, n, dtype=np.float32)
    live.push(xyz, rgb, intensity=intensity, classification=np.full(n, 300), return_number=np.full(n, 20, np.uint8),
              gps_time=np.linspace(0, 5, n), height=height)  # fmt: skip
    live.snapshot(normals=False)
    out = tmp_path / f"a{suffix}"
    assert live.save(out) == n
    las = laspy.read(out)
    assert list(las.point_format.extra_dimension_names) == ["height"]
    order = np.argsort(np.asarray(las.gps_time))  # the snapshot's order is the octree's
    np.testing.assert_array_equal(np.asarray(las.intensity)[order], intensity)
    np.testing.assert_allclose(np.asarray(las.height)[order], height)
    assert set(np.asarray(las.classification).tolist()) == {255} and set(np.asarray(las.return_number).tolist()) == {15}


def test_save_writes_rgb_only_when_a_snapshotted_frame_had_colours(tmp_path):
    """Frames pushed without rgb are drawn grey (200, 200, 200): their snapshots were saved as LAS
    point format 7 with that made-up grey; now point format 6 (PLY: no red, green, blue), the
    points and attributes as they were. A frame with colours among them keeps RGB."""
    import laspy
    from plyfile import PlyData

    xyz, rgb = frame(3, n=2000)
    label = np.arange(len(xyz), dtype=np.int32)
    live = LiveCloud()
    live.push(xyz, label=label)
    live.snapshot(normals=False)
    assert live.save(tmp_path / "grey.las") == 2000 and live.save(tmp_path / "grey.ply") == 2000
    las = laspy.read(tmp_path / "grey.las")
    assert las.header.point_format.id == 6 and "red" not in las.point_format.dimension_names
    assert_same_points(las.xyz, xyz, 2e-3)
    order = np.argsort(np.asarray(las.label))
    np.testing.assert_array_equal(np.asarray(las.label)[order], label)
    assert {"red", "green", "blue"}.isdisjoint(PlyData.read(tmp_path / "grey.ply")["vertex"].data.dtype.names)
    live.clear()
    live.push(xyz + [0, 0, 10], rgb, label=label)  # the second snapshot's frame has colours: the file has RGB
    live.snapshot(normals=False)
    assert live.save(tmp_path / "mixed.las") == 4000
    las = laspy.read(tmp_path / "mixed.las")
    assert las.header.point_format.id == 7
    red = np.asarray(las.red)[np.asarray(las.z) > 5] // 257
    assert set(red.tolist()) == {int(rgb[0, 0])}


def _colours_read_back(path) -> set:
    """The (r, g, b, a) colours gp.open draws the points of an octree ``path`` (COPC or folder) in."""
    back = gp.open(path)
    parts = [back.node_points(i)["rgba"] for i in np.flatnonzero(back.counts > 0).tolist()]
    return set(map(tuple, np.concatenate(parts).view(np.uint8).reshape(-1, 4).tolist()))


def test_save_as_copc_or_octree_writes_no_colour_where_no_frame_had_any(tmp_path):
    """The COPC file and octree folder of frames pushed without rgb held their made-up grey as
    colours (COPC point format 7, an octree that says it has colours); now point format 6 and an
    octree.json saying ``has_color: false``, as ``convert`` writes a colourless LAS file. Read
    back, both are drawn in the default grey, as that file is. A coloured cloud keeps RGB."""
    import json

    import laspy

    from gigapoint.core.chunk import DEFAULT_COLOR
    from gigapoint.lod import octree_info

    xyz, rgb = frame(4, n=3000)
    live = LiveCloud()
    live.push(xyz, intensity=np.arange(len(xyz), dtype=np.uint16))
    live.snapshot(normals=False)
    assert live.save(tmp_path / "grey.copc.laz") == 3000 and live.save(tmp_path / "grey") == 3000
    with laspy.CopcReader.open(tmp_path / "grey.copc.laz") as r:
        assert r.header.point_format.id == 6 and "red" not in r.header.point_format.dimension_names  # (was 7, every point 51400)
        np.testing.assert_array_equal(np.sort(np.asarray(r.query().intensity)), np.arange(len(xyz)))
    assert json.loads((tmp_path / "grey" / "octree.json").read_text())["has_color"] is False
    assert octree_info(tmp_path / "grey.copc.laz")["has_color"] is False and octree_info(tmp_path / "grey")["has_color"] is False

    las = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))  # the same points in a colourless LAS file, converted
    las.header.scales, las.header.offsets = [1e-3] * 3, [0.0] * 3
    las.x, las.y, las.z = xyz.T
    las.write(tmp_path / "grey.las")
    gp.convert(tmp_path / "grey.las", tmp_path / "converted")
    assert json.loads((tmp_path / "converted" / "octree.json").read_text())["has_color"] is False
    drawn = {tuple(DEFAULT_COLOR)}
    assert _colours_read_back(tmp_path / "converted") == _colours_read_back(tmp_path / "grey.copc.laz") == _colours_read_back(tmp_path / "grey") == drawn

    coloured = LiveCloud()
    coloured.push(xyz, rgb)
    coloured.snapshot(normals=False)
    assert coloured.save(tmp_path / "rgb.copc.laz") == 3000 and coloured.save(tmp_path / "rgb") == 3000
    with laspy.CopcReader.open(tmp_path / "rgb.copc.laz") as r:
        assert r.header.point_format.id == 7
        assert set((np.asarray(r.query().red) // 257).tolist()) == {int(rgb[0, 0])}
    assert json.loads((tmp_path / "rgb" / "octree.json").read_text())["has_color"] is True
    assert octree_info(tmp_path / "rgb.copc.laz")["has_color"] is True and octree_info(tmp_path / "rgb")["has_color"] is True
    pushed = (*rgb[0].tolist(), 255)
    assert _colours_read_back(tmp_path / "rgb.copc.laz") == _colours_read_back(tmp_path / "rgb") == {pushed}


def test_save_as_ply_writes_64_bit_integers_that_fit_in_32_and_refuses_others(tmp_path):
    """PLY has no 64-bit integers, half floats or booleans: numpy's default int64 attribute (a
    label pushed as np.arange) was plyfile's ValueError traceback "field type 'u8' not in [...]"."""
    from plyfile import PlyData

    live = LiveCloud()
    n = 500
    xyz = np.random.default_rng(9).random((n, 3))
    live.push(xyz, label=np.arange(n), far=np.arange(n, dtype=np.uint64) + 2**31, half=np.full(n, 1.5, np.float16), flag=np.arange(n) % 2 == 0)
    live.snapshot(normals=False)
    assert live.save(tmp_path / "a.ply") == n
    v = PlyData.read(tmp_path / "a.ply")["vertex"].data
    order = np.argsort(v["label"])
    np.testing.assert_array_equal(v["label"][order], np.arange(n))
    np.testing.assert_array_equal(v["far"][order], np.arange(n) + 2**31)
    np.testing.assert_array_equal(v["flag"][order], np.arange(n) % 2 == 0)
    assert set(v["half"].tolist()) == {1.5}
    live = LiveCloud()
    live.push(xyz, big=np.full(n, -(2**63)))
    live.snapshot(normals=False)
    problem = "holds int64 values PLY cannot hold (it has no 64-bit integers), e.g. -9223372036854775808; save as .las or .laz"
    with pytest.raises(InputError, match=f"b.ply: attribute 'big' {re.escape(problem)}$"):
        live.save(tmp_path / "b.ply")
    assert not (tmp_path / "b.ply").exists()


def test_save_as_las_takes_a_grid_the_snapshot_fits(tmp_path):
    """The LAS writer's grid was always a millimetre: a scene 3 000 km across was laspy's
    OverflowError ("do not fit after applying offset and scale"), a 10 cm object 100 steps a side."""
    import laspy

    rng = np.random.default_rng(7)
    for extent, worst in ((0.1, 2e-6), (3e6, 0.01)):
        live = LiveCloud()
        pts = rng.random((2000, 3)) * extent + 1000.0
        live.push(pts)
        live.snapshot(normals=False)
        out = tmp_path / f"s{extent:g}.las"
        assert live.save(out) == 2000
        got = np.asarray(laspy.read(out).xyz)
        assert np.abs(np.sort(got, axis=0) - np.sort(pts, axis=0)).max() < worst, extent  # (sorting moves no value further)


def test_save_names_what_it_cannot_write_and_writes_copc(tmp_path, monkeypatch):
    """save(5) was a TypeError, save("") an octree in the current folder, save("scan.xyz") an
    octree folder named scan.xyz, save("scan.copc.laz") a plain LAZ under a COPC name."""
    from gigapoint.lod import open_octree

    live = LiveCloud()
    live.push(np.random.default_rng(8).random((500, 3)))
    live.snapshot(normals=False)
    monkeypatch.chdir(tmp_path)
    for bad, problem in (
        (5, "save: the output must be a path (.las, .laz, .ply or an octree folder), got 5"),
        ("", "save: the output must be a path (.las, .laz, .ply or an octree folder), got ''"),
        ("scan.xyz", "scan.xyz: save writes .las, .laz or .ply files, an octree folder or a .copc.laz file, not .xyz"),
        ("scan.CSV", "scan.CSV: save writes .las, .laz or .ply files, an octree folder or a .copc.laz file, not .csv"),
    ):
        with pytest.raises(InputError, match=f"^{re.escape(problem)}$"):
            live.save(bad)
    assert not list(tmp_path.iterdir())
    assert live.save("scan.copc.laz") == 500
    assert type(open_octree(tmp_path / "scan.copc.laz")).__name__ == "CopcCloud" and open_octree(tmp_path / "scan.copc.laz").n_points == 500


_SAVE_ON_A_FULL_DISK = """
import resource, signal, sys
from pathlib import Path
import numpy as np
from gigapoint.errors import InputError
from gigapoint.live import LiveCloud

out = Path(sys.argv[1])
live = LiveCloud()
live.push(np.random.default_rng(3).random((20000, 3)) * 100, np.full((20000, 3), 9, np.uint8))
live.snapshot()
for suffix in (".las", ".laz", ".ply"):
    live.save(out / f"warm{suffix}")  # every kernel compiled (and cached) before the limit
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit: EFBIG, as a full disk's ENOSPC
resource.setrlimit(resource.RLIMIT_FSIZE, (4000, resource.RLIM_INFINITY))
for suffix in (".las", ".laz", ".ply"):
    try:
        live.save(out / f"scan{suffix}")
    except InputError as exc:
        print(exc)
"""


def test_save_on_a_full_disk_is_one_line_naming_the_file_and_leaves_nothing(tmp_path):
    """A LAZ that could not be written (a full disk; here a file size limit) was lazrs'
    "IoError: Failed to call write", naming no file, and no OSError (the CLI's "internal error");
    it now also says the room left on the disk, as lazrs names no cause."""
    import subprocess
    import sys

    pytest.importorskip("resource")
    run = subprocess.run([sys.executable, "-c", _SAVE_ON_A_FULL_DISK, str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    lines = run.stdout.splitlines()
    assert [line.split(" (")[0] for line in lines] == [f"{tmp_path / f'scan{s}'}: not written" for s in (".las", ".laz", ".ply")]
    assert all(line.endswith("); nothing was left there") for line in lines)
    assert "File too large" in lines[0] and "Failed to call write" in lines[1] and "File too large" in lines[2]
    assert re.search(r"Failed to call write; [\d,]+ bytes free on its disk\)", lines[1])  # (lazrs's words alone hid a full disk)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["warm.las", "warm.laz", "warm.ply"]  # no scan.*, no temporary file


def test_frames_per_second_follows_a_changing_and_a_slow_stream_and_says_when_it_stopped():
    """Over the last 120 arrivals, 4 s at 30 frames/s then 10 s at 1 frame/s read 8.7 frames/s,
    and a steady frame every 3 s read 0 (a stopped stream) from 2 s after each frame."""
    from gigapoint.live.cloud import LiveStats

    now = [0.0]
    s = LiveStats(clock=lambda: now[0])
    assert s.frames_per_second() == 0.0
    s.arrivals.extend(np.arange(120) / 30.0)
    now[0] = 4.0
    assert s.frames_per_second() == pytest.approx(30.0)
    s.arrivals.extend(4.0 + np.arange(1, 11))
    now[0] = 14.5
    assert s.frames_per_second() == pytest.approx(1.0)
    now[0] = 16.5
    assert s.frames_per_second() == 0.0  # no frame for 2.5 s: stopped
    slow = LiveStats(clock=lambda: now[0])
    slow.arrivals.extend([0.0, 3.0, 6.0, 9.0])
    now[0] = 11.5
    assert slow.frames_per_second() == pytest.approx(1 / 3)
    now[0] = 15.5
    assert slow.frames_per_second() == 0.0  # no frame for 6.5 s, twice its interval: stopped


def test_frames_per_second_of_arrivals_at_one_clock_reading_is_no_rate():
    """Two arrivals at the same reading of a frozen or coarse clock read 1e9 frames/s (their
    interval taken as 1e-9 s); a rate is told only by arrivals that span time."""
    now = [10.0]
    live = LiveCloud(clock=lambda: now[0])
    for _ in range(2):
        live.push(np.zeros((4, 3)))  # both at 10.0: a frozen clock
    assert live.stats.frames_per_second() == 0.0
    assert live.hud().startswith("live: 0.0 frames/s in, 2 frames")
    s = live.stats
    s.arrivals.clear()
    s.arrivals.extend([9.0, 9.5, 10.0, 10.0, 10.0])  # a coarse clock: three in the last tick
    assert s.frames_per_second() == pytest.approx(4 / 1.0)  # 4 intervals over the 1 s spanned
    s.arrivals.clear()
    s.arrivals.extend([5.0, 10.0, 10.0])  # the last two at one instant: the one before them spans time
    assert s.frames_per_second() == pytest.approx(2 / 5.0)


def test_close_frees_frames_and_snapshots_and_refuses_later_pushes(tmp_path):
    """``close`` stopped the source and recording only: frames and snapshots stayed in memory,
    and a push or snapshot afterwards went on as if open."""
    live = LiveCloud()
    live.push(*frame(0, n=2000))
    live.snapshot()
    live.push(*frame(1, n=1000))
    assert live.n_points == 3000 + 2000 and live.snapshots.n_points == 2000  # (a snapshot copies the ring's frames)
    live.close()
    assert live.n_points == 0 and live.snapshots.n_points == 0 and live.snapshots.pool is None
    assert repr(live) == "LiveCloud('live', 0 of 100 frames, 0 live points, 0 snapshot points, closed)"
    for what, call in (("push", lambda: live.push(*frame(2, n=10))), ("snapshot", live.snapshot), ("save", lambda: live.save("x.las")),
                       ("push_depth", lambda: live.push_depth(np.ones((2, 2)), (1, 1, 1, 1))),  # (was "live: push: ...")
                       ("record", lambda: live.record(tmp_path / "rec"))):  # (made a folder never to get a frame)  # fmt: skip
        with pytest.raises(InputError, match=f"^live: {what}: the live cloud is closed"):
            call()
    assert not (tmp_path / "rec").exists()


def test_a_nan_normal_is_an_unknown_one_and_the_point_is_still_lit():
    """Pushed normals with NaN (a sensor's unknown ones) were kept: lighting and
    color_mode="normal" drew those points black."""
    g = np.stack(np.meshgrid(np.linspace(0, 10, 20), np.linspace(0, 10, 20)), -1).reshape(-1, 2)
    xyz = np.column_stack([g, np.zeros(len(g))])
    normals = np.tile([0.0, 0.0, 1.0], (len(xyz), 1))
    normals[::2] = np.nan
    normals[1::4, 2] = np.inf
    live = LiveCloud()
    live.push(xyz, np.tile([200, 0, 0], (len(xyz), 1)).astype(np.uint8), normals=normals)
    _, _, attrs = live.frame_points()
    got = np.column_stack([attrs["nx"], attrs["ny"], attrs["nz"]])
    assert np.isfinite(got).all() and int((got == 0).all(axis=1).sum()) == 300
    cam = gp.Camera.fit(live.bounds, view="top", width=64, height=64)
    image = gp.render(live, cam, gp.RenderSettings(size_mode="fixed", background=(0, 0, 0), lighting=True))
    assert int((image[..., 0] > 0).sum()) == 400  # every point drawn in colour (NaN ones were black)


def test_an_aging_frame_fades_through_the_transparency_pass():
    now = [0.0]
    live = LiveCloud(decay=2.0, clock=lambda: now[0])
    g = np.stack(np.meshgrid(np.linspace(0, 10, 20), np.linspace(0, 10, 20)), -1).reshape(-1, 2)
    xyz = np.column_stack([g, np.zeros(len(g))])
    live.push(xyz, np.tile([255, 0, 0], (len(xyz), 1)).astype(np.uint8))
    cam = gp.Camera.fit(live.bounds, view="top", width=64, height=64)
    settings = gp.RenderSettings(size_mode="fixed", background=(0, 0, 0))
    reds = []
    for t in (0.0, 1.0, 1.5):
        now[0] = t
        image = gp.render(live, cam, settings)
        lit = image[..., 0] > 0
        assert int(lit.sum()) == 400  # one pixel a point, every point still drawn
        reds.append(sorted(set(image[lit, 0].tolist())))
    assert reds == [[255], [128], [64]]  # alpha 1 - age / decay over a black background


def test_save_without_a_point_cloud_suffix_writes_an_octree_folder(tmp_path):
    live = LiveCloud()
    xyz, rgb = frame(3, n=6000)
    live.push(xyz, rgb)
    live.snapshot()
    assert live.save(tmp_path / "octree") == 6000
    back = gp.open(tmp_path / "octree")
    assert back.n_points == 6000


def test_a_frame_waiting_gets_the_lock_while_producers_keep_pushing():
    """The producer copying queued frames into the ring went on while the queue had any: with
    producers pushing faster than that (three on two cores), a renderer's or snapshot's
    ``reading`` waited for ever. It lets go after the frame it is copying; the rest land when
    the frame is drawn."""
    live = LiveCloud(keep=3)
    live.push(*frame(0, n=1000))
    more = frame(1, n=1000)
    arrived, seen_by_reader = [0], []
    def read():
        with live.reading():
            seen_by_reader.append(live.stats.frames_in)

    reader = threading.Thread(target=read)
    insert = live._insert

    def insert_while_producers_push(f, info):
        insert(f, info)
        if arrived[0] == 0:  # a frame starts to wait for the lock
            reader.start()
            deadline = time.monotonic() + 10
            while not live.lock.frame_waiting() and time.monotonic() < deadline:
                time.sleep(0.001)
        if arrived[0] < 100 and not seen_by_reader:  # and another producer's frame arrives meanwhile, every time
            arrived[0] += 1
            live.push(*more)

    live._insert = insert_while_producers_push
    live.push(*more)
    reader.join(10)
    assert not reader.is_alive()
    assert seen_by_reader and seen_by_reader[0] <= 3, seen_by_reader  # the reader got in at once, not after 100 frames
    n = 2 + arrived[0]
    assert live.stats.frames_in == n and [f.seq for f in live.frames] == [n - 3, n - 2, n - 1]  # every frame landed, in order


def test_a_push_during_a_frame_returns_at_once_and_lands_when_the_frame_is_drawn():
    live = LiveCloud(keep=5)
    live.push(*frame(0, n=1000))
    done = threading.Event()
    with live.reading():
        version = live.buffers().version
        t = threading.Thread(target=lambda: (live.push(*frame(1, n=1000)), done.set()))
        t.start()
        assert done.wait(10)  # the producer did not wait for the frame
        live.push(*frame(2, n=1000))  # nor does a push from the drawing thread itself
        assert live.n_frames == 1 and live.buffers().version == version  # nothing moved under the frame
    t.join()
    assert live.n_frames == 3 and [f.seq for f in live.frames] == [0, 1, 2] and live.stats.frames_in == 3


def test_a_dropped_cloud_is_freed_at_once():
    import weakref

    live = LiveCloud()
    live.push(*frame(0))
    ref = weakref.ref(live)
    del live
    assert ref() is None  # no reference cycle waits for the garbage collector (GBs of buffers)


def test_depth_frame_normals_reach_the_normal_color_mode_and_lighting():
    live = LiveCloud()
    pose = np.eye(4)
    pose[:3, :3] = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]  # looking down (sensor z -> world -z) from 10 m up
    pose[2, 3] = 10.0
    live.push_depth(np.full((40, 50), 10.0, np.float32), (40.0, 40.0, 24.5, 19.5), pose=pose)  # the ground plane z = 0
    assert live.attributes["normal"].shape[1] == 3
    np.testing.assert_allclose(live.frame_points()[2]["nz"], 1.0, atol=1e-6)  # facing up, towards the sensor
    cam = gp.Camera.fit(live.bounds, view="top", width=60, height=60)
    image = gp.render(live, cam, gp.RenderSettings(size_mode="fixed", color_mode="normal"))
    lit = image[..., 3] > 0
    drawn = image[image[..., 0] != image[0, 0, 0]]
    assert len(drawn) > 100 and lit.all()
    np.testing.assert_array_equal(np.unique(drawn[:, :3], axis=0), [[128, 128, 255]])  # (0, 0, 1) * 0.5 + 0.5
    shaded = gp.render(live, cam, gp.RenderSettings(size_mode="fixed", lighting=True))
    plain = gp.render(live, cam, gp.RenderSettings(size_mode="fixed"))
    assert not np.array_equal(shaded, plain)


def test_a_flat_snapshot_seen_from_above_draws_every_point_with_its_normal():
    live = LiveCloud()
    pose = np.eye(4)
    pose[:3, :3] = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]
    pose[2, 3] = 10.0
    live.push_depth(np.full((40, 50), 10.0, np.float32), (40.0, 40.0, 24.5, 19.5), pose=pose)
    live.snapshot()
    live.clear()
    cam = gp.Camera.fit(live.bounds, view="top", width=60, height=60)
    f = gp.render_frame(live, cam, gp.RenderSettings(size_mode="fixed"))
    assert f.stats.visible_pixels == 2000  # 10-bit node positions stay inside the clip range
    info = f.point_info(int(f.index[f.index >= 0][0]))
    assert info["source"] == "snapshot" and info["normal"] == pytest.approx([0.0, 0.0, 1.0]) and np.isnan(info["frame_time"])


def test_adaptive_spacing_is_kept_between_pushes_and_measured_again_as_frames_turn_over(monkeypatch):
    """A live cloud gives its frames the ring's point spacing (adaptive point sizes) itself,
    measured again once a tenth of its kept frames are new, not in every frame of a stream; what
    it gives is the spacing of its buffers when measured, and a frame draws as with that spacing."""
    from gigapoint.live import cloud as live_cloud
    from gigapoint.render.splats import point_spacing

    calls = []
    real = live_cloud.point_spacing
    monkeypatch.setattr(live_cloud, "point_spacing", lambda buf, step: calls.append(step) or real(buf, step))
    live = LiveCloud(keep=20, chunk=2048)  # frames above half a chunk: a chunk each (packed, these overlapping frames are denser)
    cam = gp.Camera.look_at((30, -8, 6), (30, 0, 0), width=160, height=120)  # close: points of several pixels
    adaptive = gp.RenderSettings()  # size_mode "auto": adaptive sizes
    for k in range(40):
        live.push(*frame(k, n=2000))
        draw = live.prepare(cam.view(live.bounds), adaptive)
        if k == 0:
            assert draw.spacing == pytest.approx(point_spacing(live.buffers_, draw.step))
        if k == 19:
            filling = len(calls)
    # while the ring fills (fewer than 10 frames kept) every push; then every 2 pushes (a tenth of 20 kept)
    assert 11 <= filling <= 20 and len(calls) - filling == 10, (filling, len(calls))
    assert draw.spacing > 0
    live._spacing = None  # measured for this frame: the same image as the renderer's own measure
    with_kept = gp.render_frame(live, cam, adaptive)
    monkeypatch.setattr(live, "_kept_spacing", lambda buf, step: None)  # the renderer measures the buffers itself
    fresh = gp.render_frame(live, cam, adaptive)
    np.testing.assert_array_equal(with_kept.visibility, fresh.visibility)
    one_pixel = gp.render_frame(live, cam, gp.RenderSettings(size_mode="fixed"))
    assert (~with_kept.empty).sum() > 1.15 * (~one_pixel.empty).sum()  # the spacing made splats larger than a pixel


def sensor_frame():
    """A depth frame of a sloped, stepped surface with holes (an organised image) and its pose."""
    rng = np.random.default_rng(5)
    v, u = np.mgrid[0:120, 0:160]
    depth = (4.0 + 0.01 * u + 1.5 * (v > 60) + rng.normal(0, 0.005, v.shape)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = 0
    return depth, (120.0, 120.0, 79.5, 59.5), pose_of(3)


def test_a_depth_frame_is_batched_in_its_images_z_order_and_draws_as_the_sorted_frame():
    """push_depth puts a frame's points in the image's Z order (depth.pixel_order) instead of
    sorting them by Morton code: its batches hold the same points in that order, each box
    holds its points, and the frame draws as the same points pushed (Morton-sorted) by push."""
    from gigapoint.live.depth import depth_to_points

    depth, K, pose = sensor_frame()
    xyz, nrm, _, pix = depth_to_points(depth, K, pose, z_order=True)
    live = LiveCloud(keep=2, chunk=1024)
    live.push_depth(depth, K, pose=pose)
    got, _, attrs = live.frame_points()
    want = xyz
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)  # in that order: no sort
    np.testing.assert_array_equal(np.stack([attrs[p] for p in ("nx", "ny", "nz")], 1), nrm)
    buf = live.buffers_
    slots = live.frames[0].chunks
    assert len(slots) == -(-len(xyz) // 1024)
    start = 0
    for s in slots:  # each batch's box is its own points' box
        rec = buf.batches[s]
        part = want[start : start + int(rec["count"])]
        np.testing.assert_allclose(rec["bbox_min"], part.min(axis=0), atol=1e-9)
        np.testing.assert_allclose(rec["bbox_max"], part.max(axis=0), atol=1e-9)
        start += int(rec["count"])
    sorted_live = LiveCloud(keep=2, chunk=1024)
    sorted_live.push(xyz, normals=nrm @ pose[:3, :3])  # sensor normals: push applies the pose
    cam = gp.Camera.fit(live.bounds, view="iso", width=160, height=120)
    exact = gp.RenderSettings(size_mode="fixed", adaptive_precision=False)
    a, b = gp.render_frame(live, cam, exact), gp.render_frame(sorted_live, cam, exact)
    # 30-bit positions in other boxes: a point on a pixel's edge may fall on its neighbour
    assert (a.image != b.image).any(axis=-1).sum() <= 0.002 * (~b.empty).sum()
    assert a.stats.points_processed == b.stats.points_processed == len(xyz)
    # adaptive precision: 10/20/30-bit positions relative to each batch's box, so batches cut
    # differently move some points by up to a pixel: nearly every covered pixel the same
    a, b = gp.render_frame(live, cam, gp.RenderSettings(size_mode="fixed")), gp.render_frame(sorted_live, cam, gp.RenderSettings(size_mode="fixed"))
    assert (a.empty != b.empty).sum() <= 0.02 * (~b.empty).sum()


def test_the_mirror_holds_the_snapshot_pools_entries_after_every_snapshot():
    """The mirror region is the octree's (compact) pool decoded to three words: the same low,
    medium and high words, colours and normals per chunk, whether a snapshot filled a new pool
    (one run of chunks) or changed some chunks of it here and there (a later snapshot)."""
    from gigapoint.core.compact import point_words

    live = LiveCloud(keep=3)
    for k in range(3):
        live.push(*frame(k, n=6000), pose=pose_of(k), normals=np.tile([0.0, 0.0, 1.0], (6000, 1)))
    live.snapshot()
    live.prepare(gp.Camera.fit(live.bounds, view="top", width=40, height=40).view(live.bounds), gp.RenderSettings())
    for k in range(3, 5):
        live.push(*frame(k, n=6000), pose=pose_of(1), normals=np.tile([0.0, 1.0, 0.0], (6000, 1)))
    changed_before = live.snapshots.pool.version
    live.snapshot()
    pool = live.snapshots.pool
    assert 0 < int((pool.batch_version > changed_before).sum()) < pool.n_chunks  # some chunks, not all
    live.prepare(gp.Camera.fit(live.bounds, view="top", width=40, height=40).view(live.bounds), gp.RenderSettings())
    buf, mc = live.buffers_, pool.chunk
    used = np.flatnonzero(pool.batches["count"][: pool.n_chunks] > 0)
    assert len(used) > 4
    for c in used:
        n, f, o = int(pool.batches["count"][c]), c * mc, buf.ring_points + c * mc
        assert int(buf.batches["count"][buf.n_ring + c]) == n
        for got, want in zip((buf.low[o : o + n], buf.med[o : o + n], buf.high[o : o + n]), point_words(pool, c, f, f + n)):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(buf.color[o : o + n], pool.color[f : f + n])
        for k, part in enumerate(("nx", "ny", "nz")):
            np.testing.assert_array_equal(buf.attributes["normal"][o : o + n, k], pool.attributes[part][f : f + n])


def test_a_snapshot_in_batches_adds_what_one_batch_would_and_keeps_frames_that_leave_meanwhile(monkeypatch):
    """snapshot() gathers each SNAPSHOT_BATCH of points from the ring when its turn comes: the
    octree gets the points frame_points gives, cut at the same places, in the same order, with the
    bounds of all of them up front; frames pushed meanwhile (those that leave the ring then) do
    not overwrite the chunks it has yet to read."""
    import gigapoint.live.cloud as live_module
    from gigapoint.lod.progressive import ProgressiveOctree

    def filled():
        live = LiveCloud(keep=3)
        for k in range(3):
            xyz, rgb = frame(k, n=7000)
            live.push(xyz, rgb, pose=pose_of(k), intensity=np.arange(7000, dtype=np.uint16) + k)
        return live

    live = filled()
    xyz, rgba, attrs = live.frame_points()
    buf = live.buffers_
    runs = live._runs(live.frames)
    lo, hi = buf.bounds_of(runs)
    np.testing.assert_array_equal(lo, xyz.min(axis=0))  # exactly: the cube of the first snapshot comes from them
    np.testing.assert_array_equal(hi, xyz.max(axis=0))
    out: dict = {}
    for s, e in ((0, 5000), (5000, 5001), (5001, 21000), (123, 15000)):
        got = buf.gather(runs, ("frame_time",), s, e, out)
        np.testing.assert_array_equal(got[0], xyz[s:e])
        np.testing.assert_array_equal(got[1], rgba[s:e])
        assert set(got[2]) == set(attrs)
        for a in attrs:
            np.testing.assert_array_equal(got[2][a], attrs[a][s:e])

    added = []
    add = ProgressiveOctree.add

    def add_and_push(self, xyz, rgb=None, **attributes):
        added.append((xyz.copy(), np.asarray(rgb).copy(), {a: v.copy() for a, v in attributes.items()}))
        for k in range(10, 13):  # every frame snapshotted leaves the ring: its chunks go to new frames
            live.push(*frame(k, n=7000), pose=pose_of(k), intensity=np.zeros(7000, np.uint16))
        return add(self, xyz, rgb, **attributes)

    monkeypatch.setattr(live_module, "SNAPSHOT_BATCH", 4096)
    monkeypatch.setattr(ProgressiveOctree, "add", add_and_push)
    assert live.snapshot() == 21000
    assert [len(a[0]) for a in added] == [4096] * 5 + [21000 - 5 * 4096]
    np.testing.assert_array_equal(np.concatenate([a[0] for a in added]), xyz)
    np.testing.assert_array_equal(np.concatenate([a[1] for a in added]), rgba)
    for a in attrs:
        np.testing.assert_array_equal(np.concatenate([b[2][a] for b in added]), attrs[a])
    o = live.snapshots
    assert o.points == 21000 and np.all(o.origin <= lo) and np.all(o.origin + o.edge >= hi)
    assert live.n_frames == 3 and [f.seq for f in live.frames] == [18, 19, 20]
    assert not live._pins and not live._held  # the chunks read are free again
    assert sorted(live._free + [s for f in live.frames for s in f.chunks]) == list(range(buf.n_ring))
    live.push(*frame(20, n=7000), pose=pose_of(20))
    assert live.n_frames == 3


def test_a_snapshot_shapes_its_tree_from_every_32nd_point_first(monkeypatch):
    """Above one batch, snapshot() first hands the octree every SNAPSHOT_SAMPLE_STEP-th point of
    the ring (the positions frame_points gives, exactly) to split the leaves they would overflow
    (ProgressiveOctree.expect), then adds the points: none of them is spilled where the sample
    told the tree's shape."""
    import gigapoint.live.cloud as live_module
    from gigapoint.lod.progressive import ProgressiveOctree

    live = LiveCloud(keep=3)
    for k in range(3):
        live.push(*frame(k, n=7000), pose=pose_of(k))
    xyz = live.frame_points()[0]
    seen = []
    expect = ProgressiveOctree.expect

    def small_leaves(self, sample, weight):
        self.max_leaf = 500  # leaves that the 21 000 points overflow
        seen.append((sample.copy(), weight))
        return expect(self, sample, weight)

    monkeypatch.setattr(live_module, "SNAPSHOT_BATCH", 4096)
    monkeypatch.setattr(ProgressiveOctree, "expect", small_leaves)
    assert live.snapshot() == 21000
    (sample, weight), = seen
    assert weight == live_module.SNAPSHOT_SAMPLE_STEP == 32
    np.testing.assert_array_equal(sample, xyz[::32])
    o = live.snapshots
    assert o.points == 21000 and int(o.count[o.leaves()].sum()) == 21000 and o.count[o.leaves()].max() <= 500
    assert o.spilled < 21000 // 10, o.spilled


def test_depth_frames_queued_while_a_frame_draws_keep_their_own_points():
    """push_depth reuses its positions' arrays from frame to frame (one set per producer thread):
    frames pushed while a frame is drawn wait in the queue, and each keeps its own points,
    normals and colours, not those of the frame pushed after it."""
    from gigapoint.live.depth import depth_to_points

    depth, K, pose = sensor_frame()
    second = depth.copy()
    second[second > 0] += 0.5
    rgb = np.random.default_rng(5).integers(0, 255, (*depth.shape, 3), dtype=np.uint8)
    live = LiveCloud(keep=4, chunk=1024)
    with live.reading():  # a frame being drawn: pushes queue
        live.push_depth(depth, K, pose=pose, rgb=rgb)
        live.push_depth(second, K, pose=pose, rgb=rgb[::-1].copy())
        assert live.n_frames == 0
    assert live.n_frames == 2
    got, rgba, attrs = live.frame_points()
    want = [depth_to_points(d, K, pose, c, z_order=True) for d, c in ((depth, rgb), (second, rgb[::-1].copy()))]
    np.testing.assert_allclose(got, np.concatenate([w[0] for w in want]), rtol=0, atol=1e-6)
    np.testing.assert_array_equal(np.stack([attrs[p] for p in ("nx", "ny", "nz")], 1), np.concatenate([w[1] for w in want]))
    np.testing.assert_array_equal(rgba, np.concatenate([w[2] for w in want]))


def test_a_later_frame_keeps_to_the_first_frames_attributes():
    """A frame bringing an attribute the first frame had not was taken and the attribute
    dropped without a word; now a one-line InputError that leaves the cloud as it was. A frame
    leaving one out holds 0 for it."""
    live = LiveCloud()
    xyz, rgb = frame(0, n=50)
    live.push(xyz, rgb, intensity=np.arange(50, dtype=np.uint16))
    with pytest.raises(InputError, match=r"^live: push: attribute 'foo' is not one of this cloud's \(intensity\): the first frame fixes them$"):
        live.push(xyz, rgb, intensity=np.arange(50, dtype=np.uint16), foo=np.ones(50))
    assert live.n_points == 50 and live.stats.frames_rejected == 1
    live.push(xyz + 1, rgb)
    assert live.n_points == 100
    frame_a = gp.render_frame(live, gp.Camera.fit_cloud(live, width=64, height=48))
    seen = [frame_a.point_info(int(i)) for i in np.unique(frame_a.index) if i >= 0]
    assert {s["intensity"] for s in seen} - set(range(50)) <= {0} and any(s["intensity"] > 0 for s in seen)
    # values the first frame's dtype cannot hold: 1000 in its uint16's place was fine, 70 000 was kept as 4 464
    live.push(xyz, rgb, intensity=np.full(50, 1000))  # int64 values that fit
    for values, shown in ((np.full(50, 70_000), "70000"), (np.full(50, 2.5), "2.5"), (np.full(50, -1), "-1")):
        with pytest.raises(InputError, match=rf"^live: push: attribute 'intensity' holds values its uint16 \(the first frame's\) cannot hold exactly, e.g. {shown}$"):
            live.push(xyz, rgb, intensity=values)
    assert live.n_points == 150


@pytest.mark.timeout(60)  # (a NaN timeout waited forever)
def test_waits_and_snapshots_refuse_odd_arguments():
    """wait_frame(timeout=NaN) waited forever, wait_frame("a") was a TypeError inside the wait,
    snapshot("no") kept the normals."""
    live = LiveCloud()
    live.push(*frame(0))
    for kw, problem in (({"seen": 10**6, "timeout": float("nan")}, "timeout must be a number of seconds or None, got nan"),
                        ({"seen": "a", "timeout": 0.01}, "seen must be an integer, got 'a'")):  # fmt: skip
        with pytest.raises(InputError, match=rf"^live: wait_frame: {re.escape(problem)}$"):
            live.wait_frame(**kw)
    assert live.wait_frame(10**6, timeout=0.01) == live.changes  # a number still times out
    assert live.wait_frame(0, timeout=float("inf")) == live.changes  # inf: no limit (one change is there)
    with pytest.raises(InputError, match=r"^live: snapshot: normals must be True or False, got 'no'$"):
        live.snapshot("no")


def test_a_small_frame_is_pushed_on_the_calling_thread_alone(monkeypatch):
    """A sensor's small frames paid ~0.1 ms a parallel kernel to wake numba's sleeping threads
    (1 000 points a push: 0.6 M points/s, 3 M on one thread): a frame below SMALL_BATCH points is
    worked on the pushing thread, a larger one on all; the count is back after the push, taken
    or refused, and the frame draws as the same frame pushed on all threads does."""
    import numba

    import gigapoint.live.cloud as live_module
    from gigapoint.core import threads

    seen, real = [], live_module.valid_bounds
    monkeypatch.setattr(live_module, "valid_bounds", lambda *a: seen.append(numba.get_num_threads()) or real(*a))
    before = numba.get_num_threads()
    xyz, rgb = frame(2, n=3_000)
    one = LiveCloud(keep=2)
    one.push(xyz, rgb)
    big = frame(3, n=threads.SMALL_BATCH)
    one.push(*big)
    assert seen == [1, before] and numba.get_num_threads() == before
    with pytest.raises(InputError, match="no points"):
        one.push(np.zeros((0, 3)))
    with pytest.raises(InputError, match="must be 1-D numbers"):
        one.push(xyz, rgb, intensity=np.zeros(2))
    assert numba.get_num_threads() == before
    monkeypatch.setattr(threads, "SMALL_BATCH", 0)  # every frame on all threads, as before
    every = LiveCloud(keep=2)
    every.push(xyz, rgb)
    every.push(*big)
    assert seen[2:] == [before, before]
    cam = gp.Camera.fit(one.bounds, view="iso", width=160, height=120)
    a = gp.render_frame(one, cam, gp.RenderSettings(size_mode="fixed"))
    b = gp.render_frame(every, cam, gp.RenderSettings(size_mode="fixed"))
    np.testing.assert_array_equal(a.image, b.image)
    assert a.stats.points_processed == 3_000 + len(big[0])


def test_frame_points_of_a_frame_that_left_the_ring_is_an_error_not_another_frames_points():
    """frame_points(frames) read the chunks a FrameInfo named: once the frame had left the ring
    they held a newer frame's points, given as its own without a word."""
    live = LiveCloud(keep=2)
    live.push(np.full((100, 3), 1.0))
    first = list(live.frames)
    np.testing.assert_array_equal(live.frame_points(first)[0], np.full((100, 3), 1.0))
    for k in range(3):
        live.push(np.full((100, 3), 10.0 + k))
    with pytest.raises(InputError, match=r"^live: frame_points: frame 0 is not in the ring \(it has left it"):
        live.frame_points(first)
    newest = list(live.frames)[-1:]
    np.testing.assert_array_equal(live.frame_points(newest)[0], np.full((100, 3), 12.0))
    other = LiveCloud(keep=2)
    other.push(np.zeros((5, 3)))
    with pytest.raises(InputError, match="frame 0 is not in the ring"):
        live.frame_points(list(other.frames))
    for bad in ([1], newest[0], "frames"):
        with pytest.raises(InputError, match="frames must be"):
            live.frame_points(bad)


def moving_patch(k: int, n: int = 50):
    """Frame k of a slowly moving sensor's small packets: n points in a 2 x 2 x 0.5 m patch that
    moves 1 cm a frame (packets near each other, as a scanner's are)."""
    rng = np.random.default_rng(100 + k)
    return rng.uniform(-1, 1, (n, 3)) * [1, 1, 0.25] + [0.01 * k, 0, 0], np.full((n, 3), k % 250, np.uint8)


def test_small_frames_share_chunks_and_each_keeps_its_own_points():
    """A chunk a frame held 3 357 bytes a point for frames of 50 points (2 000 frames: 336 MB):
    frames of at most half a chunk are packed one after another into shared chunks, and each
    frame's points, colours and order are still its own (frame_points), the ring's those of the
    frames it keeps, in arrival order, as frames leave it from the front of their chunks."""
    live = LiveCloud(keep=2000)
    frames = [moving_patch(k) for k in range(2000)]
    for xyz, rgb in frames:
        live.push(xyz, rgb)
    buf = live.buffers_
    used = int((buf.batches["count"][: buf.n_ring] > 0).sum())
    assert live.n_points == 100_000 and used <= 11 and buf.n_ring == 32  # 100 000 points in 10 240-point chunks; never grown
    assert buf.low.nbytes + buf.attributes["normal"].nbytes <= 32 * 10_240 * 16
    for k in (0, 1, 777, 1999):
        xyz, rgba, _ = live.frame_points([live.frames[k]])
        np.testing.assert_allclose(xyz, frames[k][0], rtol=0, atol=1e-7)  # 30-bit cells of a box of a few metres
        assert (rgba[:, :3] == frames[k][1]).all()
    for k in range(2000, 2300):  # 300 frames leave from the chunks' fronts
        live.push(*moving_patch(k))
    kept = [moving_patch(k) for k in range(300, 2300)]
    xyz, rgba, _ = live.frame_points()
    np.testing.assert_allclose(xyz, np.concatenate([x for x, _ in kept]), rtol=0, atol=1e-7)
    np.testing.assert_array_equal(rgba[:, :3], np.concatenate([c for _, c in kept]))
    assert live.n_points == int(buf.batches["count"].sum()) == 100_000
    rec = live.buffers_.batches[: live.buffers_.n_ring]
    for slot in np.flatnonzero(rec["count"] > 0):  # every point drawn is inside its chunk's box: the words were made in it
        pos = live.buffers_.positions(int(slot))
        assert (pos >= rec["bbox_min"][slot]).all() and (pos <= rec["bbox_max"][slot]).all()


def test_packed_positions_are_quantized_once_from_the_pushed_points():
    """A frame that widens its chunk's box makes the chunk's words anew from the positions pushed
    (kept while the chunk is open), not from the words: each point is what quantizing the chunk's
    points in their box at once gives, however many frames widened it."""
    from gigapoint.core.quantize import dequantize, make_batches, quantize

    live = LiveCloud(keep=100)
    pushed = [moving_patch(k, n=40)[0] * (1 + 0.05 * k) for k in range(100)]  # each frame wider than the last
    for xyz in pushed:
        live.push(xyz)
    buf = live.buffers_
    slot = live.frames[0].chunks[0]
    here = [x for f, x in zip(live.frames, pushed) if f.chunks[0] == slot]
    assert len(here) > 10
    allpts = np.concatenate(here)
    one = make_batches(len(allpts), len(allpts))
    want = dequantize(*quantize(allpts, np.arange(len(allpts)), one), one[0]["bbox_min"], one[0]["bbox_max"], 30)
    np.testing.assert_array_equal(buf.positions(slot), want)


def test_frames_far_apart_or_of_other_times_are_not_packed_together():
    """A batch's box is what culling and adaptive precision see, and a chunk has one fade: a small
    frame far from the open chunk's frames, or (fading) arrived a PACK_SPAN-th of ``decay`` after
    its first, starts a new chunk."""
    from gigapoint.live.cloud import PACK_SPAN

    live = LiveCloud(keep=10)
    live.push(moving_patch(0)[0])
    live.push(moving_patch(1)[0])
    live.push(moving_patch(2)[0] + [500.0, 0, 0])
    assert [f.chunks[0] for f in live.frames][:2] == [live.frames[0].chunks[0]] * 2 and live.frames[2].chunks != live.frames[0].chunks
    now = [0.0]
    fading = LiveCloud(keep=100, decay=3.2, clock=lambda: now[0])
    for k in range(40):
        now[0] = 0.02 * k
        fading.push(moving_patch(k)[0])
    by_chunk: dict = {}
    for f in fading.frames:
        by_chunk.setdefault(f.chunks[0], []).append(f.arrived)
    assert len(by_chunk) > 1 and max(len(t) for t in by_chunk.values()) > 1
    assert all(max(t) - min(t) <= 3.2 / PACK_SPAN + 1e-9 for t in by_chunk.values())


def test_a_large_chunk_packs_at_most_a_batch_of_small_frames():
    """Each packed frame quantizes its chunk's points afresh: with ``chunk=2**20`` frames of 50
    points would each redo up to a million (quadratic time); a chunk packs up to PACK_FILL
    (10 240) points, whatever its size, and frames above half that go in as they did."""
    from gigapoint.live.cloud import PACK_FILL

    live = LiveCloud(keep=1000, chunk=2**20)
    for k in range(300):
        live.push(*moving_patch(k))
    live.push(*frame(0, n=PACK_FILL))
    ring = live.buffers_.batches[: live.buffers_.n_ring]
    full = PACK_FILL // 50 * 50  # whole frames of 50 points
    assert sorted(ring["count"][ring["count"] > 0].tolist()) == [15_000 - full, full, PACK_FILL]  # two packed chunks, the large frame's
    np.testing.assert_allclose(live.frame_points([live.frames[299]])[0], moving_patch(299)[0], rtol=0, atol=1e-7)


def test_two_sensors_interleaved_packets_fill_a_chunk_each():
    """Frames far apart do not share a chunk, but a sensor's packets need not arrive in a run:
    two sensors 500 m apart whose packets interleave pack into chunks of their own (up to
    PACK_OPEN chunks are open at once), each frame's points still its own."""
    live = LiveCloud(keep=400)
    pushed = []
    for k in range(400):
        xyz = moving_patch(k)[0] + ([500.0, 0, 0] if k % 2 else 0.0)
        live.push(xyz)
        pushed.append(xyz)
    ring = live.buffers_.batches[: live.buffers_.n_ring]
    assert int((ring["count"] > 0).sum()) == 2  # 200 frames of 50 points a sensor: 10 000 points, one chunk each
    assert all((ring["bbox_max"][s] - ring["bbox_min"][s]).max() < 10 for s in np.flatnonzero(ring["count"] > 0))
    for k in (0, 1, 398, 399):
        np.testing.assert_allclose(live.frame_points([live.frames[k]])[0], pushed[k], rtol=0, atol=1e-6)
    np.testing.assert_allclose(live.frame_points()[0], np.concatenate(pushed), rtol=0, atol=1e-6)


def test_a_snapshot_of_small_frames_holds_the_ring_while_frames_are_packed_meanwhile(monkeypatch):
    """Frames packed while a snapshot reads the ring neither widen the chunks it reads (their
    words would move) nor reuse those left: it holds exactly the ring's points at its start."""
    import gigapoint.live.cloud as live_module
    from gigapoint.lod.progressive import ProgressiveOctree

    live = LiveCloud(keep=300)
    for k in range(300):
        live.push(*moving_patch(k))
    want = sorted_rows(live.frame_points()[0])
    add = ProgressiveOctree.add

    def add_and_push(self, xyz, rgb=None, **attributes):
        for k in range(1000, 1100):  # frames that widen the open chunk's box: the snapshot's frames leave the ring
            live.push(moving_patch(299)[0] * [1, 1, 1 + 0.01 * (k - 999)])  # (taller each: the open chunk's box grows in z)
        return add(self, xyz, rgb, **attributes)

    monkeypatch.setattr(ProgressiveOctree, "add", add_and_push)
    monkeypatch.setattr(live_module, "SNAPSHOT_BATCH", 4000)  # read in four parts, frames pushed between them
    assert live.snapshot() == 15_000
    got = np.concatenate([c.xyz for c in live.snapshots.chunks()])
    np.testing.assert_allclose(sorted_rows(got), want, rtol=0, atol=1e-7)  # (the octree's own 30-bit cells)
    assert [f.seq for f in live.frames] == list(range(400, 700))  # the snapshot's frames left meanwhile (4 x 100 pushed)


def test_growing_the_ring_keeps_packed_chunks_and_the_mirror_where_they_are():
    """A ring that grows copies each chunk's record: a packed chunk's first (past its frames that
    left), and the mirror's records at the new ring's end (their firsts are the new region's)."""
    live = LiveCloud(keep=45)
    for k in range(30):
        live.push(*moving_patch(k, n=400))
    live.snapshot()
    cam = gp.Camera.fit(live.bounds, view="top", width=64, height=64)
    gp.render_frame(live, cam)  # the mirror filled
    for k in range(30, 40):
        live.push(*moving_patch(k, n=400))
    n_ring = live.buffers_.n_ring
    for k in range(20):  # 3 chunks each: from the 6th on the oldest small frames leave their chunks' fronts, at the 11th the ring grows
        live.push(*frame(k, n=30_000))
    buf = live.buffers_
    assert buf.n_ring > n_ring
    mirror = buf.batches[buf.n_ring :]
    np.testing.assert_array_equal(mirror["first"], buf.ring_points + np.arange(buf.n_mirror) * buf.mirror_chunk)
    xyz, rgba, _ = live.frame_points(list(live.frames)[:25])
    np.testing.assert_allclose(xyz, np.concatenate([moving_patch(k, n=400)[0] for k in range(15, 40)]), rtol=0, atol=1e-7)
    drawn = {}  # what each ring chunk draws: its kept frames' parts, one run
    for fr in live.frames:
        for slot, first, count in zip(fr.chunks, fr.firsts, fr.counts):
            lo, hi = drawn.get(slot, (first, first))
            assert hi == first  # frames one after another
            drawn[slot] = (lo, first + count)
    ring = buf.batches[: buf.n_ring]
    assert sorted(drawn) == np.flatnonzero(ring["count"] > 0).tolist()
    for slot, (lo, hi) in drawn.items():
        assert (int(ring["first"][slot]), int(ring["first"][slot] + ring["count"][slot])) == (lo, hi)
    f = gp.render_frame(live, gp.Camera.fit(live.bounds, view="top", width=64, height=64))
    assert f.stats.points_processed == live.n_points == 25 * 400 + 20 * 30_000 + 30 * 400


def test_frames_waiting_for_a_held_lock_are_bounded_by_keep_and_the_dropped_counted():
    """A renderer holding the lock long (or a producer outpacing the copies) grew the queue of
    waiting frames without end: 200 pushes held 200 frames for a ring of 3. At most ``keep``
    wait (an older one would leave the ring unseen once copied in): the rest are dropped,
    counted and said once, and the ring ends as it would have."""
    import warnings

    live = LiveCloud(keep=3, name="cam1")
    with live.reading(), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for k in range(20):
            live.push(*frame(k % 4, n=100 + k))
            assert len(live._pending) == min(k + 1, 3)  # waiting: at most keep
        assert live.n_frames == 0 and live.stats.frames_dropped == 17
    said = ("cam1: frames arrive faster than they are copied into the ring (the lock held long): "
            "more than keep=3 waited, the oldest are dropped unseen (stats.frames_dropped)")  # fmt: skip
    assert [str(w.message) for w in caught if w.category is gp.GigapointWarning] == [said]  # once, not per frame
    assert caught[0].filename == __file__  # the caller's push
    assert [f.seq for f in live.frames] == [17, 18, 19] and [f.n_points for f in live.frames] == [117, 118, 119]
    assert live.stats.frames_in == 3 and live.stats.frames_dropped == 17
    assert "17 dropped unseen" in live.hud()


def test_a_frame_pushed_while_the_ring_is_cleared_waits_and_lands():
    """clear() emptied the ring by setting ``keep`` to 0 meanwhile: a push in that moment saw a
    queue bound of 0 and its frame was dropped unseen."""
    live = LiveCloud(keep=3)
    live.push(*frame(0, n=100))
    expire = live._expire

    threads = []

    def expire_while_pushed(*args, **kwargs):
        if not threads:  # clear's (not the pushed frame's own commit, once clear lets go)
            threads.append(threading.Thread(target=live.push, args=frame(1, n=100)))
            threads[0].start()
            deadline = time.monotonic() + 10
            while not (live._pending or live.stats.frames_dropped) and time.monotonic() < deadline:
                time.sleep(0.001)
        expire(*args, **kwargs)

    live._expire = expire_while_pushed
    live.clear()
    threads[0].join(10)
    assert live.stats.frames_dropped == 0 and [f.seq for f in live.frames] == [1]


@pytest.mark.parametrize("dtype", [np.int16, np.int32])
def test_negative_integer_depths_are_refused_not_made_holes(dtype):
    """uint16 millimetres read as int16 show depths beyond 32.767 m as negative: they were holes,
    dropped without a word (15 of 16 points)."""
    depth = np.full((4, 4), 1000, np.uint16)
    depth[1, 2] = 40000  # 40 m
    signed = depth.view(np.int16).astype(dtype)
    live = LiveCloud(name="cam1")
    with pytest.raises(InputError) as err:
        live.push_depth(signed, (1, 1, 2, 2))
    assert str(err.value) == (f"cam1: push_depth: depth holds negative values (e.g. -25536 at row 1, column 2): integer depths must be >= 0 "
                              f"(0 marks a hole); was an unsigned image read as {np.dtype(dtype)}?")  # fmt: skip
    assert live.n_points == 0 and live.stats.frames_rejected == 1
    signed[1, 2] = 0  # a hole, as a sensor marks it
    live.push_depth(signed, (1, 1, 2, 2))
    assert live.n_points == 15
