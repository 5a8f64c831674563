"""Contact-implicit trajectory optimization of a push: solve with IPOPT, report the result.

ROS-free. `plan_push` is the one entry point (in the style of
mujoco.minimize): typed arguments, precise ValueErrors, a `Status` enum, an
`IterationLog` per iteration to an optional callback, and cancellation from
another thread through a `threading.Event`.
"""
from __future__ import annotations

import dataclasses
import enum
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import cyipopt
import numpy as np

from cito_ros.config import load_parameters, require_finite
from cito_ros.contact_models import contact_model as make_contact_model
from cito_ros.problem import Evaluation, ProblemSettings, PushProblem, PushTask
from cito_ros.scene import Scene, start_configuration
from cito_ros.simulator import Simulator, Trajectory


class Status(enum.Enum):
    """How a solve ended."""

    CONVERGED = "converged"              # IPOPT met its tolerance
    ACCEPTABLE = "acceptable"            # IPOPT met its acceptable-level tolerance
    STALLED = "stalled"                  # the cost stopped improving (stall_iterations, stall_tolerance)
    ITERATION_LIMIT = "iteration_limit"  # best iterate after max_iter iterations
    TIME_LIMIT = "time_limit"            # best iterate when the time limit ran out
    CANCELLED = "cancelled"              # best iterate when cancel was set
    SOLVER_FAILED = "solver_failed"      # IPOPT gave up (restoration failure, ...)
    NUMERICAL_ERROR = "numerical_error"  # NaN/Inf or MuJoCo warnings in the planned motion

    @property
    def finished(self) -> bool:
        """Whether the solver stopped on its own convergence test."""
        return self in (Status.CONVERGED, Status.ACCEPTABLE, Status.STALLED)


@dataclass(frozen=True)
class IterationLog:
    iteration: int
    cost: float
    constraint_violation: float
    elapsed_s: float


@dataclass(frozen=True)
class SolverOptions:
    """IPOPT settings (config/planner.yaml `solver`)."""

    max_iter: int = 100
    time_limit_s: float = 30.0
    scale_variables: bool = True
    stall_iterations: int = 8       # stop when the best cost improved by less than
    stall_tolerance: float = 1e-6   # stall_tolerance * max(1, |cost|) over this many iterations
    restarts: int = 2               # re-solves from the best point when the first solve ends short of the task
    ipopt: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_parameters(cls, parameters: Mapping[str, Any]) -> "SolverOptions":
        solver = parameters.get("solver", {})
        return cls(max_iter=int(solver.get("max_iter", 100)),
                   time_limit_s=float(solver.get("time_limit_s", 30.0)),
                   scale_variables=bool(solver.get("scale_variables", True)),
                   stall_iterations=int(solver.get("stall_iterations", 8)),
                   stall_tolerance=float(solver.get("stall_tolerance", 1e-6)),
                   restarts=int(solver.get("restarts", 2)),
                   ipopt=dict(solver.get("ipopt", {})))

    def __post_init__(self):
        if not isinstance(self.max_iter, int) or isinstance(self.max_iter, bool) or self.max_iter < 1:
            raise ValueError(f"max_iter must be a positive integer, got {self.max_iter!r}")
        require_finite("time_limit_s", self.time_limit_s, positive=True)
        if not isinstance(self.stall_iterations, int) or self.stall_iterations < 1:
            raise ValueError(f"stall_iterations must be a positive integer, got {self.stall_iterations!r}")
        require_finite("stall_tolerance", self.stall_tolerance, nonnegative=True)
        if not isinstance(self.restarts, int) or self.restarts < 0:
            raise ValueError(f"restarts must be a non-negative integer, got {self.restarts!r}")


@dataclass(frozen=True)
class Metrics:
    position_error_m: float          # final object position vs target
    orientation_error_rad: float     # norm of the final Euler-angle deviation
    physical_inaccuracy_Ns: float    # integral of the virtual force, t_c sum_l gamma_l (Table I)
    replay_position_error_m: float   # same torques and compensation, virtual force off
    replay_orientation_error_rad: float
    solve_time_s: float
    iterations: int
    status: str
    success: bool                    # position error < the success threshold (0.1 m, the paper's)


@dataclass(frozen=True)
class PlanResult:
    contact_model: str
    beta: float | None
    initial_distance_m: float
    target_position_m: np.ndarray
    target_yaw_rad: float
    knot_time_s: np.ndarray          # (N+1,) knot boundaries
    knot_torques_Nm: np.ndarray      # (N, 7) u per knot
    knot_contact_control: np.ndarray  # (N,) k (SCM/VSCM) or gamma (CCCM) per knot
    knot_variables: dict[str, np.ndarray]  # the contact model's knot variables by name
    trajectory: Trajectory           # per simulation step, with the virtual force
    replay: Trajectory               # per simulation step, virtual force off
    metrics: Metrics
    iteration_log: tuple[IterationLog, ...]
    derivative_info: dict[str, int]

    @property
    def status(self) -> Status:
        return Status(self.metrics.status)

    @property
    def knot_q(self) -> np.ndarray:
        """(N+1, 7) joint positions at the knot boundaries."""
        steps = (len(self.trajectory.time_s) - 1) // len(self.knot_torques_Nm)
        return self.trajectory.q[::steps]

    def summary(self) -> dict[str, Any]:
        """The metrics and identifiers as a JSON-serialisable dict."""
        m = self.metrics
        return {
            "contact_model": self.contact_model,
            "beta": self.beta,
            "initial_distance_m": self.initial_distance_m,
            "target_position_m": self.target_position_m.tolist(),
            "target_yaw_rad": self.target_yaw_rad,
            "position_error_m": m.position_error_m,
            "orientation_error_rad": m.orientation_error_rad,
            "physical_inaccuracy_Ns": m.physical_inaccuracy_Ns,
            "replay_position_error_m": m.replay_position_error_m,
            "replay_orientation_error_rad": m.replay_orientation_error_rad,
            "solve_time_s": m.solve_time_s,
            "iterations": m.iterations,
            "status": m.status,
            "success": m.success,
            "final_object_position_m": self.trajectory.object_position_m[-1].tolist(),
            "replay_object_position_m": self.replay.object_position_m[-1].tolist(),
            "warnings": self.trajectory.warnings,
            "derivatives": self.derivative_info,
        }


# IPOPT return codes (IpReturnCodes.h)
_IPOPT_STATUS = {0: Status.CONVERGED, 1: Status.ACCEPTABLE, -1: Status.ITERATION_LIMIT,
                 -4: Status.TIME_LIMIT, -13: Status.NUMERICAL_ERROR}


class _IpoptAdapter:
    """cyipopt callbacks over scaled variables x = z / scale."""

    def __init__(self, problem: PushProblem, scale: np.ndarray, started: float, options: SolverOptions,
                 cancel: threading.Event | None, callback: Callable[[IterationLog], None] | None,
                 violation_tolerance: float, iteration_offset: int):
        self.problem, self.scale = problem, scale
        self.started, self.options = started, options
        self.iteration_offset = iteration_offset
        self.cancel, self.callback = cancel, callback
        self.violation_tolerance = violation_tolerance
        self.lower_bounds, self.upper_bounds = problem.constraint_bounds()
        self.log: list[IterationLog] = []
        self.stop_reason: Status | None = None
        self.best: tuple[float, float, np.ndarray] | None = None  # (violation, cost, z)
        self.last: Evaluation | None = None
        self.failure: BaseException | None = None

    def _evaluate(self, x):
        evaluation = self.problem.evaluate(x * self.scale)
        self.last = evaluation
        return evaluation

    def violation(self, evaluation: Evaluation) -> float:
        if not evaluation.finite:
            return math.inf
        g = evaluation.constraints
        if not g.size:
            return 0.0
        return float(max(0.0, np.max(self.lower_bounds - g), np.max(g - self.upper_bounds)))

    def objective(self, x):
        evaluation = self._evaluate(x)
        return evaluation.cost if evaluation.finite else 1e20

    def gradient(self, x):
        try:
            return self.problem.derivatives(x * self.scale).gradient * self.scale
        except FloatingPointError:
            return np.zeros_like(x)

    def constraints(self, x):
        evaluation = self._evaluate(x)
        return evaluation.constraints if evaluation.finite else np.full(self.problem.n_constraints, 1e20)

    def jacobian(self, x):
        if not self.problem.n_constraints:
            return np.zeros(0)
        try:
            return (self.problem.derivatives(x * self.scale).jacobian * self.scale[None, :]).ravel()
        except FloatingPointError:
            return np.zeros(self.problem.n_constraints * self.problem.size)

    def jacobianstructure(self):
        rows, columns = np.indices((self.problem.n_constraints, self.problem.size))
        return rows.ravel(), columns.ravel()

    def intermediate(self, alg_mod, iter_count, obj_value, inf_pr, inf_du, mu, d_norm, regularization_size,
                     alpha_du, alpha_pr, ls_trials):
        elapsed = time.perf_counter() - self.started
        entry = IterationLog(self.iteration_offset + int(iter_count), float(obj_value), float(inf_pr), elapsed)
        self.log.append(entry)
        if self.last is not None and self.last.finite:
            candidate = (max(self.violation(self.last) - self.violation_tolerance, 0.0), self.last.cost, self.last.z)
            if self.best is None or candidate[:2] < self.best[:2]:
                self.best = candidate
        if self.callback is not None:
            self.callback(entry)
        if self.cancel is not None and self.cancel.is_set():
            self.stop_reason = Status.CANCELLED
            return False
        if elapsed > self.options.time_limit_s:
            self.stop_reason = Status.TIME_LIMIT
            return False
        if self._stalled():
            self.stop_reason = Status.STALLED
            return False
        return True

    def _stalled(self) -> bool:
        """No feasible progress: the last stall_iterations iterates are all feasible and none
        improved the best feasible cost before them by the stall tolerance."""
        window = self.options.stall_iterations
        recent = self.log[-window:]
        earlier = [e.cost for e in self.log[:-window] if e.constraint_violation <= self.violation_tolerance]
        if len(recent) < window or not earlier:
            return False
        if any(e.constraint_violation > self.violation_tolerance for e in recent):
            return False
        best_before, best_recent = min(earlier), min(e.cost for e in recent)
        return best_before - best_recent <= self.options.stall_tolerance * max(1.0, abs(best_before))


@dataclass(frozen=True)
class Continuation:
    """Stages after the paper's solve that tighten the upper bound of one knot variable.

    Each stage is warm-started from the previous one inside a trust region (a box of
    `trust_region` times the variable scales around it), so the solver follows the
    solution as the bound tightens instead of jumping to another basin. For VSCM the
    variable is the stiffness: as k_max falls, the virtual force weakens and shortens its
    reach, and the plan moves to pushing through MuJoCo's real contact. A stage whose
    position error exceeds max(accept_position_error_m, the previous one) is rejected and
    retried with half the trust region, up to `retries` times; the stages stop once the
    virtual impulse is below `physical_inaccuracy_goal_Ns`.
    """

    variable: str | None = None
    upper_bounds: tuple[float, ...] = ()
    trust_region: float = 0.2
    retries: int = 2
    accept_position_error_m: float = 0.03
    physical_inaccuracy_goal_Ns: float = 0.01

    @classmethod
    def from_parameters(cls, parameters: Mapping[str, Any], contact_model_name: str) -> "Continuation":
        section = parameters.get("continuation", {}).get(contact_model_name)
        if not section:
            return cls()
        name = f"continuation.{contact_model_name}"
        return cls(variable=str(section["variable"]),
                   upper_bounds=tuple(require_finite(f"{name}.upper_bounds", b, nonnegative=True)
                                      for b in section.get("upper_bounds", ())),
                   trust_region=require_finite(f"{name}.trust_region", section.get("trust_region", 0.2), positive=True),
                   retries=int(section.get("retries", 2)),
                   accept_position_error_m=require_finite(f"{name}.accept_position_error_m",
                                                          section.get("accept_position_error_m", 0.03), positive=True),
                   physical_inaccuracy_goal_Ns=require_finite(f"{name}.physical_inaccuracy_goal_Ns",
                                                              section.get("physical_inaccuracy_goal_Ns", 0.01),
                                                              nonnegative=True))


def plan_push(
    contact_model: str = "vscm",
    beta: float | None = None,
    *,
    target_position_m: np.ndarray | None = None,
    target_yaw_rad: float = 0.0,
    start_q: np.ndarray | None = None,
    scene: str | None = None,
    options: SolverOptions | None = None,
    parameters: Mapping[str, Any] | None = None,
    iteration_callback: Callable[[IterationLog], None] | None = None,
    cancel: threading.Event | None = None,
) -> PlanResult:
    """Plan a push of the scene's object to a target pose, starting from zero torques.

    Args:
      contact_model: 'cccm', 'scm' or 'vscm'.
      beta: start pose q0(beta); default the config's beta. Ignored if start_q is given.
      target_position_m: (x, y) or (x, y, z) of the object's goal, world frame; default
        `task.push_distance_m` along +x from the object's start (z is the object's resting height).
      target_yaw_rad: goal yaw of the object about world z.
      start_q: (7,) start configuration of the arm (at rest), instead of q0(beta).
      scene: scene name in config/scenes (default: the config's scene).
      options: solver options (default: config `solver`).
      parameters: planner parameters (default: config/planner.yaml).
      iteration_callback: called with an IterationLog after every IPOPT iteration.
      cancel: when set (from any thread), the solve stops at the next iteration and
        returns its best iterate with status CANCELLED.

    Raises:
      ValueError: for an unknown contact model, a bad beta, start configuration or target,
        or bad options.
    """
    parameters = load_parameters() if parameters is None else parameters
    model = make_contact_model(contact_model, parameters)
    options = SolverOptions.from_parameters(parameters) if options is None else options
    settings = ProblemSettings.from_parameters(parameters, model.name)
    continuation = Continuation.from_parameters(parameters, model.name)
    the_scene = Scene(model, scene or parameters["scene"])
    simulator = Simulator(the_scene, parameters["horizon_s"], parameters["control_period_s"], nthread=settings.threads)
    if start_q is None:
        beta = float(parameters["beta"]) if beta is None else beta
        start_q = start_configuration(beta)
    else:
        beta = None
    initial_state = the_scene.initial_state(start_q)
    initial_distance = the_scene.signed_distance(the_scene.data_at(start_q))
    task = _task(the_scene, initial_state, target_position_m, target_yaw_rad, parameters)
    problem = PushProblem(simulator, initial_state, task, settings)
    success_threshold = float(parameters.get("task", {}).get("success_position_error_m", 0.10))
    return optimize(problem, options, continuation, beta=beta, initial_distance_m=initial_distance,
                    success_position_error_m=success_threshold, iteration_callback=iteration_callback, cancel=cancel)


def _task(scene: Scene, initial_state: np.ndarray, target_position_m, target_yaw_rad, parameters) -> PushTask:
    """The push target, checked against what pushing on this table can reach."""
    start = initial_state[1 + scene.object_qpos_adr:1 + scene.object_qpos_adr + 3]
    task_config = parameters.get("task", {})
    if target_position_m is None:
        push = require_finite("task.push_distance_m", task_config.get("push_distance_m", 0.25))
        target = start + np.array([push, 0.0, 0.0])
    else:
        target = np.asarray(target_position_m, dtype=float)
        if target.shape == (2,):
            target = np.array([target[0], target[1], start[2]])
        if target.shape != (3,):
            raise ValueError(f"target position must be (x, y) or (x, y, z), got shape {target.shape}")
    task = PushTask(target, target_yaw_rad)
    low, high, _ = scene.table_top()
    half = float(scene.object_half_size[0])
    if np.any(task.target_position_m[:2] < low + half) or np.any(task.target_position_m[:2] > high - half):
        raise ValueError(f"target ({task.target_position_m[0]:.3f}, {task.target_position_m[1]:.3f}) m is off the "
                         f"table: the object must end within x [{low[0] + half:.3f}, {high[0] - half:.3f}], "
                         f"y [{low[1] + half:.3f}, {high[1] - half:.3f}] m")
    height_tolerance = float(task_config.get("target_height_tolerance_m", 0.02))
    if abs(task.target_position_m[2] - start[2]) > height_tolerance:
        raise ValueError(f"target z {task.target_position_m[2]:.3f} m is not the object's resting height "
                         f"{start[2]:.3f} m (+-{height_tolerance} m): pushing cannot lift it")
    reach = float(task_config.get("max_reach_m", 1.25))
    if np.linalg.norm(task.target_position_m[:2]) > reach:
        raise ValueError(f"target is {np.linalg.norm(task.target_position_m[:2]):.3f} m from the arm base, beyond "
                         f"the {reach} m the arm can push the object to")
    return task


@dataclass(frozen=True)
class _Stage:
    z: np.ndarray
    status: Status
    log: list[IterationLog]


def _solve_stage(problem: PushProblem, options: SolverOptions, start: np.ndarray, lower: np.ndarray,
                 upper: np.ndarray, started: float, iteration_offset: int, cancel: threading.Event | None,
                 callback: Callable[[IterationLog], None] | None) -> _Stage:
    scale = problem.scale if options.scale_variables else np.ones(problem.size)
    tolerance = float(options.ipopt.get("constr_viol_tol", 1e-4))
    adapter = _IpoptAdapter(problem, scale, started, options, cancel, callback, tolerance, iteration_offset)
    nlp = cyipopt.Problem(n=problem.size, m=problem.n_constraints, problem_obj=adapter,
                          lb=lower / scale, ub=upper / scale, cl=adapter.lower_bounds, cu=adapter.upper_bounds)
    nlp.add_option("max_iter", options.max_iter)
    nlp.add_option("print_level", 0)
    nlp.add_option("sb", "yes")
    for key, value in options.ipopt.items():
        nlp.add_option(key, value)
    x, info = nlp.solve(np.clip(start, lower, upper) / scale)
    status = adapter.stop_reason or _IPOPT_STATUS.get(int(info["status"]), Status.SOLVER_FAILED)
    z = np.clip(x * scale, lower, upper)
    if not status.finished and adapter.best is not None:
        z = adapter.best[2]  # the best iterate seen (feasibility first, then cost)
    return _Stage(z, status, adapter.log)


def optimize(problem: PushProblem, options: SolverOptions, continuation: Continuation = Continuation(), *,
             beta: float | None = None, initial_distance_m: float = math.nan, success_position_error_m: float = 0.10,
             iteration_callback: Callable[[IterationLog], None] | None = None,
             cancel: threading.Event | None = None) -> PlanResult:
    """Solve the paper's problem from zero torques, then the continuation stages; return the
    plan, among all the stages solved, that is best (task success first, then the replay error)."""
    started = time.perf_counter()
    log: list[IterationLog] = []
    stage = _solve_stage(problem, options, problem.initial_guess, problem.lower, problem.upper, started, 0, cancel,
                         iteration_callback)
    log += stage.log
    best = evaluate_plan(problem, stage.z, stage.status, time.perf_counter() - started, log, beta=beta,
                         initial_distance_m=initial_distance_m, success_position_error_m=success_position_error_m)
    # A solve that stops short of the task has usually stalled at a contact kink, where the
    # gradient is no descent direction. IPOPT restarted from its last iterate (a fresh
    # quasi-Newton model and barrier) leaves the kink, and each restart chains from the
    # previous one; the best plan of all is kept.
    for _ in range(options.restarts):
        if best.metrics.success or not stage.status.finished:
            break
        offset = log[-1].iteration + 1 if log else 0
        stage = _solve_stage(problem, options, stage.z, problem.lower, problem.upper, started, offset, cancel,
                             iteration_callback)
        log += stage.log
        result = evaluate_plan(problem, stage.z, stage.status, time.perf_counter() - started, log, beta=beta,
                               initial_distance_m=initial_distance_m, success_position_error_m=success_position_error_m)
        if _better(result, best):
            best = result
    names = [v.name for v in problem.variables]
    if continuation.variable is not None and continuation.variable not in names:
        raise ValueError(f"continuation variable {continuation.variable!r} is not one of {problem.contact_model.name}'s "
                         f"knot variables {names}")
    column = None if continuation.variable is None else problem.n_joints + names.index(continuation.variable)
    latest = best
    for bound in continuation.upper_bounds:
        if (latest.metrics.physical_inaccuracy_Ns <= continuation.physical_inaccuracy_goal_Ns
                or stage.status in (Status.CANCELLED, Status.TIME_LIMIT)):
            break
        accept_error = max(continuation.accept_position_error_m, latest.metrics.position_error_m)
        radius = continuation.trust_region
        accepted = False
        for _ in range(continuation.retries + 1):
            upper = problem.upper.copy()
            upper[column::problem.width] = np.minimum(upper[column::problem.width], bound)
            lower = np.maximum(problem.lower, stage.z - radius * problem.scale)
            upper = np.maximum(np.minimum(upper, stage.z + radius * problem.scale), lower)
            offset = log[-1].iteration + 1 if log else 0
            attempt = _solve_stage(problem, options, np.clip(stage.z, lower, upper), lower, upper, started, offset,
                                   cancel, iteration_callback)
            log += attempt.log
            result = evaluate_plan(problem, attempt.z, attempt.status, time.perf_counter() - started, log, beta=beta,
                                   initial_distance_m=initial_distance_m,
                                   success_position_error_m=success_position_error_m)
            if _better(result, best):
                best = result
            if attempt.status in (Status.CANCELLED, Status.TIME_LIMIT):
                latest = result
                break
            if result.metrics.position_error_m <= accept_error:
                stage, latest, accepted = attempt, result, True
                break
            radius /= 2
        if not accepted:
            break
    status = latest.status if latest.status in (Status.CANCELLED, Status.TIME_LIMIT) else best.status
    # report the whole solve's time, iterations and interruption
    return _with_totals(best, status, time.perf_counter() - started, log)


def _better(candidate: PlanResult, incumbent: PlanResult) -> bool:
    a, b = candidate.metrics, incumbent.metrics
    return (not a.success, a.replay_position_error_m) < (not b.success, b.replay_position_error_m)


def _with_totals(result: PlanResult, status: Status, solve_time_s: float, log: list[IterationLog]) -> PlanResult:
    metrics = dataclasses.replace(result.metrics, status=status.value, solve_time_s=solve_time_s,
                                  iterations=log[-1].iteration if log else 0)
    return dataclasses.replace(result, metrics=metrics, iteration_log=tuple(log))


def evaluate_plan(problem: PushProblem, z: np.ndarray, status: Status, solve_time_s: float,
                  log: list[IterationLog], *, beta: float | None, initial_distance_m: float,
                  success_position_error_m: float) -> PlanResult:
    """Simulate the plan with and without the virtual force and compute the metrics."""
    simulator, model = problem.simulator, problem.contact_model
    torques, variables = problem.split(z)
    control = model.contact_control(variables)
    # the optimizer's own rollout of z (usually cached) is the planned trajectory
    evaluation = problem.evaluate(z)
    trajectory = simulator.trajectory(problem.initial_state, evaluation.states, evaluation.sensordata,
                                      simulator.step_controls(evaluation.knot_controls), evaluation.warnings)
    replay = simulator.rollout(problem.initial_state, torques, control, virtual_force=False)
    derivative_info = dict(evaluation.derivative_info)

    def errors(result: Trajectory) -> tuple[float, float]:
        final = np.concatenate([result.object_position_m[-1], result.object_quaternion[-1]])
        _, position_error, angle_error = problem.terminal_cost(final)
        return float(np.linalg.norm(position_error)), float(np.linalg.norm(angle_error))

    position_error, orientation_error = errors(trajectory)
    replay_position_error, replay_orientation_error = errors(replay)
    if not (trajectory.finite and replay.finite) or trajectory.warnings:
        status = Status.NUMERICAL_ERROR
    metrics = Metrics(
        position_error_m=position_error,
        orientation_error_rad=orientation_error,
        physical_inaccuracy_Ns=float(simulator.timestep_s * np.sum(trajectory.gamma_N)),
        replay_position_error_m=replay_position_error,
        replay_orientation_error_rad=replay_orientation_error,
        solve_time_s=solve_time_s,
        iterations=log[-1].iteration if log else 0,
        status=status.value,
        success=bool(math.isfinite(position_error) and position_error < success_position_error_m
                     and status is not Status.NUMERICAL_ERROR),
    )
    return PlanResult(
        contact_model=model.name,
        beta=beta,
        initial_distance_m=initial_distance_m,
        target_position_m=problem.task.target_position_m.copy(),
        target_yaw_rad=problem.task.target_yaw_rad,
        knot_time_s=np.arange(problem.n_knots + 1) * simulator.control_period_s,
        knot_torques_Nm=torques.copy(),
        knot_contact_control=control.copy(),
        knot_variables={v.name: variables[:, i].copy() for i, v in enumerate(model.knot_variables)},
        trajectory=trajectory,
        replay=replay,
        metrics=metrics,
        iteration_log=tuple(log),
        derivative_info=derivative_info,
    )
