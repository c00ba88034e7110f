"""Live streams in the viewer: ``gigapoint view --live SOURCE``, ``gigapoint view --replay DIR``,
``gigapoint demo --live`` (the synthetic depth sensor flying through the demo town)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from ..errors import GigapointError, counted, number_text


def view_live(source: str, *, replay: bool = False, keep: int = 100, decay: float | None = None, record: Path | None = None, overwrite: bool = False,
              rate: float | None = 1.0, loop: bool = False, host: str = "127.0.0.1", port: int = 0, browser: bool = True,
              open_browser=None) -> None:  # fmt: skip
    """Play ``source`` into a LiveCloud and serve the viewer on it until Ctrl+C."""
    from .app import prefer_passive_wait

    prefer_passive_wait()  # `gigapoint demo --live` comes here without `view`
    from ..live import LiveCloud
    from ..live.sources import Player, ReplaySource, SyntheticSensor, open_source

    sock = listen_at(host, port)  # before anything plays or records: a bad or busy --port failed with a recording made
    live = None
    try:
        src = ReplaySource(source) if replay else open_source(source)
        bounds = None
        if isinstance(src, SyntheticSensor):
            from ..io.demo import SCENE_SIZE

            bounds = ((0.0, 0.0, -30.0), (SCENE_SIZE, SCENE_SIZE, 60.0))  # frame the town from the start
        live = LiveCloud(keep=keep, decay=decay, name=f"live: {src.name}", bounds=bounds)
        player = Player(src, live, rate=rate, loop=loop)  # (before the recording: it refuses to record over the recording replayed)
        recorder = live.record(record, overwrite=overwrite) if record is not None else None
        player.start()
        deadline = time.monotonic() + 10.0
        while live.n_frames == 0 and not player.done.is_set() and time.monotonic() < deadline:  # the first view frames a first frame
            time.sleep(0.02)
        if player.error is not None:
            raise player.error
        server = serve_at(live, host, port, sock=sock)
    except BaseException:
        sock.close()
        if live is not None:
            live.close()  # the player stops and the recording is closed with its index
        raise
    print(f"gigapoint viewer: {live.name} (keep {keep} frames{f', decay {decay:g} s' if decay else ''})", file=sys.stderr)
    if not server.loopback:
        print(f"warning: listening on {host}, reachable from the network; the URL's token is the only key", file=sys.stderr)
    print(f"push frames from another process: {server.push_url}", file=sys.stderr)
    print(server.url, flush=True)
    if browser and open_browser is not None:
        open_browser(server.url)
    try:
        server.serve_forever()
    finally:
        live.close()
        if recorder is not None:  # the frames written (dropped unseen ones too); every frame in was said when a full disk stopped it
            print(f"recorded {counted(recorder.n_frames, 'frame')} into {record}" + (f" ({recorder.error})" if recorder.error else ""), file=sys.stderr)


def check_live_options(keep: int, decay: float | None, rate: float | None) -> None:
    if keep < 1:
        raise GigapointError(f"--keep must be >= 1, got {keep}")
    if decay is not None and not decay > 0:
        raise GigapointError(f"--decay must be > 0 seconds, got {number_text(decay)}")
    if rate is not None and not rate > 0:
        raise GigapointError(f"--rate must be > 0, got {number_text(rate)}")


def listen_at(host: str, port: int):
    """The viewer's listening socket, made before the cloud is read; an address it cannot listen on
    said as the options typed (viewer/server.py says gp.Viewer's keywords: ``host='::1', port=80: cannot listen there``)."""
    from ..viewer.server import listening_socket
    from .settings_opts import named_option

    try:
        return listening_socket(host, port)
    except GigapointError as exc:
        raise named_option(exc, {f"host={host!r}, port={port!r}": f"--host {host} --port {port}"}) from None


def serve_at(cloud, host: str, port: int, sock=None, **options):
    """A ViewerServer of ``cloud`` on ``sock`` (``listen_at``'s; made here when None)."""
    from ..viewer.server import ViewerServer

    return ViewerServer(cloud, host=host, port=port, sock=sock if sock is not None else listen_at(host, port), **options)
