"""Pushes in sequence: a goal well off the near face's normal reached by two pushes, the first across that normal on
the side face it needs, the second along it from where the first leaves the object, the arm drawn back between them
the way it came. ROS-free.

One push on the near face moves the object within that face's friction cone, and a side face's push along its own
normal reaches only so far before the plate falls short of the face (docs/planner.md: Side faces). Split into its
parts across and along the near face's normal (side_faces.across_first, as the executor splits such a push), each
push is one a face makes well: on the any distribution's posed goals, two pushes reached 19 of 21 inside the steady
reach where one reached 14 (docs/results.md: Pushes in sequence). The returned plan is one motion over both pushes
and the transit between them, judged as any plan: executed from the request's start, held, at rest.
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time
from typing import Callable

import numpy as np

from cito_ros.model.simulator import Trajectory
from cito_ros.model.speed_guard import path_slowdown
from cito_ros.planner import tracking
from cito_ros.planner.builder import PlanningProblem, PushRequest, build_problem
from cito_ros.planner.results import IterationLog, PlanResult, Status
from cito_ros.planner.side_faces import across_first
from cito_ros.planner.task import yaw_of
from cito_ros.settings import Settings

Plan = Callable[[PushRequest, Settings, Callable[[IterationLog], None] | None, threading.Event | None], PlanResult]
Judge = Callable[[tuple[PlanResult, ...], Trajectory, Trajectory | None, float], PlanResult]


def first_target(posed: PlanningProblem, settings: Settings) -> tuple[np.ndarray, float] | None:
    """Where the first of two pushes takes the object (position, yaw), for a goal ahead of the near face more than
    stages.sequence.across_first_rad off its inward normal, with more than the position tolerance of it both across
    and along that normal, and the waypoint on the table; None where one push is planned."""
    limit_rad, tolerance_m = settings.stages.sequence.across_first_rad, settings.task.success_position_error_m
    qpos = posed.scene.object_qpos(posed.initial_state)
    xy, yaw = qpos[:2], float(yaw_of(qpos[3:7]))
    waypoint, waypoint_yaw, across_m, along_m = across_first(xy, yaw, posed.task.target_position_m,
                                                             posed.task.target_yaw_rad)
    if limit_rad <= 0.0 or min(abs(across_m), along_m) <= tolerance_m or \
            abs(math.atan2(across_m, along_m)) <= limit_rad:
        return None
    low, high, _ = posed.scene.table_top()
    half_m = math.sqrt(2.0) * float(posed.scene.object_half_size[0])  # any yaw of the cube on the table
    if np.any(np.asarray(waypoint) - half_m < low[:2]) or np.any(np.asarray(waypoint) + half_m > high[:2]):
        return None
    return np.asarray(waypoint, dtype=float), float(waypoint_yaw)


def plan_sequence(settings: Settings, request: PushRequest, posed: PlanningProblem, waypoint: tuple[np.ndarray, float],
                  plan: Plan, judge: Judge, iteration_callback: Callable[[IterationLog], None] | None = None,
                  cancel: threading.Event | None = None) -> PlanResult:
    """The two pushes to `waypoint` and on to the request's goal, within solver.time_limit_s together (the first
    given stages.sequence.first_time_fraction of it). `plan` plans one push; `judge` makes the sequence's result
    from the pushes' plans, the motion of all of it executed from the request's start, its hold at rest, and the
    solve time: of the first push alone where it is cancelled or numerically broken. Where the waypoint or the
    object where the first push leaves it is not posed, the one push to the goal is planned in the time left."""
    began = time.perf_counter()
    limit_s, sequence = settings.solver.time_limit_s, settings.stages.sequence
    one = settings.with_overrides({"stages.sequence.across_first_rad": 0.0})

    def within(seconds: float) -> Settings:  # none left: a start's first plan, no iteration
        return one.with_overrides({"solver.time_limit_s": max(seconds, 1e-3)})

    def relayed(push: int, offset_s: float):  # the iterations of both pushes, on one clock, named by push
        if iteration_callback is None:
            return None
        return lambda log: iteration_callback(dataclasses.replace(log, elapsed_s=log.elapsed_s + offset_s,
                                                                  stage=f"push {push}: {log.stage}"))

    position, yaw = waypoint
    try:
        first = plan(dataclasses.replace(request, target_position_m=position, target_yaw_rad=yaw),
                     within(sequence.first_time_fraction * limit_s), relayed(1, 0.0), cancel)
    except ValueError:  # a waypoint no push is posed to: the one push to the goal
        return plan(request, within(limit_s - (time.perf_counter() - began)), iteration_callback, cancel)
    if first.status in (Status.CANCELLED, Status.NUMERICAL_ERROR):  # judged against the goal, not its waypoint
        return judge((first,), first.trajectory, first.rest, time.perf_counter() - began)
    simulator = posed.simulator
    held = first.executed_motion
    transit_began = time.perf_counter()
    back = transit(simulator, held.final_state, first.trajectory.q[::-1], sequence.transit_speed_fraction,
                   settings.tracking)
    arrived = back.followed_by(tracking.held_motion(simulator, back.final_state, settings.tracking))
    # what follows the second push's solve (its execution from here, the whole motion tracked and held) simulates
    # about three times the transit's steps: that long again, with a margin, is kept from its time limit
    reserve_s = 4.0 * (time.perf_counter() - transit_began)
    scene = posed.scene
    state = arrived.final_state
    object_qpos = scene.object_qpos(state)
    start_q = state[scene.state_qpos_adr + scene.arm_qpos_adr]
    second_request = dataclasses.replace(request, beta=None, start_q=start_q,
                                         object_pose=(object_qpos[:2].copy(), float(yaw_of(object_qpos[3:7]))))
    elapsed_s = time.perf_counter() - began
    try:
        second = plan(second_request, within(limit_s - elapsed_s - reserve_s), relayed(2, elapsed_s), cancel)
    except ValueError:  # the object where no push is posed from: the one push to the goal instead
        return plan(request, within(limit_s - elapsed_s), iteration_callback, cancel)
    # the second push's torques from where the transit really leaves the arm and the object, not its plan's
    # idealized start (the arm at rest at start_q, the object at rest on the table)
    knotted = settings.with_overrides({"horizon_s": float(second.knot_time_s[-1]),
                                       "control_period_s": float(second.knot_time_s[1] - second.knot_time_s[0])})
    pushing = build_problem(knotted, second_request).simulator
    pushed = pushing.rollout(state, second.knot_torques_Nm, virtual_force=False)
    motion = held.followed_by(arrived).followed_by(pushed)
    return judge((first, second), motion, tracking.held_motion(pushing, pushed.final_state, settings.tracking),
                 time.perf_counter() - began)


def sequence_note(result: PlanResult) -> str:
    """What an answer says of a plan made of pushes in sequence ("" for one push)."""
    if len(result.legs) < 2:
        return ""
    x, y = result.legs[0].target_position_m[:2]
    return (f"in {len(result.legs)} pushes: across the near face's normal to ({x:.3f}, {y:.3f}) m, the arm back "
            f"the way it came, then along it to the goal")


def transit(simulator, state: np.ndarray, path_q: np.ndarray, speed_fraction: float, gains) -> Trajectory:
    """The tracking controller taking the arm from `state` along path_q (joint poses a timestep apart), slowed where
    a joint would pass speed_fraction of its limit: back the way a push came, the plate leaving the object along
    the way it arrived (straight back from a side push, the arm crosses the object it reached around)."""
    timestep_s = simulator.timestep_s
    slowdown = path_slowdown(path_q, timestep_s, speed_fraction, simulator.scene.velocity_limit)
    steps = max(int(math.ceil((len(path_q) - 1) * slowdown)), 1)
    where = np.linspace(0.0, len(path_q) - 1, steps + 1)
    q_ref = np.stack([np.interp(where, np.arange(len(path_q)), path_q[:, j]) for j in range(path_q.shape[1])], axis=1)
    qdot_ref = np.gradient(q_ref, timestep_s, axis=0)
    qdot_ref[-1] = 0.0
    return tracking.pd_motion(simulator, state, q_ref, qdot_ref, gains)
