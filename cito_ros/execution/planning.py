"""The executor's planning side: what a planning process runs for the executor (cito_ros.execution.executor), in
another process beside the control loop on a robot or in line in a simulation. `compute` turns a `Job` into its
outcome: a push planned from rest with its policy, one MPC replan, or a `Failure`.
"""
from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping

import numpy as np

from cito_ros.execution.executor import Ending, Executor, Failure, Job, Work
from cito_ros.execution.goal import ExecuteGoal, moved_beyond, polishing, predict
from cito_ros.execution.identify import identify
from cito_ros.execution.mpc import executor_costs, push_model, servo_tracking
from cito_ros.execution.policy import Policy
from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.planner.physical import side_start
from cito_ros.planner.plan import plan_push
from cito_ros.planner.results import PlanResult, Status, tolerance_ratio, within_limits
from cito_ros.planner.side_faces import NEAR, across_first
from cito_ros.planner.task import cube_turn_rad, nearest_equivalent_yaw, push_turn_limit_rad, yaw_of
from cito_ros.settings import Settings


def executor_plan_settings(settings: Settings, time_left_s: float, iterations: int, worlds: list | None = None,
                           overrides: dict | None = None) -> Settings:
    """The planner's settings for the executor's pushes: `iterations` within the time left (at most
    plan_time_limit_s), and a plan checked with the controller that will run it, the executor's servo with its speed
    guard (a push the guard changes is judged as it runs: docs/results.md), in the model
    and in the worlds of executor.world_*_scales (so that a push whose outcome hangs on the cube's friction and mass
    is not taken), or in `worlds` (friction and mass scales: those identify left possible). Its first script is
    made with the servo, the next with the planner's stiff gains (gain_scale 1 /
    servo_gain_scale): first plans in a median 3.9 s against 8.2 s in closed-loop --n 10, as many successes. Its
    pushes are on the near face only (side faces: docs/planner.md), unless `overrides` (more of them) say so."""
    executor, script, variants = settings.executor, settings.stages.scripted, settings.stages.scripted.variants
    return dataclasses.replace(executor_costs(settings).with_overrides({
        "solver.time_limit_s": max(min(time_left_s, executor.plan_time_limit_s), 1.0),
        "solver.iteration_budget": iterations,
        "stages.scripted.follow_face": True,
        # side starts spent the pushes' iteration budget: closed loop 58 of 72 with them, 64 without (docs/results.md)
        "stages.scripted.side_faces.enabled": False,
        "stages.scripted.side_faces.gradient_stride": 1,  # its side pushes as measured closed loop (docs/results.md)
        "stages.sequence.across_first_rad": 0.0,  # its own pushes are its sequence, each from the measured state
        "stages.scripted.variants.contact_height_m": [script.contact_height_m, *variants.contact_height_m],
        "stages.scripted.variants.push_end_fraction": [script.push_end_fraction, *variants.push_end_fraction],
        "stages.scripted.variants.horizon_scale": [1.0, *variants.horizon_scale],
        "stages.scripted.variants.gain_scale": [script.gain_scale / executor.servo_gain_scale, *variants.gain_scale],
        **(overrides or {})}), tracking=servo_tracking(settings, worlds))


def compute(settings: Settings, goal: ExecuteGoal, job: Job) -> Policy | Failure | None:
    """A job's outcome (blocking; in this process or another): a push planned from rest (plan_push from the
    measured arm and cube) with its policy, or one MPC step; a Failure when no push can be planned from there.
    A push with pushes left after it is planned to the goal within executor.direct_iterations (a sturdy plan there
    takes 3-19), and where that plan is not sturdy, again to executor.waypoint_fraction of the way, made if sturdy
    and it moves the cube: a shorter push lands alike in more worlds (docs/results.md), and the next starts from
    where it ended. Once a push has gone to a waypoint (job.direct_missed), the next are planned the other way round
    where executor.waypoint_first_after_miss says so: the waypoint first, and the goal only where that is not made
    (on seed 3 the plans to the goal after one that missed were sturdy in 4 of 26, the 22 others taking 5-15 s
    each: docs/results.md). Where neither is so, the one the model has nearer the goal is made, within the arm's limits
    first (the plan to a goal at the arm's reach that goes beyond the joints' range and never touches the cube
    had been made, and the execution ended with no closer push where the waypoint's moved it closer), and only where
    its worst check world ends within executor.max_world_ratio times the tolerances, else a Failure (such pushes
    tipped the cube or threw it off the table on the any distribution: docs/results.md). After a
    push, the cube's friction is identified from what the camera saw of it (identify), and the next is planned for
    it; where that push would not bring the cube closer (the executor ends there), the side face's push to the goal
    is planned (executor.side_when_stuck) and made where it is sturdy and does, and else the near face's planned for
    the identified cube alone (executor.nominal_when_stuck), made where it does there. A cube at rest within the
    tolerances but turned more than executor.polish_orientation_rad allows (polishing) gets one plan to the goal with
    that yaw tolerance, within executor.plan_iterations, returned only where it is sturdy to it (else a Failure: the
    executor ends a success). A push's plans share one executor.plan_time_limit_s of wall clock, each given what the
    ones before it left (at least a second)."""
    if job.kind == "replan":  # in the model the running push was planned in: its knots, its cube
        return push_model(_knotted(settings, job.running.control_period_s), goal, job.running.object_scales).replan(
            job.now_s, job.state, job.running, settings.executor.replan_budget_s)
    polish = polishing(settings, *goal.errors(*job.object_pose))  # its push planned to the tighter yaw, run as any other
    model = push_model(settings, goal)
    executor = settings.executor
    deadline = time.perf_counter() + min(job.time_left_s, executor.plan_time_limit_s)

    def left() -> Job:  # with 20 s each, three plans took a push 50 s of the execution's 60 (docs/results.md)
        return dataclasses.replace(job, time_left_s=deadline - time.perf_counter())

    scales, worlds = (1.0, 1.0), None
    if job.observed and executor.identify_friction_scales:
        cube = identify(model, job.observed, dataclasses.replace(settings.tracking, feed_forward=False),
                        executor.identify_friction_scales, executor.identified_spread, executor.identify_tolerance)
        scales, worlds = (cube.friction_scale, 1.0), [cube.worlds(executor.world_friction_scales),
                                                      executor.world_mass_scales]
    side = None if polish else _side_first(settings, goal, left(), scales, worlds)
    if side is not None:
        return side
    try:
        sequence = job.pushes_left > 0 and executor.waypoint_fraction > 0 and polish is None
        tries = [(1.0, executor.direct_iterations if sequence else executor.plan_iterations),
                 (executor.waypoint_fraction, executor.plan_iterations)]
        if sequence and job.direct_missed and executor.waypoint_first_after_miss:
            tries.reverse()
        request, result = _plan_to(polish or settings, goal, left(), *tries[0], scales, worlds)
        if sequence and not _taken(settings, tries[0][0], result):
            other = _plan_to(settings, goal, left(), *tries[1], scales, worlds)
            if _taken(settings, tries[1][0], other[1]) or \
                    _predicted(settings, goal, other[1]) < _predicted(settings, goal, result):
                request, result = other
    except ValueError as error:
        return Failure(Ending.INVALID_REQUEST, f"no push can be planned from here: {error}")
    if result.status is Status.NUMERICAL_ERROR:
        return Failure(Ending.NUMERICAL_ERROR, "the plan is not finite or raised MuJoCo warnings")
    if polish and not result.sturdy:
        return Failure(Ending.TASK_NOT_ACHIEVED, f"no push found is sturdy to within "
                                                 f"{executor.polish_orientation_rad:g} rad")
    if _throws(settings, result):
        # not a refusal: the goal may be reachable, only no push found here is safe to make
        return Failure(Ending.TASK_NOT_ACHIEVED, f"no push found keeps the cube within {executor.max_world_ratio:g} "
                                                 f"times the tolerances in every check world (the push the model "
                                                 f"has nearest the goal: {result.worst_world:.3g} times)",
                       "no_safe_push")
    policy = _policy(settings, goal, job, request, result, scales)
    if polish or job.pushes_left >= executor.max_pushes - 1 or \
            predict(settings, model.scene, goal, job.object_pose, policy).closer:
        return policy
    # no near-face push sturdy in the worlds brings the cube closer, and the executor would end there
    if executor.side_when_stuck:  # one beside the goal and a little past it: pushed further along, it goes further past
        side = _side_push(settings, goal, left(), scales, worlds, goal)
        if side is not None and predict(settings, model.scene, goal, job.object_pose, side).closer:
            return side
    if executor.nominal_when_stuck:
        request, result = _plan_to(settings, goal, left(), 1.0, executor.plan_iterations, scales, NOMINAL)
        nominal = _policy(settings, goal, job, request, result, scales)
        if result.status is not Status.NUMERICAL_ERROR and \
                predict(settings, model.scene, goal, job.object_pose, nominal).closer:
            return nominal
    return policy


def _cube_moved(result: PlanResult) -> tuple[tuple[np.ndarray, float], tuple[np.ndarray, float]]:
    """Where a plan, executed in the model and held, has the cube at its start and at rest: (x, y), yaw."""
    motion = result.executed_motion
    return tuple((motion.object_position_m[i, :2], yaw_of(motion.object_quaternion[i])) for i in (0, -1))


def _taken(settings: Settings, fraction: float, result: PlanResult) -> bool:
    """Whether a plan to `fraction` of the way is made without planning the other: sturdy, and a waypoint's moving
    the cube too."""
    return result.sturdy and (fraction == 1.0 or _moves(settings, result))


def _moves(settings: Settings, result: PlanResult) -> bool:
    """Whether a plan moves the cube (moved_beyond, as the executor asks of a next push: a plan sturdy to a
    waypoint whose tolerances already hold the cube never touches it)."""
    return moved_beyond(settings, *_cube_moved(result), settings.executor.predicted_moved_fraction)


def _throws(settings: Settings, result: PlanResult) -> bool:
    """Whether a plan's worst check world ends beyond executor.max_world_ratio times the tolerances: a push some
    world throws the cube with."""
    return result.worst_world > settings.executor.max_world_ratio


def _predicted(settings: Settings, goal: ExecuteGoal, result: PlanResult) -> tuple[bool, bool, float]:
    """A plan's standing against the goal, lower better: one whose worst check world ends beyond
    executor.max_world_ratio last, then one beyond the arm's limits, then the model's tolerance ratio of where it
    leaves the cube."""
    metrics, (_, end) = result.metrics, _cube_moved(result)
    return _throws(settings, result), \
        not within_limits(metrics.max_joint_speed_ratio, metrics.joint_range_excess_rad), \
        tolerance_ratio(*goal.errors(*end), settings.task)


def _policy(settings: Settings, goal: ExecuteGoal, job: Job, request: PushRequest, result: PlanResult,
            scales: tuple[float, float], face: int = NEAR) -> Policy:
    """The plan's policy from the job's state, in the model of the plan's knots (a side push's are longer)."""
    knotted = _knotted(settings, float(result.knot_time_s[1] - result.knot_time_s[0]))
    start = build_problem(knotted.with_overrides({"horizon_s": float(result.knot_time_s[-1])}), request).initial_state
    target = ((float(request.target_position_m[0]), float(request.target_position_m[1])), request.target_yaw_rad)
    return dataclasses.replace(push_model(knotted, goal, scales).policy(job.now_s, start, result.knot_torques_Nm,
                                                                        target=target, face=face), sturdy=result.sturdy)


def _knotted(settings: Settings, control_period_s: float) -> Settings:
    """The settings with knots of control_period_s (the same settings where they have them)."""
    return settings if math.isclose(control_period_s, settings.control_period_s) else \
        settings.with_overrides({"control_period_s": control_period_s})


# the identified cube's world alone (the plan's model: no other worlds tracked), for executor.nominal_when_stuck
NOMINAL = [[1.0], [1.0]]

# the side face's starts alone: where they are not sturdy, the push is planned as any other
SIDE_ONLY = {"stages.scripted.side_faces.enabled": True, "stages.scripted.enabled": False, "stages.starts": []}


def _side_first(settings: Settings, goal: ExecuteGoal, job: Job, scales: tuple[float, float],
                worlds: list | None) -> Policy | None:
    """executor.side_first_rad's push, with pushes left after it: a goal more than that off the near face's inward
    normal is first pushed towards on the side face its offset across that normal needs, to side_waypoint; planned
    with the side face's starts alone, taken where its worst world lands within executor.waypoint_world_ratio of the
    waypoint's tolerances (the plate pushing the near face outside its friction cone slides along it, and where the
    cube goes then hangs on the friction the executor does not know: docs/results.md, Where the misses are). None
    where it does not apply, the plate does not reach that side face, or its plan is not taken."""
    waypoint = side_waypoint(settings, goal, job.object_pose)
    if waypoint is None or job.pushes_left <= 0:
        return None
    return _side_push(settings, goal, job, scales, worlds, waypoint, settings.executor.waypoint_world_ratio)


def side_waypoint(settings: Settings, goal: ExecuteGoal, object_pose: tuple[tuple[float, float], float]
                  ) -> ExecuteGoal | None:
    """Where executor.side_first_rad's side push takes a cube at object_pose ((x, y), yaw) on its way to the goal:
    across the near face's inward normal to the line that leaves the rest of the way along it, turned only by what
    the near face's push along that rest cannot turn it (push_turn_limit_rad: a side push that also turns
    the cube lands it far off, goal 2 of docs/results.md's any distribution 8.6 cm and 0.6 rad off such a waypoint
    in the model). None for a goal within side_first_rad of the normal, or behind the cube."""
    (x, y), yaw = object_pose
    waypoint_xy, _, across_m, along_m = across_first((x, y), yaw, goal.target_position_m, goal.target_yaw_rad)
    if settings.executor.side_first_rad <= 0.0 or along_m <= 0.0 or \
            abs(math.atan2(across_m, along_m)) <= settings.executor.side_first_rad:
        return None
    turn_rad = cube_turn_rad(yaw, goal.target_yaw_rad)
    side_turn_rad = max(abs(turn_rad) - push_turn_limit_rad(settings.task, along_m), 0.0)
    return dataclasses.replace(goal, target_position_m=waypoint_xy,
                               target_yaw_rad=yaw + math.copysign(side_turn_rad, turn_rad))


def _side_push(settings: Settings, goal: ExecuteGoal, job: Job, scales: tuple[float, float], worlds: list | None,
               target: ExecuteGoal, world_ratio: float = 1.0) -> Policy | None:
    """A push to `target` (the goal, or a waypoint towards it) on the side face it needs, planned with the side
    face's starts alone, taken where its worst world ends within world_ratio of the tolerances of `target` (1:
    sturdy); None where it needs none, the plate does not reach that face, or its plan is not taken."""
    plan_settings = executor_plan_settings(settings, job.time_left_s, settings.executor.plan_iterations, worlds,
                                           SIDE_ONLY)
    request = _request(target, job, 1.0, scales)
    try:
        start = side_start(plan_settings, request)
        if start is None or not start.reaches:
            return None
        result = _plan(request, plan_settings)
    except ValueError:
        return None
    if not result.worst_world < world_ratio or result.status is Status.NUMERICAL_ERROR:
        return None
    return _policy(settings, goal, job, request, result, scales, start.face)


def _request(goal: ExecuteGoal, job: Job, fraction: float, object_scales: tuple[float, float]) -> PushRequest:
    """A push from the job's measured arm and cube to `fraction` of the way to the goal, in position and in yaw
    (to the goal yaw's equivalent nearest the cube's), for a cube whose friction and mass are object_scales times the
    scene's."""
    (x, y), yaw = job.object_pose
    position, target_yaw = np.array(goal.target_position_m), nearest_equivalent_yaw(goal.target_yaw_rad, yaw)
    if fraction < 1.0:
        position = np.array([x, y]) + fraction * (position - np.array([x, y]))
        target_yaw = yaw + fraction * cube_turn_rad(yaw, target_yaw)
    return PushRequest(goal.contact_model, start_q=job.q, target_position_m=position, target_yaw_rad=target_yaw,
                       scene=goal.scene, object_pose=((x, y), yaw), object_scales=object_scales)


def _plan(request: PushRequest, settings: Settings) -> PlanResult:
    return plan_push(request.contact_model, start_q=request.start_q, target_position_m=request.target_position_m,
                     target_yaw_rad=request.target_yaw_rad, scene=request.scene, object_pose=request.object_pose,
                     object_scales=request.object_scales, settings=settings)


def _plan_to(settings: Settings, goal: ExecuteGoal, job: Job, fraction: float, iterations: int,
             object_scales: tuple[float, float], worlds: list | None) -> tuple[PushRequest, PlanResult]:
    """_request's push planned within `iterations`, sturdy in `worlds` around the cube (friction and mass scales;
    None: executor.world_*_scales); ValueError where none can be planned."""
    request = _request(goal, job, fraction, object_scales)
    # over executor.horizon_s; a side push keeps its horizon_scale of the planner's (at 2.5 x 3.2 s its plans were not
    # sturdy), the near face's slower pushes being for the last centimetres, not for a transit
    return request, _plan(request, executor_plan_settings(settings, job.time_left_s, iterations, worlds,
                                                          {"horizon_s": settings.executor.horizon_s}))


def work_in_line(executor: Executor, now_s: float, clock_s: Mapping[str, float] | None = None) -> Work | None:
    """The executor's job, computed and accepted in line (blocking): for a caller whose clock stands still while
    it computes (cito_ros.execution.episode, the tests). Its compute time passes on that clock as measured, or as
    clock_s gives it per job kind ("plan", "replan"): the same outcome on a fast machine as on a slow one."""
    job = executor.job(now_s)
    if job is None:
        return None
    began = time.perf_counter()
    outcome = compute(executor.settings, executor.goal, job)
    elapsed_s = time.perf_counter() - began
    return executor.accept(job, outcome, elapsed_s if clock_s is None else clock_s[job.kind])
