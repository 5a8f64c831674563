"""Where a solve's time goes: wall-clock time per phase, accumulated on one simulator.

ROS-free. A start of the physical pipeline (and the paper's solve) runs on one thread with one
Simulator, so the phases of its problems accumulate on that simulator's `PhaseClock`. A phase
measured inside another (the rollouts of knot-restart differences, inside a linearization) counts
for the outer one only, so the phases never overlap.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass

PHASES = ("rollout", "linearization")


@dataclass(frozen=True)
class PhaseTimes:
    rollout_s: float = 0.0        # simulating decisions (evaluations, line-search and forward-pass trials)
    linearization_s: float = 0.0  # per-step linearizations and knot-restart differences

    def __sub__(self, other: "PhaseTimes") -> "PhaseTimes":
        return PhaseTimes(self.rollout_s - other.rollout_s, self.linearization_s - other.linearization_s)


class PhaseClock:
    """Accumulates the time spent in each phase (one thread per clock)."""

    def __init__(self):
        self._seconds = dict.fromkeys(PHASES, 0.0)
        self._depth = 0

    @contextmanager
    def measure(self, phase: str):
        if phase not in self._seconds:
            raise ValueError(f"unknown phase {phase!r}; phases: {list(PHASES)}")
        self._depth += 1
        began = time.perf_counter()
        try:
            yield
        finally:
            self._depth -= 1
            if self._depth == 0:
                self._seconds[phase] += time.perf_counter() - began

    def read(self) -> PhaseTimes:
        return PhaseTimes(self._seconds["rollout"], self._seconds["linearization"])
