"""A one-line progress display on stderr: redrawn in place on a terminal, otherwise
a log line at most every `log_interval_s` (and at the end)."""
from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    def __init__(self, total: int | None, label: str, stream: TextIO | None = None, width: int = 28,
                 log_interval_s: float = 2.0):
        self.total, self.label, self.width = total, label, width
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.log_interval_s = log_interval_s
        self.started = time.perf_counter()
        self.last_log = -float("inf")
        self.line = ""

    def update(self, done: int, note: str = "") -> None:
        elapsed = time.perf_counter() - self.started
        if self.total:
            done = min(done, self.total)
            filled = int(self.width * done / self.total)
            counter = f"[{'#' * filled}{'.' * (self.width - filled)}] {done}/{self.total}"
        else:
            counter = f"{done}"
        self.line = f"{self.label} {counter} {elapsed:6.1f} s {note}"
        if self.tty:
            self.stream.write("\r" + self.line[:150].ljust(150))
            self.stream.flush()
        elif elapsed - self.last_log >= self.log_interval_s:
            self._log()

    def _log(self) -> None:
        self.stream.write(self.line + "\n")
        self.stream.flush()
        self.last_log = time.perf_counter() - self.started

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()
        elif self.line:
            self._log()
