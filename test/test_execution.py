"""The execution layer in process: the simulated robot's world and camera, the state estimate, the feedback
policy, the compute delay honoured, and the executor holding the arm when its measurements stop or it is
cancelled. Real MuJoCo, real iLQR."""
import dataclasses
import math
from collections.abc import Callable

import mujoco
import numpy as np
import pytest

from cito_ros.execution.episode import Watch, at_goal
from cito_ros.execution.estimator import tipping_tilt_rad
from cito_ros.execution.executor import Ending, Executor, Failure, Phase
from cito_ros.execution.goal import ExecuteGoal
from cito_ros.execution.planning import compute, work_in_line
from cito_ros.execution.policy import SPEED_GUARD, Policy, bias_torques, state_difference
from cito_ros.execution.world import Mismatch, PoseReading, SimulatedWorld
from cito_ros.model.scene import start_configuration

GOAL = ExecuteGoal((1.09, 0.03), 0.1, "vscm")  # 10 cm from q0(beta = 7), inside the steady push reach


def deliver(executor: Executor, world: SimulatedWorld) -> None:
    executor.on_joints(world.joints())
    for reading in world.camera():
        executor.on_pose(reading, world.time_s)


def started(settings, mismatch=Mismatch(), goal: ExecuteGoal = GOAL) -> tuple[Executor, SimulatedWorld]:
    """An executor and its world, the camera's first pose in."""
    world, executor = SimulatedWorld(settings, mismatch, start_configuration(7)), Executor(settings, goal)
    deliver(executor, world)
    while not executor.estimator.has_pose:
        joints = world.joints()
        world.step(bias_torques(world.scene, mujoco.MjData(world.model), joints.q, joints.qdot))
        deliver(executor, world)
    return executor, world


def test_the_executor_judges_the_cube_by_its_yaw_modulo_a_quarter_turn():
    """The cube turned by a quarter turn is the same cube: a goal a quarter turn or a whole turn from the cube's
    yaw is reached, and the yaw error is the turn to the nearest equivalent, never more than an eighth of a turn."""
    for turns in (1, -1, 3, 4):
        goal = dataclasses.replace(GOAL, target_yaw_rad=GOAL.target_yaw_rad + turns * math.pi / 2)
        assert goal.errors(GOAL.target_position_m, GOAL.target_yaw_rad) == pytest.approx((0.0, 0.0), abs=1e-12)
        assert goal.errors((1.10, 0.03), GOAL.target_yaw_rad + 0.7)[1] == pytest.approx(0.7)
        assert goal.errors((1.10, 0.03), GOAL.target_yaw_rad + 0.9)[1] == pytest.approx(math.pi / 2 - 0.9)


def test_the_world_is_the_scene_with_the_mismatch_and_its_camera_is_late_noisy_and_slow(settings):
    mismatch = Mismatch("off", 1.5, 2.0, (0.015, -0.015), 0.1, 0.001, 0.01, 0.03, 30.0)
    world = SimulatedWorld(settings, mismatch, start_configuration(7), seed=3)
    told = settings.scene.object
    assert world.scene.config.object.mass_kg == pytest.approx(2.0 * told.mass_kg)
    assert world.scene.config.object.friction == pytest.approx(1.5 * told.friction)
    position, _ = world.true_object_pose()
    assert position[:2] == pytest.approx(np.add(told.position_m, (0.015, -0.015)), abs=1e-3)
    readings = []
    for _ in range(200):  # 1 s
        world.step(np.full(7, 1e4))  # clamped to the motor limits
        assert np.all(np.abs(world.joints().effort) <= world.scene.torque_limit)
        readings += [(world.time_s, r) for r in world.camera()]
    assert 28 <= len(readings) <= 31  # 30 Hz
    assert all(arrived - r.stamp_s >= 0.03 - 1e-9 for arrived, r in readings)  # 30 ms late
    errors = [np.linalg.norm(r.position_m[:2] - world.true_object_pose()[0][:2]) for _, r in readings[:5]]
    assert 0 < max(errors) < 0.01  # noisy, by millimetres


def test_a_push_from_rest_is_planned_from_the_rest_windows_mean_while_the_noise_says_the_cube_moves(settings):
    """The camera's noise (1 mm, 0.01 rad) makes a cube at rest seem to move faster than executor.rest_speed_m_s now
    and then; a push planned then starts from the rest window's mean pose at rest, not from one noisy pose carried
    forward, and the check that drops a planned push whose cube has moved compares that mean with it."""
    sensing = Mismatch("noisy", pose_noise_m=0.001, yaw_noise_rad=0.01, latency_s=0.03)
    executor, world = started(settings, sensing)
    data = mujoco.MjData(world.model)
    flickers = 0
    while world.time_s < 4.0:
        joints = world.joints()
        world.step(bias_torques(world.scene, data, joints.q, joints.qdot))
        deliver(executor, world)
        if world.time_s < 0.5 or executor.cube_at_rest:
            continue
        flickers += 1
        job = executor.job(world.time_s)
        assert job.kind == "plan"
        (x, y), yaw = executor.estimator.resting_pose()
        assert job.object_pose[0] == pytest.approx((x, y), abs=1e-12) and job.object_pose[1] == pytest.approx(yaw)
        scene = executor.model.scene
        assert scene.object_qpos(job.state)[:2] == pytest.approx((x, y), abs=1e-12)
        assert np.all(scene.object_qvel(job.state) == 0.0)
        assert not executor._moved_since(Policy(0.0, 0.04, 0.005, np.zeros((1, 7)), np.zeros((1, 7, 2 * scene.model.nv)),
                                                job.state[None].repeat(9, axis=0)))
    assert flickers > 0  # the noise did make the cube seem to move, and the plan did not follow it


def test_a_policy_commands_its_torques_on_its_reference_and_pulls_back_off_it(settings):
    executor, world = started(settings)
    work_in_line(executor, world.time_s)  # the push planned, in line
    policy = executor._pending.policy
    scene = executor.model.scene
    step = 40
    on = policy.reference[step]
    at = policy.start_s + step * policy.timestep_s
    assert np.array_equal(policy.command(at, on, scene), np.clip(policy.torques_Nm[step // 16], -scene.torque_limit,
                                                                       scene.torque_limit))
    off = on.copy()
    off[scene.state_qpos_adr + scene.arm_qpos_adr[0]] += 1e-3  # the first joint ahead of its reference
    assert state_difference(scene, off, on)[0] == pytest.approx(1e-3)
    assert policy.command(at, off, scene)[0] < policy.command(at, on, scene)[0]  # and pulled back


def pushing(settings, steps: int) -> tuple[Executor, SimulatedWorld]:
    """An execution planned and run for `steps` control steps."""
    executor, world = started(settings)
    work_in_line(executor, world.time_s)
    for _ in range(steps):
        world.step(executor.command(world.time_s))
        deliver(executor, world)
    return executor, world


def push_under_way(settings) -> tuple[Executor, SimulatedWorld]:
    """An execution planned and run until its plan has taken effect (after its compute time)."""
    executor, world = pushing(settings, 0)
    while executor.phase is not Phase.PUSHING:
        world.step(executor.command(world.time_s))
        deliver(executor, world)
    return executor, world


def test_the_executor_keeps_every_joint_within_its_speed_limit_under_a_policy_that_would_take_it_past(settings):
    """A policy of full torque on every joint, the shoulder lifting (the arm touches nothing for 0.3 s): sent as it
    is (with the bias forces) it drives joints past their speed limits; through the executor no joint passes
    SPEED_GUARD of its limit (plus the model's 1 % between one step and the next)."""
    executor, world = push_under_way(settings)
    scene = executor.model.scene
    flat_out = np.tile(np.array([1, -1, 1, -1, 1, 1, 1]) * scene.torque_limit, (len(executor.policy.torques_Nm), 1))
    executor.policy = dataclasses.replace(executor.policy, torques_Nm=flat_out,
                                          gains=np.zeros_like(executor.policy.gains))
    raw_world = SimulatedWorld(settings, Mismatch(), world.joints().q)
    data = mujoco.MjData(raw_world.model)
    raw, limited = [], []
    for _ in range(int(0.3 / world.timestep_s)):
        joints = raw_world.joints()
        raw_world.step(flat_out[0] + bias_torques(raw_world.scene, data, joints.q, joints.qdot))
        raw.append(raw_world.joint_speed_ratio())
        world.step(executor.command(world.time_s))
        deliver(executor, world)
        limited.append(world.joint_speed_ratio())
    assert executor.phase is Phase.PUSHING
    assert max(raw) > 1.2
    assert max(limited) <= SPEED_GUARD + 0.01


def test_a_push_whose_cube_leaves_its_path_is_cut_short_with_the_arm_held_where_it_is(settings):
    """The cube knocked 6 cm sideways under the plate (as a slippery cube slides off a push that does not suit
    it): the push stops within the camera's period and latency, well before its end, and the arm holds where it
    was then; an undisturbed push runs to its end."""
    executor, world = push_under_way(settings)
    end_s = executor._push_end_s
    for _ in range(20):  # the push under way, on its path
        world.step(executor.command(world.time_s))
        deliver(executor, world)
    assert executor.phase is Phase.PUSHING and executor.pushes_cut == 0
    adr = world.scene.object_qpos_adr
    world.data.qpos[adr + 1] += 0.06
    knocked_s = world.time_s
    while executor.phase is Phase.PUSHING:
        world.step(executor.command(world.time_s))
        deliver(executor, world)
    assert executor.phase is Phase.SETTLING and executor.pushes_cut == 1
    assert world.time_s - knocked_s < 0.1 < end_s - world.time_s
    held = executor._hold_q.copy()
    for _ in range(40):
        world.step(executor.command(world.time_s))
        deliver(executor, world)
    assert np.abs(world.joints().q - held).max() < 0.01
    undisturbed, world = push_under_way(settings)
    while undisturbed.phase is Phase.PUSHING:
        world.step(undisturbed.command(world.time_s))
        deliver(undisturbed, world)
    assert undisturbed.pushes_cut == 0 and world.time_s >= undisturbed._push_end_s


def test_stale_measurements_end_the_execution_with_the_arm_held_where_it_is(settings):
    executor, world = pushing(settings, 40)
    q = world.joints().q
    for _ in range(30):  # 150 ms without a camera pose: the joint states still come
        world.step(executor.command(world.time_s))
        executor.on_joints(world.joints())
    assert executor.ending is Ending.STALE_MEASUREMENTS and "cube poses" in executor.message
    assert executor.phase is Phase.DONE and np.allclose(executor._hold_q, q, atol=0.05)
    for _ in range(100):  # held: the arm stays where it was stopped
        world.step(executor.command(world.time_s))
        executor.on_joints(world.joints())
    assert np.abs(world.joints().qdot).max() < 0.05


def test_a_cancelled_execution_holds_the_arm(settings):
    executor, world = pushing(settings, 60)
    executor.cancel()
    assert executor.ending is Ending.CANCELLED and executor.job(world.time_s) is None
    for _ in range(100):
        world.step(executor.command(world.time_s))
        deliver(executor, world)
    assert np.abs(world.joints().qdot).max() < 0.05 and executor.phase is Phase.DONE


def test_a_push_that_missed_takes_the_arm_back_to_its_start_without_moving_the_cube_and_plans_the_next_there(
        settings):
    """Judged against a goal tolerance no push meets, the first push misses: the arm goes back to where the
    execution started, along a path within the retreat's speed limit, the cube left where it came to rest, and
    the next push is planned from there while it goes, and made no sooner than it is there; a next push the model
    predicts would leave the cube no closer is not made, and the execution ends there."""
    strict = settings.with_overrides({"task.success_position_error_m": 1e-5})
    home = start_configuration(7)
    executor, world = retreating(settings, strict)
    cube_before, retreat = world.true_object_pose()[0], executor._retreat
    limit = strict.executor.retreat_speed_fraction * world.scene.velocity_limit
    assert np.all(np.abs(retreat.at(0.5 * (retreat.start_s + retreat.end_s))[1]) <= limit + 1e-9)
    job = executor.job(world.time_s)  # the next push, planned as the arm retreats: from where it will be
    assert job is not None and job.kind == "plan" and np.array_equal(job.q, home)
    assert executor.policy.target[0] == GOAL.target_position_m and not job.direct_missed  # the first went to the goal
    closer = ending_at(executor, executor.policy, executor.goal.target_position_m, executor.goal.target_yaw_rad,
                       job.state)
    waypoint = ((1.05, 0.02), 0.05)  # the next goes to a waypoint: its plan to the goal was not sturdy
    next_push = executor.accept(job, dataclasses.replace(closer, start_s=world.time_s, target=waypoint), 0.5)
    assert next_push.effective_s == retreat.end_s and executor.pushes == 1  # counted once it is made
    while executor.phase is Phase.RETREATING:
        assert executor.policy is not next_push.policy
        world.step(executor.command(world.time_s))
        deliver(executor, world)
    executor.command(world.time_s)
    assert executor.policy is next_push.policy and world.time_s >= retreat.end_s  # made once the arm is back
    assert executor.pushes == 2 and executor.job(world.time_s).direct_missed  # the plans after it know
    assert np.abs(world.joints().q - home).max() < 0.05  # back where it started (the servo's error)
    assert np.linalg.norm(world.true_object_pose()[0][:2] - cube_before[:2]) < 0.003  # the cube not dragged along
    # the same, with a next push that would leave the cube no closer
    executor, world = retreating(settings, strict)
    job = executor.job(world.time_s)
    no_closer = ending_at(executor, executor.policy, *job.object_pose)  # the cube predicted to stay where it is
    assert executor.accept(job, no_closer, 0.5) is None
    assert executor.ending is Ending.TASK_NOT_ACHIEVED and "would leave it" in executor.message
    assert executor.pushes == 1 and executor.phase is Phase.DONE and executor.cause == "no_closer_push"


def retreating(settings, strict) -> tuple[Executor, SimulatedWorld]:
    """An execution whose first push missed, the arm retreating: the push planned for `settings`, the cube judged
    against `strict` (a tolerance no push meets). A push planned for such a tolerance is the best of bad ones, and
    one of them tipped the cube or not as the replans' timing fell (in one clean clone's run, and every time on a
    fixed clock)."""
    executor, world = started(settings)
    while executor.phase is not Phase.RETREATING and world.time_s < 25:
        if executor.phase is Phase.PUSHING:
            executor.settings = strict
        work_in_line(executor, world.time_s)
        world.step(executor.command(world.time_s))
        deliver(executor, world)
    assert executor.phase is Phase.RETREATING and executor.pushes == 1
    return executor, world


def ending_at(executor: Executor, policy: Policy, position_m, yaw_rad: float, start=None) -> Policy:
    """`policy` with the cube predicted at (x, y), yaw_rad at its end (and its reference at `start` before)."""
    reference = policy.reference.copy() if start is None else np.repeat(start[None], len(policy.reference), axis=0)
    cube = executor.model.scene.object_qpos(reference[-1])
    cube[:2], cube[3:7] = position_m, [math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2)]
    return dataclasses.replace(policy, reference=reference)


def judged_once_drawn_back(settings, strict, tolerance_m: Callable[[float], float]) -> Executor:
    """An execution whose first push missed (retreating), its next push planned during the retreat, and the cube
    judged once the arm is back against tolerance_m(its position error after the push) and a yaw tolerance it
    meets."""
    executor, world = retreating(settings, strict)
    job = executor.job(world.time_s)
    closer = ending_at(executor, executor.policy, executor.goal.target_position_m, executor.goal.target_yaw_rad)
    assert executor.accept(job, dataclasses.replace(closer, start_s=world.time_s), 0.5) is not None
    executor.settings = strict.with_overrides({
        "task.success_position_error_m": tolerance_m(executor.errors(world.time_s)[0]),
        "task.success_orientation_error_rad": 3.0})
    while executor.phase is Phase.RETREATING:
        world.step(executor.command(world.time_s))
        deliver(executor, world)
    return executor


def test_a_cube_found_at_the_goal_once_the_arm_has_drawn_back_ends_the_execution_as_succeeded(settings):
    """The judgement after a push can disagree with the cube at rest once the arm is away: then it is not pushed
    again. Here the first push is judged against a tolerance no push meets, and the cube after the retreat against
    one it meets. The next push, planned during the retreat, is then not made nor counted."""
    executor = judged_once_drawn_back(settings, settings.with_overrides({"task.success_position_error_m": 1e-5}),
                                      lambda _: 0.5)
    assert executor.ending is Ending.SUCCEEDED and "after 1 push(es), once the arm drew back" in executor.message
    assert executor.pushes == 1 and executor.phase is Phase.DONE and len(executor.sturdy_pushes) == 1


def test_an_execution_begun_with_the_arm_against_the_cube_draws_it_back_to_the_start_pose_and_pushes_from_there(
        settings):
    """The last execution was cancelled during its push, the arm against the cube: a push planned from there
    would start in the cube. The next execution draws the arm back to the start pose of beta first, the cube left
    where it is, and plans its push from there."""
    home = start_configuration(settings.beta)
    executor, world = started(settings)
    clearance_m = settings.executor.start_clearance_m
    while not (executor.phase is Phase.PUSHING and world.scene.arm_clearance(world.data, 0.01)[0] < clearance_m) \
            and executor.phase is not Phase.DONE and world.time_s < 20:
        work_in_line(executor, world.time_s)
        world.step(executor.command(world.time_s))
        deliver(executor, world)
    executor.cancel()
    assert world.scene.arm_clearance(world.data, 0.01)[0] < clearance_m
    follow_up = Executor(settings, dataclasses.replace(GOAL, target_position_m=(1.13, 0.03)))
    while not follow_up.estimator.has_pose:
        world.step(executor.command(world.time_s))  # the cancelled execution holds the arm
        deliver(follow_up, world)
    cube_before = world.true_object_pose()[0]
    assert follow_up.job(world.time_s) is None and follow_up.phase is Phase.RETREATING
    while follow_up.phase is Phase.RETREATING:
        world.step(follow_up.command(world.time_s))
        deliver(follow_up, world)
    assert follow_up.phase is Phase.PLANNING and np.abs(world.joints().q - home).max() < 0.05
    assert np.linalg.norm(world.true_object_pose()[0][:2] - cube_before[:2]) < 0.003  # the cube not dragged along
    job = follow_up.job(world.time_s)
    assert job is not None and job.kind == "plan" and np.abs(job.q - home).max() < 0.05
    assert not isinstance(compute(settings, follow_up.goal, job), Failure)


def test_a_cube_pushed_past_the_goal_ends_the_execution_as_not_achieved_without_a_search(settings):
    """After a push that left the cube 6 cm beyond the goal, a next push would have to pull it back: it is refused
    before any search, and the execution ends as not achieved, with the reason."""
    executor, world = started(settings)
    executor.pushes = 1  # as after a first push
    job = executor.job(world.time_s)
    assert job is not None and job.kind == "plan"
    overshot = dataclasses.replace(job, object_pose=(np.array([GOAL.target_position_m[0] + 0.06,
                                                               GOAL.target_position_m[1]]), GOAL.target_yaw_rad))
    outcome = compute(settings, GOAL, overshot)
    assert isinstance(outcome, Failure) and "behind the object's pushed face" in outcome.message
    assert executor.accept(overshot, outcome, 0.01) is None
    assert executor.ending is Ending.TASK_NOT_ACHIEVED and "6.0 cm behind" in executor.message
    assert executor.cause == "no_push_from_here"


def test_a_cube_seen_tipped_past_its_edge_ends_the_execution_with_the_arm_held(settings):
    """The camera sees the cube's top 60 degrees from upright (past 45, where a cube falls onto its side): the
    execution ends as not achieved, the arm held where it is; a cube rocking by 20 degrees does not end it."""
    executor, world = pushing(settings, 60)
    position = world.true_object_pose()[0]
    for degrees, ends in ((20.0, False), (60.0, True)):
        half = math.radians(degrees) / 2
        executor.on_pose(PoseReading(world.time_s, position, np.array([math.cos(half), math.sin(half), 0.0, 0.0])),
                         world.time_s)
        q = world.joints().q
        executor.command(world.time_s)
        assert (executor.phase is Phase.DONE) is ends, executor.message
    assert executor.ending is Ending.TASK_NOT_ACHIEVED and "tipped over (its top 60 degrees" in executor.message
    assert executor.cause == "tipped"
    np.testing.assert_array_equal(executor._hold_q, q)


def test_an_episode_with_a_cube_that_fell_onto_its_side_is_no_success(settings):
    """Judged on the truth: a cube whose top turned 90 degrees (now on its side) is not at a flat goal, whatever its
    position and yaw; one upright is judged by them."""
    world = SimulatedWorld(settings, Mismatch(), start_configuration(7))
    assert Watch(world).upright and tipping_tilt_rad(world.scene) == pytest.approx(math.pi / 4)
    adr = world.scene.object_qpos_adr
    world.data.qpos[adr + 3:adr + 7] = [math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0]  # rolled onto a side
    watch = Watch(world)
    assert watch.max_tilt_rad == pytest.approx(math.pi / 2) and not watch.upright
    assert at_goal(settings.task, True, 0.001, 0.01) and not at_goal(settings.task, True, 0.001, 0.01, upright=False)
