"""cito_planner node: the plan-push service over the ROS-free planner.

    cito-planner-node [--ros-args --params-file FILE -p name:=value ...]

Without a params file it loads config/planner.yaml. Service /cito/plan_push
(cito_msgs/srv/PlanPush); topics /cito/joint_trajectory (transient local),
/cito/contact_forces and /cito/object_pose (one message per simulation step,
stamped along the planned horizon), /cito/object_path (transient local),
/cito/progress, /cito/plan_result (transient local). Each plan is recorded as a
rosbag2 (MCAP) bag under node.bag_directory.

One plan at a time: it runs in a worker thread while the executor keeps
serving; a request that arrives meanwhile is answered STATUS_BUSY at once.
SIGINT/SIGTERM cancel a running solve, finish its bag and exit.
"""
from __future__ import annotations

import concurrent.futures
import itertools
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import rclpy
from cito_msgs.msg import ContactForce, PlanRequest, PlanResult as PlanResultMsg, SolverProgress
from cito_msgs.srv import PlanPush
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path as PathMsg
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from trajectory_msgs.msg import JointTrajectory

from cito_ros import ros_messages
from cito_ros.bag import BagWriter, TopicQos
from cito_ros.paths import config_path
from cito_ros.planner import plan_push
from cito_ros.scene import start_configuration
from cito_ros.settings import Settings

SERVICE = "/cito/plan_push"
ROS_PARAMETERS = ("use_sim_time", "start_type_description_service")  # every rclpy node's own
STEP_DEPTH = 1000  # a plan's per-step messages (200 at the default horizon) fit in one history


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
}


def nested(parameters: dict[str, Any]) -> dict[str, Any]:
    """{'a.b': 1} -> {'a': {'b': 1}}, arrays as lists."""
    tree: dict[str, Any] = {}
    for name, value in parameters.items():
        keys = name.split(".")
        node = tree
        for key in keys[:-1]:
            node = node.setdefault(key, {})
        node[keys[-1]] = list(value) if hasattr(value, "tolist") or isinstance(value, (list, tuple)) else value
    return tree


class PlannerNode(Node):
    def __init__(self):
        super().__init__("cito_planner", automatically_declare_parameters_from_overrides=True)
        self.settings = Settings.from_mapping(nested({name: p.value for name, p in
                                                     self.get_parameters_by_prefix("").items()
                                                     if name not in ROS_PARAMETERS}))
        self.frame_id = self.settings.node.frame_id
        self.default_contact_model = self.settings.node.default_contact_model
        self.bag_directory = Path(self.settings.node.bag_directory).expanduser().resolve()
        self.bag_directory.mkdir(parents=True, exist_ok=True)

        group = ReentrantCallbackGroup()
        self.publishers_ = {topic: self.create_publisher(cls, topic, _qos(depth, latched))
                            for topic, (cls, _, depth, latched) in TOPICS.items()}
        self.service = self.create_service(PlanPush, SERVICE, self._on_plan_push, callback_group=group)
        self.cancel_event = threading.Event()
        self._busy = threading.Lock()
        self._worker = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="cito_solver")
        self._request_ids = itertools.count(1)
        self.get_logger().info(f"ready: {SERVICE}, default contact model {self.default_contact_model}, "
                               f"bags in {self.bag_directory}")

    # ------------------------------------------------------------------ service

    def _on_plan_push(self, request: PlanPush.Request, response: PlanPush.Response) -> PlanPush.Response:
        if not self._busy.acquire(blocking=False):
            return self._reject(response, PlanPush.Response.STATUS_BUSY,
                                "busy: another plan is being computed; call again when it has finished")
        try:
            if self.cancel_event.is_set():
                return self._reject(response, PlanPush.Response.STATUS_CANCELLED, "the node is shutting down")
            try:
                inputs = ros_messages.parse_request(request, self.default_contact_model,
                                                    self.settings.solver.time_limit_s)
            except ValueError as error:
                return self._reject(response, PlanPush.Response.STATUS_INVALID_REQUEST, f"invalid request: {error}")
            request_id = next(self._request_ids)
            received_ns = self.get_clock().now().nanoseconds
            return self._worker.submit(self._plan, inputs, request_id, received_ns, response).result()
        finally:
            self._busy.release()

    def _reject(self, response: PlanPush.Response, status: int, message: str) -> PlanPush.Response:
        self.get_logger().warning(message)
        response.success, response.status, response.message = False, status, message
        return response

    # ------------------------------------------------------------------ worker

    def _plan(self, inputs: ros_messages.PlanInputs, request_id: int, received_ns: int,
              response: PlanPush.Response) -> PlanPush.Response:
        name = time.strftime("plan_%Y%m%d_%H%M%S", time.localtime(received_ns / 1e9)) + f"_{request_id:04d}"
        bag = BagWriter(self.bag_directory / name)
        try:
            for topic, (_, interface, depth, latched) in TOPICS.items():
                bag.add_topic(topic, interface, TopicQos(transient_local=latched, depth=depth))
            start_q = inputs.start_q if inputs.start_q is not None else start_configuration(self.settings.beta)
            self._emit(bag, "/cito/plan_request",
                       ros_messages.request_msg(inputs, start_q, request_id, received_ns, self.frame_id), received_ns)

            def progress(entry):
                now = self.get_clock().now().nanoseconds
                self._emit(bag, "/cito/progress", ros_messages.progress_msg(
                    entry, request_id, inputs.contact_model, now, self.frame_id), now)

            settings = self.settings.with_overrides({"solver.time_limit_s": inputs.time_limit_s})
            self.get_logger().info(f"plan {request_id}: {inputs.contact_model} to "
                                   f"({inputs.target_position_m[0]:.3f}, {inputs.target_position_m[1]:.3f}) m, "
                                   f"yaw {inputs.target_yaw_rad:.3f} rad")
            try:
                result = plan_push(inputs.contact_model, start_q=start_q, target_position_m=inputs.target_position_m,
                                   target_yaw_rad=inputs.target_yaw_rad, settings=settings,
                                   iteration_callback=progress, cancel=self.cancel_event)
            except ValueError as error:
                failed = PlanResultMsg(request_id=request_id, bag_path=str(bag.path),
                                       status=PlanPush.Response.STATUS_INVALID_REQUEST,
                                       message=f"invalid request: {error}")
                failed.header.stamp = ros_messages.time_msg(received_ns)
                failed.header.frame_id = self.frame_id
                self._emit(bag, "/cito/plan_result", failed, received_ns)
                response.bag_path = str(bag.path)
                return self._reject(response, failed.status, failed.message)

            stamp = self.get_clock().now().nanoseconds
            messages = ros_messages.plan_messages(result, request_id, stamp, self.frame_id, str(bag.path),
                                                  inputs.target_orientation, settings)
            self._emit(bag, "/cito/joint_trajectory", messages.trajectory, stamp)
            self._emit(bag, "/cito/object_path", messages.object_path, stamp)
            self._emit(bag, "/cito/plan_result", messages.result, stamp)
            for force, step_ns in zip(messages.contact_forces, messages.step_stamps_ns):
                self._emit(bag, "/cito/contact_forces", force, step_ns)
            for pose in messages.object_poses:
                self._emit(bag, "/cito/object_pose", pose, pose.header.stamp.sec * 10**9 + pose.header.stamp.nanosec)
            self.get_logger().info(f"plan {request_id}: {messages.result.message} ({result.metrics.solve_time_s:.2f} s, "
                                   f"bag {bag.path})")
            return ros_messages.fill_response(response, messages)
        except Exception as error:  # a bug must not kill the node; report it as a solver failure
            self.get_logger().error(f"plan {request_id} failed: {error!r}")
            response.bag_path = str(bag.path)
            return self._reject(response, PlanPush.Response.STATUS_SOLVER_FAILED, f"internal error: {error!r}")
        finally:
            bag.close()

    def _emit(self, bag: BagWriter, topic: str, message, stamp_ns: int) -> None:
        self.publishers_[topic].publish(message)
        bag.write(topic, message, stamp_ns)

    # ------------------------------------------------------------------ shutdown

    def stop(self, timeout_s: float) -> None:
        """Cancel a running solve and wait (bounded) until its bag is finished."""
        self.cancel_event.set()
        self._worker.shutdown(wait=False, cancel_futures=True)
        deadline = time.monotonic() + timeout_s
        while self._busy.locked() and time.monotonic() < deadline:
            time.sleep(0.02)


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv if argv is None else argv)
    if "--params-file" not in args:
        # the package's parameters first, so that the caller's -p overrides come after them
        default = ["--params-file", str(config_path("planner.yaml"))]
        if "--ros-args" in args:
            at = args.index("--ros-args") + 1
            args[at:at] = default
        else:
            args += ["--ros-args", *default]
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    try:
        node = PlannerNode()
    except (ValueError, KeyError) as error:
        print(f"cito-planner-node: bad parameters: {error}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    try:
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    finally:
        node.get_logger().info("shutting down")
        node.stop(timeout_s=4.0)
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
