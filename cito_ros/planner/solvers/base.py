"""The solver seam: what a solver sees of a problem, what it returns, and the stopping rules
every solver shares.

ROS-free. A solver (cito_ros.planner.solvers.ipopt.IpoptSolver today) takes an `NlpProblem`,
a start and a box, and returns a `StageOutcome`; the stages
(cito_ros.planner.stages) never see which solver ran. `IterationMonitor` is the part
of every solver that is not the solver's own: the iteration log and callback,
cancellation, the wall-clock limit, the stall test and the best iterate seen.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from cito_ros.planner.results import IterationLog, Status
from cito_ros.settings import SolverSettings


class NlpPoint(Protocol):
    """A decision vector's evaluation."""

    z: np.ndarray
    cost: float
    constraints: np.ndarray
    finite: bool
    position_error_m: float  # final object position error of the rollout


class NlpProblem(Protocol):
    """min cost(z) s.t. lower <= z <= upper, constraint bounds on constraints(z)."""

    size: int
    n_constraints: int
    lower: np.ndarray
    upper: np.ndarray
    scale: np.ndarray  # typical magnitude of each variable

    def evaluate(self, z: np.ndarray) -> NlpPoint: ...

    def gradient(self, z: np.ndarray) -> np.ndarray: ...

    def jacobian(self, z: np.ndarray) -> np.ndarray: ...  # (n_constraints, size), dense

    def constraint_bounds(self) -> tuple[np.ndarray, np.ndarray]: ...

    # the cost as a sum of squares r . r: for Levenberg-Marquardt and Gauss-Newton curvature
    def residuals(self, z: np.ndarray) -> np.ndarray: ...

    def residual_jacobian(self, z: np.ndarray) -> np.ndarray: ...  # (len(r), size), dense


@dataclass(frozen=True)
class StageOutcome:
    z: np.ndarray
    status: Status
    log: list[IterationLog]


class Solver(Protocol):
    violation_tolerance: float  # constraint violation that still counts as feasible

    def solve(self, problem: NlpProblem, start: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              monitor: "IterationMonitor") -> StageOutcome: ...


def violation(point: NlpPoint, lower: np.ndarray, upper: np.ndarray) -> float:
    """Largest constraint violation of a point (inf if it is not finite)."""
    if not point.finite:
        return math.inf
    g = point.constraints
    if not g.size:
        return 0.0
    return float(max(0.0, np.max(lower - g), np.max(g - upper)))


class IterationMonitor:
    """Logs the iterations of one stage and decides when it must stop.

    `record` is called by the solver once per iteration with the iteration's cost and constraint
    violation and the point it last evaluated; it returns the Status to stop with, or None. `spend`, where
    given, counts each iteration after the first record (the stage's start) against the solve's iteration budget
    and says whether that is spent. The wall-clock limit is honoured, not just checked: no iteration is begun that
    the time left does not cover, as long as the last one took (`iteration_s`: at first the one given, an earlier
    stage's) plus `reserve_s`, what the stage does after its last (executing its plan); checked only after each
    iteration, a solve ran up to 0.86 s past a 20 s limit (docs/results.md).
    """

    def __init__(self, settings: SolverSettings, started: float, iteration_offset: int,
                 violation_tolerance: float, cancel: threading.Event | None,
                 callback: Callable[[IterationLog], None] | None, stage: str = "", virtual_force: bool = True,
                 goal: Callable[[NlpPoint], tuple[float, bool]] | None = None,
                 spend: Callable[[], bool] | None = None, iteration_s: float = 0.0, reserve_s: float = 0.0,
                 clock: Callable[[], float] = time.perf_counter):
        self.settings, self.started, self.iteration_offset = settings, started, iteration_offset
        self.spend, self.iteration_s, self.reserve_s, self.clock = spend, iteration_s, reserve_s, clock
        # a point's executed position error (logged instead of its rollout's) and whether the stage has
        # done its job there (Status.GOAL_REACHED)
        self.goal = goal
        self.stage, self.virtual_force = stage, virtual_force
        self.violation_tolerance = violation_tolerance
        self.cancel, self.callback = cancel, callback
        self.log: list[IterationLog] = []
        self.best: tuple[float, float, np.ndarray] | None = None  # (violation beyond tolerance, cost, z)

    def record(self, iteration: int, cost: float, constraint_violation: float, last: NlpPoint | None,
               last_violation: float) -> Status | None:
        elapsed = self.clock() - self.started
        if self.log:
            self.iteration_s = elapsed - self.log[-1].elapsed_s
        error = last.position_error_m if last is not None and last.finite else math.nan
        reached = False
        if self.goal is not None and last is not None and last.finite:
            error, reached = self.goal(last)
            reached = reached and last_violation <= self.violation_tolerance
        entry = IterationLog(self.iteration_offset + iteration, cost, constraint_violation, elapsed, self.stage,
                             error, self.virtual_force)
        self.log.append(entry)
        if last is not None and last.finite:
            candidate = (max(last_violation - self.violation_tolerance, 0.0), last.cost, last.z)
            if self.best is None or candidate[:2] < self.best[:2]:
                self.best = candidate
        if self.callback is not None:
            self.callback(entry)
        if self.cancel is not None and self.cancel.is_set():
            return Status.CANCELLED
        if reached:
            return Status.GOAL_REACHED
        if iteration > 0 and self.spend is not None and self.spend():  # iteration 0: the stage's start
            return Status.BUDGET_SPENT
        if elapsed + self.iteration_s + self.reserve_s > self.settings.time_limit_s:
            return Status.TIME_LIMIT
        if self._stalled():
            return Status.STALLED
        return None

    def _stalled(self) -> bool:
        """No feasible progress: the last stall_iterations iterates are all feasible and none
        improved the best feasible cost before them by the stall tolerance."""
        window = self.settings.stall_iterations
        recent = self.log[-window:]
        earlier = [e.cost for e in self.log[:-window] if e.constraint_violation <= self.violation_tolerance]
        if len(recent) < window or not earlier:
            return False
        if any(e.constraint_violation > self.violation_tolerance for e in recent):
            return False
        best_before, best_recent = min(earlier), min(e.cost for e in recent)
        return best_before - best_recent <= self.settings.stall_tolerance * max(1.0, abs(best_before))

    def outcome(self, z: np.ndarray, status: Status, final: NlpPoint | None = None,
                final_violation: float = 0.0) -> StageOutcome:
        """The stage's result: z, or the best iterate seen (feasibility first, then cost) when the
        solver did not stop on its own convergence test or when the best iterate beats z."""
        if self.best is not None:
            if not status.finished or final is None or not final.finite or \
                    self.best[:2] < (max(final_violation - self.violation_tolerance, 0.0), final.cost):
                z = self.best[2]
        return StageOutcome(z, status, self.log)
