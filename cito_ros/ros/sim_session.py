"""Closed-loop executions through the ROS graph, as a robot stack runs them: cito-sim-robot spawned with a world's
differences from the planner's model, cito-executor-node, and an ExecutePush action client in this process that
judges every execution on the simulator's truth (/sim/true_object_pose, the cube at rest). Each program is a
process of its own, talking over DDS on one domain of this host. `cito-bench closed-loop --ros`, the demo and the
executor's DDS tests run executions through it.
"""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import rclpy
from cito_msgs.action import ExecutePush
from geometry_msgs.msg import PoseStamped
from rclpy.action import ActionClient
from rclpy.context import Context
from rclpy.experimental import EventsExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from cito_ros.execution.goal import ExecuteGoal
from cito_ros.execution.world import Mismatch
from cito_ros.planner.task import tilt_of, yaw_of

BIN = Path(sys.executable).parent
REST_WAIT_S = 3.0   # after an execution, the longest wait for the true cube to come to rest
RESULT_TIMEOUT_S = 120.0
GOAL_RESPONSE_S = 10.0  # longer than the node's lapse of an accepted goal's claim (goal_slot.ACCEPTED_LAPSE_S)


def spawn(program: str, domain: int, *parameters: str, log: Path | None = None) -> subprocess.Popen:
    """One of this package's programs on `domain` of this host, with -p parameters, its output appended to `log`
    (or dropped). Never a pipe: a node that outlives its reader would block once the pipe's 64 kB were full."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    command = [str(BIN / program), "--ros-args", *(a for p in parameters for a in ("-p", p))]
    if log is None:
        return subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    with open(log, "ab") as output:  # the child has its own copy of the descriptor
        return subprocess.Popen(command, env=env, stdout=output, stderr=subprocess.STDOUT)


def stop(process: subprocess.Popen) -> None:
    """SIGINT, as a launch system stops a node; killed after 20 s."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            process.kill()


def robot_parameters(mismatch: Mismatch, beta: float, seed: int) -> list[str]:
    """cito-sim-robot's parameters for a world with `mismatch`, the arm at q0(beta)."""
    return [f"beta:={float(beta)}", f"friction_scale:={mismatch.friction_scale}", f"mass_scale:={mismatch.mass_scale}",
            f"offset_x_m:={mismatch.offset_m[0]}", f"offset_y_m:={mismatch.offset_m[1]}",
            f"offset_yaw_rad:={mismatch.offset_yaw_rad}", f"pose_noise_m:={mismatch.pose_noise_m}",
            f"yaw_noise_rad:={mismatch.yaw_noise_rad}", f"latency_s:={mismatch.latency_s}",
            f"camera_rate_hz:={mismatch.camera_rate_hz}", f"seed:={int(seed)}"]


@dataclass(frozen=True)
class Outcome:
    """An execution's result and the simulator's truth after it."""

    result: ExecutePush.Result
    position_error_m: float          # the true cube at rest (or where it was after REST_WAIT_S)
    orientation_error_rad: float
    at_rest: bool
    max_joint_speed: np.ndarray      # per joint over the execution, from /sim/joint_speed_peaks (rad/s)
    max_tilt_rad: float              # the true cube's, over the execution and the wait for rest
    phases: tuple[str, ...]          # every phase the feedback showed, in order of first appearance
    round_trip_s: float              # from the goal sent to its result
    final_pose: tuple[float, float, float]  # the true cube there: x, y (m) and yaw (rad)


class Operator:
    """An ExecutePush action client, /sim/true_object_pose and /sim/joint_speed_peaks subscribers on `domain` (the
    simulator's truth at 20 Hz: subscribed to /joint_states at 200 Hz, this client took a third of a core from the
    planner, and the replans through the nodes ran at 7.0 Hz against 8.2 Hz without: docs/results.md)."""

    def __init__(self, domain: int):
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node("cito_operator", context=self.context)
        # rclpy's Python executors rebuild their wait set for every message, the EventsExecutor does not
        # (cito_ros.ros.process.LoopNode), and this client's CPU is the planner's
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.action = ActionClient(self.node, ExecutePush, "/cito/execute_push")
        self.speed_peaks: list[JointState] = []
        self.feedback: list = []
        self.true_poses: list[tuple[float, np.ndarray, float]] = []  # (stamp, position, yaw)
        self.max_tilt_rad = 0.0  # of the true cube since the last execution began
        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(JointState, "/sim/joint_speed_peaks", self.speed_peaks.append, qos)
        self.node.create_subscription(PoseStamped, "/sim/true_object_pose", self._on_true_pose, qos)

    def _on_true_pose(self, message: PoseStamped) -> None:
        p, o = message.pose.position, message.pose.orientation
        stamp = message.header.stamp.sec + 1e-9 * message.header.stamp.nanosec
        self.true_poses = [*self.true_poses[-9:], (stamp, np.array([p.x, p.y, p.z]),
                                                   yaw_of(np.array([o.w, o.x, o.y, o.z])))]
        self.max_tilt_rad = max(self.max_tilt_rad, tilt_of(np.array([o.w, o.x, o.y, o.z])))

    def spin_until(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Spin until done() or timeout_s has passed; done()."""
        deadline = time.monotonic() + timeout_s
        while not done() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)
        return done()

    def spin(self, seconds: float) -> None:
        self.spin_until(lambda: False, seconds)

    def wait(self, future, timeout_s: float = RESULT_TIMEOUT_S):
        assert self.spin_until(future.done, timeout_s), "no answer from the executor node"
        return future.result()

    def wait_for_robot(self, timeout_s: float = 60.0) -> bool:
        """Whether the action server is up and the robot's truth is flowing (its stepping loop publishes it with the
        joint states)."""
        if not self.action.wait_for_server(timeout_sec=timeout_s):
            return False
        self.speed_peaks.clear()
        self.true_poses.clear()
        return self.spin_until(lambda: len(self.speed_peaks) >= 2 and bool(self.true_poses), timeout_s)

    def send(self, goal: ExecuteGoal, z_m: float = 0.1, tries: int = 3):
        """The goal's handle (accepted or not). A goal not answered within GOAL_RESPONSE_S is sent again: Fast DDS
        drops a response whose reader it has not matched within 100 ms (this client new on a busy machine), and
        the node lets that goal's claim lapse (cito_ros.ros.goal_slot)."""
        message = ExecutePush.Goal(contact_model=goal.contact_model, scene=goal.scene or "",
                                   time_limit_s=goal.time_limit_s)
        message.target_pose.position.x, message.target_pose.position.y = goal.target_position_m
        message.target_pose.position.z = z_m
        yaw = goal.target_yaw_rad
        message.target_pose.orientation.z, message.target_pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        for _ in range(tries):
            answer = self.action.send_goal_async(message, feedback_callback=lambda m: self.feedback.append(m.feedback))
            if self.spin_until(answer.done, GOAL_RESPONSE_S):
                return answer.result()
        raise TimeoutError(f"the executor node answered none of {tries} goals, each waited for {GOAL_RESPONSE_S:g} s")

    def start(self, goal: ExecuteGoal, tries: int = 10):
        """The handle of an execution of `goal` that has begun (its first feedback arrived), or of one that ended
        before any. A goal refused because the node has no fresh measurements yet (a robot just started: DDS
        discovery takes the node longer than this client) is sent again a second later, `tries` times at most."""
        for _ in range(tries):
            self.feedback.clear()
            self.speed_peaks.clear()
            handle = self.send(goal)
            if not handle.accepted:
                raise RuntimeError("the executor node rejected the goal")
            ending = handle.get_result_async()
            self.spin_until(lambda ending=ending: bool(self.feedback) or ending.done(), RESULT_TIMEOUT_S)
            if self.feedback or not ending.done() or \
                    ending.result().result.status != ExecutePush.Result.STATUS_STALE_MEASUREMENTS:
                break
            self.spin(1.0)
        return handle

    def execute(self, goal: ExecuteGoal, rest_speed_m_s: float, start_tries: int = 10) -> Outcome:
        """One execution to its end (begun as `start` does), then the true cube awaited at rest (at most
        REST_WAIT_S)."""
        began, self.max_tilt_rad = time.monotonic(), 0.0
        result = self.wait(self.start(goal, start_tries).get_result_async()).result
        round_trip = time.monotonic() - began
        speeds = np.max([m.velocity for m in self.speed_peaks], axis=0) if self.speed_peaks else np.zeros(7)
        at_rest, deadline = False, time.monotonic() + REST_WAIT_S
        while time.monotonic() < deadline:
            self.spin(0.1)
            if self.true_speed_m_s() < rest_speed_m_s:
                at_rest = True
                break
        _, position, yaw = self.true_poses[-1]
        position_error, orientation_error = goal.errors(position[:2], yaw)
        phases = tuple(dict.fromkeys(f.phase for f in self.feedback))
        return Outcome(result, position_error, orientation_error, at_rest, speeds, self.max_tilt_rad, phases,
                       round_trip, (float(position[0]), float(position[1]), float(yaw)))

    def true_speed_m_s(self) -> float:
        """The true cube's centre speed over the last two true poses (inf before two)."""
        if len(self.true_poses) < 2:
            return math.inf
        (t0, p0, _), (t1, p1, _) = self.true_poses[-2:]
        return float(np.linalg.norm(p1 - p0) / (t1 - t0)) if t1 > t0 else math.inf

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)
