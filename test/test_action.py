"""The plan-push action and the node's parameters as a robot stack meets them: the node in its own
process, an rclpy ActionClient and parameter client in this one, over Fast DDS on an isolated
domain. Bags read back with mcap_ros2 and rosbags."""
from __future__ import annotations

import math
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from action_msgs.msg import GoalStatus
from cito_msgs.action import PlanPush as PlanPushAction
from cito_msgs.srv import PlanPush
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.action import ActionClient

from node_harness import LONG_GOAL, Client, read_with_mcap, read_with_rosbags, request, start_node, wait_for_bag

STEADY_GOAL = dict(start=None, model="vscm", x=1.14)  # the main job's: 15 cm from q0(beta = 5), inside the steady reach


class ActionUser(Client):
    """A Client (service, subscribers) with an action client and the node's set_parameters service."""

    def __init__(self, domain: int):
        super().__init__(domain)
        self.action = ActionClient(self.node, PlanPushAction, "/cito/plan_push")
        self.parameters = self.node.create_client(SetParameters, "/cito_planner/set_parameters")
        self.feedback: list = []

    def send(self, **fields):
        """Send a goal; the goal handle (accepted or not)."""
        goal = request(r=PlanPushAction.Goal(), **fields)
        return self.wait([self.action.send_goal_async(goal, feedback_callback=lambda m: self.feedback.append(
            m.feedback))], 30.0)[0]

    def result(self, handle, timeout_s: float = 180.0):
        return self.wait([handle.get_result_async()], timeout_s)[0]

    def wait_for_feedback(self, count: int, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while len(self.feedback) < count and time.monotonic() < deadline:
            self.spin_for(0.05)
        assert len(self.feedback) >= count, "no feedback from the running goal"

    def set_parameter(self, name: str, value) -> tuple[bool, str]:
        if isinstance(value, str):
            v = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
        elif isinstance(value, int):
            v = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=value)
        else:
            v = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(value))
        answer = self.wait([self.parameters.call_async(SetParameters.Request(
            parameters=[Parameter(name=name, value=v)]))], 30.0)[0]
        return answer.results[0].successful, answer.results[0].reason


@pytest.fixture(scope="module")
def user(tmp_path_factory):
    domain = 201 + os.getpid() % 30
    bags = tmp_path_factory.mktemp("action_bags")
    process = start_node(domain, bags)
    client = ActionUser(domain)
    try:
        assert client.action.wait_for_server(timeout_sec=30.0), "the plan_push action did not appear"
        assert client.wait_for_service()
        yield client, process
    finally:
        client.close()
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()


def test_a_goal_gets_feedback_and_a_successful_result(user):
    client, _ = user
    client.feedback.clear()
    handle = client.send(**STEADY_GOAL)  # the scripted start's physical stages iterate
    assert handle.accepted
    answer = client.result(handle)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED
    result = answer.result
    assert result.success and result.status == PlanPush.Response.STATUS_SUCCEEDED, result.message
    assert result.metrics.position_error_m < 0.02 and len(result.trajectory.points) > 1
    client.spin_for(0.5)
    feedback = client.feedback
    assert 3 <= len(feedback) <= result.metrics.iterations + len({f.stage for f in feedback})  # one per iteration
    assert {f.stage for f in feedback} <= {stage.name for stage in result.stages}  # each iteration's stage
    assert all(f.elapsed_s > 0 and math.isfinite(f.cost) for f in feedback)
    # the best errors so far only shrink; the executed one is there once a stage runs without the virtual force
    executed = [f.best_executed_position_error_m for f in feedback if math.isfinite(f.best_executed_position_error_m)]
    assert executed and executed == sorted(executed, reverse=True) and executed[-1] < 0.02
    # the planned one (with the virtual force) only once a discovery has run; NaN before
    discovered = any("discovery" in f.stage for f in feedback)
    assert math.isfinite(feedback[-1].best_planned_position_error_m) == discovered


def test_a_busy_node_rejects_a_second_goal_and_a_cancelled_goal_returns_its_best_plan(user):
    client, process = user
    client.feedback.clear()
    running = client.send(**LONG_GOAL)
    assert running.accepted
    client.wait_for_feedback(3)
    second = client.send(model="scm")
    assert not second.accepted
    busy = client.call(request("scm"))
    assert busy.status == PlanPush.Response.STATUS_BUSY and "busy" in busy.message
    cancelling = client.wait([running.cancel_goal_async()], 30.0)[0]
    assert len(cancelling.goals_canceling) == 1
    answer = client.result(running, 60.0)
    assert answer.status == GoalStatus.STATUS_CANCELED
    result = answer.result
    assert result.status == PlanPush.Response.STATUS_CANCELLED and not result.success
    assert result.metrics.status == "cancelled" and len(result.trajectory.points) > 1  # the best plan so far
    assert wait_for_bag(Path(result.bag_path))  # the cancelled plan's bag is finished too
    for reader in (read_with_mcap, read_with_rosbags):
        (_, recorded), = reader(Path(result.bag_path))["/cito/plan_result"]
        assert recorded.status == PlanPush.Response.STATUS_CANCELLED
    assert process.poll() is None
    again = client.send(model="scm")  # and the node serves the next goal
    assert again.accepted and client.result(again).result.success


def test_a_moved_and_rotated_cube_is_pushed_to_its_goal(user):
    client, _ = user
    yaw = 0.3
    quaternion = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    handle = client.send(model="vscm", x=1.09, y=0.05, q=quaternion, object_pose=(0.99, 0.05, 0.1, quaternion))
    answer = client.result(handle)
    result = answer.result
    assert answer.status == GoalStatus.STATUS_SUCCEEDED and result.success, result.message
    assert result.metrics.position_error_m < 0.02 and result.metrics.orientation_error_rad < 0.15
    assert wait_for_bag(Path(result.bag_path))
    (_, planned), = read_with_mcap(Path(result.bag_path))["/cito/plan_request"]
    assert (planned.object_pose.position.x, planned.object_pose.position.y) == (0.99, 0.05)
    assert planned.object_pose.orientation.z == pytest.approx(math.sin(yaw / 2))
    markers = read_with_rosbags(Path(result.bag_path))["/cito/scene_markers"]
    cube = next(m for m in markers[0][1].markers if m.ns == "object_geom")
    assert (cube.pose.position.x, cube.pose.position.y) == pytest.approx((0.99, 0.05), abs=1e-3)


def test_a_bad_goal_is_refused_with_its_reason(user):
    client, process = user
    handle = client.send(object_pose=(0.87, 0.0, 0.1, (0.0, 0.0, 0.0, 1.0)))
    answer = client.result(handle, 30.0)
    assert answer.status == GoalStatus.STATUS_ABORTED
    assert answer.result.status == PlanPush.Response.STATUS_INVALID_REQUEST
    assert "intersects the arm's" in answer.result.message
    assert process.poll() is None


def test_a_parameter_change_applies_to_the_next_plan_and_bad_values_are_refused(user):
    client, _ = user
    assert client.set_parameter("node.default_contact_model", "rigid") == (
        False, "node.default_contact_model must be one of ['cccm', 'scm', 'vscm'], got 'rigid'")
    ok, reason = client.set_parameter("solver.time_limit_s", -1.0)
    assert not ok and "solver.time_limit_s" in reason
    ok, reason = client.set_parameter("beta", 6.0)
    assert not ok and "read-only" in reason
    ok, reason = client.set_parameter("tracking.reference_offsets", -1)  # the descriptor's range
    assert not ok and "tracking.reference_offsets out of range" in reason
    assert client.set_parameter("tracking.reference_offsets", 4) == (True, "")  # sturdier plans, from the next on
    assert client.set_parameter("tracking.reference_offsets", 0) == (True, "")
    assert client.set_parameter("node.default_contact_model", "cccm") == (True, "")
    try:
        handle = client.send(model="")
        result = client.result(handle).result
        assert wait_for_bag(Path(result.bag_path))
        (_, planned), = read_with_mcap(Path(result.bag_path))["/cito/plan_request"]
        assert planned.contact_model == "cccm"
        assert client.set_parameter("solver.time_limit_s", 0.5)[0]
        handle = client.send(**{**LONG_GOAL, "model": "scm"})
        result = client.result(handle).result
        assert result.metrics.status == "time_limit" and result.metrics.solve_time_s < 5.0
    finally:
        client.set_parameter("node.default_contact_model", "vscm")
        client.set_parameter("solver.time_limit_s", 60.0)


@pytest.mark.parametrize("override, message", [
    ("solver.maxiter:=10", "solver.maxiter: unknown parameter"),
    ("solver.time_limit_s:=-3.0", "solver.time_limit_s"),
    ("node.default_contact_model:=rigid", "must be one of"),
])
def test_a_bad_parameter_stops_the_node_with_its_name(tmp_path, override, message):
    log = tmp_path / "node.log"
    process = start_node(201 + os.getpid() % 30, tmp_path, override, log=log)  # fails before it joins the graph
    process.wait(timeout=60)
    output = log.read_text()
    assert process.returncode == 2 and message in output, output
