"""A stage's plan as a candidate: its torques executed without the virtual force, judged where the object
comes to rest, tracked, and ranked. ROS-free.

A stage without the virtual force ends as soon as its plan, executed, is at the goal with a margin
(`stages.goal_margin`), and the start with it. Every stage's torques, executed without the virtual
force, are a candidate; the plan returned is the first start's that succeeds and that a PD joint
trajectory controller follows (its tracked execution within tracking.max_error_increase_m of the
executed error; with tracking.reference_offsets, also to the goal with its reference slightly off; with
tracking.world_*_scales, also in worlds whose object's friction and mass are not the model's), or
else the best of all (within the arm's speed limits and ranges first, then at the goal, then followed,
then followed with the offsets, then closest to it). A script's success short of the goal margin is the one
exception: the scripts after it run too, and the best of them is returned.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from cito_ros.model.simulator import Trajectory
from cito_ros.planner import results, tracking
from cito_ros.planner.problem import PushProblem
from cito_ros.planner.task import PushTask
from cito_ros.settings import Settings, TrackingSettings


@dataclass(frozen=True)
class Motions:
    """The executions an Executed was judged on, so that the returned plan's evaluation need not repeat them."""

    trajectory: Trajectory           # the torques executed without the virtual force, over the horizon
    rest: Trajectory | None          # then the arm held at its last position (tracking.held_motion)
    tracked: Trajectory              # the executed joint trajectory tracked by a PD controller
    tracked_rest: Trajectory | None  # then likewise held


@dataclass(frozen=True)
class Executed:
    """A candidate's torques executed without the virtual force (and, at the end of a stage, tracked)."""

    position_error_m: float
    orientation_error_rad: float
    max_joint_speed_ratio: float               # over the horizon and the hold
    joint_range_excess_rad: float              # likewise
    rest_object_speed_m_s: float               # after the hold
    tracked_position_error_m: float = math.nan  # by a PD joint trajectory controller; nan: not tracked
    offset_tracked_error_m: float = math.nan    # the worst with the reference off (tracking.reference_offsets)
    world_tracked_errors: tuple = ()            # tracking.WorldErrors tracked in each of tracking.world_*_scales
    motions: Motions | None = field(default=None, compare=False, repr=False)  # when tracked

    def rank(self, settings: Settings) -> tuple:
        task = settings.task
        at_goal = results.at_goal(self.position_error_m, self.orientation_error_rad, self.rest_object_speed_m_s, task)
        beyond_limits = not results.within_limits(self.max_joint_speed_ratio, self.joint_range_excess_rad)
        # comparisons, not math.isnan: an untracked candidate is never taken for a trackable one
        trackable = self.tracked_position_error_m - self.position_error_m <= settings.tracking.max_error_increase_m
        # with reference offsets, followed to the goal also with the reference slightly off; ranked after
        # the nominal tracking, so that where no start gives such a plan the best is one the controller follows
        # and in the other worlds of tracking.world_*_scales within both tolerances; among plans sturdy in none,
        # the one whose worst world is nearest
        sturdy = not settings.tracking.reference_offsets or all(
            error < task.success_position_error_m for error in (self.tracked_position_error_m,
                                                                 self.offset_tracked_error_m))
        worst_world = self.worst_world(settings)
        sturdy = sturdy and worst_world < 1.0
        return (beyond_limits, not at_goal, not trackable, not sturdy, worst_world,
                self.position_error_m / task.success_position_error_m
                + self.orientation_error_rad / task.success_orientation_error_rad)

    def worst_world(self, settings: Settings) -> float:
        """The largest world_ratio over world_tracked_errors (0: none tracked): below 1, sturdy in them all."""
        return max((results.world_ratio(errors, settings.task, settings.tracking.world_max_tilt_rad)
                    for errors in self.world_tracked_errors), default=0.0)

    @staticmethod
    def succeeds(rank: tuple) -> bool:
        """Whether a rank ends the search: within the arm's limits, at the goal, and followed by a joint
        trajectory controller to within tracking.max_error_increase_m of the executed error (and with
        tracking.reference_offsets, to the goal under each offset and without; with tracking.world_*_scales, to
        the goal in each of those worlds)."""
        beyond_limits, away, untrackable, fragile, _, _ = rank
        return not beyond_limits and not away and not untrackable and not fragile

    def reaches(self, settings: Settings, task: PushTask) -> bool:
        """Whether it is at the goal with the margin that ends the stages early (goal_margin): within that
        fraction of the success tolerances, at rest and within the arm's limits."""
        return results.at_goal(self.position_error_m, self.orientation_error_rad, self.rest_object_speed_m_s,
                               settings.task, goal_margin(settings, task)) and \
            results.within_limits(self.max_joint_speed_ratio, self.joint_range_excess_rad)


def goal_margin(settings: Settings, task: PushTask) -> float:
    """The fraction of the success tolerances that ends a start's stages early: stages.goal_margin, or for a task
    aimed past its goal (PushTask.aim_position_m) the whole tolerances. Its pushes are drawn to the aim, up to
    task.aim_past_max_m past the goal and with a turn the push can just make, so its plans end 1 cm and 0.1 rad from
    the goal: short of the margin, every start ran every stage to its last iteration."""
    return 1.0 if task.aim_position_m is not None else settings.stages.goal_margin


def execute(executor: PushProblem, torques: np.ndarray, gains: TrackingSettings) -> Executed:
    """The executed errors and arm limits of torques, by `executor` (no virtual force), the error of the
    executed joint trajectory tracked by a PD controller with `gains` (cito_ros.planner.tracking), and the worst
    error of that tracking with the reference off by each of gains.reference_offsets seeded smooth offsets
    (the same for every plan) of up to gains.reference_offset_rad; with the executions themselves."""
    evaluation = executor.evaluate(executor.with_torques(torques))
    executed, rest = _judged(executor, evaluation, gains)
    if not math.isfinite(executed.position_error_m):
        return executed
    simulator, trajectory = executor.simulator, executor.trajectory(evaluation.z)
    offset_errors = tracking.offset_position_errors_m(simulator, executor.initial_state, trajectory, gains,
                                                      executor.task, gains.reference_offsets,
                                                      gains.reference_offset_rad, seed=12345)  # the same for every plan
    tracked = tracking.track(simulator, executor.initial_state, trajectory, gains)
    tracked_rest = tracking.held_motion(simulator, tracked.final_state, gains)
    tracked_errors = tracking.motion_errors(tracked, tracked_rest, executor.task)
    worlds = tracking.world_errors(simulator, executor.initial_state, trajectory, gains, executor.task, tracked_errors)
    return dataclasses.replace(executed, tracked_position_error_m=tracked_errors.position_m,
                               offset_tracked_error_m=max(offset_errors, default=math.nan),
                               world_tracked_errors=tuple(worlds),
                               motions=Motions(trajectory, rest, tracked, tracked_rest))


def judge(executor: PushProblem, evaluation, gains: TrackingSettings) -> Executed:
    """The executed errors where the object comes to rest (tracking.errors_at_rest, the arm holding its last
    position for gains.hold_s), the object's speed then, and the arm's limits over the horizon and the hold, of
    an evaluation of `executor` (no virtual force), untracked."""
    return _judged(executor, evaluation, gains)[0]


def _judged(executor: PushProblem, evaluation, gains: TrackingSettings) -> tuple[Executed, Trajectory | None]:
    """judge, and the hold it judged."""
    nowhere = Executed(math.inf, math.inf, math.inf, math.inf, math.inf)
    if not evaluation.finite:
        return nowhere, None
    scene = executor.scene
    held = tracking.held_motion(executor.simulator, evaluation.states[-1], gains)
    position_error, angle_error = tracking.errors_at_rest(held, executor.task)
    if not math.isfinite(position_error):
        return nowhere, held
    speeds = np.abs(scene.arm_qvel(evaluation.states)) / scene.velocity_limit
    held_speeds = np.abs(held.qdot) / scene.velocity_limit
    return Executed(position_error, angle_error, max(float(speeds.max()), float(held_speeds.max())),
                    max(scene.joint_range_excess(scene.arm_qpos(evaluation.states)), scene.joint_range_excess(held.q)),
                    scene.object_speed_m_s(held.final_state)), held
