"""FrameLock: the lock of a cloud that changes while it is drawn (core/renderable.Renderable.reading).

Frames go first: a writer (a loader, a sensor's producer thread) takes the lock only while no
frame waits for it, or once a frame has been drawn since its own last write, so a renderer
drawing back to back cannot starve it (frames and writes alternate). ``builder_turn`` is the
same rule for work done outside the lock (decoding the next chunk), SimLOD's frame schedule.
"""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager

FRAMES_RECENT_S = 0.5  # a frame ended this recently: frames are being drawn


class FrameLock:
    def __init__(self) -> None:
        self.lock = threading.RLock()  # also taken directly by code that must not wait for frames (close, trim)
        self._turn = threading.Condition()
        self._readers_waiting = 0
        self._drawing = 0  # frames reading now
        self._frames_drawn = 0  # frames drawn so far
        self._writer_seen = -1  # _frames_drawn at the last write
        self._frame_end = float("-inf")  # when the last frame ended (perf_counter)

    def __enter__(self):
        return self.lock.__enter__()

    def __exit__(self, *exc):
        return self.lock.__exit__(*exc)

    @contextmanager
    def writing(self):
        """The lock for a writer: taken when no frame waits for it, or once a frame has been
        drawn since this lock's last write."""
        with self._turn:
            seen = self._writer_seen
            while self._readers_waiting and self._frames_drawn == seen:
                self._turn.wait(0.05)
        with self.lock:
            yield
            self._writer_seen = self._frames_drawn

    @contextmanager
    def reading(self):
        """The lock for a frame: held while it reads what ``prepare`` returned."""
        with self._turn:
            self._readers_waiting += 1
        try:
            self.lock.acquire()
        finally:
            with self._turn:
                self._readers_waiting -= 1
                self._drawing += 1
        try:
            yield
        finally:
            self.lock.release()
            with self._turn:
                self._drawing -= 1
                self._frames_drawn += 1
                self._frame_end = time.perf_counter()
                self._turn.notify_all()

    def builder_turn(self, seen: int) -> tuple[int, bool]:
        """For work outside the lock: waits while a frame draws or waits to, unless a frame has
        been drawn since the caller's turn ``seen`` (one piece of work a frame at least).
        Returns (this turn, whether frames are being drawn: the caller then takes small steps)."""
        with self._turn:
            while (self._drawing or self._readers_waiting) and self._frames_drawn == seen:
                self._turn.wait(0.05)
            return self._frames_drawn, self._frames_recent()

    def _frames_recent(self) -> bool:
        return time.perf_counter() - self._frame_end < FRAMES_RECENT_S

    def frames_recent(self) -> bool:
        """Whether frames are being drawn (one ended within FRAMES_RECENT_S), without waiting."""
        with self._turn:
            return self._frames_recent()

    def frame_waiting(self) -> bool:
        """Whether a frame waits for the lock: a writer holding it for a run of writes lets go
        between two of them (frames first)."""
        with self._turn:
            return self._readers_waiting > 0

    def try_write(self, behind_writers: bool = False) -> bool:
        """Take the lock for a writer that must not wait for frames: True if no frame draws or
        waits to (then ``release`` it), else False at once. ``behind_writers``: held by another
        writer, wait for it (a short write) rather than give up."""
        with self._turn:
            if self._readers_waiting or self._drawing:
                return False
        while not self.lock.acquire(timeout=0.002 if behind_writers else -1, blocking=behind_writers):
            with self._turn:  # held: by another writer, waited for; by a frame that came meanwhile, not
                if not behind_writers or self._readers_waiting or self._drawing:
                    return False
        if self._drawing:  # this thread is drawing a frame (the lock is reentrant): not now
            self.lock.release()
            return False
        return True

    def release(self) -> None:
        self.lock.release()
