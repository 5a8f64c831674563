"""Replanning while a push runs (MPC): a replan's policy takes effect no sooner than its compute time, it is taken
only where it keeps the push as sturdy in the executor's worlds, and it starts from a cube at rest held still. Real
MuJoCo, real iLQR."""
import dataclasses
import math

import numpy as np
import pytest

from cito_ros.execution.executor import Phase
from cito_ros.execution.planning import compute, work_in_line
from cito_ros.execution.policy import Policy
from cito_ros.execution.world import JointReading
from cito_ros.model.scene import start_configuration
from cito_ros.planner.problem import PushProblem
from test_estimator import seen_at_rest
from test_execution import deliver, push_under_way, started


# replans on, with a budget a slow moment does not use up before the replan's first iteration: these tests are about a
# replan's verdict, and at the configured 0.08 s a process's first replan, its setup and first rollout slow, stopped
# on its time limit with no step taken in 1 of 5 runs of a test alone and once in a clean clone's `make test`
# on the first replan of the push below; and with the paper's orientation weight: with the executor's balanced one
# (executor.orientation_balance) that replan lowers its cost 5.77 to 2.13 by a turn that leaves the cube 0.2 mm further
# from the goal at the horizon's end, and a replan that leaves it further is not taken (mpc.PushModel.replan), so
# there would be no replan for these tests to judge
REPLANNING = {"executor.replan": True, "executor.replan_budget_s": 0.3, "executor.orientation_balance": 0.0}


def test_a_cube_at_rest_is_put_in_the_state_still_at_its_resting_pose(settings, scenes):
    """Fitted through the camera's noise, the last poses of a cube at rest give it a velocity; the state the
    replans start from has it at rest where the mean of its poses puts it."""
    scene = scenes["vscm"]
    estimator = seen_at_rest(scene)
    joints = JointReading(0.3, start_configuration(7), np.zeros(7), np.zeros(7))
    moving, still = (estimator.state(joints, 0.3, at_rest) for at_rest in (False, True))
    assert np.abs(scene.object_qvel(moving)).max() > 0 and not np.any(scene.object_qvel(still))
    (x, y), yaw = estimator.resting_pose()
    assert scene.object_qpos(still)[:2] == pytest.approx([x, y], abs=1e-12)
    assert 2 * math.atan2(scene.object_qpos(still)[6], scene.object_qpos(still)[3]) == pytest.approx(yaw, abs=1e-12)


def test_a_plan_takes_effect_no_sooner_than_its_compute_time_after_the_state_it_was_computed_from(settings):
    """In lock step the world's clock stands still while a plan is computed; the plan waits on the world's clock
    for as long as it took, the arm driven by the running policy meanwhile (replans on: they are plans too)."""
    executor, world = started(settings.with_overrides({"executor.replan": True}))
    works, active = [], []
    while executor.phase is not Phase.DONE and world.time_s < executor.time_limit_s + 5:  # it ends by its limit
        job = executor.job(world.time_s)
        work = work_in_line(executor, world.time_s)
        if work is not None:
            works.append((job.now_s, work))
        before = executor.policy
        world.step(executor.command(world.time_s))
        deliver(executor, world)
        if executor.policy is not before:
            active.append((world.time_s - world.timestep_s, executor.policy))
    assert executor.ending is not None and works and len(works) >= 3  # the plan, and replans
    assert all(work.effective_s >= computed + work.compute_s for computed, work in works)
    effective = {id(work.policy): work.effective_s for _, work in works}
    assert active and all(t >= effective[id(policy)] for t, policy in active)


def test_on_a_fixed_clock_a_plan_takes_effect_after_the_clocks_time_however_long_it_took_to_compute(settings):
    """cito-bench closed-loop --clock-s: each plan costs the world's clock what the clock says, on a fast machine as
    on a slow one."""
    executor, world = started(settings)
    work = work_in_line(executor, world.time_s, {"plan": 3.0, "replan": 0.1})
    assert work.kind == "plan" and work.compute_s == 3.0 and work.effective_s == pytest.approx(world.time_s + 3.0)


def test_a_push_is_replanned_while_it_runs_only_with_replans_on(settings):
    for replan in (False, True):
        executor, world = push_under_way(settings.with_overrides({"executor.replan": replan}))
        job = executor.job(world.time_s)
        assert (job is not None and job.kind == "replan") if replan else job is None


def test_a_side_push_is_replanned_only_with_side_replans_on(settings):
    for side_replans in (False, True):
        executor, world = push_under_way(settings.with_overrides({"executor.replan": True,
                                                                   "executor.replan_side_pushes": side_replans}))
        assert executor.job(world.time_s).kind == "replan"  # a push on the near face is replanned either way
        executor.policy = dataclasses.replace(executor.policy, face=1)
        job = executor.job(world.time_s)
        assert (job is not None and job.kind == "replan") if side_replans else job is None


def test_a_replan_is_taken_only_if_the_servo_would_end_it_as_near_the_goal_in_the_executors_worlds_as_the_push(
        settings):
    """The same replan from the same measured state: taken where the running push's worst world is unknown,
    not where it is half the replan's (tolerance ratios at rest, tracked by the servo: PushModel.worst_world)."""
    replanning = settings.with_overrides(REPLANNING)
    executor, world = push_under_way(replanning)
    job = executor.job(world.time_s)
    assert 0 < job.running.worst_world < math.inf

    def replanned(running_worst_world: float):
        running = dataclasses.replace(job.running, worst_world=running_worst_world)
        return compute(replanning, executor.goal, dataclasses.replace(job, running=running))

    taken = replanned(math.inf)
    assert isinstance(taken, Policy) and 0 < taken.worst_world < math.inf
    assert replanned(0.5 * taken.worst_world) is None


def test_a_push_to_a_waypoint_is_replanned_to_that_waypoint_not_on_to_the_goal(settings):
    """The same replan of the same running push, once as a push to the goal and once as a push to a waypoint 4 cm
    short of it: each keeps its push's target, and the waypoint's replan leaves the cube nearer the waypoint (replans
    made for the goal carried a push to a waypoint on past it: docs/results.md)."""
    replanning = settings.with_overrides(REPLANNING)
    executor, world = push_under_way(replanning)
    job = executor.job(world.time_s)
    (x, y), yaw = executor.goal.target_position_m, executor.goal.target_yaw_rad
    waypoint = ((x - 0.04, y), yaw)

    def replanned(target):
        running = dataclasses.replace(job.running, worst_world=math.inf, target=target)
        return compute(replanning, executor.goal, dataclasses.replace(job, running=running))

    to_goal, to_waypoint = replanned(None), replanned(waypoint)
    assert isinstance(to_goal, Policy) and isinstance(to_waypoint, Policy)
    assert to_goal.target is None and to_waypoint.target == waypoint

    def from_waypoint_m(policy: Policy) -> float:
        return float(np.hypot(*(executor.model.scene.object_qpos(policy.final_state)[:2] - waypoint[0])))

    assert from_waypoint_m(to_waypoint) < from_waypoint_m(to_goal)


def test_a_replan_linearizes_every_other_step_and_where_the_plate_first_touches_and_last_leaves_the_cube(settings):
    """executor.replan_switches ends: the plate chatters on the face it pushes, its contact switching on and off
    all along the push; a replan linearizes the even steps and the steps around the contact's first beginning and
    last end as in full, and a switch between them takes the Jacobians of the step before."""
    executor, _ = push_under_way(settings)
    model, policy = executor.model, executor.policy
    problem = model.problem(policy.reference[0], len(policy.torques_Nm), policy.torques_Nm,
                            model.task_to(policy.target))
    exact_problem = PushProblem(problem.simulator, problem.initial_state, problem.task, problem.cost,
                                dataclasses.replace(problem.derivative_settings, stride=1),
                                problem.position_scale_min_m)
    z = problem.with_torques(policy.torques_Nm)
    replanned, exact = problem.linearize(z), exact_problem.linearize(z)
    found = problem.evaluate(z).sensordata[:, model.scene.sensors.contact_found.start] > 0
    switches = np.flatnonzero(found[1:] != found[:-1]) + 1
    ends = switches[[0, -1]]
    computed = np.union1d(np.arange(0, len(found), 2), np.union1d(ends - 1, ends))
    inner_odd = np.setdiff1d(switches, computed)
    assert inner_odd.size >= 3  # the chatter: switches no even step nor the contact's ends cover
    np.testing.assert_array_equal(replanned.A[computed], exact.A[computed])
    np.testing.assert_array_equal(replanned.A[inner_odd], replanned.A[inner_odd - 1])
    assert not np.array_equal(replanned.A[inner_odd], exact.A[inner_odd])
