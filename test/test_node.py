"""The planner node as ROS users meet it: a separate process, a client and subscribers in this
one, over Fast DDS on an isolated domain (localhost only)."""

from __future__ import annotations

import math
import re
import time
from pathlib import Path

import numpy as np
import pytest
from cito_msgs.srv import PlanPush

from cito_ros.planner.plan import plan_push

from node_harness import (
    HOLD_STEPS,
    JOINTS,
    Q0_BETA_7,
    Client,
    read_with_rosbags,
    request,
    steps,
)


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
    "pull back": (request(x=0.89), "target is 10.0 cm behind the object's pushed face"),
    "turn in place": (request(x=0.99, q=(0.0, 0.0, math.sin(0.3), math.cos(0.3))),
                      "target turns the object by 0.60 rad over a 1.2 cm push (aimed 1.2 cm past the goal)"),
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


def test_a_goal_yaw_a_quarter_turn_round_is_planned_as_the_same_cube_and_the_answer_says_so(client):
    """The cube turned by pi/2 is the same cube: the push to (1.09, 0) with yaw pi/2 is planned to yaw 0, and
    succeeds without turning the cube; the message names the yaw it aimed at."""
    half = math.sqrt(0.5)
    response = client.call(request("vscm", q=(0.0, 0.0, half, half)))
    assert response.success, response.message
    assert re.search(r"the goal yaw 1.571 rad was taken as -?0.000 rad, 1 quarter turn\(s\) clockwise from it",
                     response.message), response.message
    assert response.metrics.orientation_error_rad < 0.15


def test_two_concurrent_requests_one_is_busy(client):
    first, second = client.wait([client.call_async(request("cccm")), client.call_async(request("scm"))])
    statuses = sorted([first.status, second.status])
    assert statuses == [PlanPush.Response.STATUS_SUCCEEDED, PlanPush.Response.STATUS_BUSY]
    busy = first if first.status == PlanPush.Response.STATUS_BUSY else second
    assert "busy" in busy.message and not busy.success
