"""Plans sturdy where the cube is not the model's: with tracking.world_*_scales a plan ends the search only if
the joint trajectory controller also brings the cube to the goal where its friction and mass are scaled. Real
MuJoCo."""
import math
import os

import mujoco
import numpy as np
import pytest

from cito_ros.model.scene import start_configuration
from cito_ros.model.simulator import Simulator
from cito_ros.planner import tracking
from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.planner.candidates import Executed, execute
from cito_ros.planner.plan import plan_push
from cito_ros.planner.results import world_ratio
from cito_ros.planner.scripted import scripted_torques
from cito_ros.planner.stages import physical_twin

NOMINAL = tracking.WorldErrors(0.0, 0.0, 0.0)
AT_GOAL = dict(position_error_m=0.01, orientation_error_rad=0.05, max_joint_speed_ratio=0.9,
               joint_range_excess_rad=0.0, rest_object_speed_m_s=0.0, tracked_position_error_m=0.012)


def with_worlds(settings, friction=(1.0, 0.5, 1.5), mass=(1.0, 0.5, 2.0)):
    return settings.with_overrides({"tracking.world_friction_scales": friction, "tracking.world_mass_scales": mass})


def test_with_world_scales_a_plan_succeeds_only_if_tracked_to_the_goal_in_every_world(settings):
    settings = with_worlds(settings)
    sturdy = Executed(**AT_GOAL, world_tracked_errors=((0.015, 0.1, 0.0), (0.019, 0.14, 0.05)))
    slides_off = Executed(**AT_GOAL, world_tracked_errors=((0.015, 0.1, 0.0), (0.05, 0.1, 0.0)))  # overshoots on ice
    turns_off = Executed(**AT_GOAL, world_tracked_errors=((0.015, 0.16, 0.0), (0.01, 0.1, 0.0)))
    warned = Executed(**AT_GOAL, world_tracked_errors=((math.nan, math.nan, math.nan), (0.01, 0.1, 0.0)))
    assert Executed.succeeds(sturdy.rank(settings))
    assert not any(Executed.succeeds(e.rank(settings)) for e in (slides_off, turns_off, warned))
    # where none is sturdy, the one whose worst world is nearest the goal ranks first
    assert sturdy.rank(settings) < turns_off.rank(settings) < slides_off.rank(settings) < warned.rank(settings)
    # tracked in the model's own world alone (the default), the nominal tracking decides
    assert Executed.succeeds(Executed(**AT_GOAL).rank(settings))


def test_a_plan_that_rocks_the_cube_past_the_tilt_limit_in_a_world_is_not_sturdy_there(settings):
    """At the goal at rest in every world, but tilted 0.2 rad on the way in one (tracking.world_max_tilt_rad 0.1):
    not sturdy, ranked by its tilt's share of the limit; with the tilt not judged (0), sturdy."""
    settings = with_worlds(settings)
    upright = Executed(**AT_GOAL, world_tracked_errors=((0.015, 0.1, 0.0), (0.019, 0.14, 0.09)))
    rocked = Executed(**AT_GOAL, world_tracked_errors=((0.015, 0.1, 0.0), (0.01, 0.05, 0.2)))
    assert settings.tracking.world_max_tilt_rad == 0.1
    assert Executed.succeeds(upright.rank(settings)) and not Executed.succeeds(rocked.rank(settings))
    assert rocked.worst_world(settings) == pytest.approx(2.0) and upright.rank(settings) < rocked.rank(settings)
    assert Executed.succeeds(rocked.rank(settings.with_overrides({"tracking.world_max_tilt_rad": 0.0})))


def test_a_plan_is_tracked_in_each_scaled_world_and_the_cube_ends_elsewhere_there(settings):
    settings = with_worlds(settings)
    problem = build_problem(settings, PushRequest("vscm", 7)).problem
    executor = physical_twin(problem, problem.cost)
    torques = scripted_torques(executor, settings.stages.scripted, settings.tracking)
    executed = execute(executor, torques, settings.tracking)
    assert len(executed.world_tracked_errors) == 3
    # the model's own pair is the nominal tracking, position and orientation within the tolerances
    assert executed.world_tracked_errors[0][0] == executed.tracked_position_error_m
    positions = [p for p, _, _ in executed.world_tracked_errors]
    assert all(math.isfinite(p) for p in positions) and len(set(positions)) == 3
    # the nominal's tilt: the cube's top against world z over the tracking and the hold, from MuJoCo's rotation
    motions = executed.motions
    rotation = np.empty(9)
    tilts = []
    for quaternion in np.vstack([motions.tracked.object_quaternion, motions.tracked_rest.object_quaternion]):
        mujoco.mju_quat2Mat(rotation, quaternion / np.linalg.norm(quaternion))
        tilts.append(math.acos(min(1.0, rotation[8])))
    assert executed.world_tracked_errors[0].tilt_rad == pytest.approx(max(tilts), abs=1e-9) and max(tilts) > 0
    world = executor.simulator.in_world(0.5, 2.0)
    model, scaled = executor.scene.model, world.scene.model
    body = model.geom_bodyid[executor.scene.object_geom_id]
    assert scaled.body_mass[body] == pytest.approx(2.0 * model.body_mass[body])
    cube = executor.scene.object_geom_id
    pairs = (model.pair_geom1 == cube) | (model.pair_geom2 == cube)
    assert pairs.any() and np.allclose(scaled.pair_friction[pairs, :2], 0.5 * model.pair_friction[pairs, :2])
    assert world is executor.simulator.in_world(0.5, 2.0) and world.nstate == executor.simulator.nstate


def test_the_worlds_scenes_are_shared_by_simulators_of_one_scene_and_tracking_stops_where_told(settings):
    """The executor's replans build a simulator per push length: its worlds are compiled once per scene. A caller
    that rejects a plan at the first world over its bound (a replan) gets the same first worlds, and no more."""
    settings = with_worlds(settings, (1.0, 0.5, 1.5, 0.5), (1.0, 0.5, 2.0, 2.0))
    problem = build_problem(settings, PushRequest("vscm", 7)).problem
    executor = physical_twin(problem, problem.cost)
    shorter = Simulator(executor.scene, executor.simulator.horizon_s / 2, executor.simulator.control_period_s)
    assert shorter.in_world(0.5, 2.0).scene is executor.simulator.in_world(0.5, 2.0).scene
    reference = tracking.track(executor.simulator, executor.initial_state,
                               executor.trajectory(executor.with_torques(
                                   scripted_torques(executor, settings.stages.scripted, settings.tracking))),
                               settings.tracking)
    every = tracking.world_errors(executor.simulator, executor.initial_state, reference, settings.tracking,
                                  executor.task, NOMINAL)
    seen = []
    first_two = tracking.world_errors(executor.simulator, executor.initial_state, reference, settings.tracking,
                                      executor.task, NOMINAL, stop=lambda error: seen.append(error) or len(seen) == 2)
    assert len(every) == 4 and first_two == every[:3] and seen == every[1:3]


def test_scales_that_do_not_pair_up_are_refused(settings):
    with pytest.raises(ValueError, match="must pair up"):
        with_worlds(settings, (1.0, 0.5), (1.0,))


def test_a_plan_says_whether_the_controller_brings_the_cube_to_the_goal_in_every_world_it_was_checked_in(settings):
    """PlanResult.sturdy: the returned plan tracked to within the tolerances in the model and each scaled world,
    as executing it there again finds; never sturdy where no other world was asked for."""
    push = dict(start_q=start_configuration(7), target_position_m=np.array([1.09, 0.03]), target_yaw_rad=0.1)
    assert not plan_push("vscm", settings=settings, **push).sturdy
    for tolerance_m in (0.02, 1e-5):  # a tolerance no plan meets: not sturdy
        checked = with_worlds(settings).with_overrides({"task.success_position_error_m": tolerance_m,
                                                        "solver.iteration_budget": 6})
        result = plan_push("vscm", settings=checked, **push)
        horizon = checked.with_overrides({"horizon_s": float(result.knot_time_s[-1])})
        problem = build_problem(horizon, PushRequest("vscm", **push)).problem
        again = execute(physical_twin(problem, problem.cost), result.knot_torques_Nm, checked.tracking)
        assert len(again.world_tracked_errors) == 3
        ratios = [world_ratio(errors, checked.task, checked.tracking.world_max_tilt_rad)
                  for errors in again.world_tracked_errors]
        assert result.sturdy == all(ratio < 1.0 for ratio in ratios)
        assert result.worst_world == pytest.approx(max(ratios))
        assert result.sturdy == (tolerance_m == 0.02), again.world_tracked_errors


def test_worlds_tracked_side_by_side_give_the_errors_tracked_one_after_the_other(settings, monkeypatch):
    """tracking.world_errors tracks as many worlds at a time as the machine has cores: the errors, and where
    `stop` cuts the list, are those of one world after the other."""
    settings = with_worlds(settings, (1.0, 0.5, 0.5, 1.5, 1.5), (1.0, 0.5, 2.0, 0.5, 2.0))
    problem = build_problem(settings, PushRequest("vscm", 7)).problem
    executor = physical_twin(problem, problem.cost)
    reference = executor.trajectory(executor.with_torques(scripted_torques(executor, settings.stages.scripted,
                                                                           settings.tracking)))

    def errors(stop=None):
        return tracking.world_errors(executor.simulator, executor.initial_state, reference, settings.tracking,
                                     executor.task, NOMINAL, stop)

    side_by_side = errors()
    pool, threads = tracking._world_pool()
    assert threads == (os.cpu_count() or 1) and len(side_by_side) == 5
    second = side_by_side[2]
    cut = errors(lambda error: error == second)
    monkeypatch.setattr(tracking, "_world_pool", lambda: (pool, 1))
    assert errors() == side_by_side and len(set(side_by_side)) == 5
    assert errors(lambda error: error == second) == cut == side_by_side[:3]
