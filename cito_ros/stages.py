"""The stages of a solve: the paper's problem from zero torques, restarts, then the continuation.

ROS-free and solver-agnostic: each stage is one `Solver.solve` over the same
problem with its own start and box, and every stage's plan is evaluated; the
plan returned is the best of all (task success first, then the replay error),
reported with the whole solve's status, time and iteration log.

- Restarts: a solve that stops short of the task has usually stalled at a
  contact kink, where the gradient is no descent direction. The solver
  restarted from its last iterate (a fresh quasi-Newton model and barrier)
  leaves the kink; each restart chains from the previous one.
- Continuation (`Continuation` settings): stages that tighten the upper bound
  of one knot variable, each warm-started from the previous one inside a trust
  region (a box of `trust_region` times the variable scales around it), so the
  solver follows the solution as the bound tightens instead of jumping to
  another basin. For VSCM the variable is the stiffness: as k_max falls, the
  virtual force weakens and shortens its reach, and the plan moves to pushing
  through MuJoCo's real contact. A stage whose position error exceeds
  max(accept_position_error_m, the previous one) is rejected and retried with
  half the trust region, up to `retries` times; the stages stop once the
  virtual impulse is below `physical_inaccuracy_goal_Ns`.
"""
from __future__ import annotations

import threading
import time
from typing import Callable

import numpy as np

from cito_ros.problem import PushProblem
from cito_ros.results import IterationLog, PlanResult, Status
from cito_ros.settings import Continuation, SolverSettings
from cito_ros.solver import IterationMonitor, Solver, StageOutcome

#: evaluate(z, status, elapsed_s, log) -> the plan of decision vector z
PlanEvaluator = Callable[[np.ndarray, Status, float, list[IterationLog]], PlanResult]


class _Run:
    """One solve's clock, iteration log and stage runner."""

    def __init__(self, problem: PushProblem, solver: Solver, settings: SolverSettings, evaluate: PlanEvaluator,
                 cancel: threading.Event | None, callback: Callable[[IterationLog], None] | None):
        self.problem, self.solver, self.settings, self.evaluate = problem, solver, settings, evaluate
        self.cancel, self.callback = cancel, callback
        self.started = time.perf_counter()
        self.log: list[IterationLog] = []

    def stage(self, start: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[StageOutcome, PlanResult]:
        offset = self.log[-1].iteration + 1 if self.log else 0
        monitor = IterationMonitor(self.settings, self.started, offset, self.solver.violation_tolerance,
                                   self.cancel, self.callback)
        outcome = self.solver.solve(self.problem, start, lower, upper, monitor)
        self.log += outcome.log
        return outcome, self.evaluate(outcome.z, outcome.status, self.elapsed(), self.log)

    def elapsed(self) -> float:
        return time.perf_counter() - self.started


def better(candidate: PlanResult, incumbent: PlanResult) -> bool:
    a, b = candidate.metrics, incumbent.metrics
    return (not a.success, a.replay_position_error_m) < (not b.success, b.replay_position_error_m)


def optimize(problem: PushProblem, solver: Solver, settings: SolverSettings, continuation: Continuation | None,
             evaluate: PlanEvaluator, *, iteration_callback: Callable[[IterationLog], None] | None = None,
             cancel: threading.Event | None = None) -> PlanResult:
    """Solve the paper's problem from zero torques, then the continuation stages; return the
    plan, among all the stages solved, that is best (task success first, then the replay error)."""
    run = _Run(problem, solver, settings, evaluate, cancel, iteration_callback)
    stage, best = run.stage(problem.initial_guess, problem.lower, problem.upper)
    for _ in range(settings.restarts):
        if best.metrics.success or not stage.status.finished:
            break
        stage, result = run.stage(stage.z, problem.lower, problem.upper)
        if better(result, best):
            best = result
    latest = best
    if continuation is not None:
        stage, latest, best = _continue(run, continuation, stage, latest, best)
    status = latest.status if latest.status.interrupted else best.status
    return best.with_totals(status, run.elapsed(), run.log)


def _continue(run: _Run, continuation: Continuation, stage: StageOutcome, latest: PlanResult,
              best: PlanResult) -> tuple[StageOutcome, PlanResult, PlanResult]:
    problem = run.problem
    column = problem.variable_column(continuation.variable)
    for bound in continuation.upper_bounds:
        if latest.metrics.physical_inaccuracy_Ns <= continuation.physical_inaccuracy_goal_Ns \
                or stage.status.interrupted:
            break
        accept_error = max(continuation.accept_position_error_m, latest.metrics.position_error_m)
        radius = continuation.trust_region
        accepted = False
        for _ in range(continuation.retries + 1):
            upper = problem.upper.copy()
            upper[column::problem.width] = np.minimum(upper[column::problem.width], bound)
            lower = np.maximum(problem.lower, stage.z - radius * problem.scale)
            upper = np.maximum(np.minimum(upper, stage.z + radius * problem.scale), lower)
            attempt, result = run.stage(np.clip(stage.z, lower, upper), lower, upper)
            if better(result, best):
                best = result
            if attempt.status.interrupted:
                latest = result
                break
            if result.metrics.position_error_m <= accept_error:
                stage, latest, accepted = attempt, result, True
                break
            radius /= 2
        if not accepted:
            break
    return stage, latest, best
