"""`cito-bench targets`: seeded random pushes, solved by each contact model, judged by execution.

ROS-free. Goals are drawn from a seeded generator, in one of four distributions (DISTRIBUTIONS), all
from the start pose q0(beta) for beta uniform in [4, 7] (initial distances 0.11-0.45 m):

- forward: a push of 5-35 cm in a direction within +-35 degrees of +x from the cube's start, a goal
  yaw within +-0.5 rad;
- beside: a push of 3-25 cm in a direction 50-130 degrees either side of +x from the cube's start
  (mostly a side face's, cito_ros.planner.side_faces), a goal yaw within +-0.3 rad;
- any: a goal anywhere on the table that the arm can push the cube to (the table top, the cube
  inside it, within the push reach of the arm base: the region the planner's checks accept, drawn
  in the report), a goal yaw in [-pi, pi);
- turn: a goal within 1.5 cm of the cube's start, in any direction, turned 0.16-0.30 rad either way: a turn at
  the cube's place, beyond the orientation tolerance, which one push makes only aimed past the goal
  (cito_ros.planner.builder: task.aim_past_max_m).

A draw the planner would refuse (off the table, beyond the arm's reach) is drawn again and counted.
Every goal is labelled with the face of the cube a push towards it needs (`face_needed`). Every plan
is judged by its execution without the virtual force, and also executed by a PD joint trajectory
controller (cito_ros.planner.tracking). A goal the planner refuses is a record of the refusal, its reason
and its time. The report is cito_ros.studies.targets_report's.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np

from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import Scene, start_configuration
from cito_ros.planner import tracking
from cito_ros.planner.builder import PushRequest, build_problem, make_task, warm_up
from cito_ros.planner.plan import plan_push
from cito_ros.planner.results import PlanResult
from cito_ros.planner.side_faces import FAR, NEAR, face_for
from cito_ros.settings import Settings, load_settings

MODELS = ("cccm", "scm", "vscm")
BETA_RANGE = (4.0, 7.0)
PUSH_RANGE_M = (0.05, 0.35)
DIRECTION_RANGE_RAD = math.radians(35.0)
YAW_RANGE_RAD = 0.5
BESIDE_PUSH_RANGE_M = (0.03, 0.25)
BESIDE_DIRECTION_RANGE_RAD = (math.radians(50.0), math.radians(130.0))
BESIDE_YAW_RANGE_RAD = 0.3
TURN_PUSH_RANGE_M = (0.0, 0.015)
TURN_YAW_RANGE_RAD = (0.16, 0.30)
DISTRIBUTIONS = ("forward", "beside", "any", "turn")
FACES = ("near", "side", "far")


@dataclass(frozen=True)
class Goal:
    index: int
    beta: float
    target_position_m: tuple[float, float]
    target_yaw_rad: float
    push_m: float
    direction_rad: float
    face: str = "near"      # the face a push towards the goal needs (face_needed)


def face_needed(direction_rad: float, object_position_m, object_yaw_rad: float) -> str:
    """The cube's face a push in direction_rad (world) needs, the cube at object_position_m with object_yaw_rad:
    the near face (the face towards the arm, scene.pushed_face, whose inward normal points away from it) for
    directions within 45 degrees of that normal, a side face for those within 45 degrees of the normal turned by
    90 degrees either way, else the far face (a pull back towards the arm)."""
    target = np.asarray(object_position_m, dtype=float) + [math.cos(direction_rad), math.sin(direction_rad)]
    quarter = face_for(object_position_m, object_yaw_rad, target)
    return FACES[0] if quarter == NEAR else FACES[2] if quarter == FAR else FACES[1]


def region(settings: Settings, scene: Scene | None = None) -> dict[str, Any]:
    """Where goals can be (the `any` distribution's region, drawn in the report): the table top the cube's centre
    stays on, the scene's push reach (Scene.push_reach_m: the farthest a goal may be from the arm base), and the
    cube's start. `scene`: the settings' scene, if already built."""
    scene = Scene(contact_model("vscm", settings.contact_models), settings.scene) if scene is None else scene
    low, high, _ = scene.table_top()
    half = float(scene.object_half_size[0])
    return {"table_low_m": (low + half).tolist(), "table_high_m": (high - half).tolist(),
            "push_reach_m": scene.push_reach_m(), "object_start_m": list(settings.scene.object.position_m)}


def draw_goals(n: int, seed: int, settings: Settings | None = None, distribution: str = "forward"
               ) -> tuple[list[Goal], list[str]]:
    """n plannable goals from the seed in a distribution (DISTRIBUTIONS), and the reasons of the draws refused
    on the way."""
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"unknown goal distribution {distribution!r}: one of {', '.join(DISTRIBUTIONS)}")
    settings = load_settings() if settings is None else settings
    scene = Scene(contact_model("vscm", settings.contact_models), settings.scene)
    (x0, y0), yaw0 = settings.scene.object.position_m, settings.scene.object.yaw_rad
    where = region(settings, scene)
    rng = np.random.default_rng(seed)
    goals, refused = [], []
    while len(goals) < n:
        beta = float(rng.uniform(*BETA_RANGE))
        if distribution == "forward":
            push = float(rng.uniform(*PUSH_RANGE_M))
            direction = float(rng.uniform(-DIRECTION_RANGE_RAD, DIRECTION_RANGE_RAD))
            yaw = float(rng.uniform(-YAW_RANGE_RAD, YAW_RANGE_RAD))
        elif distribution == "beside":
            push = float(rng.uniform(*BESIDE_PUSH_RANGE_M))
            direction = float(rng.choice((-1.0, 1.0)) * rng.uniform(*BESIDE_DIRECTION_RANGE_RAD))
            yaw = float(rng.uniform(-BESIDE_YAW_RANGE_RAD, BESIDE_YAW_RANGE_RAD))
        elif distribution == "turn":
            push = float(rng.uniform(*TURN_PUSH_RANGE_M))
            direction = float(rng.uniform(-math.pi, math.pi))
            yaw = yaw0 + float(rng.choice((-1.0, 1.0)) * rng.uniform(*TURN_YAW_RANGE_RAD))
        else:  # the whole table top the cube fits on; make_task refuses what is beyond the arm's push reach
            target = tuple(float(v) for v in rng.uniform(where["table_low_m"], where["table_high_m"]))
            yaw = float(rng.uniform(-math.pi, math.pi))
            push, direction = math.hypot(target[0] - x0, target[1] - y0), math.atan2(target[1] - y0, target[0] - x0)
        if distribution != "any":  # a push from the cube's start
            target = (x0 + push * math.cos(direction), y0 + push * math.sin(direction))
        try:
            make_task(scene, scene.initial_state(start_configuration(beta)), np.array(target), yaw, settings)
        except ValueError as error:
            refused.append(str(error))
            continue
        goals.append(Goal(len(goals), beta, target, yaw, push, direction, face_needed(direction, (x0, y0), yaw0)))
    return goals, refused


PERTURBATIONS = {"none": (0.0, 0.0), "target x +1e-9 m": (1e-9, 0.0), "start q +1e-9 rad": (0.0, 1e-9)}


# the returned plan's joint trajectory tracked with its reference off by this many seeded smooth offsets of up
# to this much (cito_ros.planner.tracking.offset_references, seeded by the goal: others than the planner's own check
# with tracking.reference_offsets): whether a success survives a servo's small error (docs/planner.md: Tiny changes and rough pushes)
OFFSETS = 4
OFFSET_AMPLITUDE_RAD = 1e-4


def perturbed_request(model: str, beta: float, target_position_m, target_yaw_rad: float,
                      perturbation: str) -> PushRequest:
    """The push from q0(beta) to (x, y, yaw) with a perturbation (PERTURBATIONS): the target moved along x
    or every start joint angle moved by a hair."""
    target_shift, joint_shift = PERTURBATIONS[perturbation]
    return PushRequest(model, beta, start_q=start_configuration(beta) + joint_shift,
                       target_position_m=np.asarray(target_position_m, dtype=float) + np.array([target_shift, 0.0]),
                       target_yaw_rad=target_yaw_rad)


def plan_perturbed(model: str, beta: float, target_position_m, target_yaw_rad: float, settings: Settings,
                   perturbation: str) -> PlanResult:
    """The plan of perturbed_request."""
    return _plan(perturbed_request(model, beta, target_position_m, target_yaw_rad, perturbation), settings)


def _plan(request: PushRequest, settings: Settings) -> PlanResult:
    return plan_push(request.contact_model, start_q=request.start_q, target_position_m=request.target_position_m,
                     target_yaw_rad=request.target_yaw_rad, settings=settings)


def offset_tracked_errors_m(result: PlanResult, request: PushRequest, settings: Settings, seed: int,
                            count: int = OFFSETS, amplitude_rad: float = OFFSET_AMPLITUDE_RAD) -> list[float]:
    """The final position errors of `result`'s joint trajectory (the plan of `request`) tracked by the PD
    controller with its reference off by each of `count` smooth offsets of up to amplitude_rad from `seed`."""
    settings = settings.with_overrides({"horizon_s": float(result.knot_time_s[-1])})
    problem = build_problem(settings, request).problem
    return tracking.offset_position_errors_m(problem.simulator, problem.initial_state, result.trajectory,
                                             settings.tracking, problem.task, count, amplitude_rad, seed)


def solve_goal(goal: Goal, model: str, settings: Settings, perturbation: str = "none") -> dict[str, Any]:
    """One goal with one model: the plan's summary with the goal's description, under a perturbation
    (plan_perturbed); unperturbed, also its tracked errors under reference offsets (offset_tracked_errors_m)."""
    request = perturbed_request(model, goal.beta, goal.target_position_m, goal.target_yaw_rad, perturbation)
    described = {"goal": goal.index, "push_m": goal.push_m, "direction_rad": goal.direction_rad, "face": goal.face,
                 "perturbation": perturbation, "requested_yaw_rad": goal.target_yaw_rad}
    warm_up(settings)  # as a node does before it serves: its answers, refusals too, do not pay for the reaches
    began = time.perf_counter()
    try:
        result = _plan(request, settings)
    except ValueError as error:  # refused: how fast, and why
        return {**described, "contact_model": model, "refused": str(error), "success": False,
                "refusal_time_s": time.perf_counter() - began, "target_position_m": list(goal.target_position_m),
                "target_yaw_rad": goal.target_yaw_rad}
    summary = {key: value for key, value in result.summary().items() if key not in ("stages", "derivatives")}
    summary["beta"] = goal.beta
    if perturbation == "none":
        summary["offset_tracked_position_errors_m"] = offset_tracked_errors_m(result, request, settings, goal.index)
    return {**described, **summary}


def jobs(goals: Iterable[Goal], models: Iterable[str], settings: Settings, perturbed: int = 0) -> list:
    """The sweep's jobs (cito_ros.studies.sweep): every goal with every model, and the first `perturbed` goals
    again under each perturbation."""
    goals = list(goals)
    runs = [(goal, model, "none") for goal in goals for model in models]
    runs += [(goal, model, name) for goal in goals[:perturbed] for model in models for name in PERTURBATIONS
             if name != "none"]
    return [(f"goal{goal.index:03d}-{model}-{name}", solve_goal, (goal, model, settings, name))
            for goal, model, name in runs]
