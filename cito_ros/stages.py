"""The stages of a solve, for both pipelines. ROS-free and solver-agnostic: a stage is one
`Solver.solve` of one problem from a start inside a box (cito_ros.solver).

Paper pipeline: exactly the paper's problem (section II.C), from zero torques, by IPOPT, with
restarts: a solve that stops short of the task has usually stalled at a contact kink, where the
gradient is no descent direction; IPOPT restarted from its last iterate (a fresh quasi-Newton model
and barrier) leaves it.

Physical pipeline: a scripted push, or the contact model where that does not do, discovers contact;
the plan that leaves is refined without the virtual force. First the scripted start and its variants
(when `stages.scripted.enabled`), then each of `stages.starts` at each of `stages.horizon_scales`, in
that order, until one succeeds (two side by side when `stages.parallel`, see `solve_physical`):

0. scripted start (cito_ros.scripted): instead of a discovery, the torques of a PD-tracked push that
   touches the object by construction, straight into the physical stages (2.) with the contact term
   from the script's first touch. Most pushes within the arm's quasi-static reach succeed from it in
   a few iterations. Where it misses, its variants (`stages.scripted.variants`: another contact
   height, an earlier end of the push, a longer horizon) follow, each a start of its own: near the
   arm's push reach a few different pushes are cheaper tickets than the discoveries. The rest go on
   to the discoveries.
1. discovery: the contact model's problem from zero torques, plus the arm's limits and a reach
   term, the plate-object gap squared from the start's fraction of the horizon on. The virtual force
   alone pushes from centimetres away and never along the face (it acts at the face centre, along
   its normal); the reach term brings the plate onto the object so that real contact pushes too.
   CCCM's slack is eliminated (stages.discovery.cccm, StageCost.complementarity): box-bounded, its
   discovery is solved like SCM's and VSCM's rather than by IPOPT with constraints.
2. physical stages (`stages.physical`): the torques alone, the contact control held at 0 (the
   dynamics the plan is executed with), from the previous stage's torques, with a contact term
   that keeps the plate on the object from the discovery's touch-down to the end: a push, not a
   strike, whose outcome depends smoothly on the torques. A stage marked only_if_beyond_limits runs
   only while the best plan still exceeds the arm's joint speed limits or ranges.

A stage without the virtual force ends as soon as its plan, executed, is at the goal with a margin
(`stages.goal_margin`), and the start with it. Every stage's torques, executed without the virtual
force, are a candidate; the plan returned is the first start's that succeeds and that a PD joint
trajectory controller follows (its tracked execution within tracking.max_error_increase_m of the
executed error; with tracking.reference_offsets, also to the goal with its reference slightly off), or
else the best of all (within the arm's speed limits and ranges first, then at the goal, then followed,
then followed with the offsets, then closest to it). A script's success short of the goal margin is the one
exception: the scripts after it run too, and the best of them is returned.
"""
from __future__ import annotations

import concurrent.futures
import dataclasses
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from cito_ros import tracking
from cito_ros.builder import PlanningProblem, PushRequest, build_problem
from cito_ros.ilqr import IlqrSolver
from cito_ros.ipopt import IpoptSolver
from cito_ros.least_squares import LeastSquaresSolver
from cito_ros.problem import PushProblem, StageCost
from cito_ros.results import IterationLog, StageRecord, Status
from cito_ros.scripted import scripted_torques
from cito_ros.settings import Settings, TrackingSettings
from cito_ros.solver import IterationMonitor, Solver, StageOutcome

SOLVERS = {"ilqr": IlqrSolver, "least_squares": LeastSquaresSolver}  # and "ipopt", with a curvature


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


@dataclass(frozen=True)
class Executed:
    """A candidate's torques executed without the virtual force (and, at the end of a stage, tracked)."""

    position_error_m: float
    orientation_error_rad: float
    max_joint_speed_ratio: float
    joint_range_excess_rad: float
    tracked_position_error_m: float = math.nan  # by a PD joint trajectory controller; nan: not tracked
    offset_tracked_error_m: float = math.nan    # the worst with the reference off (tracking.reference_offsets)

    def rank(self, settings: Settings) -> tuple:
        task = settings.task
        at_goal = (self.position_error_m < task.success_position_error_m
                   and self.orientation_error_rad < task.success_orientation_error_rad)
        beyond_limits = (self.max_joint_speed_ratio > settings.limits.max_joint_speed_ratio
                         or self.joint_range_excess_rad > 0.0)
        # comparisons, not math.isnan: an untracked candidate is never taken for a trackable one
        trackable = self.tracked_position_error_m - self.position_error_m <= settings.tracking.max_error_increase_m
        # with reference offsets, followed to the goal also with the reference slightly off; ranked after
        # the nominal tracking, so that where no start gives such a plan the best is one the controller follows
        sturdy = not settings.tracking.reference_offsets or all(
            error < task.success_position_error_m for error in (self.tracked_position_error_m,
                                                                 self.offset_tracked_error_m))
        return (beyond_limits, not at_goal, not trackable, not sturdy,
                self.position_error_m / task.success_position_error_m
                + self.orientation_error_rad / task.success_orientation_error_rad)

    @staticmethod
    def succeeds(rank: tuple) -> bool:
        """Whether a rank ends the search: within the arm's limits, at the goal, and followed by a joint
        trajectory controller to within tracking.max_error_increase_m of the executed error (and with
        tracking.reference_offsets, to the goal under each offset and without)."""
        beyond_limits, away, untrackable, fragile, _ = rank
        return not beyond_limits and not away and not untrackable and not fragile

    def reaches(self, settings: Settings) -> bool:
        """Whether it is at the goal with the margin that ends the stages early (stages.goal_margin):
        within that fraction of the success tolerances and of the arm's limits."""
        task, limits, margin = settings.task, settings.limits, settings.stages.goal_margin
        return (self.position_error_m < margin * task.success_position_error_m
                and self.orientation_error_rad < margin * task.success_orientation_error_rad
                and self.max_joint_speed_ratio <= limits.max_joint_speed_ratio and self.joint_range_excess_rad == 0.0)


def execute(executor: PushProblem, torques: np.ndarray, gains: TrackingSettings) -> Executed:
    """The executed errors and arm limits of torques, by `executor` (no virtual force), the error of the
    executed joint trajectory tracked by a PD controller with `gains` (cito_ros.tracking), and the worst
    error of that tracking with the reference off by each of gains.reference_offsets seeded smooth offsets
    (the same for every plan) of up to gains.reference_offset_rad."""
    evaluation = executor.evaluate(executor.with_torques(torques))
    executed = judge(executor, evaluation, gains)
    if not math.isfinite(executed.position_error_m):
        return executed
    simulator, trajectory = executor.simulator, executor.trajectory(evaluation.z)
    offset_errors = tracking.offset_position_errors_m(simulator, executor.initial_state, trajectory, gains,
                                                      executor.task, gains.reference_offsets,
                                                      gains.reference_offset_rad, seed=12345)  # the same for every plan
    tracked_error = tracking.tracked_rest_error_m(simulator, executor.initial_state, trajectory, executor.task, gains)
    return dataclasses.replace(executed, tracked_position_error_m=tracked_error,
                               offset_tracked_error_m=max(offset_errors, default=math.nan))


def judge(executor: PushProblem, evaluation, gains: TrackingSettings) -> Executed:
    """The executed errors where the object comes to rest (tracking.rest_errors, the arm holding its last
    position for gains.hold_s) and the arm limits over the horizon of an evaluation of `executor` (no
    virtual force), untracked."""
    if not evaluation.finite:
        return Executed(math.inf, math.inf, math.inf, math.inf)
    scene = executor.scene
    position_error, angle_error = tracking.rest_errors(executor.simulator, evaluation.states[-1], executor.task, gains)
    if not math.isfinite(position_error):
        return Executed(math.inf, math.inf, math.inf, math.inf)
    speeds = np.abs(scene.arm_qvel(evaluation.states)) / scene.velocity_limit  # to the end
    return Executed(position_error, angle_error, float(speeds.max()),
                    scene.joint_range_excess(scene.arm_qpos(evaluation.states)))


class _Clock:
    """What the starts of one solve share: the clock, the settings and the callback."""

    def __init__(self, settings: Settings, callback: Callable[[IterationLog], None] | None):
        self.settings, self.callback = settings, callback
        self.started = time.perf_counter()
        self._lock = threading.Lock()

    def report(self, entry: IterationLog) -> None:
        if self.callback is not None:
            with self._lock:
                self.callback(entry)

    def elapsed(self) -> float:
        return time.perf_counter() - self.started


class _Run:
    """The stages of one start: their log, records and candidates."""

    def __init__(self, clock: _Clock, prefix: str, stop: "_Stop | threading.Event | None", curvature: str):
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
            return executed.position_error_m, executed.reaches(self.clock.settings)
        monitor = IterationMonitor(settings, self.clock.started, offset, solver.violation_tolerance,
                                   self.stop, self.clock.report, f"{self.prefix}{name}",
                                   problem.cost.virtual_force, None if problem.cost.virtual_force else goal)
        phases = problem.simulator.clock.read()
        outcome = solver.solve(problem, start, lower, upper, monitor)
        phases, solved = problem.simulator.clock.read() - phases, time.perf_counter()
        self.log += outcome.log
        cost = float(problem.evaluate(outcome.z).cost)
        executed = execute(executor, problem.split(outcome.z)[0], self.clock.settings.tracking)
        ended = time.perf_counter()
        iterations = outcome.log[-1].iteration - offset if outcome.log else 0  # the log starts at iteration 0
        self.records.append(StageRecord(
            f"{self.prefix}{name}", outcome.status, iterations, ended - began, cost, executed.position_error_m,
            phases.rollout_s, phases.linearization_s, solved - began - phases.rollout_s - phases.linearization_s,
            ended - solved))
        if outcome.status.interrupted:
            self.interrupted = outcome.status
        return outcome, executed


# ------------------------------------------------------------------------------------------ paper

def solve_paper(posed: PlanningProblem, settings: Settings, *,
                iteration_callback: Callable[[IterationLog], None] | None = None,
                cancel: threading.Event | None = None) -> Outcome:
    """The paper's problem from zero torques by IPOPT, with restarts while it ends short of the task."""
    clock = _Clock(settings, iteration_callback)
    problem = posed.problem
    began = time.perf_counter()
    executor = physical_twin(problem, StageCost.paper(problem.weights))
    setup_s = time.perf_counter() - began
    run = _Run(clock, "", cancel, "limited_memory")  # the paper's
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


# ------------------------------------------------------------------------------------- physical

def solve_physical(settings: Settings, request: PushRequest, *,
                   iteration_callback: Callable[[IterationLog], None] | None = None,
                   cancel: threading.Event | None = None) -> Outcome:
    """Every start at every horizon (stages.starts within stages.horizon_scales), in that order, until
    one succeeds: the plan is the first success in that order (the best of the scripts where a script
    succeeds short of the goal margin), or the best executed plan of all.
    Each start is a lottery ticket of a non-convex problem: about half the pushes succeed with the
    first and pay for one. With stages.parallel the next start runs beside the earliest unfinished
    one, on a thread of its own, and is abandoned when an earlier start succeeds: the threads change
    how long a solve takes (README: shorter misses, longer easy pushes), never which plan is returned."""
    clock = _Clock(settings, iteration_callback)
    stages = settings.stages
    labelled = len(stages.starts) > 1
    horizon_label = (lambda horizon_s: f"horizon {horizon_s:g} s, " if len(stages.horizon_scales) > 1 else "")
    first_horizon_s = settings.round_horizons_s[0]
    # (settings overrides, discovery start fraction or None for a script, stage-name prefix)
    jobs = []
    if stages.scripted.enabled:
        jobs.append(({"horizon_s": first_horizon_s}, None, f"{horizon_label(first_horizon_s)}scripted: "))
        for i, (height_m, push_end, scale) in enumerate(stages.scripted.variants):
            horizon_s = settings.round_horizon_s(scale)
            jobs.append(({"horizon_s": horizon_s, "stages.scripted.contact_height_m": height_m,
                          "stages.scripted.push_end_fraction": push_end}, None,
                         f"{horizon_label(horizon_s)}scripted {i + 2}: "))
    jobs += [({"horizon_s": horizon_s}, fraction, horizon_label(horizon_s) + (f"start {i + 1}: " if labelled else ""))
             for horizon_s in settings.round_horizons_s for i, fraction in enumerate(stages.starts)]
    width = 2 if stages.parallel and len(jobs) > 1 else 1
    scripts = sum(1 for _, fraction, _ in jobs if fraction is None)
    abandoned = [threading.Event() for _ in jobs]
    results: dict[int, tuple] = {}

    def settles(index: int) -> bool:
        """Whether a finished start ends the search: an interruption; before the last script, a success
        at the goal with the margin; from the last script on, a success of its own or of a script before
        it. A script's success short of the margin lets the next scripts run, and the best is kept: at
        the tolerance, which start's plan is returned flips with a hair of change in the request, and a
        script costs a second or two (README: stability)."""
        executed, outcome = results[index]
        if outcome.status.interrupted:
            return True
        if index + 1 < scripts:
            return succeeds(executed) and executed.reaches(settings)
        return any(succeeds(results[i][0]) for i in range(index + 1) if i in results)

    def succeeds(executed: Executed) -> bool:
        return Executed.succeeds(executed.rank(settings))

    def decided() -> bool:
        """Whether the finished starts settle the plan: the first unfinished start comes after a start
        that settles it, or none is left."""
        for index in range(len(jobs)):
            if index not in results:
                return False
            if settles(index):
                return True
        return True

    def solve(index: int):
        overrides, fraction, prefix = jobs[index]
        overrides = {**overrides, **({"gradient.threads": 1} if width > 1 else {})}
        return _solve_start(clock, _Stop(cancel, abandoned[index]), settings, overrides, request, fraction, prefix)

    if width == 1:
        while not decided():
            results[len(results)] = solve(len(results))
    else:
        with concurrent.futures.ThreadPoolExecutor(width, thread_name_prefix="cito_start") as pool:
            running: dict[concurrent.futures.Future, int] = {}
            submitted = 0
            while not decided():
                # no start after a success is needed, whatever the earlier ones give
                while len(running) < width and submitted < len(jobs) and not any(map(settles, results)):
                    running[pool.submit(solve, submitted)] = submitted
                    submitted += 1
                finished, _ = concurrent.futures.wait(running, return_when=concurrent.futures.FIRST_COMPLETED)
                for future in finished:
                    results[running.pop(future)] = future.result()
            for index in running.values():  # later starts, no longer needed
                abandoned[index].set()
            concurrent.futures.wait(running)
    ordered = []
    for index in sorted(results):
        ordered.append(results[index])
        if settles(index):
            break
    _, outcome = min(ordered, key=lambda result: result[0].rank(settings))
    log = tuple(entry for _, result in ordered for entry in result.log)
    records = tuple(record for _, result in ordered for record in result.stages)
    interrupted = next((result.status for _, result in ordered if result.status.interrupted), None)
    return dataclasses.replace(outcome, log=log, stages=records, status=interrupted or outcome.status,
                               solve_time_s=clock.elapsed(), setup_s=sum(result.setup_s for _, result in ordered))


class _Stop:
    """What a start's solver polls to stop: the solve's cancellation or the start's abandonment."""

    def __init__(self, *events: threading.Event | None):
        self.events = [event for event in events if event is not None]

    def is_set(self) -> bool:
        return any(event.is_set() for event in self.events)


def _solve_start(clock: _Clock, stop: _Stop, settings: Settings, overrides: dict, request: PushRequest,
                 fraction: float | None, prefix: str):
    """One start, under `settings` with `overrides` (its horizon, its script): the discovery drawing the
    plate onto the object from `fraction` of the horizon on (None: the scripted push, cito_ros.scripted,
    instead of a discovery), then the physical stages. Returns the best plan's execution (from which the
    search derives its rank and goal margin) and the outcome."""
    began = time.perf_counter()
    settings = settings.with_overrides(overrides)  # the start's horizon and script: setup too
    posed = build_problem(settings, request)
    base, limits = posed.problem, settings.limits
    T = base.n_steps
    reach = np.where(np.arange(T) >= int((fraction or 0.0) * T), 1.0 / T, 0.0)
    eliminated = base.contact_model.slack_variable is not None and settings.stages.discovery.cccm == "slack_eliminated"
    discovery = PushProblem(base.simulator, base.initial_state, base.task,
                            stage_cost(settings, base.weights, True, settings.stages.discovery.reach_weight, reach,
                                       limits.joint_speed_weight, limits.joint_position_weight,
                                       base.weights.w5 if eliminated else 0.0),
                            base.derivative_settings, base.position_scale_min_m)
    executor = physical_twin(discovery, discovery.cost)
    run = _Run(clock, prefix, stop, settings.stages.ipopt_curvature)
    best = None  # (executed, torques, status)
    if fraction is None:
        torques = scripted_torques(executor, settings.stages.scripted, settings.tracking)
        touch = touch_profile(executor, executor.with_torques(torques), settings.stages.touch_force_N)
        setup_s = time.perf_counter() - began
    else:
        setup_s = time.perf_counter() - began
        stage, executed = run.stage(discovery, settings.stages.solver, discovery.initial_guess, discovery.lower,
                                    discovery.upper, "discovery", settings.stages.discovery.max_iter, executor)
        planned_z = stage.z
        best = (executed, discovery.split(stage.z)[0], stage.status)
        began = time.perf_counter()
        touch = touch_profile(discovery, planned_z, settings.stages.touch_force_N)
        setup_s += time.perf_counter() - began
        torques = best[1]
    for index, spec in enumerate(settings.stages.physical):
        if run.interrupted:
            break
        if spec.only_if_beyond_limits and not best[0].rank(settings)[0]:  # rank[0]: beyond the arm's limits
            continue
        began = time.perf_counter()  # posing a stage's problem is setup, as the discovery's is
        problem = physical_twin(discovery, stage_cost(settings, base.weights, False, spec.contact_weight, touch,
                                                      spec.joint_speed_weight, spec.joint_position_weight))
        setup_s += time.perf_counter() - began
        stage, result = run.stage(problem, settings.stages.solver, problem.with_torques(torques),
                                    problem.lower, problem.upper, f"physical {index + 1}", spec.max_iter, executor)
        torques = problem.split(stage.z)[0]
        if best is None or result.rank(settings) < best[0].rank(settings):
            best = (result, torques, stage.status)
        if result.reaches(settings):
            break
    executed, chosen, status = best
    if fraction is None:  # no discovery: the plan under the contact model is the returned torques
        planned_z = discovery.with_torques(chosen)
    return executed, Outcome(discovery, planned_z, chosen, executor, run.interrupted or status, tuple(run.log),
                             tuple(run.records), clock.elapsed(), setup_s)


def stage_cost(settings: Settings, weights, virtual_force: bool, contact_weight: float,
               contact_profile: np.ndarray | None, joint_speed_weight: float,
               joint_position_weight: float, complementarity: float = 0.0) -> StageCost:
    limits = settings.limits
    return StageCost(weights, virtual_force, joint_speed_weight, limits.joint_speed_margin,
                     joint_position_weight, limits.joint_position_margin_rad,
                     0.0 if virtual_force else limits.object_velocity_weight, contact_weight, contact_profile,
                     complementarity)


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
