"""One piece of work at a time in a node: a goal claims the slot when it is accepted and holds it while it executes.

rclpy's ActionServer sends the acceptance after the goal callback, and when that response cannot be sent it drops
the goal without executing it (Fast DDS gives up on a response whose client reader it has not matched within 100 ms:
a client that has just come up on a busy machine). A lock taken in the goal callback and released in the execute
callback would then be held for ever, every later goal refused as busy. Here an accepted goal's claim lapses when its
execution has not begun within `lapse_s`.
"""
from __future__ import annotations

import math
import threading
import time

ACCEPTED_LAPSE_S = 5.0  # an executor thread starts an accepted goal within milliseconds, or never


class GoalSlot:
    """accept() in the goal callback (or before a service call's work), begin() when the work starts, end() after."""

    def __init__(self, lapse_s: float = ACCEPTED_LAPSE_S):
        if not lapse_s > 0:
            raise ValueError(f"lapse_s must be positive, got {lapse_s}")
        self.lapse_s = lapse_s
        self._lock = threading.Lock()
        self._running = False
        self._accepted_at = -math.inf

    def accept(self) -> bool:
        """Claim the slot for a new goal: False while work runs or another accepted goal's claim stands."""
        with self._lock:
            if not self._free():
                return False
            self._accepted_at = time.monotonic()
            return True

    def take(self) -> bool:
        """Claim and begin at once (a service call's work), on the same terms as accept()."""
        with self._lock:
            if not self._free():
                return False
            self._running = True
            return True

    def begin(self) -> bool:
        """The accepted goal's work starts: False when other work runs (a goal whose claim had lapsed and another
        was accepted and begun meanwhile)."""
        with self._lock:
            if self._running:
                return False
            self._running, self._accepted_at = True, -math.inf
            return True

    def _free(self) -> bool:
        return not self._running and time.monotonic() - self._accepted_at >= self.lapse_s

    def end(self) -> None:
        with self._lock:
            self._running = False

    @property
    def running(self) -> bool:
        return self._running
