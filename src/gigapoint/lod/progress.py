"""A rich progress display for conversions: phase, bar, points/s, elapsed and ETA."""

from __future__ import annotations

import sys


class NullProgress:
    def phase(self, name: str, total: int | None) -> None:
        pass

    def advance(self, n: int) -> None:
        pass

    def close(self) -> None:
        pass


class RichProgress(NullProgress):
    def __init__(self) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            Progress,
            ProgressColumn,
            TaskProgressColumn,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )
        from rich.text import Text

        class Rate(ProgressColumn):
            def render(self, task):
                speed = task.finished_speed or task.speed
                return Text("" if not speed else f"{speed / 1e6:6.2f} M pts/s", style="cyan")

        self._progress = Progress(
            TextColumn("[bold]{task.description:<10}"),
            BarColumn(),
            TaskProgressColumn(),
            TextColumn("{task.completed:,.0f} pts"),
            Rate(),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=Console(file=sys.stderr),
            transient=False,
        )
        self._progress.start()
        self._task = None

    def phase(self, name: str, total: int | None) -> None:
        if self._task is not None:
            t = self._progress.tasks[-1]
            self._progress.update(self._task, total=t.completed or 1, completed=t.completed or 1)
        self._task = self._progress.add_task(name, total=total)

    def advance(self, n: int) -> None:
        if self._task is not None:
            self._progress.advance(self._task, n)

    def close(self) -> None:
        if self._task is not None:
            t = self._progress.tasks[-1]
            self._progress.update(self._task, total=t.completed or 1, completed=t.completed or 1)
        self._progress.stop()
