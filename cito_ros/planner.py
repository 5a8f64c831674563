"""Plan a push: the one entry point, and the evaluation of a plan.

ROS-free. `plan_push` is in the style of mujoco.minimize: typed arguments,
precise ValueErrors, a `Status` enum, an `IterationLog` per iteration to an
optional callback, and cancellation from another thread through a
`threading.Event`. It poses the problem (cito_ros.builder), runs the stages
(cito_ros.stages) with the configured solver, and returns a `PlanResult`
(cito_ros.results).
"""
from __future__ import annotations

import math
import threading
from typing import Callable

import numpy as np

from cito_ros.builder import PlanningProblem, PushRequest, build_problem
from cito_ros.ipopt import IpoptSolver
from cito_ros.problem import PushProblem
from cito_ros.results import IterationLog, Metrics, PlanResult, Status
from cito_ros.settings import Settings, load_settings
from cito_ros.simulator import Trajectory
from cito_ros.stages import optimize


def plan_push(
    contact_model: str = "vscm",
    beta: float | None = None,
    *,
    target_position_m: np.ndarray | None = None,
    target_yaw_rad: float = 0.0,
    start_q: np.ndarray | None = None,
    scene: str | None = None,
    settings: Settings | None = None,
    iteration_callback: Callable[[IterationLog], None] | None = None,
    cancel: threading.Event | None = None,
) -> PlanResult:
    """Plan a push of the scene's object to a target pose, starting from zero torques.

    Args:
      contact_model: 'cccm', 'scm' or 'vscm'.
      beta: start pose q0(beta); default the settings' beta. Ignored if start_q is given.
      target_position_m: (x, y) or (x, y, z) of the object's goal, world frame; default
        `task.push_distance_m` along +x from the object's start (z is the object's resting height).
      target_yaw_rad: goal yaw of the object about world z.
      start_q: (7,) start configuration of the arm (at rest), instead of q0(beta).
      scene: scene name in config/scenes (default: the settings' scene).
      settings: planner settings (default: config/planner.yaml).
      iteration_callback: called with an IterationLog after every solver iteration.
      cancel: when set (from any thread), the solve stops at the next iteration and
        returns its best iterate with status CANCELLED.

    Raises:
      ValueError: for an unknown contact model, a bad beta, start configuration or target.
    """
    settings = load_settings() if settings is None else settings
    request = PushRequest(contact_model, beta, start_q, target_position_m, target_yaw_rad, scene)
    return solve(build_problem(settings, request), settings, iteration_callback=iteration_callback, cancel=cancel)


def solve(posed: PlanningProblem, settings: Settings, *,
          iteration_callback: Callable[[IterationLog], None] | None = None,
          cancel: threading.Event | None = None) -> PlanResult:
    """Run the stages on a posed problem and return the best plan."""
    problem = posed.problem
    continuation = getattr(settings.continuation, problem.contact_model.name)

    def evaluate(z, status, elapsed_s, log):
        return evaluate_plan(problem, z, status, elapsed_s, log, beta=posed.beta,
                             initial_distance_m=posed.initial_distance_m,
                             success_position_error_m=settings.task.success_position_error_m)

    return optimize(problem, IpoptSolver(settings.solver), settings.solver, continuation, evaluate,
                    iteration_callback=iteration_callback, cancel=cancel)


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
        status=status,
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
        derivative_info=dict(evaluation.derivative_info),
    )
