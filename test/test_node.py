"""The planner node as ROS users meet it: a separate process, a client and subscribers in this
one, over Fast DDS on an isolated domain (localhost only). Bags read back with mcap_ros2 and
with the independent rosbags reader."""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest
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
from visualization_msgs.msg import Marker, MarkerArray

from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import Scene
from cito_ros.planner.plan import plan_push
from cito_ros.settings import load_settings

NODE = str(Path(sys.executable).parent / "cito-planner-node")
Q0_BETA_7 = [-math.pi / 12, -math.pi / 7, 0.0, 3 * math.pi / 7, -math.pi / 6, -2 * math.pi / 7, 0.0]
JOINTS = ["j0", "j1", "j2", "j3", "j4", "j5", "j6"]
TOPICS = {
    "/cito/plan_request": PlanRequest, "/cito/progress": SolverProgress, "/cito/joint_trajectory": JointTrajectory,
    "/cito/contact_forces": ContactForce, "/cito/object_pose": PoseStamped, "/cito/object_path": PathMsg,
    "/cito/plan_result": PlanResult, "/joint_states": JointState, "/cito/scene_markers": MarkerArray,
}
LATCHED = {"/cito/joint_trajectory", "/cito/object_path", "/cito/plan_result"}
HORIZON_STEPS = {round(h / load_settings().scene.timestep_s) for h in load_settings().round_horizons_s}


HOLD_STEPS = round(load_settings().tracking.hold_s / load_settings().scene.timestep_s)


def steps(response) -> int:
    """The simulation steps of a plan: one of the horizons its starts are solved at."""
    end = response.trajectory.points[-1].time_from_start
    count = round((end.sec + 1e-9 * end.nanosec) / load_settings().scene.timestep_s)
    assert count in HORIZON_STEPS
    return count


def start_node(domain: int, bag_directory: Path, *extra: str) -> subprocess.Popen:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.Popen([NODE, "--ros-args", "-p", f"node.bag_directory:={bag_directory}", *extra],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


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
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.client.service_is_ready():
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


@pytest.fixture(scope="module")
def domain():
    return 1 + os.getpid() % 100


@pytest.fixture(scope="module")
def node(domain, tmp_path_factory):
    bags = tmp_path_factory.mktemp("bags")
    process = start_node(domain, bags)
    yield process, bags
    process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        process.kill()


@pytest.fixture(scope="module")
def client(node, domain):
    c = Client(domain)
    assert c.wait_for_service(), "the planner service did not appear"
    yield c
    c.close()


@pytest.fixture(scope="module")
def plans(client):
    """One plan per contact model from q0(beta = 7), with the messages each published."""
    out = {}
    for model in ("cccm", "scm", "vscm"):
        for received in client.received.values():
            received.clear()
        response = client.call(request(model))
        wait_for_states(client, response)
        out[model] = (response, {t: list(v) for t, v in client.received.items()})
    return out


def wait_for_states(client: Client, response, timeout_s: float = 30.0) -> None:
    """Spin until every per-state message of the plan in `response` has arrived (or the timeout)."""
    n = steps(response) + HOLD_STEPS  # the horizon, then the arm held where the cube comes to rest
    expected = {"/joint_states": n + 1, "/cito/scene_markers": n + 1, "/cito/object_pose": n + 1,
                "/cito/contact_forces": n}
    deadline = time.monotonic() + timeout_s
    while any(len(client.received[t]) < count for t, count in expected.items()) and time.monotonic() < deadline:
        client.spin_for(0.05)
    client.spin_for(0.2)  # and nothing beyond them


@pytest.mark.parametrize("model", ["cccm", "scm", "vscm"])
def test_a_plan_for_each_contact_model(plans, model):
    response, _ = plans[model]
    assert response.success, response.message
    assert response.status == PlanPush.Response.STATUS_SUCCEEDED
    m = response.metrics
    assert m.success and m.position_error_m < 0.02 and m.solve_time_s > 0
    assert m.max_joint_speed_ratio <= 1.0 and m.rest_object_speed_m_s < 0.005
    assert len(response.trajectory.points) == steps(response) + 1 and len(response.contact_forces) == steps(response) + HOLD_STEPS
    assert response.trajectory.joint_names == JOINTS
    assert response.stages and sum(stage.iterations for stage in response.stages) == m.iterations
    assert Path(response.bag_path, "metadata.yaml").is_file()


def test_the_service_plan_is_the_library_plan(plans):
    """The node plans exactly what plan_push plans for the same problem, to the last bit."""
    response, _ = plans["scm"]
    library = plan_push("scm", start_q=np.array(Q0_BETA_7), target_position_m=np.array([1.09, 0.0, 0.1]))
    assert [list(p.positions) for p in response.trajectory.points] == library.trajectory.q.tolist()
    assert response.metrics.position_error_m == library.metrics.position_error_m


@pytest.mark.parametrize("model", ["cccm", "vscm"])
def test_every_topic_is_received(plans, model):
    response, received = plans[model]
    n_steps = steps(response) + HOLD_STEPS  # the horizon, then the arm held where the cube comes to rest
    assert len(received["/cito/plan_request"]) == 1 and received["/cito/plan_request"][0].contact_model == model
    assert len(received["/cito/progress"]) >= 1
    assert len(received["/cito/contact_forces"]) == n_steps and len(received["/cito/object_pose"]) == n_steps + 1
    assert len(received["/joint_states"]) == len(received["/cito/scene_markers"]) == n_steps + 1
    assert received["/cito/joint_trajectory"][-1].points[-1].positions.tolist() == \
        response.trajectory.points[-1].positions.tolist()
    assert len(received["/cito/object_path"][-1].poses) == n_steps + 1
    result = received["/cito/plan_result"][-1]
    # the last pose recorded is where the executed error is measured
    assert result.final_object_pose == received["/cito/object_pose"][-1].pose
    p, target = result.final_object_pose.position, result.target_pose.position
    assert math.dist((p.x, p.y, p.z), (target.x, target.y, target.z)) == pytest.approx(
        response.metrics.position_error_m, abs=1e-12)
    assert result.metrics == response.metrics and result.bag_path == response.bag_path
    assert result.stages == response.stages
    assert result.header.frame_id == "world"
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in received["/cito/contact_forces"]]
    assert stamps == sorted(stamps) and stamps[-1] - stamps[0] == pytest.approx((n_steps - 1) * 5e6, abs=2e6)


def test_late_subscriber_gets_the_last_plan(plans, domain):
    vscm_response, _ = plans["vscm"]
    late = Client(domain)
    try:
        deadline = time.monotonic() + 15
        while not (late.received["/cito/joint_trajectory"] and late.received["/cito/plan_result"]) \
                and time.monotonic() < deadline:
            late.spin_for(0.1)
        trajectory = late.received["/cito/joint_trajectory"]
        assert trajectory and trajectory[-1].points[-1].positions.tolist() == \
            vscm_response.trajectory.points[-1].positions.tolist()
        assert late.received["/cito/plan_result"][-1].bag_path == vscm_response.bag_path
    finally:
        late.close()


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


@pytest.mark.parametrize("reader", [read_with_mcap, read_with_rosbags])
@pytest.mark.parametrize("model", ["cccm", "vscm"])
def test_the_bag_matches_the_response(plans, reader, model):
    response, _ = plans[model]
    bag = reader(Path(response.bag_path))
    assert set(bag) == set(TOPICS)
    (_, trajectory), = bag["/cito/joint_trajectory"]
    assert len(trajectory.points) == len(response.trajectory.points)
    for stored, sent in zip(trajectory.points[::40], response.trajectory.points[::40]):
        np.testing.assert_array_equal(np.asarray(stored.positions), np.asarray(sent.positions))
        np.testing.assert_array_equal(np.asarray(stored.effort), np.asarray(sent.effort))
    forces = bag["/cito/contact_forces"]
    assert [m.gamma_n for _, m in forces] == [m.gamma_n for m in response.contact_forces]
    # stamped along the planned horizon and the hold: the log times are the message stamps, 5 ms apart
    log_times = np.array([t for t, _ in forces])
    np.testing.assert_array_equal(log_times, [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in forces])
    np.testing.assert_allclose(np.diff(log_times), 5e6, atol=1)
    assert len(bag["/cito/object_pose"]) == steps(response) + HOLD_STEPS + 1
    (_, result), = bag["/cito/plan_result"]
    # the bag ends where the cube comes to rest: its last pose is the one the executed error measures
    p, target = bag["/cito/object_pose"][-1][1].pose.position, result.target_pose.position
    assert math.dist((p.x, p.y, p.z), (target.x, target.y, target.z)) == pytest.approx(
        response.metrics.position_error_m, abs=1e-12)
    assert [stage.name for stage in result.stages] == [stage.name for stage in response.stages]
    assert result.metrics.position_error_m == response.metrics.position_error_m
    assert result.metrics.physical_inaccuracy_ns == response.metrics.physical_inaccuracy_ns
    assert result.status == response.status and result.bag_path == response.bag_path
    (_, planned), = bag["/cito/plan_request"]
    assert planned.contact_model == model and list(planned.start_state.position) == pytest.approx(Q0_BETA_7)
    assert len(bag["/cito/progress"]) >= response.metrics.iterations


@pytest.mark.parametrize("reader", [read_with_mcap, read_with_rosbags])
def test_the_bag_draws_the_arm_and_the_cube_at_every_step(plans, reader):
    """/joint_states and /cito/scene_markers at every state, the markers where MuJoCo puts the geoms."""
    response, _ = plans["vscm"]
    bag = reader(Path(response.bag_path))
    joints, markers, poses = bag["/joint_states"], bag["/cito/scene_markers"], bag["/cito/object_pose"]
    n_steps = steps(response)
    assert len(joints) == len(markers) == n_steps + HOLD_STEPS + 1
    assert [t for t, _ in joints] == [t for t, _ in markers] == [t for t, _ in poses]
    settings = load_settings()
    scene = Scene(contact_model("vscm", settings.contact_models), settings.scene)
    for t in (0, n_steps // 3, 2 * n_steps // 3, n_steps):
        q = np.asarray(joints[t][1].position)
        np.testing.assert_array_equal(q, response.trajectory.points[t].positions)
        data = scene.data_at(q)
        drawn = {(m.ns, m.id): m for m in markers[t][1].markers}
        assert all(m.header.frame_id == "world" for m in drawn.values())
        for geom in ("plate", "l4_geom", "l1_geom"):
            marker = drawn[(geom, 0)]
            p, o = marker.pose.position, marker.pose.orientation
            np.testing.assert_allclose([p.x, p.y, p.z], data.geom_xpos[scene.model.geom(geom).id], atol=1e-12)
            expected = np.empty(4)
            mujoco.mju_mat2Quat(expected, data.geom_xmat[scene.model.geom(geom).id])
            assert abs(np.dot([o.w, o.x, o.y, o.z], expected)) == pytest.approx(1.0, abs=1e-12)
        cube, pose = drawn[("object_geom", 0)].pose, poses[t][1].pose
        assert (cube.position.x, cube.position.y, cube.position.z) == pytest.approx(
            (pose.position.x, pose.position.y, pose.position.z), abs=1e-12)
    contact = [m for _, array in markers for m in array.markers if m.ns == "contact" and m.type == Marker.ARROW
               and m.action == Marker.ADD]
    assert contact, "the push's contact force is drawn"


BAD_REQUESTS = {
    "nan position": (request(x=float("nan")), "position contains NaN or Inf"),
    "inf orientation": (request(q=(0.0, 0.0, math.inf, 1.0)), "orientation contains NaN or Inf"),
    "zero quaternion": (request(q=(0.0, 0.0, 0.0, 0.0)), "zero quaternion"),
    "tilted target": (request(q=(0.3, 0.0, 0.0, 0.95)), "must be a rotation about z"),
    "unknown model": (request(model="rigid"), "unknown contact model 'rigid'"),
    "wrong joint names": (request(names=["a", "b", "c", "d", "e", "f", "g"]), "must name the joints"),
    "wrong sizes": (request(start=Q0_BETA_7[:5]), "has 7 names but 5 positions"),
    "joint limit": (request(start=[0, 0, 0, 9.0, 0, 0, 0]), "outside its range"),
    "off the table": (request(x=1.95), "off the table"),
    "beyond reach": (request(x=1.25, y=0.4), "beyond the 1.249 m the arm can push"),
    "negative time limit": (request(time_limit=-1.0), "time_limit_s must be a non-negative number"),
    "tilted object": (request(object_pose=(0.99, 0.0, 0.1, (0.0, 0.01, 0.0, 1.0))), "object_pose.orientation must be "
                      "a rotation about z"),
    "object off the table": (request(object_pose=(1.74, 0.0, 0.1, (0.0, 0.0, 0.0, 1.0))), "overhangs the table"),
    "object in the air": (request(object_pose=(0.99, 0.0, 0.4, (0.0, 0.0, 0.0, 1.0))), "must rest on the table"),
    "object inside the arm": (request(object_pose=(0.87, 0.0, 0.1, (0.0, 0.0, 0.0, 1.0))), "intersects the arm's"),
    "object out of reach": (request(x=1.25, y=0.5, object_pose=(1.2, 0.5, 0.1, (0.0, 0.0, 0.0, 1.0))),
                            "1.300 m from the arm base, beyond the 1.249 m the arm can push it from"),
    "unknown scene": (request(scene="moon"), "unknown scene 'moon'"),
    "scene path": (request(scene="/etc/passwd.yaml"), "scene must be the name of a scene"),
}


@pytest.mark.parametrize("case", sorted(BAD_REQUESTS))
def test_bad_input_is_rejected_and_the_node_stays_up(client, node, case):
    bad, message = BAD_REQUESTS[case]
    response = client.call(bad)
    assert not response.success
    assert response.status == PlanPush.Response.STATUS_INVALID_REQUEST
    assert message in response.message
    assert node[0].poll() is None  # still running


def test_next_valid_request_after_bad_ones_is_served(client, plans):
    client.call(request(x=float("nan")))
    # a non-unit quaternion is normalised, not rejected
    response = client.call(request(q=(0.0, 0.0, 0.0, 2.0)))
    assert response.success and response.status == PlanPush.Response.STATUS_SUCCEEDED
    earlier = [Path(plans[m][0].bag_path) for m in plans]
    assert all(read_with_rosbags(bag) for bag in earlier)  # nothing recorded before was lost


def test_two_concurrent_requests_one_is_busy(client):
    first, second = client.wait([client.call_async(request("cccm")), client.call_async(request("scm"))])
    statuses = sorted([first.status, second.status])
    assert statuses == [PlanPush.Response.STATUS_SUCCEEDED, PlanPush.Response.STATUS_BUSY]
    busy = first if first.status == PlanPush.Response.STATUS_BUSY else second
    assert "busy" in busy.message and not busy.success
