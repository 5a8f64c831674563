"""`cito-bench closed-loop --ros`: the closed-loop episodes through the nodes. One cito-executor-node for the
run; per goal and world a cito-sim-robot with that world's differences (cito_ros.studies.closed_loop.world_for),
stepped in real time, and the goal sent as an ExecutePush action from this process; judged on the simulator's
true cube at rest. The open-loop episodes are the in-process ones (a joint trajectory controller needs no node).
Episodes run one after another: each is a real-time robot on this machine's two cores.
"""
from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any, Callable

import numpy as np

from cito_ros.execution.episode import TIGHT_YAW_RAD, at_goal
from cito_ros.execution.estimator import tipped_over
from cito_ros.execution.goal import ExecuteGoal
from cito_ros.model.scene import Scene, start_configuration
from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.ros.sim_session import Operator, robot_parameters, spawn, stop
from cito_ros.settings import Settings
from cito_ros.studies import closed_loop
from cito_ros.studies.targets import Goal


def ros_records(goals: list[Goal], model: str, settings: Settings, bag_directory: Path,
                progress: Callable[[str], None] = lambda _: None) -> list[dict[str, Any]]:
    """Every goal in every world (closed_loop.WORLDS), open loop in process and closed loop through the nodes."""
    domain = random.randint(101, 180)
    scene = build_problem(settings, PushRequest(model, start_q=start_configuration(settings.beta))).scene
    node = spawn("cito-executor-node", domain, f"node.bag_directory:={bag_directory.resolve()}")
    operator = Operator(domain)
    records = []
    try:
        for goal in goals:
            margin = closed_loop.steady_margin_m(goal, settings)
            for world in closed_loop.WORLDS:
                records.append(closed_loop.episode(goal, world, "open_loop", model, settings))
                progress(f"goal{goal.index:03d}-{world.name}-open_loop")
                records.append(closed_loop_episode(operator, domain, goal, world, model, settings, margin,
                                                   scene))
                progress(f"goal{goal.index:03d}-{world.name}-closed_loop")
    finally:
        operator.close()
        stop(node)
    return records


def closed_loop_episode(operator: Operator, domain: int, goal: Goal, world, model: str, settings: Settings,
                        margin_m: float, scene: Scene) -> dict[str, Any]:
    """One goal closed loop in one world: a cito-sim-robot with the world's differences beside the running executor
    node, the goal sent from this process, judged on the simulator's true cube at rest (the bench's record)."""
    mismatch = closed_loop.world_for(world, goal)
    sim = spawn("cito-sim-robot", domain, *robot_parameters(mismatch, goal.beta, goal.index))
    try:
        if not operator.wait_for_robot():
            raise RuntimeError("the simulated robot or the executor node did not come up")
        target = ExecuteGoal(tuple(goal.target_position_m), goal.target_yaw_rad, model)
        outcome = operator.execute(target, settings.task.rest_speed_m_s)
    finally:
        stop(sim)
    task, result, upright = settings.task, outcome.result, not tipped_over(scene, outcome.max_tilt_rad)
    rate = result.replan_rate_hz or math.nan
    record = {"goal": goal.index, "world": world.name, "mode": "closed_loop", "contact_model": model,
              "offset_m": list(mismatch.offset_m), "offset_yaw_rad": mismatch.offset_yaw_rad,
              "steady_reach_margin_m": margin_m,
              "success": at_goal(task, outcome.at_rest, outcome.position_error_m, outcome.orientation_error_rad,
                                 upright=upright),
              "success_tight": at_goal(task, outcome.at_rest, outcome.position_error_m, outcome.orientation_error_rad,
                                       TIGHT_YAW_RAD, upright),
              "position_error_m": outcome.position_error_m, "orientation_error_rad": outcome.orientation_error_rad,
              "at_rest": outcome.at_rest,
              "max_joint_speed_ratio": float(np.max(outcome.max_joint_speed / scene.velocity_limit)),
              "max_tilt_rad": outcome.max_tilt_rad, "tipped": not upright,
              "duration_s": outcome.round_trip_s, "ending": f"status {result.status}", "message": result.message,
              "pushes": int(result.pushes),
              "first_push_sturdy": bool(result.first_push_sturdy) if result.pushes else None,
              "cause": result.cause, "replans": int(result.replans), "replan_rate_hz": rate,
              "replan_compute_s": 1.0 / rate, "plan_compute_s": math.nan, "phases": list(outcome.phases),
              "bag_path": result.bag_path, "final_pose": list(outcome.final_pose), "face": goal.face,
              **closed_loop.poses(goal, mismatch, settings)}
    return {**record, "place": closed_loop.place(record, task)}
