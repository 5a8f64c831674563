"""What the node tests share: the node in its own process, a client and subscribers to every topic in this one,
over Fast DDS on an isolated domain (localhost only), the plan requests, and both bag readers."""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import subprocess
import time
from pathlib import Path

import rclpy
from cito_msgs.msg import ContactForce, PlanRequest, PlanResult, SolverProgress
from cito_msgs.srv import PlanPush
from geometry_msgs.msg import PoseStamped
from mcap_ros2.reader import read_ros2_messages
from nav_msgs.msg import Path as PathMsg
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from cito_ros.ros.sim_session import spawn
from cito_ros.settings import load_settings

Q0_BETA_7 = [-math.pi / 12, -math.pi / 7, 0.0, 3 * math.pi / 7, -math.pi / 6, -2 * math.pi / 7, 0.0]
JOINTS = ["j0", "j1", "j2", "j3", "j4", "j5", "j6"]
# a push 62 degrees off the cube's pushed face, 24 cm away, that no push on that face reaches (it ran to the time
# limit 11 and 24 cm off): every start runs, for tens of seconds (request(**LONG_GOAL))
LONG_GOAL = dict(start=None, model="vscm", x=1.10, y=-0.21, q=(0.0, 0.0, math.sin(-0.245), math.cos(-0.245)))
TOPICS = {
    "/cito/plan_request": PlanRequest, "/cito/progress": SolverProgress, "/cito/joint_trajectory": JointTrajectory,
    "/cito/contact_forces": ContactForce, "/cito/object_pose": PoseStamped, "/cito/object_path": PathMsg,
    "/cito/plan_result": PlanResult, "/joint_states": JointState, "/cito/scene_markers": MarkerArray,
}
LATCHED = {"/cito/joint_trajectory", "/cito/object_path", "/cito/plan_result"}
HORIZON_STEPS = {round(h / load_settings().scene.timestep_s) for h in load_settings().round_horizons_s}


SERVICE_MATCH_S = 1.0  # after a service is seen, for the server to match this client's response reader
LOG_DIRECTORY = Path()  # the session's, under pytest's temporary directory (conftest.log_directory)
_LOG_NUMBERS = itertools.count()
HOLD_STEPS = round(load_settings().tracking.hold_s / load_settings().scene.timestep_s)


def steps(response) -> int:
    """The simulation steps of a plan: one of the horizons its starts are solved at."""
    end = response.trajectory.points[-1].time_from_start
    count = round((end.sec + 1e-9 * end.nanosec) / load_settings().scene.timestep_s)
    assert count in HORIZON_STEPS
    return count


def launch(program: str, domain: int, *parameters: str, log: Path | None = None) -> subprocess.Popen:
    """spawn() with the program's output in `log`, or in a new file of LOG_DIRECTORY: a failing test shows the
    output written while it ran (conftest.pytest_runtest_makereport)."""
    return spawn(program, domain, *parameters, log=log or LOG_DIRECTORY / f"{program}.{next(_LOG_NUMBERS)}.log")


def logs_written_since(epoch_s: float) -> list[Path]:
    return sorted((p for p in LOG_DIRECTORY.glob("*.log") if p.stat().st_mtime >= epoch_s),
                  key=lambda p: p.stat().st_mtime)


def start_node(domain: int, bag_directory: Path, *parameters: str, log: Path | None = None) -> subprocess.Popen:
    """A planner node on `domain`, with -p parameters after its bag directory."""
    return launch("cito-planner-node", domain, f"node.bag_directory:={bag_directory}", *parameters, log=log)


@contextlib.contextmanager
def node_process(domain: int, bag_directory: Path):
    """A planner node in its own process and a Client of it, once its service is up; the node killed on the way out
    if it still runs."""
    process = start_node(domain, bag_directory)
    client = Client(domain)
    try:
        assert client.wait_for_service(), "the planner service did not appear"
        yield process, client
    finally:
        if process.poll() is None:
            process.kill()
        client.close()


class Client:
    """A client and subscribers to every topic, in this process, on `domain`."""

    def __init__(self, domain: int):
        os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node("test_client", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.client = self.node.create_client(PlanPush, "/cito/plan_push")
        self.received: dict[str, list] = {topic: [] for topic in TOPICS}
        for topic, cls in TOPICS.items():
            qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL if topic in LATCHED else DurabilityPolicy.VOLATILE)
            self.node.create_subscription(cls, topic, lambda m, t=topic: self.received[t].append(m), qos)

    def wait_for_service(self, timeout_s: float = 30.0) -> bool:
        """Whether the service is up; and then a moment more: this client sees the node's request reader before the
        node has matched this client's response reader, and Fast DDS drops a response to a reader it has not matched
        within 100 ms ("failed to send response (timeout)": a clean clone's test_sigterm_during_a_solve, 2026-11-30)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.client.service_is_ready():
                self.spin_for(SERVICE_MATCH_S)
                return True
            self.executor.spin_once(timeout_sec=0.1)
        return False

    def call_async(self, request: PlanPush.Request):
        return self.client.call_async(request)

    def wait(self, futures, timeout_s: float = 180.0):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not all(f.done() for f in futures):
            self.executor.spin_once(timeout_sec=0.05)
        assert all(f.done() for f in futures), "no answer from the node"
        return [f.result() for f in futures]

    def call(self, request: PlanPush.Request, timeout_s: float = 180.0) -> PlanPush.Response:
        return self.wait([self.call_async(request)], timeout_s)[0]

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def request(model: str = "scm", x: float = 1.09, y: float = 0.0, z: float = 0.1, q=(0.0, 0.0, 0.0, 1.0),
            start=Q0_BETA_7, names=JOINTS, time_limit: float = 0.0, object_pose=None, scene: str = "",
            r=None) -> PlanPush.Request:
    """A service request (or, given r, an action goal) to push the cube to (x, y) from q0(beta = 7);
    object_pose: (x, y, z, (qx, qy, qz, qw)) where the cube is now."""
    r = PlanPush.Request() if r is None else r
    r.target_pose.position.x, r.target_pose.position.y, r.target_pose.position.z = x, y, z
    r.target_pose.orientation.x, r.target_pose.orientation.y, r.target_pose.orientation.z, r.target_pose.orientation.w = q
    r.contact_model = model
    if start is not None:
        r.start_state.name = list(names)
        r.start_state.position = [float(v) for v in start]
    r.time_limit_s = time_limit
    if object_pose is not None:
        p, o = r.object_pose.position, r.object_pose.orientation
        (p.x, p.y, p.z), (o.x, o.y, o.z, o.w) = object_pose[:3], object_pose[3]
    r.scene = scene
    return r


def wait_for_bag(path: Path, timeout_s: float = 30.0) -> bool:
    """Whether the bag at `path` is complete (under its final name) within timeout_s; it is `.partial` until."""
    deadline = time.monotonic() + timeout_s
    while not (path / "metadata.yaml").is_file() and time.monotonic() < deadline:
        time.sleep(0.02)
    return (path / "metadata.yaml").is_file() and not path.with_name(path.name + ".partial").exists()


def recorded_counts(response) -> dict[str, int]:
    """The messages a plan's bag holds per topic: the per-state topics over the horizon and the hold."""
    n = steps(response) + HOLD_STEPS
    return {"/cito/plan_request": 1, "/cito/joint_trajectory": 1, "/cito/object_path": 1, "/cito/plan_result": 1,
            "/cito/contact_forces": n, "/cito/object_pose": n + 1, "/joint_states": n + 1,
            "/cito/scene_markers": n + 1}


def wait_for_states(client: Client, response, timeout_s: float = 30.0) -> None:
    """Spin until every per-state message of the plan in `response` has arrived (or the timeout)."""
    n = steps(response) + HOLD_STEPS  # the horizon, then the arm held where the cube comes to rest
    expected = {"/joint_states": n + 1, "/cito/scene_markers": n + 1, "/cito/object_pose": n + 1,
                "/cito/contact_forces": n}
    deadline = time.monotonic() + timeout_s
    while any(len(client.received[t]) < count for t, count in expected.items()) and time.monotonic() < deadline:
        client.spin_for(0.05)
    client.spin_for(0.2)  # and nothing beyond them


def read_with_mcap(bag: Path) -> dict[str, list]:
    messages: dict[str, list] = {}
    for entry in read_ros2_messages(str(next(bag.glob("*.mcap")))):
        messages.setdefault(entry.channel.topic, []).append((entry.log_time_ns, entry.ros_msg))
    return messages


def read_with_rosbags(bag: Path) -> dict[str, list]:
    store = get_typestore(Stores.ROS2_JAZZY)
    messages: dict[str, list] = {}
    with RosbagsReader(bag) as reader:
        for connection in reader.connections:
            if connection.msgtype.startswith("cito_msgs/"):
                store.register(get_types_from_msg(connection.msgdef.data, connection.msgtype))
        for connection, timestamp, raw in reader.messages():
            messages.setdefault(connection.topic, []).append(
                (timestamp, store.deserialize_cdr(raw, connection.msgtype)))
    return messages


