"""An execution's goal, and how a cube's pose stands against it: the errors, whether the cube has moved, and what the
model predicts of a next push (whether it brings the cube closer). ROS-free."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cito_ros.execution.policy import Policy
from cito_ros.planner.results import tolerance_ratio
from cito_ros.planner.task import cube_turn_rad, yaw_of
from cito_ros.settings import Settings


@dataclass(frozen=True)
class ExecuteGoal:
    target_position_m: tuple[float, float]
    target_yaw_rad: float = 0.0
    contact_model: str = "vscm"
    scene: str | None = None                # a scene in config/scenes; None: the settings' scene
    time_limit_s: float = 0.0               # 0: executor.time_limit_s

    def errors(self, position_m, yaw_rad: float) -> tuple[float, float]:
        """The position (m) and yaw (rad) error of a cube at (x, y) with yaw_rad against this goal."""
        return pose_errors(position_m, yaw_rad, self.target_position_m, self.target_yaw_rad)


def pose_errors(position_m, yaw_rad: float, other_position_m, other_yaw_rad: float) -> tuple[float, float]:
    """How far apart two planar poses of the cube are: in position (m, x and y) and in yaw (rad, task.cube_turn_rad)."""
    return float(math.hypot(position_m[0] - other_position_m[0], position_m[1] - other_position_m[1])), \
        abs(cube_turn_rad(other_yaw_rad, yaw_rad))


def moved_beyond(settings: Settings, pose, other_pose, fraction: float) -> bool:
    """Whether two poses of the cube ((x, y), yaw) lie further apart than `fraction` of the task's tolerances (the
    larger of position and yaw): executor.moved_fraction for poses the camera saw (the cube has moved),
    executor.predicted_moved_fraction for the model's, which carry no camera noise (a push moves it)."""
    return tolerance_ratio(*pose_errors(*pose, *other_pose), settings.task) > fraction


def polishes(settings: Settings, position_m: float, orientation_rad: float) -> bool:
    """Whether a cube at rest this far from the goal (m, rad) is within executor.done_fraction of the task's
    tolerances but turned by more than that of executor.polish_orientation_rad: its next push is then planned to
    that yaw tolerance (polishing)."""
    executor = settings.executor
    return executor.polish_orientation_rad > 0.0 and \
        orientation_rad >= executor.done_fraction * executor.polish_orientation_rad and \
        tolerance_ratio(position_m, orientation_rad, settings.task) < executor.done_fraction


def polishing(settings: Settings, position_m: float, orientation_rad: float) -> Settings | None:
    """The settings a next push from a cube at rest this far from the goal is planned and judged with where it
    polishes: the task's with executor.polish_orientation_rad as its yaw tolerance. None where it does not."""
    if not polishes(settings, position_m, orientation_rad):
        return None
    return settings.with_overrides({"task.success_orientation_error_rad": settings.executor.polish_orientation_rad})


def cube_in(scene, state: np.ndarray) -> tuple[np.ndarray, float]:
    """The cube's (x, y) and yaw in a state of the model."""
    qpos = scene.object_qpos(state)
    return qpos[:2], yaw_of(qpos[3:7])


@dataclass(frozen=True)
class Prediction:
    """What the model predicts of a next push from a cube at rest: its errors at the push's end against the goal and
    how far it moves the cube (each position in m, yaw in rad), and whether that brings the cube closer: the larger
    of the two errors against its tolerance lower than now (a cube at the place but turned is brought closer by a
    push that turns it), and the cube moved by more than executor.predicted_moved_fraction of the tolerances (a plan
    that never touches a cube within its waypoint's tolerances is "sturdy" there: five such ran out the time) or
    brought within executor.done_fraction of them."""

    predicted: tuple[float, float]
    moved: tuple[float, float]
    closer: bool


def predict(settings: Settings, scene, goal: ExecuteGoal, object_pose, policy: Policy) -> Prediction:
    """A next push's Prediction for a cube at rest at object_pose ((x, y), yaw)."""
    start, cube = cube_in(scene, policy.reference[0]), cube_in(scene, policy.final_state)
    predicted, moved = goal.errors(*cube), pose_errors(*start, *cube)
    task = settings.task
    ratio, now = tolerance_ratio(*predicted, task), tolerance_ratio(*goal.errors(*object_pose), task)
    # a push that ends the cube within done_fraction of the tolerances from outside them touches it however little
    # it moves it (a sturdy one 2.07 cm off to 1.73 cm, moving it 0.38 cm, was not made: the execution missed)
    lands = ratio < settings.executor.done_fraction <= now
    moves = moved_beyond(settings, start, cube, settings.executor.predicted_moved_fraction)
    return Prediction(predicted, moved, ratio < now and (lands or moves))
