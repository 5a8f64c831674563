"""The stages of a solve, for both pipelines. ROS-free and solver-agnostic: a stage is one
`Solver.solve` of one problem from a start inside a box (cito_ros.planner.solvers.base).

Paper pipeline: exactly the paper's problem (section II.C), from zero torques, by IPOPT, with
restarts: a solve that stops short of the task has usually stalled at a contact kink, where the
gradient is no descent direction; IPOPT restarted from its last iterate (a fresh quasi-Newton model
and barrier) leaves it.

The physical pipeline (cito_ros.planner.physical) runs its starts' stages with the same `StartRun`;
its candidates are ranked by cito_ros.planner.candidates.
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from cito_ros.planner.builder import PlanningProblem
from cito_ros.planner.candidates import Executed, execute, judge
from cito_ros.planner.problem import PushProblem, StageCost
from cito_ros.planner.results import IterationLog, StageRecord, Status
from cito_ros.planner.solvers.base import IterationMonitor, Solver, StageOutcome
from cito_ros.planner.solvers.ilqr import IlqrSolver
from cito_ros.planner.solvers.ipopt import IpoptSolver
from cito_ros.planner.solvers.least_squares import LeastSquaresSolver
from cito_ros.settings import Settings

SOLVERS = {"ilqr": IlqrSolver, "least_squares": LeastSquaresSolver}  # and "ipopt", with a curvature


class Stoppable(Protocol):
    """What a solver polls to stop: a threading.Event, or several (cito_ros.planner.physical.StartStop)."""

    def is_set(self) -> bool: ...


@dataclass(frozen=True)
class Outcome:
    """What the stages leave for evaluation."""

    discovery: PushProblem        # the contact model's problem (with the virtual force)
    planned_z: np.ndarray         # its solution: the plan with the virtual force
    torques: np.ndarray           # (N, 7) the returned torques
    executor: PushProblem         # a problem without the virtual force on the same simulator
    status: Status
    log: tuple[IterationLog, ...]
    stages: tuple[StageRecord, ...]
    solve_time_s: float
    setup_s: float                # posing the problems, summed over starts
    executed: Executed | None = None  # the returned torques' execution, judged (the physical pipeline)
    note: str = ""                # what the search could not try (physical.SideStart.note), for the answer


class SolveClock:
    """What the starts of one solve share: the clock, the iteration budget, the settings and the callback."""

    def __init__(self, settings: Settings, callback: Callable[[IterationLog], None] | None):
        self.settings, self.callback = settings, callback
        self.started = time.perf_counter()
        self.iterations = 0
        # the last iteration's wall clock, for the next stage's first, and the longest a stage took after its last
        # iteration: what IterationMonitor leaves room for within the time limit
        self.iteration_s = self.reserve_s = 0.0
        self._lock = threading.Lock()

    def spend(self) -> bool:
        """Count one iteration; whether the solve's iteration budget (solver.iteration_budget) is spent. With
        stages.parallel the speculative start's iterations count too, so there the plan at the budget depends
        on the threads' timing."""
        budget = self.settings.solver.iteration_budget
        with self._lock:
            self.iterations += 1
            return 0 < budget <= self.iterations

    def report(self, entry: IterationLog) -> None:
        if self.callback is not None:
            with self._lock:
                self.callback(entry)

    def elapsed(self) -> float:
        return time.perf_counter() - self.started


class StartRun:
    """The stages of one start: their log, records and candidates."""

    def __init__(self, clock: SolveClock, prefix: str, stop: Stoppable | None, curvature: str):
        self.clock, self.prefix, self.stop, self.curvature = clock, prefix, stop, curvature
        self.log: list[IterationLog] = []
        self.records: list[StageRecord] = []
        self.interrupted: Status | None = None

    def stage(self, problem: PushProblem, kind: str, start: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              name: str, max_iter: int, executor: PushProblem) -> tuple[StageOutcome, Executed]:
        """Solve one stage with the solver `kind` (IPOPT, with the run's curvature, whenever the problem
        has constraints)."""
        began = time.perf_counter()  # the stage's wall clock: setting its solver up is the solver's work
        # the stage's own budget, capped by solver.max_iter (the CLI's --max-iter)
        settings = dataclasses.replace(self.clock.settings.solver,
                                       max_iter=min(max_iter, self.clock.settings.solver.max_iter))
        solver: Solver = IpoptSolver(settings, self.curvature) if problem.n_constraints or kind == "ipopt" \
            else SOLVERS[kind](settings)
        offset = self.log[-1].iteration + 1 if self.log else 0
        # a stage without the virtual force evaluates the plan as executed: its log shows where the object comes
        # to rest, and it ends once that is at the goal

        def goal(point) -> tuple[float, bool]:
            executed = judge(problem, point, self.clock.settings.tracking)
            return executed.position_error_m, executed.reaches(self.clock.settings, problem.task)
        monitor = IterationMonitor(settings, self.clock.started, offset, solver.violation_tolerance,
                                   self.stop, self.clock.report, f"{self.prefix}{name}",
                                   problem.cost.virtual_force, None if problem.cost.virtual_force else goal,
                                   self.clock.spend, self.clock.iteration_s, self.clock.reserve_s)
        phases = problem.simulator.clock.read()
        outcome = solver.solve(problem, start, lower, upper, monitor)
        self.clock.iteration_s = monitor.iteration_s
        phases, solved = problem.simulator.clock.read() - phases, time.perf_counter()
        self.log += outcome.log
        cost = float(problem.evaluate(outcome.z).cost)
        executed = execute(executor, problem.split(outcome.z)[0], self.clock.settings.tracking)
        ended = time.perf_counter()
        self.clock.reserve_s = max(self.clock.reserve_s, ended - solved)
        iterations = outcome.log[-1].iteration - offset if outcome.log else 0  # the log starts at iteration 0
        self.records.append(StageRecord(
            f"{self.prefix}{name}", outcome.status, iterations, ended - began, cost, executed.position_error_m,
            phases.rollout_s, phases.linearization_s, solved - began - phases.rollout_s - phases.linearization_s,
            ended - solved))
        if outcome.status.interrupted:
            self.interrupted = outcome.status
        return outcome, executed


def solve_paper(posed: PlanningProblem, settings: Settings, *,
                iteration_callback: Callable[[IterationLog], None] | None = None,
                cancel: threading.Event | None = None) -> Outcome:
    """The paper's problem from zero torques by IPOPT, with restarts while it ends short of the task."""
    clock = SolveClock(settings, iteration_callback)
    problem = posed.problem
    began = time.perf_counter()
    executor = physical_twin(problem, StageCost.paper(problem.weights))
    setup_s = time.perf_counter() - began
    run = StartRun(clock, "", cancel, "limited_memory")  # the paper's
    stage, executed = run.stage(problem, "ipopt", problem.initial_guess, problem.lower, problem.upper, "paper",
                                settings.solver.max_iter, executor)
    best, best_error = stage, planned_error(problem, stage.z)
    for index in range(settings.solver.restarts):
        if best_error < settings.task.planned_success_position_error_m or not stage.status.finished:
            break
        stage, _ = run.stage(problem, "ipopt", stage.z, problem.lower, problem.upper, f"restart {index + 1}",
                             settings.solver.max_iter, executor)
        if planned_error(problem, stage.z) < best_error:
            best, best_error = stage, planned_error(problem, stage.z)
    status = run.interrupted or best.status
    return Outcome(problem, best.z, problem.split(best.z)[0], executor, status, tuple(run.log), tuple(run.records),
                   clock.elapsed(), setup_s)


def planned_error(problem: PushProblem, z: np.ndarray) -> float:
    evaluation = problem.evaluate(z)
    if not evaluation.finite:
        return float("inf")
    return float(np.linalg.norm(problem.task.pose_error(problem.scene.object_qpos(evaluation.states[-1]))[0]))


def physical_twin(problem: PushProblem, cost: StageCost) -> PushProblem:
    """The same push on the same simulator without the virtual force, under `cost`."""
    return PushProblem(problem.simulator, problem.initial_state, problem.task,
                       dataclasses.replace(cost, virtual_force=False), problem.derivative_settings,
                       problem.position_scale_min_m)


def stage_cost(settings: Settings, weights, virtual_force: bool, contact_weight: float,
               contact_profile: np.ndarray | None, joint_speed_weight: float,
               joint_position_weight: float, complementarity: float = 0.0) -> StageCost:
    limits, task = settings.limits, settings.task
    return StageCost(weights, virtual_force, joint_speed_weight, limits.joint_speed_margin,
                     joint_position_weight, limits.joint_position_margin_rad,
                     0.0 if virtual_force else limits.object_velocity_weight, contact_weight, contact_profile,
                     complementarity, math.sqrt(settings.stages.orientation_balance) * task.success_position_error_m
                     / task.success_orientation_error_rad)


def touch_profile(discovery: PushProblem, z: np.ndarray, touch_force_N: float) -> np.ndarray:
    """Step weights 1/T from the discovery plan's first touch (real contact or a virtual force above
    touch_force_N) to the end; from mid-horizon when it never touches."""
    evaluation = discovery.evaluate(z)
    sensors = discovery.scene.sensors
    touching = (evaluation.sensordata[:, discovery.gamma_row] > touch_force_N) | \
        (evaluation.sensordata[:, sensors.contact_found.start] > 0)
    steps = np.nonzero(touching)[0]
    T = discovery.n_steps
    first = int(steps[0]) if steps.size else T // 2
    return np.where(np.arange(T) >= first, 1.0 / T, 0.0)
