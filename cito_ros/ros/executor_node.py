"""cito-executor-node: pushes executed on a robot, closed loop: the action /cito/execute_push over the ROS-free
executor (cito_ros.execution.executor).

    cito-executor-node [--ros-args --params-file FILE -p name:=value]

It takes the planner's parameters (config/planner.yaml; executor.* are its own). It subscribes to /joint_states
(sensor_msgs/JointState, j0..j6 by name) and /object/pose (geometry_msgs/PoseStamped, frame world: the perceived
cube) and commands /effort_controller/commands (std_msgs/Float64MultiArray: seven total joint torques, N m, for
j0..j6, the arm's bias forces included), as a ros2_control effort controller takes them.

Action /cito/execute_push (cito_msgs/action/ExecutePush): the push is planned from the state measured when the
goal is accepted, executed by the plan's feedback policy on every joint state, replanned from the measured state
beside it (each replan's predicted cube path on /cito/predicted_object_path), and pushed again from where the
cube rests if it is not there. Feedback about every 0.1 s. One execution at a time: a second goal is rejected.
Cancelling, measurements older than executor.stale_after_s or the time limit hold the arm where it is and end
the execution with its status; then, and between executions, the node sends no command and the robot's own
hold (a robot holds its joints when commands stop: cito-sim-robot after command_timeout_s) keeps the arm where it
is. Every execution is
recorded as a rosbag2 (MCAP) bag under node.bag_directory: the measurements, the commands and the replans'
predicted paths. SIGINT/SIGTERM cancel a running execution, finish its bag and exit.
"""
from __future__ import annotations

import concurrent.futures
import gc
import math
import multiprocessing
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
from cito_msgs.action import ExecutePush
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path as PathMsg
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, Header

from cito_ros.execution.executor import Ending, Executor, Phase
from cito_ros.execution.goal import ExecuteGoal
from cito_ros.execution.planning import compute
from cito_ros.execution.world import JointReading, PoseReading
from cito_ros.model.contact_models import CONTACT_MODELS
from cito_ros.model.scene import ARM_JOINTS
from cito_ros.planner.builder import warm_up
from cito_ros.ros import messages as ros_messages, parameters as ros_parameters
from cito_ros.ros.bag import TopicQos
from cito_ros.ros.goal_slot import GoalSlot
from cito_ros.ros.process import LoopNode, run
from cito_ros.ros.recorder import Recorder, Recording

NAME = "/cito/execute_push"
Result = ExecutePush.Result
STATUS = {Ending.SUCCEEDED: Result.STATUS_SUCCEEDED, Ending.INVALID_REQUEST: Result.STATUS_INVALID_REQUEST,
          Ending.TASK_NOT_ACHIEVED: Result.STATUS_TASK_NOT_ACHIEVED, Ending.CANCELLED: Result.STATUS_CANCELLED,
          Ending.TIME_LIMIT: Result.STATUS_TIME_LIMIT, Ending.STALE_MEASUREMENTS: Result.STATUS_STALE_MEASUREMENTS,
          Ending.NUMERICAL_ERROR: Result.STATUS_NUMERICAL_ERROR}
FEEDBACK_PERIOD_S = 0.1
PLANNER_NICENESS = 10  # the planner's process yields the cores to the control loop (and to the robot's)
BAG_TOPICS = {"/joint_states": ("sensor_msgs/msg/JointState", TopicQos(depth=10)),
              "/object/pose": ("geometry_msgs/msg/PoseStamped", TopicQos(depth=10)),
              "/effort_controller/commands": ("std_msgs/msg/Float64MultiArray", TopicQos(depth=10)),
              "/cito/predicted_object_path": ("nav_msgs/msg/Path", TopicQos(depth=10))}


def _seconds(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


class ExecutorNode(Node):
    def __init__(self):
        super().__init__("cito_executor", automatically_declare_parameters_from_overrides=False)
        self.settings = ros_parameters.declare(self, self._parameter_overrides)
        self.frame_id = self.settings.node.frame_id
        self.bag_directory = Path(self.settings.node.bag_directory).expanduser().resolve()
        self.bag_directory.mkdir(parents=True, exist_ok=True)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.predicted = self.create_publisher(PathMsg, "/cito/predicted_object_path", qos)
        # a control step on every joint state, in a loop node: beside the action server, steps came up to 60 ms
        # apart on two cores. The measurements and the watchdog are its too: the action server's executor, woken
        # by nothing else, leaves the CPU to the planner's process
        self._control = LoopNode("cito_executor_control")
        control = self._control.node
        self.commands = control.create_publisher(Float64MultiArray, "/effort_controller/commands", qos)
        # the latest joint state only: a backlog of old ones is no use to a control step
        control.create_subscription(JointState, "/joint_states", self._on_joints,
                                    QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        control.create_subscription(PoseStamped, "/object/pose", self._on_pose, qos)
        control.create_timer(0.02, self._watchdog)  # when the joint states stop
        self.recorder = Recorder(on_error=lambda message: self.get_logger().error(message))
        # the plans and replans run in a process of their own (spawned: no DDS state is forked), so that their
        # Python never holds up the control steps, which run on every joint state
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # its numpy's threads would not be niced
        self._planner = concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                                               initializer=_start_planner_process)
        # its threads as configured (gradient.threads): niced, they take only what the control loop and the robot
        # leave; with one, 5 of 16 executions through the nodes reached the goal, with two 7 of 16
        planner_ready = self._planner.submit(_warm_up_planner, self.settings)
        warm_up(self.settings)  # and here: an execution's model is made here too (the push reach, once)
        planner_ready.result()  # ready means ready: a first goal's plan waits for no process's start
        self.stopping = threading.Event()
        self._slot = GoalSlot()
        self._executor: Executor | None = None   # the running execution's, or the last one's (holding the arm)
        self._bag: Recording | None = None
        self._joints: JointReading | None = None
        self._joints_arrival = -math.inf
        self._poses: list[tuple[PoseReading, float]] = []  # the latest few (with their arrival), for a new execution
        self._executions = 0
        # after the warm-up: a client that finds the action finds the node ready (a goal sent to a node still
        # warming up waited seconds for its response)
        self.action = ActionServer(self, ExecutePush, NAME, execute_callback=self._on_execute,
                                   goal_callback=self._on_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
                                   callback_group=ReentrantCallbackGroup())
        self.get_logger().info(f"ready: action {NAME}, bags in {self.bag_directory}")
        # what is built by now lives as long as the node: out of the collector's way, whose full collections of it
        # held every thread here, the control steps too, for up to 38 ms
        gc.freeze()
        self._control.start()

    # ------------------------------------------------------------------ measurements and control

    def _on_joints(self, message: JointState) -> None:
        try:
            positions = dict(zip(message.name, message.position))
            velocities = dict(zip(message.name, message.velocity))
            q = np.array([positions[j] for j in ARM_JOINTS])
            qdot = np.array([velocities.get(j, 0.0) for j in ARM_JOINTS])
        except KeyError:
            self.get_logger().warning(f"joint states without {list(ARM_JOINTS)} ignored", throttle_duration_sec=1.0)
            return
        reading = JointReading(_seconds(message.header.stamp), q, qdot, np.array(message.effort, dtype=float))
        arrival = time.time()
        self._joints, self._joints_arrival = reading, arrival
        executor, bag = self._executor, self._bag
        if bag is not None:
            bag.write("/joint_states", message, int(reading.stamp_s * 1e9))
        if executor is not None:
            executor.on_joints(reading, arrival)
            self._send(executor, time.time())

    def _on_pose(self, message: PoseStamped) -> None:
        p, o = message.pose.position, message.pose.orientation
        reading = PoseReading(_seconds(message.header.stamp), np.array([p.x, p.y, p.z]),
                              np.array([o.w, o.x, o.y, o.z]))
        arrival = time.time()
        self._poses = [*self._poses[-3:], (reading, arrival)]
        executor, bag = self._executor, self._bag
        if bag is not None:
            bag.write("/object/pose", message, int(reading.stamp_s * 1e9))
        if executor is not None:
            executor.on_pose(reading, arrival)

    def _send(self, executor: Executor, now: float) -> None:
        """A control step. Once an execution has ended, no more commands: the robot's own hold takes the arm (a
        servo loop behind this node's DDS and Python delays cannot hold it stiffly: measured, it oscillates)."""
        if executor.phase is Phase.DONE:
            return
        torques = executor.command(now)
        message = Float64MultiArray(data=torques.tolist())
        self.commands.publish(message)
        bag = self._bag
        if bag is not None:
            bag.write("/effort_controller/commands", message, int(now * 1e9))

    def _watchdog(self) -> None:
        """Without joint states no control step runs: the executor is asked here, and it stops on stale data."""
        executor, now = self._executor, time.time()
        if executor is not None and self._joints is not None and executor.phase is not Phase.DONE and \
                now - self._joints_arrival > self.settings.executor.stale_after_s:
            self._send(executor, now)

    # ------------------------------------------------------------------ the action

    def _on_goal(self, goal: ExecutePush.Goal) -> GoalResponse:
        if self.stopping.is_set() or not self._slot.accept():
            self.get_logger().warning("execute_push goal rejected: " + (
                "the node is shutting down" if self.stopping.is_set() else "an execution is running"))
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_execute(self, goal_handle) -> ExecutePush.Result:
        if not self._slot.begin():
            return self._refuse(goal_handle, Result.STATUS_BUSY, "an execution is running")
        try:
            return self._execute(goal_handle)
        finally:
            self._slot.end()

    def _execute(self, goal_handle) -> ExecutePush.Result:
        request, now = goal_handle.request, time.time()
        limit = self.settings.executor.stale_after_s
        fresh = self._joints is not None and now - self._joints_arrival <= limit and self._poses and \
            now - self._poses[-1][1] <= limit
        try:
            position, yaw, _ = ros_messages.flat_pose(request.target_pose, "target_pose")
            model = request.contact_model.strip().lower() or self.settings.node.default_contact_model
            if model not in CONTACT_MODELS:
                raise ValueError(f"unknown contact model {request.contact_model!r}; choose one of "
                                 f"{sorted(CONTACT_MODELS)} (or empty for the default)")
            if not math.isfinite(request.time_limit_s) or request.time_limit_s < 0:
                raise ValueError(f"time_limit_s must be a non-negative number (0: the default), got "
                                 f"{request.time_limit_s}")
            executor = Executor(self.settings, ExecuteGoal((float(position[0]), float(position[1])), yaw, model,
                                                           request.scene.strip() or None, request.time_limit_s))
        except ValueError as error:
            return self._refuse(goal_handle, Result.STATUS_INVALID_REQUEST, f"invalid goal: {error}")
        if not fresh:  # after the request's own checks: a bad goal is told what is wrong with it, whatever the robot
            return self._refuse(goal_handle, Result.STATUS_STALE_MEASUREMENTS,
                                f"no joint states and cube poses newer than {limit:g} s: nothing to start from")
        for reading, arrival in self._poses:  # the current ones: older poses may show a cube since moved or replaced
            if now - arrival <= limit:
                executor.on_pose(reading, arrival)
        executor.on_joints(self._joints, self._joints_arrival)
        self._executions += 1
        name = time.strftime("execute_%Y%m%d_%H%M%S", time.localtime(now)) + f"_{self._executions:04d}"
        bag = self.recorder.open(self.bag_directory / name, BAG_TOPICS)
        self._bag, self._executor = bag, executor
        self.get_logger().info(f"execution {self._executions}: {model} to ({position[0]:.3f}, {position[1]:.3f}) m, "
                               f"yaw {yaw:.3f} rad")
        next_feedback, phase = now, executor.phase
        try:
            while executor.phase is not Phase.DONE:
                now = time.time()
                if executor.phase is not phase:  # the execution's course in the log: what each push left
                    phase, (position, orientation) = executor.phase, executor.errors(now)
                    self.get_logger().info(f"execution {self._executions}: {phase.value} at "
                                           f"{now - executor.started_s:.1f} s, the cube {100 * position:.2f} cm "
                                           f"and {orientation:.3f} rad from the goal")
                if goal_handle.is_cancel_requested or self.stopping.is_set():
                    executor.cancel()
                    break
                job = executor.job(now)
                if job is not None:  # computed in the planner's process: the control here is never starved of it
                    outcome = self._planner.submit(compute, self.settings, executor.goal, job).result()
                    elapsed = time.time() - now
                    # a plan runs to its end: the control steps may have ended the execution meanwhile (stale data)
                    ended = executor.phase is Phase.DONE
                    work = executor.accept(job, outcome, elapsed)
                    if job.kind == "plan":
                        made = f"push {executor.pushes} planned in {elapsed:.1f} s" if work else \
                            f"the plan came back after {elapsed:.1f} s to an execution that had ended meanwhile: " \
                            f"{executor.message}" if ended else f"no push made after {elapsed:.1f} s of planning"
                        self.get_logger().info(f"execution {self._executions}: {made}")
                    if work is not None:
                        self._publish_prediction(work.policy, bag)
                else:
                    time.sleep(0.002)
                if now >= next_feedback:
                    next_feedback = now + FEEDBACK_PERIOD_S
                    goal_handle.publish_feedback(self._feedback(executor, now))
        finally:
            bag.close()
            self._bag = None
        result = self._result(executor, time.time(), str(bag.path))
        self.get_logger().info(f"execution {self._executions}: {result.message}")
        if executor.ending is Ending.CANCELLED and goal_handle.is_cancel_requested:
            goal_handle.canceled()
        elif executor.ending is Ending.SUCCEEDED:
            goal_handle.succeed()
        else:
            goal_handle.abort()
        return result

    def _refuse(self, goal_handle, status: int, message: str) -> ExecutePush.Result:
        self.get_logger().warning(message)
        goal_handle.abort()
        return ExecutePush.Result(success=False, status=status, message=message)

    def _publish_prediction(self, policy, bag: Recording) -> None:
        """A replan's predicted cube path, stamped along its time on the robot's clock."""
        scene = self._executor.model.scene
        steps = range(0, len(policy.reference), 4)
        path = PathMsg(header=Header(stamp=ros_messages.time_msg(int(policy.start_s * 1e9)), frame_id=self.frame_id))
        for step in steps:
            pose = scene.object_qpos(policy.reference[step])
            path.poses.append(PoseStamped(
                header=Header(stamp=ros_messages.time_msg(int((policy.start_s + step * policy.timestep_s) * 1e9)),
                              frame_id=self.frame_id), pose=ros_messages.pose_msg(pose[:3], pose[3:])))
        self.predicted.publish(path)
        bag.write("/cito/predicted_object_path", path, int(policy.start_s * 1e9))

    def _object_pose(self, executor: Executor, now: float):
        (x, y), yaw = executor.object_pose(now)
        z = float(executor.model.scene.object_qpos(executor.model.resting_state)[2])
        return ros_messages.pose_msg(np.array([x, y, z]), np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]))

    def _feedback(self, executor: Executor, now: float) -> ExecutePush.Feedback:
        position, _ = executor.errors(now)
        return ExecutePush.Feedback(elapsed_s=now - executor.started_s, object_pose=self._object_pose(executor, now),
                                    position_error_m=position, replans=executor.replans, phase=executor.phase.value)

    def _result(self, executor: Executor, now: float, bag_path: str) -> ExecutePush.Result:
        position, orientation = executor.errors(now)
        rate = executor.replan_rate_hz
        return ExecutePush.Result(
            success=executor.ending is Ending.SUCCEEDED, status=STATUS[executor.ending], message=executor.message,
            final_object_pose=self._object_pose(executor, now), position_error_m=position,
            orientation_error_rad=orientation, replans=executor.replans, replan_rate_hz=rate if math.isfinite(rate)
            else 0.0, bag_path=bag_path, pushes=executor.pushes,
            first_push_sturdy=bool(executor.first_push_sturdy), cause=executor.cause)

    # ------------------------------------------------------------------ shutdown

    def stop(self, timeout_s: float) -> None:
        """Cancel a running execution (the arm held), wait (bounded) until it has ended, and for its bag."""
        self.stopping.set()
        deadline = time.monotonic() + timeout_s
        while self._slot.running and time.monotonic() < deadline:
            time.sleep(0.02)
        self._planner.shutdown(wait=False, cancel_futures=True)
        self.recorder.drain(60.0)

    def destroy_node(self) -> None:
        self._control.destroy()
        super().destroy_node()


def _warm_up_planner(settings) -> None:
    """builder.warm_up in the planner's process, nothing sent back (what it made stays there)."""
    warm_up(settings)


def _start_planner_process() -> None:
    """The planner's process: niced; and a terminal's Ctrl-C, which reaches the node's whole process group, ends it
    at once and quietly (without, it printed a KeyboardInterrupt traceback): the node stops the execution itself."""
    os.nice(PLANNER_NICENESS)
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def main(argv: list[str] | None = None) -> int:
    # a control step runs on every joint state: its callback must get the GIL soon even while another thread
    # computes (Python hands it over every switch interval, 5 ms by default)
    sys.setswitchinterval(5e-4)
    return run(ExecutorNode, "cito-executor-node", argv)


if __name__ == "__main__":
    sys.exit(main())
