"""The one way to pose a push problem: settings + request -> scene, simulator, start, task, problem.

ROS-free. `plan_push`, the benchmarks, the studies and the tests all call
`build_problem`; the task checks (the target on the table, at the object's
resting height, within the arm's reach) live here and nowhere else.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import TABLE_TOP_Z_M, Scene, start_configuration
from cito_ros.model.simulator import Simulator
from cito_ros.planner import push_limits
from cito_ros.planner.problem import PushProblem, StageCost
from cito_ros.planner.side_faces import NEAR, face_for
from cito_ros.planner.task import PushTask, aim_past_m, nearest_equivalent_yaw, push_turn_limit_rad, turn_rad, yaw_of
from cito_ros.settings import SceneConfig, Settings
from cito_ros.settings.typed_config import require_finite


@dataclass(frozen=True)
class PushRequest:
    """What to plan. Unset fields take the settings' values.

    contact_model: 'cccm', 'scm' or 'vscm'.
    beta: start pose q0(beta); ignored when start_q is given.
    start_q: (7,) start configuration of the arm (at rest), instead of q0(beta).
    target_position_m: (x, y) or (x, y, z) of the object's goal, world frame; default
      task.push_distance_m along +x from the object's start (z: the object's resting height).
    target_yaw_rad: goal yaw of the object about world z.
    scene: a scene name in config/scenes (or a scene YAML path).
    object_pose: ((x, y) or (x, y, z), yaw) of the object where it is now, world frame, instead
      of the scene's pose (z: its resting height).
    object_scales: (friction, mass) of the object as these times the scene's (what the executor's pushes
      showed of it: cito_ros.execution.identify).
    """

    contact_model: str = "vscm"
    beta: float | None = None
    start_q: np.ndarray | None = None
    target_position_m: np.ndarray | None = None
    target_yaw_rad: float = 0.0
    scene: str | None = None
    object_pose: tuple[np.ndarray, float] | None = None
    object_scales: tuple[float, float] = (1.0, 1.0)


@dataclass(frozen=True)
class PlanningProblem:
    """A posed problem and what it was built from."""

    scene: Scene
    simulator: Simulator
    initial_state: np.ndarray
    task: PushTask
    problem: PushProblem
    beta: float | None          # None when the request gave start_q
    initial_distance_m: float   # signed distance between the contact candidates at the start


def build_problem(settings: Settings, request: PushRequest) -> PlanningProblem:
    """Pose `request` under `settings`. Raises ValueError for anything that cannot be planned."""
    model = contact_model(request.contact_model, settings.contact_models)
    scene = Scene(model, scene_config(settings, request))
    horizon_s, control_period_s = settings.horizon
    simulator = Simulator(scene, horizon_s, control_period_s, nthread=settings.gradient.threads)
    if request.start_q is None:
        beta = settings.beta if request.beta is None else request.beta
        start_q = start_configuration(beta)
    else:
        beta, start_q = None, request.start_q
    check_object_start(scene, start_q)
    initial_state = scene.initial_state(start_q)
    task = make_task(scene, initial_state, request.target_position_m, request.target_yaw_rad, settings)
    check_pushable(scene, initial_state, task, settings)
    problem = PushProblem(simulator, initial_state, task, StageCost.paper(getattr(settings.weights, model.name)),
                          settings.gradient, settings.task.position_error_scale_min_m)
    return PlanningProblem(scene, simulator, initial_state, task, problem, beta,
                           scene.signed_distance(scene.data_at(start_q)))


def scene_config(settings: Settings, request: PushRequest) -> SceneConfig:
    """The request's scene, with the object where and as the request says it is."""
    config = settings.scene if request.scene is None else SceneConfig.load(request.scene)
    if request.object_scales != (1.0, 1.0):
        if not all(math.isfinite(v) and v > 0 for v in request.object_scales):
            raise ValueError(f"object scales must be positive (friction, mass), got {request.object_scales}")
        config = config.with_object_scaled(*request.object_scales)
    if request.object_pose is None:
        return config
    position, yaw = request.object_pose
    position = np.asarray(position, dtype=float)
    if position.shape not in ((2,), (3,)) or not np.all(np.isfinite(position)) or not math.isfinite(yaw):
        raise ValueError(f"object pose must be a finite (x, y) or (x, y, z) and yaw, got {position.tolist()}, {yaw}")
    resting_z = TABLE_TOP_Z_M + config.object.half_size_m
    if position.shape == (3,) and abs(position[2] - resting_z) > settings.task.target_height_tolerance_m:
        raise ValueError(f"object pose z {position[2]:.3f} m is not the object's resting height {resting_z:.3f} m "
                         f"(+-{settings.task.target_height_tolerance_m} m): it must rest on the table")
    return dataclasses.replace(config, object=dataclasses.replace(
        config.object, position_m=(float(position[0]), float(position[1])), yaw_rad=float(yaw)))


def warm_up(settings: Settings) -> PlanningProblem:
    """What a planning process pays for once per scene, so that no answer does: the default request's problem of the
    configured scene, its steady push reach (every plan's reach zone: 1.4 s) and its pull reach (a refusal's reason:
    1.3 s), the reaches computed once per machine and read back after (reach_cache.cached)."""
    posed = build_problem(settings, PushRequest(settings.node.default_contact_model))
    push_limits.steady_reach_m(posed.scene, posed.initial_state)
    push_limits.pull_reach_m(posed.scene)
    return posed


def check_pushable(scene: Scene, initial_state: np.ndarray, task: PushTask, settings: Settings) -> None:
    """A goal one push cannot reach is refused at once rather than searched for to the time limit:
    - one behind the near face (the object candidate's) by more than the success tolerance: the plate's force on
      the face points into the object within the friction cone, so pushing moves the object away from the face's
      plane, never back (nor does the tilted plate on a side face: a pull needs the far face, which the plate
      reaches only for an object within push_limits.pull_reach_m of the arm base);
    - one whose turn (to the goal yaw's equivalent nearest the object's, at most an eighth of a turn: make_task) is
      more than the orientation tolerance plus task.turn_per_push_rad_per_m times the distance the object's centre
      moves (to the aim past the goal, where make_task sets one): an off-centre push turns the object as it moves it,
      no push turns it in place, and in a sweep of single pushes none turned it faster (docs/results.md: A turn one
      push cannot make is refused at once)."""
    qpos = scene.object_qpos(initial_state)
    _, along_m, turn = _near_push(scene, qpos, task)
    behind_m = -along_m
    if behind_m > settings.task.success_position_error_m:
        out_m, pull_m = float(np.hypot(*qpos[:2])), push_limits.pull_reach_m(scene)
        pull = f"and the plate can press that face, with the arm clear of the object, only for an object within " \
               f"{pull_m:.3f} m of the arm base; this one is {out_m:.3f} m out" if out_m > pull_m else \
               "which this planner does not push on yet"
        raise ValueError(f"target is {100 * behind_m:.1f} cm behind the object's pushed face (back towards the arm): "
                         f"a push on that face (or on a side face) moves the object away from the arm, never back; "
                         f"only a pull on its far face does, {pull}")
    distance_m = float(np.linalg.norm(task.aim_m[:2] - qpos[:2]))  # the push's: to the aim past the goal (make_task)
    limits = settings.task
    most_rad = push_turn_limit_rad(limits, distance_m)
    if turn > most_rad:
        aimed = "" if task.aim_position_m is None else \
            f" (aimed {100 * aim_past_m(task.target_position_m, task.aim_position_m):.1f} cm past the goal)"
        raise ValueError(f"target turns the object by {turn:.2f} rad over a {100 * distance_m:.1f} cm push{aimed}: "
                         f"one push on one of the object's faces turns it by at most {most_rad:.2f} rad there "
                         f"({limits.success_orientation_error_rad:g} rad plus {limits.turn_per_push_rad_per_m:g} rad "
                         f"per metre pushed, aimed at most {100 * limits.aim_past_max_m:g} cm past the goal); a turn "
                         f"in place needs pushes on other faces")


def check_object_start(scene: Scene, start_q: np.ndarray) -> None:
    """The object must stand wholly on the table, within reach, clear of the arm at its start."""
    low, high, _ = scene.table_top()
    obj = scene.config.object
    centre = np.asarray(obj.position_m, dtype=float)
    c, s = math.cos(obj.yaw_rad), math.sin(obj.yaw_rad)
    corners = centre + np.array([[c * x - s * y, s * x + c * y] for x in (-1, 1) for y in (-1, 1)]) * obj.half_size_m
    if np.any(corners < low) or np.any(corners > high):
        raise ValueError(f"object pose ({centre[0]:.3f}, {centre[1]:.3f}) m, yaw {obj.yaw_rad:.3f} rad: the object "
                         f"overhangs the table (x [{low[0]:.3f}, {high[0]:.3f}], y [{low[1]:.3f}, {high[1]:.3f}] m)")
    reach = scene.push_reach_m()
    if np.linalg.norm(centre) > reach:
        raise ValueError(f"object pose ({centre[0]:.3f}, {centre[1]:.3f}) m is {np.linalg.norm(centre):.3f} m from "
                         f"the arm base, beyond the {reach:.3f} m the arm can push it from")
    distance, geom = scene.arm_clearance(scene.data_at(start_q), 0.01)
    if distance < 0:
        raise ValueError(f"object pose ({centre[0]:.3f}, {centre[1]:.3f}) m, yaw {obj.yaw_rad:.3f} rad: the object "
                         f"intersects the arm's {geom} at its start pose (by {-distance * 1000:.1f} mm)")


def make_task(scene: Scene, initial_state: np.ndarray, target_position_m, target_yaw_rad: float,
              settings: Settings) -> PushTask:
    """The push target, checked against what pushing on this table can reach; its yaw the goal's equivalent
    (task.nearest_equivalent_yaw: the cube turned by quarter turns) nearest the object's."""
    qpos = scene.object_qpos(initial_state)
    start = qpos[:3]
    if target_position_m is None:
        target = start + np.array([settings.task.push_distance_m, 0.0, 0.0])
    else:
        target = np.asarray(target_position_m, dtype=float)
        if target.shape == (2,):
            target = np.array([target[0], target[1], start[2]])
        if target.shape != (3,):
            raise ValueError(f"target position must be (x, y) or (x, y, z), got shape {target.shape}")
    low, high, _ = scene.table_top()
    half = float(scene.object_half_size[0])
    if np.any(target[:2] < low + half) or np.any(target[:2] > high - half):
        raise ValueError(f"target ({target[0]:.3f}, {target[1]:.3f}) m is off the "
                         f"table: the object must end within x [{low[0] + half:.3f}, {high[0] - half:.3f}], "
                         f"y [{low[1] + half:.3f}, {high[1] - half:.3f}] m")
    height_tolerance = settings.task.target_height_tolerance_m
    if abs(target[2] - start[2]) > height_tolerance:
        raise ValueError(f"target z {target[2]:.3f} m is not the object's resting height "
                         f"{start[2]:.3f} m (+-{height_tolerance} m): pushing cannot lift it")
    # a pushed object ends at its resting height: a z within the tolerance says "on the table", so the
    # same goal with another such z (the table top plus the half edge is 0.1 mm above the settled cube)
    # is the same problem and the same plan
    task = PushTask(np.array([target[0], target[1], start[2]]),
                    nearest_equivalent_yaw(require_finite("target yaw", target_yaw_rad), yaw_of(qpos[3:7])))
    reach = scene.push_reach_m()
    distance = float(np.linalg.norm(task.target_position_m[:2]))
    if distance > reach:
        raise ValueError(f"target is {distance:.3f} m from the arm base, beyond the {reach:.3f} m the arm can push "
                         f"the object's centre to (the plate's reach at the object's height, plus the plate's "
                         f"radius and the object's half size)")
    aim = _aim_past(scene, qpos, task, settings)
    return task if aim is None else dataclasses.replace(task, aim_position_m=aim)


def _aim_past(scene: Scene, qpos: np.ndarray, task: PushTask, settings: Settings) -> np.ndarray | None:
    """Where a push aims past the goal, along the near face's inward normal, so that the object's centre moves along
    that normal at least the goal's turn beyond the orientation tolerance over task.aim_turn_rad_per_m, but at most
    task.aim_past_max_m past it: a push turns the object only as it moves it, and a goal near or at the object's
    place turned further than that is otherwise a turn in place (refused, or a push that never moves it:
    docs/results.md). None where no aim is needed, where the goal needs another face than the near face (more than
    45 degrees off its normal and beyond the position tolerance), where even the aim lies behind the near face (a
    goal behind it, within the tolerance: the aim moves such a goal's push from backwards, which no push on that
    face makes, to forwards), or beyond the push reach; check_pushable judges the turn over the push to the aim."""
    limits = settings.task
    normal, along_m, turn = _near_push(scene, qpos, task)
    needed_m = (turn - limits.success_orientation_error_rad) / limits.aim_turn_rad_per_m
    # what turns the cube is its push along the normal: a goal beside the cube is no push along it (near-face
    # pushes towards such goals never moved the cube: docs/results.md, Turns at the cube's place)
    push = task.target_position_m[:2] - qpos[:2]
    beside = np.linalg.norm(push) > limits.success_position_error_m and \
        face_for(qpos[:2], yaw_of(qpos[3:7]), task.target_position_m[:2]) != NEAR  # a side face's push, or a pull
    if limits.aim_past_max_m <= 0.0 or along_m >= needed_m or beside:
        return None
    past_m = min(needed_m - along_m, limits.aim_past_max_m)
    aim = task.target_position_m[:2] + past_m * normal
    if along_m + past_m <= 0.0 or np.linalg.norm(aim) > scene.push_reach_m():  # behind the face too, or unreachable
        return None
    return np.r_[aim, task.target_position_m[2]]


def _near_push(scene: Scene, qpos: np.ndarray, task: PushTask) -> tuple[np.ndarray, float, float]:
    """What a push on the near face is judged by (check_pushable, _aim_past): the face's inward unit normal (x, y),
    how far the goal lies along it from the object's centre (m; negative: behind the face's push), and the size of
    the goal's turn (rad)."""
    normal = scene.inward_normals(qpos[None, 3:7])[0][:2]
    normal = normal / np.linalg.norm(normal)
    along_m = float((task.target_position_m[:2] - qpos[:2]) @ normal)
    return normal, along_m, abs(turn_rad(yaw_of(qpos[3:7]), task.target_yaw_rad))
