"""One push executed on a simulated robot, in this process, open loop or closed loop, judged on the world's truth.

The world and the controller run in lock step, one world timestep at a time, on the world's clock. Closed loop,
the executor's planning runs in line whenever it has a job (`planning.work_in_line`): the world stands still while it
computes, and the result takes effect once the world's clock has moved on by the compute time, the arm driven
by the running policy meanwhile; so every replan costs on the robot's clock what it cost here. Open loop, the
plan is made from where the planner was told the cube is, and a joint trajectory controller sends the plan's
efforts as feed-forward plus a PD on its positions and velocities, then holds the last point.

Either way the arm is then held until the cube has come to rest (the world's truth, at most REST_WAIT_S), and
the push is judged there: the cube upright (never tipped past its edge on the way) and within 2 cm and 0.15 rad
(and 0.1 rad) of the goal.
"""
from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass

import mujoco
import numpy as np

from cito_ros.execution.estimator import tipped_over
from cito_ros.execution.executor import Ending, Executor, Phase
from cito_ros.execution.goal import ExecuteGoal
from cito_ros.execution.planning import work_in_line
from cito_ros.execution.policy import bias_torques, hold_torques
from cito_ros.execution.world import SimulatedWorld
from cito_ros.planner.plan import plan_push
from cito_ros.planner.task import tilt_of, yaw_of
from cito_ros.settings import Settings

REST_WAIT_S = 3.0        # the longest the arm is held after an execution for the cube to come to rest
TIGHT_YAW_RAD = 0.1      # the stricter orientation tolerance reported beside the success one


@dataclass(frozen=True)
class Episode:
    mode: str                        # "open_loop" or "closed_loop"
    success: bool                    # at rest within task.success_position_error_m and success_orientation_error_rad
    success_tight: bool              # and within TIGHT_YAW_RAD
    position_error_m: float          # the world's truth, at rest
    orientation_error_rad: float
    at_rest: bool
    max_joint_speed_ratio: float     # the world's arm over the whole run
    max_tilt_rad: float              # the world's cube over the whole run
    tipped: bool                     # past its edge on the way (estimator.tipped_over): never a success
    duration_s: float                # on the world's clock, to the end of the execution
    ending: str                      # the executor's (closed loop), "executed" (open loop), or why nothing ran
    message: str
    pushes: int
    replans: int
    replan_rate_hz: float            # 1 / the median replan compute time
    replan_compute_s: float          # median
    plan_compute_s: float            # the first plan's
    pushes_cut: int = 0              # pushes cut short with the cube off their path (executor.off_path_m)
    first_push_sturdy: bool | None = None  # its plan reached the goal in the executor's worlds (None: no push)
    cause: str = ""                  # closed loop: why the executor ended (Executor.cause)
    final_pose: tuple[float, ...] = ()  # the world's cube at rest: x, y (m) and yaw (rad)
    replans_taken: int = 0           # closed loop: the replans that took the running plan's place

    def as_dict(self) -> dict:
        return asdict(self)


def run_closed_loop(settings: Settings, goal: ExecuteGoal, world: SimulatedWorld,
                    clock_s: Mapping[str, float] | None = None) -> Episode:
    """The executor on `world`, its compute times passing on the world's clock as measured, or as clock_s gives them
    per job kind (planning.work_in_line)."""
    executor = Executor(settings, goal)
    watch = Watch(world)

    def deliver() -> None:
        executor.on_joints(world.joints())
        for reading in world.camera():
            executor.on_pose(reading, world.time_s)

    def step(torques: np.ndarray) -> None:
        watch.step(torques)
        deliver()

    deliver()
    while not executor.estimator.has_pose:  # the arm held by its bias forces until the camera's first pose
        joints = world.joints()
        step(bias_torques(executor.model.scene, executor._data, joints.q, joints.qdot))
    plan_compute_s = math.nan
    while executor.phase is not Phase.DONE:
        work = work_in_line(executor, world.time_s, clock_s)
        if work is not None and work.kind == "plan" and math.isnan(plan_compute_s):
            plan_compute_s = work.compute_s
        step(executor.command(world.time_s))
    duration_s = world.time_s
    position, orientation, at_rest, pose = _settle(world, lambda: step(executor.command(world.time_s)), goal,
                                                     settings.task.rest_speed_m_s)
    seconds = executor.replan_seconds
    return _episode("closed_loop", settings, position, orientation, at_rest, watch, duration_s,
                    executor.ending.value, executor.message, executor.pushes, len(seconds), executor.replan_rate_hz,
                    float(np.median(seconds)) if seconds else math.nan, plan_compute_s, executor.pushes_cut,
                    executor.first_push_sturdy, executor.cause, final_pose=pose,
                    replans_taken=executor.replans_taken)


def run_open_loop(settings: Settings, goal: ExecuteGoal, world: SimulatedWorld,
                  told_pose: tuple[tuple[float, float], float]) -> Episode:
    """The plan from where the planner was told the cube is, by a joint trajectory controller with feed-forward."""
    start = world.joints()
    began = time.perf_counter()
    try:
        result = plan_push(goal.contact_model, start_q=start.q, target_position_m=np.array(goal.target_position_m),
                           target_yaw_rad=goal.target_yaw_rad, scene=goal.scene, object_pose=told_pose,
                           settings=settings)
    except ValueError as error:
        return _episode("open_loop", settings, math.nan, math.nan, False, Watch(world), 0.0,
                        Ending.INVALID_REQUEST.value, str(error), 0, 0, math.nan, math.nan, math.nan)
    plan_compute_s = time.perf_counter() - began
    trajectory, gains = result.trajectory, settings.tracking
    kp, kd = np.asarray(gains.kp), np.asarray(gains.kd)
    data = mujoco.MjData(world.scene.model)  # the controller's model of the arm: the same arm
    watch = Watch(world)
    step = watch.step
    for index in range(len(trajectory.torque_Nm)):
        joints = world.joints()
        step(trajectory.torque_Nm[index] + kp * (trajectory.q[index] - joints.q)
             + kd * (trajectory.qdot[index] - joints.qdot))
    duration_s = world.time_s

    def hold() -> None:  # the controller past its last point: the last point held, the arm's bias added
        joints = world.joints()
        step(hold_torques(world.scene, data, kp, kd, trajectory.q[-1], joints.q, joints.qdot))

    position, orientation, at_rest, pose = _settle(world, hold, goal, settings.task.rest_speed_m_s)
    return _episode("open_loop", settings, position, orientation, at_rest, watch, duration_s, "executed",
                    result.metrics.status.value, 1, 0, math.nan, math.nan, plan_compute_s, final_pose=pose)


class Watch:
    """Steps the world and keeps the largest joint speed ratio of its arm and tilt of its cube on the way."""

    def __init__(self, world: SimulatedWorld):
        self.world, self.max_joint_speed_ratio = world, 0.0
        self.max_tilt_rad = tilt_of(world.true_object_pose()[1])

    def step(self, torques: np.ndarray) -> None:
        self.world.step(torques)
        self.max_joint_speed_ratio = max(self.max_joint_speed_ratio, self.world.joint_speed_ratio())
        self.max_tilt_rad = max(self.max_tilt_rad, tilt_of(self.world.true_object_pose()[1]))

    @property
    def upright(self) -> bool:
        """Whether the cube never tipped past its edge (a cube that fell onto its side is not at any flat goal)."""
        return not tipped_over(self.world.scene, self.max_tilt_rad)


def at_goal(task, at_rest: bool, position_m: float, orientation_rad: float, yaw_tolerance_rad: float | None = None,
            upright: bool = True) -> bool:
    """A push's verdict on the world's truth: upright, at rest within the task's tolerances (or yaw_tolerance_rad)."""
    yaw_tolerance_rad = task.success_orientation_error_rad if yaw_tolerance_rad is None else yaw_tolerance_rad
    return bool(upright and at_rest and position_m < task.success_position_error_m and
                orientation_rad < yaw_tolerance_rad)


def _episode(mode: str, settings: Settings, position: float, orientation: float, at_rest: bool, watch: Watch,
             *rest, **named) -> Episode:
    task, upright = settings.task, watch.upright
    return Episode(mode, at_goal(task, at_rest, position, orientation, upright=upright),
                   at_goal(task, at_rest, position, orientation, TIGHT_YAW_RAD, upright), position, orientation,
                   at_rest, watch.max_joint_speed_ratio, watch.max_tilt_rad, not upright, *rest, **named)


def _settle(world: SimulatedWorld, hold, goal: ExecuteGoal, rest_speed_m_s: float
            ) -> tuple[float, float, bool, tuple[float, float, float]]:
    """hold() step by step until the cube is at rest in the world (no point faster than rest_speed_m_s, at most
    REST_WAIT_S); its true errors there, whether it is at rest, and its true x, y and yaw."""
    waited = 0.0
    while world.object_speed_m_s() >= rest_speed_m_s and waited < REST_WAIT_S:
        hold()
        waited += world.timestep_s
    position, quaternion = world.true_object_pose()
    yaw = yaw_of(quaternion)
    return (*goal.errors(position, yaw), world.object_speed_m_s() < rest_speed_m_s,
            (float(position[0]), float(position[1]), yaw))
