"""The node's bags: complete, whole and the same as what was answered and published, read back with mcap_ros2 and
with the independent rosbags reader; written after the answer, none lost when requests follow without pause."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
from visualization_msgs.msg import Marker

from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import Scene
from cito_ros.settings import load_settings

from node_harness import (
    HOLD_STEPS,
    Q0_BETA_7,
    TOPICS,
    read_with_mcap,
    read_with_rosbags,
    recorded_counts,
    request,
    steps,
    wait_for_bag,
)


@pytest.mark.parametrize("reader", [read_with_mcap, read_with_rosbags])
@pytest.mark.parametrize("model", ["cccm", "vscm"])
def test_the_bag_matches_the_response(plans, reader, model):
    response, _ = plans[model]
    bag = reader(Path(response.bag_path))
    assert set(bag) == set(TOPICS)
    assert {topic: len(messages) for topic, messages in bag.items() if topic != "/cito/progress"} == \
        recorded_counts(response)
    # the per-state messages are those the subscribers received, field for field
    _, received = plans[model]
    for topic, fields in (("/joint_states", lambda m: [*m.position, *m.velocity, *m.effort]),
                          ("/cito/object_pose", lambda m: [m.pose.position.x, m.pose.position.y, m.pose.position.z,
                                                           m.pose.orientation.w, m.pose.orientation.z]),
                          ("/cito/contact_forces", lambda m: [m.gamma_n, m.signed_distance_m, m.contact_count,
                                                              m.contact_wrench.force.x, m.contact_point.z])):
        assert [fields(m) for _, m in bag[topic]] == [fields(m) for m in received[topic]], topic
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
    # the contact force as an arrow from the contact point, shown while the arm touches the cube, transparent else
    shown = 0
    for (_, array), (_, force) in zip(markers, bag["/cito/contact_forces"]):  # one force per step
        arrow, = (m for m in array.markers if (m.ns, m.id) == ("contact", 1) and m.type == Marker.ARROW)
        assert arrow.color.a == (1.0 if force.contact_count > 0 else 0.0)
        if force.contact_count > 0:
            shown += 1
            tail, tip = ([p.x, p.y, p.z] for p in arrow.points)
            point = [force.contact_point.x, force.contact_point.y, force.contact_point.z]
            wrench = force.contact_wrench.force
            np.testing.assert_allclose(tail, point, atol=1e-12)
            np.testing.assert_allclose(tip, np.add(point, 0.02 * np.array([wrench.x, wrench.y, wrench.z])), atol=1e-12)
    assert shown, "the push's contact force is drawn"


def test_requests_without_pause_lose_no_bag(client):
    """Each answer comes before its bag is written; the next request starts at once; every bag is finished
    whole, in the order of the requests."""
    responses = [client.call(request(model, x=x)) for model, x in (("scm", 1.07), ("vscm", 1.08), ("cccm", 1.06))]
    assert all(r.success for r in responses), [r.message for r in responses]
    for response in responses:
        assert wait_for_bag(Path(response.bag_path)), response.bag_path
        bag = read_with_rosbags(Path(response.bag_path))
        counts = {topic: len(messages) for topic, messages in bag.items() if topic != "/cito/progress"}
        assert counts == recorded_counts(response) and len(bag["/cito/progress"]) >= 1


