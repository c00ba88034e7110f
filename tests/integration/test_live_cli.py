"""`gigapoint view --replay DIR` / `--live SOURCE` as a process, frames pushed into it from this one."""

from __future__ import annotations

import signal
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("uvicorn")
pytest.importorskip("websockets")
httpx = pytest.importorskip("httpx")

from gigapoint.errors import GigapointError
from gigapoint.live import LiveCloud
from gigapoint.live.wire import PushClient, encode_frame

pytestmark = [pytest.mark.timeout(180)]


def start_viewer(*args):
    proc = subprocess.Popen([sys.executable, "-m", "gigapoint.cli", "view", *args, "--no-browser"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    lines = []
    while True:
        line = proc.stderr.readline()
        if not line:
            raise AssertionError(f"viewer exited: {''.join(lines)}")
        lines.append(line)
        if "push frames from another process:" in line:
            push_url = line.split(": ", 1)[1].strip()
            break
    url = proc.stdout.readline().strip()
    return proc, url, push_url


def stop(proc):
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise


def test_replay_a_recording_and_push_into_it_from_another_process(tmp_path):
    live = LiveCloud()
    live.record(tmp_path / "rec")
    rng = np.random.default_rng(0)
    for k in range(3):
        live.push(rng.uniform(0, 10, (1000, 3)), time=0.05 * k)
    live.stop_recording()
    proc, url, push_url = start_viewer("--replay", str(tmp_path / "rec"), "--keep", "10")
    try:
        token = push_url.split("push_token=")[1]
        info = httpx.get(url.rstrip("/") + "/api/info", timeout=10).json()["cloud"]
        assert info["name"].startswith("live: ") and info["points"] >= 1000
        with pytest.raises(GigapointError, match="refused"):
            PushClient(url, "not-the-token")
        with PushClient(url, token) as client:
            assert client.push(rng.uniform(0, 10, (500, 3)))["type"] == "ack"
            bad = client.send(encode_frame("points", xyz=np.zeros((4, 3)))[:-3])
            assert bad["type"] == "error" and "cut short" in bad["message"]
            assert client.push(rng.uniform(0, 10, (250, 3)))["type"] == "ack"  # the stream goes on
        for _ in range(50):
            info = httpx.get(url.rstrip("/") + "/api/info", timeout=10).json()["cloud"]
            if info["points"] == 3750:
                break
        assert info["points"] == 3750
    finally:
        stop(proc)
    assert proc.returncode in (0, 130)


def test_view_live_a_folder_of_frames_and_bad_sources(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(2):
        np.save(frames / f"{k}.npy", np.random.default_rng(k).uniform(0, 5, (300, 3)))
    proc, url, _ = start_viewer("--live", str(frames))
    try:
        info = httpx.get(url.rstrip("/") + "/api/info", timeout=10).json()["cloud"]
        assert info["points"] >= 300
    finally:
        stop(proc)
    for args, message in ((["--live", str(tmp_path / "nowhere")], "no such file"), (["--replay", str(frames)], "not a live recording"),
                          (["--live", "demo", "--keep", "0"], "--keep"),
                          (["--live", "demo", "--progressive"], "--progressive: an option of files and --demo, not of a live stream"),
                          # a file's viewer recorded nothing and kept nothing, without a word
                          ([str(frames / "0.npy"), "--record", str(tmp_path / "rec2")], "--record: options of a live stream"),
                          (["--demo", "1000", "--keep", "5", "--decay", "2"], "--keep and --decay: options of a live stream")):  # fmt: skip
        bad = subprocess.run([sys.executable, "-m", "gigapoint.cli", "view", *args, "--no-browser"], capture_output=True, text=True, timeout=60)
        assert bad.returncode == 1 and message in bad.stderr and len(bad.stderr.strip().splitlines()) == 1, bad.stderr


def test_record_into_a_recording_asks_for_an_option_view_has_and_a_bad_port_records_nothing(tmp_path):
    """`view --live S --record DIR` on a recording said 'pass --overwrite', an option `view` did
    not have; and a --port it cannot use failed only after the stream had been recording into DIR."""
    frames = tmp_path / "frames"
    frames.mkdir()
    np.save(frames / "0.npy", np.random.default_rng(0).uniform(0, 5, (300, 3)))

    def view(*args):
        return subprocess.run([sys.executable, "-m", "gigapoint.cli", "view", "--live", str(frames), *args, "--no-browser"],
                              capture_output=True, text=True, timeout=60)  # fmt: skip

    fresh = tmp_path / "fresh"
    bad = view("--record", str(fresh), "--port", "99999")
    assert bad.returncode == 1 and "--port must be in 0..65535" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
    assert not fresh.exists()  # nothing recorded for a command that failed
    live = LiveCloud()
    live.record(tmp_path / "rec")
    live.push(np.random.default_rng(1).uniform(0, 5, (50, 3)))
    live.stop_recording()
    before = sorted((p.name, p.stat().st_size) for p in (tmp_path / "rec").rglob("*"))
    held = view("--record", str(tmp_path / "rec"))
    assert held.returncode == 1 and "pass --overwrite to replace it" in held.stderr, held.stderr
    bad = view("--record", str(tmp_path / "rec"), "--overwrite", "--port", "99999")  # the option exists; the recording is kept
    assert bad.returncode == 1 and "--port must be in 0..65535" in bad.stderr, bad.stderr
    assert sorted((p.name, p.stat().st_size) for p in (tmp_path / "rec").rglob("*")) == before
    lone = subprocess.run([sys.executable, "-m", "gigapoint.cli", "view", "--live", str(frames), "--overwrite", "--no-browser"],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert lone.returncode == 1 and "--overwrite: replaces a recording in --record DIR" in lone.stderr, lone.stderr


def test_a_port_in_use_records_nothing(tmp_path):
    """`view --live S --record DIR --port TAKEN` found the port in use after the stream had
    started recording into DIR: a recording left behind by a command that failed."""
    import socket

    frames = tmp_path / "frames"
    frames.mkdir()
    np.save(frames / "0.npy", np.random.default_rng(0).uniform(0, 5, (300, 3)))
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        bad = subprocess.run([sys.executable, "-m", "gigapoint.cli", "view", "--live", str(frames), "--record", str(tmp_path / "rec"),
                              "--port", str(port), "--no-browser"], capture_output=True, text=True, timeout=60)  # fmt: skip
    assert (bad.returncode, bad.stderr) == (1, f"error: --host 127.0.0.1 --port {port}: cannot listen there (Address already in use)\n")
    assert not (tmp_path / "rec").exists()


def test_view_replay_refuses_to_record_over_the_recording_it_replays(tmp_path):
    """`view --replay DIR --record DIR --overwrite` deleted DIR's frames before they were read:
    it served an empty stream and said "recorded 0 frames", the recording lost."""
    live = LiveCloud()
    live.record(tmp_path / "rec")
    live.push(np.random.default_rng(1).uniform(0, 5, (50, 3)))
    live.stop_recording()
    before = sorted((p.name, p.stat().st_size) for p in (tmp_path / "rec").rglob("*"))
    for option in ("--replay", "--live"):
        bad = subprocess.run([sys.executable, "-m", "gigapoint.cli", "view", option, str(tmp_path / "rec"), "--record", str(tmp_path / "rec"),
                              "--overwrite", "--no-browser"], capture_output=True, text=True, timeout=60)  # fmt: skip
        assert bad.returncode == 1 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
        assert f"{tmp_path / 'rec'}: the recording being replayed (recording into it would delete its frames)" in bad.stderr
    assert sorted((p.name, p.stat().st_size) for p in (tmp_path / "rec").rglob("*")) == before


_VIEW_ON_A_FILLING_DISK = """
import errno, sys
import numpy as np
from gigapoint.cli import main
from gigapoint.live import record

savez, calls = np.savez, []

def filling(f, **arrays):  # frame 3 on finds the disk full
    calls.append(1)
    if len(calls) > 3:
        raise OSError(errno.ENOSPC, "No space left on device")
    savez(f, **arrays)

record.np.savez = filling
sys.exit(main(sys.argv[1:]))
"""


def test_view_live_says_how_many_frames_a_recording_cut_short_holds(tmp_path):
    """`view --live S --record DIR` said "recorded 8 frames" of a recording a full disk had
    stopped after 3: the frames in, not the frames written."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(8):
        np.save(frames / f"{k}.npy", np.random.default_rng(k).uniform(0, 5, (100, 3)))
    rec = tmp_path / "rec"
    proc = subprocess.Popen([sys.executable, "-c", _VIEW_ON_A_FILLING_DISK, "view", "--live", str(frames), "--record", str(rec), "--no-browser"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        url = proc.stdout.readline().strip()
        for _ in range(100):  # the 8 frames at 10 a second
            if httpx.get(url.rstrip("/") + "/api/info", timeout=10).json()["cloud"]["points"] == 800:
                break
    finally:
        stop(proc)
    said = [line for line in proc.stderr.read().splitlines() if line.startswith("recorded")]
    assert said == [f"recorded 3 frames into {rec} ({rec}: recording stopped after 3 frames: [Errno 28] No space left on device: '{rec / 'frames' / '000003.npz'}')"]
    assert len(list((rec / "frames").iterdir())) == 3


def test_demo_live_refuses_the_options_of_the_image_it_does_not_render(tmp_path):
    """`demo --live -o x.png --points 5 --seed 3` served the live demo and dropped every other option without a word."""
    bad = subprocess.run([sys.executable, "-m", "gigapoint.cli", "demo", "--live", "-o", str(tmp_path / "x.png"), "--points", "5", "--seed", "3"],
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert bad.returncode == 1 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
    assert "--points and --output and --seed: options of the demo image, not of --live" in bad.stderr, bad.stderr
