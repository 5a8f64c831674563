"""Pushes on the cube's side faces (cito_ros.planner.side_faces): the face a goal needs, the transit around the
cube, the refusals, and a side push planned and executed. Real MuJoCo, real solves."""
import re

import numpy as np
import pytest
from cito_msgs.srv import PlanPush

from cito_ros.planner import push_limits, side_faces
from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.planner.physical import side_start
from cito_ros.planner.plan import plan_push
from cito_ros.planner.stages import physical_twin
from cito_ros.ros.messages import response_status


def posed(settings, target, yaw=0.0, object_pose=None):
    return build_problem(settings, PushRequest("vscm", 5.0, None, target, yaw, None, object_pose))


@pytest.mark.parametrize("target, face", [((1.10, 0.02), side_faces.NEAR), ((0.99, 0.12), 1), ((0.99, -0.12), 3),
                                          ((0.85, 0.03), side_faces.FAR), ((1.05, 0.10), 1), ((0.99, 0.015), 0)])
def test_a_goal_needs_the_face_whose_inward_normal_is_nearest_the_push(settings, target, face):
    # the last within the position tolerance of the cube: the near face's pushes hold it there
    assert side_faces.face_needed((0.99, 0.0), 0.0, target, settings) == face


def test_a_turned_cube_is_pushed_sideways_on_the_face_that_is_then_beside_it(settings):
    # turned by a quarter turn, another of the cube's faces is the one towards the arm (scene.pushed_face): the count
    # starts there, and a push along +y is still on side face 1
    for yaw in (np.pi / 2, 0.3, -0.3):
        assert side_faces.face_needed((0.99, 0.0), yaw, (0.99, 0.12), settings) == 1
    assert side_faces.face_needed((0.99, 0.0), 0.0, (0.99, 0.12),
                                  settings.with_overrides({"stages.scripted.side_faces.enabled": False})) == 0


def test_the_side_transit_stays_clear_of_the_cube_until_the_plate_comes_onto_its_face(settings):
    side = settings.stages.scripted.side_faces
    settings = settings.with_overrides({"horizon_s": settings.round_horizon_s(side.horizon_scale),
                                        "control_period_s": side.control_period_s})
    for target, yaw, face in (((0.99, 0.12), 0.0, 1), ((1.03, 0.15), -0.2, 1), ((0.98, 0.05), 0.1, 1),
                              ((0.99, -0.12), 0.0, 3), ((1.03, -0.15), 0.2, 3)):
        planning = posed(settings, target, yaw)
        problem = physical_twin(planning.problem, planning.problem.cost)
        tilt, _ = side_faces.plate_tilt(problem.scene, problem.initial_state, problem.task, face, side,
                                        settings.stages.scripted.joint_margin_rad)
        path = side_faces.side_joint_path(problem, settings.stages.scripted, face, tilt)
        scene = problem.scene
        transit = int(side.transit_fraction * problem.simulator.n_steps)
        clearances = [scene.arm_clearance(scene.data_at(q), 0.1)[0] for q in path.q[:transit + 1:10]]
        assert min(clearances) > 0.01, target  # the plate ends standoff_m off the face, the arm clear all the way
        assert np.max(np.abs(path.qdot) / scene.velocity_limit) < 1.0
        # and off the table: along face 3's path the forearm lay on it (docs/planner.md: Side faces)
        lowest = min(side_faces._low_points(scene, scene.data_at(q))[2].min() for q in path.q[::10])
        assert lowest > 0.0, (target, lowest)


def test_a_pull_is_refused_with_the_reason_the_far_face_beyond_the_plate_or_not_yet_pushed(settings):
    pull_m = push_limits.pull_reach_m(posed(settings, (1.10, 0.0)).scene)
    # the plate reaches over the cube to its far face near the arm, not over the cube where the scene puts it
    assert 0.7 < pull_m < 0.99 - 0.05
    beyond = re.escape(f"only a pull on its far face does, and the plate can press that face, with the arm clear of "
                       f"the object, only for an object within {pull_m:.3f} m of the arm base; this one is 0.990 m out")
    with pytest.raises(ValueError, match=r"10.0 cm behind the object's pushed face .* " + beyond):
        posed(settings, (0.89, 0.0))
    with pytest.raises(ValueError, match=r"10.0 cm behind the object's pushed face .* only a pull on its far face "
                                         r"does, which this planner does not push on yet"):
        posed(settings, (0.70, 0.0), object_pose=((0.80, 0.0), 0.0))


def test_the_side_starts_come_first_where_the_plate_reaches_the_side_face_and_the_near_faces_follow(settings):
    beside = PushRequest("vscm", 5.0, None, (0.99, 0.12), 0.0)
    assert side_start(settings, beside).face == 1 and side_start(settings, beside).reaches
    # the cube 11 cm further out: its side faces are beyond the tilted plate, and only the near face is tried
    out = PushRequest("vscm", 5.0, None, (1.10, 0.12), 0.0, None, ((1.10, 0.0), 0.0))
    problem = build_problem(settings, out)
    tilt, short_m = side_faces.plate_tilt(problem.scene, problem.initial_state, problem.task, 1,
                                          settings.stages.scripted.side_faces, settings.stages.scripted.joint_margin_rad)
    assert short_m > settings.stages.scripted.side_faces.reach_tolerance_m
    assert tilt == settings.stages.scripted.side_faces.tilts_rad[-1]
    start = side_start(settings, out)
    assert start.face == 1 and not start.reaches and start.short_m == pytest.approx(short_m)
    # the other side face, where `faces` has it
    other = PushRequest("vscm", 5.0, None, (0.99, -0.12), 0.0)
    assert side_start(settings, other).face == 3
    assert side_start(settings.with_overrides({"stages.scripted.side_faces.faces": [1]}), other) is None


def test_an_answer_that_misses_a_goal_beside_the_cube_says_the_side_face_is_beyond_the_plate(settings):
    """The cube 1.10 m out, the goal 12 cm beside it: the side face's contact is 11 cm further out than the plate
    reaches tilted, the near face's pushes cannot move the cube sideways, and the answer says so."""
    out = PushRequest("vscm", 5.0, None, (1.10, 0.12), 0.0, None, ((1.10, 0.0), 0.0))
    result = plan_push("vscm", 5.0, settings=settings.with_overrides({"solver.time_limit_s": 2.0}),
                       target_position_m=np.array(out.target_position_m), object_pose=out.object_pose)
    assert not result.metrics.success
    assert re.search(r"needs the object's side face 1 .* the plate falls \d+\.\d cm short", result.note), result.note
    assert not any(record.name.startswith("side face") for record in result.stages)
    status, message = response_status(result, settings, 0.0)
    assert status == PlanPush.Response.STATUS_TASK_NOT_ACHIEVED and message.endswith(result.note)
    assert result.summary()["note"] == result.note


@pytest.mark.parametrize("target, yaw", [((0.99, 0.15), 0.0), ((1.03, -0.15), 0.2)])
def test_a_side_push_brings_the_cube_beside_it_to_the_goal_executed_without_the_virtual_force(settings, target, yaw):
    # beside the cube either way, where every near-face push ran to the time limit and missed (docs/results.md)
    result = plan_push("vscm", 5.0, settings=settings, target_position_m=np.array(target), target_yaw_rad=yaw)
    assert result.metrics.success, result.metrics
    assert result.metrics.position_error_m < settings.task.success_position_error_m
    # the second goal, 4 cm along the near face's normal as well, in two pushes: across it on the side face first
    assert re.match(r"(push 1: )?side face", result.stages[0].name), result.stages[0].name
