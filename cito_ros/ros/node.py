"""cito_planner node: the plan-push action and service over the ROS-free planner.

    cito-planner-node [--ros-args --params-file FILE -p name:=value ...]

Without a params file it loads config/planner.yaml. Every setting is a declared parameter
(cito_ros.ros.parameters); solver.time_limit_s and node.default_contact_model can be changed
while the node runs and apply to the next plan.

Action /cito/plan_push (cito_msgs/action/PlanPush): feedback every solver iteration, cancellable
(the best plan so far comes back with STATUS_CANCELLED). Service /cito/plan_push
(cito_msgs/srv/PlanPush): the same request and answer in one call. Both run on one worker
thread, one plan at a time: a goal that arrives meanwhile is rejected (the reason goes to
/rosout), a service call is answered STATUS_BUSY.

Topics: /cito/joint_trajectory, /cito/object_path, /cito/plan_result (transient local);
/joint_states, /cito/scene_markers, /cito/contact_forces, /cito/object_pose (one message per
simulation step, stamped along the planned horizon and the hold after it, where the object comes to
rest); /cito/plan_request, /cito/progress. Each plan is recorded as a rosbag2 (MCAP) bag under
node.bag_directory.

The answer goes out as soon as the plan is evaluated, with its bag path; the latched topics, the
per-state topics and the rest of the bag follow, from the recorder's thread (cito_ros.ros.recorder),
while the next request may already be planning. SIGINT/SIGTERM cancel a
running solve, finish every bag and exit.
"""
from __future__ import annotations

import concurrent.futures
import dataclasses
import itertools
import math
import sys
import threading
import time
from pathlib import Path
from typing import Callable

from cito_msgs.action import PlanPush as PlanPushAction
from cito_msgs.msg import ContactForce, PlanRequest, PlanResult as PlanResultMsg, SolverProgress
from cito_msgs.srv import PlanPush
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path as PathMsg
from rcl_interfaces.msg import SetParametersResult
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from cito_ros.model.scene import Scene, start_configuration
from cito_ros.planner.builder import PushRequest, scene_config, warm_up
from cito_ros.planner.plan import plan_push
from cito_ros.planner.results import IterationLog
from cito_ros.ros import messages as ros_messages, parameters as ros_parameters
from cito_ros.ros.bag import TopicQos
from cito_ros.ros.goal_slot import GoalSlot
from cito_ros.ros.markers import SceneMarkers, joint_states
from cito_ros.ros.process import run
from cito_ros.ros.recorder import Recorder, Recording

NAME = "/cito/plan_push"  # the action's and the service's
STEP_DEPTH = 1000  # a plan's per-step messages (321 at the default horizon) fit in one history
DRAIN_S = 60.0     # at shutdown, the longest the node waits for its bags to be finished
BUSY = "busy: another plan is being computed"
ANSWER_WAIT_S = 1.0  # the recorder waits this long at most for an answer to be handed to rclpy
Status = PlanPush.Response


def _qos(depth: int, latched: bool) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


# topic -> (message class, interface name, depth, transient local)
TOPICS = {
    "/cito/plan_request": (PlanRequest, "cito_msgs/msg/PlanRequest", 10, False),
    "/cito/progress": (SolverProgress, "cito_msgs/msg/SolverProgress", 100, False),
    "/cito/joint_trajectory": (JointTrajectory, "trajectory_msgs/msg/JointTrajectory", 1, True),
    "/cito/contact_forces": (ContactForce, "cito_msgs/msg/ContactForce", STEP_DEPTH, False),
    "/cito/object_pose": (PoseStamped, "geometry_msgs/msg/PoseStamped", STEP_DEPTH, False),
    "/cito/object_path": (PathMsg, "nav_msgs/msg/Path", 1, True),
    "/cito/plan_result": (PlanResultMsg, "cito_msgs/msg/PlanResult", 1, True),
    "/joint_states": (JointState, "sensor_msgs/msg/JointState", STEP_DEPTH, False),
    "/cito/scene_markers": (MarkerArray, "visualization_msgs/msg/MarkerArray", STEP_DEPTH, False),
}
# every topic in every bag, with the QoS it is offered with
BAG_TOPICS = {topic: (interface, TopicQos(transient_local=latched, depth=depth))
              for topic, (_, interface, depth, latched) in TOPICS.items()}


class Answer:
    """What a plan request gets back: the fields shared by the service response and the action result."""

    def __init__(self, status: int, message: str, bag_path: str = "", messages=None):
        self.status, self.message, self.bag_path, self.messages = status, message, bag_path, messages
        # set once the answer is filled and goes to rclpy: the plan's recording starts only then, so that the
        # recorder's Python does not take the GIL from the answer on its way out
        self.filled = threading.Event()

    def fill(self, response):
        if self.messages is not None:
            response = ros_messages.fill_response(response, self.messages)
        else:
            response.success, response.status, response.message = False, self.status, self.message
            response.bag_path = self.bag_path
        self.filled.set()
        return response


class PlannerNode(Node):
    def __init__(self):
        super().__init__("cito_planner", automatically_declare_parameters_from_overrides=False)
        # rclpy has no public list of the params file's entries; the schema check needs them all
        self.settings = ros_parameters.declare(self, self._parameter_overrides)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.frame_id = self.settings.node.frame_id
        self.bag_directory = Path(self.settings.node.bag_directory).expanduser().resolve()
        self.bag_directory.mkdir(parents=True, exist_ok=True)

        self.recorder = Recorder(on_error=lambda message: self.get_logger().error(message))
        self._markers: dict = {}  # scene (its object's pose aside) -> SceneMarkers; used on the recorder's thread
        self._warm_up()  # before the service and the action appear: a client that finds them finds the node ready
        group = ReentrantCallbackGroup()
        self.publishers_ = {topic: self.create_publisher(cls, topic, _qos(depth, latched))
                            for topic, (cls, _, depth, latched) in TOPICS.items()}
        self.service = self.create_service(PlanPush, NAME, self._on_plan_push, callback_group=group)
        self.action = ActionServer(self, PlanPushAction, NAME, execute_callback=self._on_execute,
                                   goal_callback=self._on_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
                                   callback_group=group)
        self.stopping = threading.Event()
        self._cancel = threading.Event()  # the running plan's
        self._slot = GoalSlot()
        self._worker = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="cito_solver")
        self._request_ids = itertools.count(1)
        self.get_logger().info(f"ready: action and service {NAME}, default contact model "
                               f"{self.settings.node.default_contact_model}, bags in {self.bag_directory}")

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        """Read-only parameters are refused by rclpy; the run-time ones are checked like the params file."""
        try:
            settings = self.settings.with_overrides({p.name: p.value for p in parameters})
        except ValueError as error:
            return SetParametersResult(successful=False, reason=str(error))
        self.settings = settings
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ service and action

    def _on_plan_push(self, request: PlanPush.Request, response: PlanPush.Response) -> PlanPush.Response:
        if not self._slot.take():
            return self._refuse(Status.STATUS_BUSY, BUSY + "; call again when it has finished").fill(response)
        try:
            return self._run(request, None).fill(response)
        finally:
            self._slot.end()

    def _on_goal(self, goal: PlanPushAction.Goal) -> GoalResponse:
        # the goal holds the worker from acceptance until its execute callback ends
        if self.stopping.is_set() or not self._slot.accept():
            self.get_logger().warning("plan_push goal rejected: " + (
                "the node is shutting down" if self.stopping.is_set() else
                BUSY + "; send the goal again when it has finished"))
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_execute(self, goal_handle) -> PlanPushAction.Result:
        if not self._slot.begin():
            goal_handle.abort()
            return self._refuse(Status.STATUS_BUSY, BUSY).fill(PlanPushAction.Result())
        try:
            best = {True: math.nan, False: math.nan}  # best position error with / without the virtual force

            def feedback(entry: IterationLog) -> None:
                if goal_handle.is_cancel_requested:
                    self._cancel.set()
                if math.isfinite(entry.position_error_m):
                    best[entry.virtual_force] = min(best[entry.virtual_force], entry.position_error_m) \
                        if math.isfinite(best[entry.virtual_force]) else entry.position_error_m
                goal_handle.publish_feedback(PlanPushAction.Feedback(
                    stage=entry.stage, iteration=entry.iteration, cost=entry.cost,
                    constraint_violation=entry.constraint_violation, elapsed_s=entry.elapsed_s,
                    best_planned_position_error_m=best[True], best_executed_position_error_m=best[False]))

            answer = self._run(goal_handle.request, feedback)
            if answer.status == Status.STATUS_CANCELLED and goal_handle.is_cancel_requested:
                goal_handle.canceled()
            elif answer.status == Status.STATUS_SUCCEEDED:
                goal_handle.succeed()
            else:
                goal_handle.abort()
            return answer.fill(PlanPushAction.Result())
        finally:
            self._slot.end()

    def _refuse(self, status: int, message: str, bag_path: str = "") -> Answer:
        self.get_logger().warning(message)
        return Answer(status, message, bag_path)

    def _run(self, request, feedback: Callable[[IterationLog], None] | None) -> Answer:
        """Validate a request or goal and plan it on the worker thread (the caller holds the slot)."""
        if self.stopping.is_set():
            return self._refuse(Status.STATUS_CANCELLED, "the node is shutting down")
        settings = self.settings
        try:
            inputs = ros_messages.parse_request(request, settings.node.default_contact_model,
                                                settings.solver.time_limit_s)
            scene = scene_config(settings, PushRequest(scene=inputs.scene, object_pose=inputs.object_pose))
        except ValueError as error:
            return self._refuse(Status.STATUS_INVALID_REQUEST, f"invalid request: {error}")
        self._cancel.clear()
        request_id, received_ns = next(self._request_ids), self.get_clock().now().nanoseconds
        return self._worker.submit(self._plan, inputs, scene, settings, request_id, received_ns, feedback).result()

    # ------------------------------------------------------------------ worker

    def _plan(self, inputs: ros_messages.PlanInputs, scene, settings, request_id: int, received_ns: int,
              feedback: Callable[[IterationLog], None] | None) -> Answer:
        name = time.strftime("plan_%Y%m%d_%H%M%S", time.localtime(received_ns / 1e9)) + f"_{request_id:04d}"
        bag = self.recorder.open(self.bag_directory / name, BAG_TOPICS)
        try:
            start_q = inputs.start_q if inputs.start_q is not None else start_configuration(settings.beta)
            self._emit(bag, "/cito/plan_request", ros_messages.request_msg(
                inputs, start_q, scene, request_id, received_ns, self.frame_id), received_ns)

            def progress(entry: IterationLog) -> None:
                now = self.get_clock().now().nanoseconds
                self._emit(bag, "/cito/progress", ros_messages.progress_msg(
                    entry, request_id, inputs.contact_model, now, self.frame_id), now)
                if feedback is not None:
                    feedback(entry)

            # parse_request has checked the time limit; with_overrides would validate every setting again (8 ms)
            settings = dataclasses.replace(settings, solver=dataclasses.replace(settings.solver,
                                                                                time_limit_s=inputs.time_limit_s))
            self.get_logger().info(f"plan {request_id}: {inputs.contact_model} to "
                                   f"({inputs.target_position_m[0]:.3f}, {inputs.target_position_m[1]:.3f}) m, "
                                   f"yaw {inputs.target_yaw_rad:.3f} rad")
            try:
                result = plan_push(inputs.contact_model, start_q=start_q, target_position_m=inputs.target_position_m,
                                   target_yaw_rad=inputs.target_yaw_rad, scene=inputs.scene,
                                   object_pose=inputs.object_pose, settings=settings,
                                   iteration_callback=progress, cancel=self._cancel)
            except ValueError as error:
                failed = PlanResultMsg(request_id=request_id, bag_path=str(bag.path),
                                       status=Status.STATUS_INVALID_REQUEST, message=f"invalid request: {error}")
                failed.header.stamp = ros_messages.time_msg(received_ns)
                failed.header.frame_id = self.frame_id
                self._emit(bag, "/cito/plan_result", failed, received_ns)
                return self._refuse(failed.status, failed.message, str(bag.path))

            stamp = self.get_clock().now().nanoseconds
            messages = ros_messages.plan_messages(result, request_id, stamp, self.frame_id, str(bag.path),
                                                  inputs.target_orientation, settings)
            answer = Answer(messages.result.status, messages.result.message, str(bag.path), messages)
            self.recorder.submit(self._publish_plan, result, messages, bag, answer.filled, recording=bag)
            self.get_logger().info(f"plan {request_id}: {messages.result.message} ({result.metrics.solve_time_s:.2f} s, "
                                   f"bag {bag.path})")
            return answer
        except Exception as error:  # a bug must not kill the node; report it as a solver failure
            self.get_logger().error(f"plan {request_id} failed: {error!r}")
            return self._refuse(Status.STATUS_SOLVER_FAILED, f"internal error: {error!r}", str(bag.path))
        finally:
            bag.close()  # queued after everything of the plan, the per-state topics included

    def _publish_plan(self, result, messages: ros_messages.PlanMessages, bag: Recording,
                      answered: threading.Event) -> None:
        """On the recorder's thread, once the answer is on its way: the latched topics, then the per-state topics
        of the plan (the horizon, then the arm held where the object comes to rest); each per-state message
        serialized once where rclpy's bytes are exact (cito_ros.ros.bag.exact_encoding_needed), published and
        written."""
        answered.wait(ANSWER_WAIT_S)
        stamp = messages.state_stamps_ns[0]
        poses = ros_messages.object_poses(result, messages.state_stamps_ns, self.frame_id)
        path = PathMsg(header=messages.result.header, poses=poses)
        for topic, message in (("/cito/joint_trajectory", messages.trajectory), ("/cito/plan_result", messages.result),
                               ("/cito/object_path", path)):
            self.publishers_[topic].publish(message)
            bag.write_now(topic, message, stamp)
        motion, stamps = result.executed_motion, messages.state_stamps_ns
        per_state = [
            ("/cito/contact_forces", map(serialize_message, messages.contact_forces), messages.step_stamps_ns),
            ("/cito/object_pose", map(serialize_message, poses), stamps),
            ("/joint_states", joint_states(motion, stamps, self.frame_id), stamps),  # exact_encoding_needed
            ("/cito/scene_markers", self._scene_markers(result.scene).serialize(motion, stamps), stamps),
        ]
        for topic, frames, frame_stamps in per_state:
            publisher = self.publishers_[topic]
            for frame, stamp_ns in zip(frames, frame_stamps):
                publisher.publish(frame)
                bag.write_now(topic, frame, stamp_ns)

    def _scene_markers(self, scene: Scene) -> SceneMarkers:
        """The marker template of a scene (its object's pose aside), made once; on the recorder's thread."""
        key = scene.config.object_pose_aside
        if key not in self._markers:
            self._markers[key] = SceneMarkers(scene, self.frame_id)
        return self._markers[key]

    def _warm_up(self) -> None:
        """What the first answer for the configured scene would otherwise pay for on top of its solve: the reaches
        (builder.warm_up), and the scene's marker template (on the recorder's thread)."""
        try:
            self.recorder.submit(self._scene_markers, warm_up(self.settings).scene)
        except Exception as error:  # the first plan pays for it instead
            self.get_logger().warning(f"warm-up failed: {error!r}")

    def _emit(self, bag: Recording, topic: str, message, stamp_ns: int) -> None:
        self.publishers_[topic].publish(message)
        bag.write(topic, message, stamp_ns)

    # ------------------------------------------------------------------ shutdown

    def stop(self, timeout_s: float) -> None:
        """Cancel a running solve, wait (bounded) until it has answered, then until every bag is finished."""
        self.stopping.set()
        self._cancel.set()
        self._worker.shutdown(wait=False, cancel_futures=True)
        deadline = time.monotonic() + timeout_s
        while self._slot.running and time.monotonic() < deadline:
            time.sleep(0.02)
        if not self.recorder.drain(DRAIN_S):
            self.get_logger().error(f"bags still being written after {DRAIN_S:g} s; they stay .partial")


def main(argv: list[str] | None = None) -> int:
    return run(PlannerNode, "cito-planner-node", argv)


if __name__ == "__main__":
    sys.exit(main())
