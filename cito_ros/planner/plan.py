"""Plan a push: the one entry point, and the evaluation of a plan.

ROS-free. `plan_push` is in the style of mujoco.minimize: typed arguments,
precise ValueErrors, a `Status` enum, an `IterationLog` per iteration to an
optional callback, and cancellation from another thread through a
`threading.Event`. It poses the problem (cito_ros.planner.builder), runs the stages of
the configured pipeline (cito_ros.planner.stages), and returns a `PlanResult`
(cito_ros.planner.results) whose trajectory is the plan executed without the virtual
force, as the robot will execute it.
"""
from __future__ import annotations

import dataclasses
import math
import threading
from typing import Callable

import numpy as np

from cito_ros.model.simulator import Trajectory
from cito_ros.planner import push_limits, sequence, tracking
from cito_ros.planner.builder import PlanningProblem, PushRequest, build_problem
from cito_ros.planner.candidates import Motions
from cito_ros.planner.physical import solve_physical
from cito_ros.planner.results import IterationLog, Metrics, PlanResult, Status, succeeds
from cito_ros.planner.stages import Outcome, solve_paper
from cito_ros.settings import Settings, load_settings


def plan_push(
    contact_model: str = "vscm",
    beta: float | None = None,
    *,
    target_position_m: np.ndarray | None = None,
    target_yaw_rad: float = 0.0,
    start_q: np.ndarray | None = None,
    scene: str | None = None,
    object_pose: tuple[np.ndarray, float] | None = None,
    object_scales: tuple[float, float] = (1.0, 1.0),
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
      object_pose: ((x, y) or (x, y, z), yaw) where the object is now, world frame (default: the
        scene's pose); it must stand on the table, clear of the arm, within reach.
      object_scales: (friction, mass) of the object as these times the scene's.
      settings: planner settings (default: config/planner.yaml); `pipeline` selects the physical
        pipeline or exactly the paper's problem.
      iteration_callback: called with an IterationLog after every solver iteration (from the
        solving threads; calls are serialized).
      cancel: when set (from any thread), the solve stops at the next iteration and
        returns its best plan with status CANCELLED.

    Raises:
      ValueError: for an unknown contact model, a bad beta, start configuration, target or scene.
    """
    settings = load_settings() if settings is None else settings
    request = PushRequest(contact_model, beta, start_q, target_position_m, target_yaw_rad, scene, object_pose,
                          object_scales)
    return _plan(request, settings, iteration_callback, cancel)


def _plan(request: PushRequest, settings: Settings, iteration_callback: Callable[[IterationLog], None] | None,
          cancel: threading.Event | None) -> PlanResult:
    posed = build_problem(settings, request)
    if settings.pipeline == "paper":
        outcome = solve_paper(posed, settings, iteration_callback=iteration_callback, cancel=cancel)
        return evaluate_plan(outcome, posed, settings)
    waypoint = sequence.first_target(posed, settings)
    if waypoint is not None:
        return sequence.plan_sequence(settings, request, posed, waypoint, _plan, _judge_sequence(posed, settings),
                                      iteration_callback, cancel)
    outcome = solve_physical(settings, request, iteration_callback=iteration_callback, cancel=cancel)
    return evaluate_plan(outcome, posed, settings)


def evaluate_plan(outcome: Outcome, posed: PlanningProblem, settings: Settings) -> PlanResult:
    """Simulate the plan: with the virtual force as planned, executed without it, and tracked by a
    PD joint trajectory controller; compute the metrics."""
    discovery, executor = outcome.discovery, outcome.executor
    simulator, task = discovery.simulator, discovery.task
    _, variables = discovery.split(outcome.planned_z)
    planned = discovery.trajectory(outcome.planned_z)
    # executed, tracked, and where the object comes to rest once the arm holds its last position (a plan may end
    # with it sliding): as the stages judged the returned torques, when they did (with the same tracking gains)
    motions = outcome.executed.motions if outcome.executed is not None else None
    if motions is None:
        trajectory = executor.trajectory(executor.with_torques(outcome.torques))
        tracked = tracking.track(simulator, discovery.initial_state, trajectory, settings.tracking)
        motions = Motions(trajectory, tracking.held_motion(simulator, trajectory.final_state, settings.tracking),
                          tracked, tracking.held_motion(simulator, tracked.final_state, settings.tracking))
    trajectory, rest, tracked, tracked_rest = motions.trajectory, motions.rest, motions.tracked, motions.tracked_rest
    planned_position_error, planned_orientation_error = task.final_errors(planned)  # the paper's, at T
    figures, broken = _executed(discovery.scene, discovery.initial_state, trajectory, rest, tracked_rest, task)
    status = Status.NUMERICAL_ERROR if broken or not planned.finite or planned.warnings else outcome.status
    worst_world = outcome.executed.worst_world(settings) if outcome.executed is not None and \
        outcome.executed.world_tracked_errors else math.inf
    metrics = Metrics(
        **figures,
        planned_position_error_m=planned_position_error,
        planned_orientation_error_rad=planned_orientation_error,
        physical_inaccuracy_Ns=float(simulator.timestep_s * np.sum(planned.gamma_N)),
        solve_time_s=outcome.solve_time_s,
        setup_time_s=outcome.setup_s,
        rollout_time_s=sum(record.rollout_s for record in outcome.stages),
        linearization_time_s=sum(record.linearization_s for record in outcome.stages),
        solver_time_s=sum(record.solver_s for record in outcome.stages),
        evaluation_time_s=sum(record.evaluation_s for record in outcome.stages),
        iterations=sum(record.iterations for record in outcome.stages),
        status=status,
        success=False,  # the verdict on these figures, below
        planned_success=bool(status is not Status.NUMERICAL_ERROR and math.isfinite(figures["position_error_m"])
                             and planned_position_error < settings.task.planned_success_position_error_m),
    )
    metrics = dataclasses.replace(metrics, success=succeeds(metrics, settings.task))
    return PlanResult(
        contact_model=discovery.contact_model.name,
        beta=posed.beta,
        initial_distance_m=posed.initial_distance_m,
        target_position_m=task.target_position_m.copy(),
        target_yaw_rad=task.target_yaw_rad,
        knot_time_s=np.arange(discovery.n_knots + 1) * simulator.control_period_s,
        knot_torques_Nm=np.array(outcome.torques, dtype=float),
        knot_contact_control=discovery.contact_control(variables).copy(),
        knot_variables={v.name: variables[:, i].copy() for i, v in enumerate(discovery.variables)},
        trajectory=trajectory,
        planned=planned,
        tracked=tracked,
        rest=rest,
        tracked_rest=tracked_rest,
        metrics=metrics,
        iteration_log=outcome.log,
        stages=outcome.stages,
        derivative_info=dict(discovery.evaluate(outcome.planned_z).derivative_info),
        scene=discovery.scene,
        worst_world=worst_world,
        note=outcome.note,
        aim_position_m=None if task.aim_position_m is None else task.aim_position_m.copy(),
    )


def _executed(scene, initial_state: np.ndarray, trajectory: Trajectory, rest: Trajectory | None,
              tracked_rest: Trajectory | None, task) -> tuple[dict, bool]:
    """The Metrics of a motion executed from initial_state (trajectory, then the arm held: rest) and of its tracked
    twin's rest, and whether it is numerically broken (not finite, MuJoCo warned, or no rest: NaN errors)."""
    position_error, orientation_error = tracking.errors_at_rest(rest, task)
    tracked_position_error, tracked_orientation_error = tracking.errors_at_rest(tracked_rest, task)
    motion = trajectory.followed_by(rest)  # the limits hold over the horizon and the hold
    figures = dict(
        position_error_m=position_error,
        orientation_error_rad=orientation_error,
        tracked_position_error_m=tracked_position_error,
        tracked_orientation_error_rad=tracked_orientation_error,
        max_joint_speed_ratio=float(np.max(np.abs(motion.qdot) / scene.velocity_limit)),
        joint_range_excess_rad=scene.joint_range_excess(motion.q),
        final_object_speed_m_s=float(np.linalg.norm(scene.object_qvel(trajectory.final_state)[:3])),
        rest_object_speed_m_s=math.nan if rest is None else scene.object_speed_m_s(rest.final_state),
        steady_reach_margin_m=push_limits.steady_reach_margin_m(scene, initial_state, task.target_position_m))
    # NaN: MuJoCo warned while the arm held its last position
    return figures, not trajectory.finite or bool(trajectory.warnings) or not math.isfinite(position_error)


def _judge_sequence(posed: PlanningProblem, settings: Settings) -> sequence.Judge:
    """The result of a sequence (cito_ros.planner.sequence): its motion from the request's start judged as one plan
    against the goal (executed, held, at rest; tracked by the PD controller from the same start), its figures of
    planning summed over its pushes, the contact model's plan and knots the last push's, the pushes' results in
    `legs`, the status the last push's."""

    def judge(legs: tuple[PlanResult, ...], motion: Trajectory, rest: Trajectory | None,
              solve_time_s: float) -> PlanResult:
        last = legs[-1]
        gains, steps = settings.tracking, len(motion.torque_Nm)
        tracked = tracking.pd_motion(posed.simulator, posed.initial_state, motion.q[:steps], motion.qdot[:steps], gains,
                                     motion.control_torque_Nm if gains.feed_forward else None)
        tracked_rest = tracking.held_motion(posed.simulator, tracked.final_state, gains)
        figures, broken = _executed(posed.scene, posed.initial_state, motion, rest, tracked_rest, posed.task)
        summed = {name: sum(getattr(leg.metrics, name) for leg in legs)
                  for name in ("physical_inaccuracy_Ns", "setup_time_s", "rollout_time_s", "linearization_time_s",
                               "solver_time_s", "evaluation_time_s", "iterations")}
        status = Status.NUMERICAL_ERROR if broken else last.status
        planned_position_error, planned_orientation_error = posed.task.final_errors(last.planned)
        metrics = dataclasses.replace(
            last.metrics, **figures, **summed, solve_time_s=solve_time_s, status=status,
            planned_position_error_m=planned_position_error, planned_orientation_error_rad=planned_orientation_error,
            planned_success=bool(status is not Status.NUMERICAL_ERROR and
                                 planned_position_error < settings.task.planned_success_position_error_m))
        metrics = dataclasses.replace(metrics, success=succeeds(metrics, settings.task))
        stages = tuple(dataclasses.replace(record, name=f"push {i}: {record.name}")
                       for i, leg in enumerate(legs, 1) for record in leg.stages)
        return dataclasses.replace(
            last, beta=posed.beta, initial_distance_m=posed.initial_distance_m,
            target_position_m=posed.task.target_position_m.copy(), target_yaw_rad=posed.task.target_yaw_rad,
            aim_position_m=None if posed.task.aim_position_m is None else posed.task.aim_position_m.copy(),
            trajectory=motion, tracked=tracked,
            rest=rest, tracked_rest=tracked_rest, metrics=metrics, stages=stages, scene=posed.scene,
            iteration_log=tuple(entry for leg in legs for entry in leg.iteration_log), worst_world=math.inf, legs=legs,
            note="; ".join(leg.note for leg in legs if leg.note))

    return judge
