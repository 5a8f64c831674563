"""Named planning cases (config/hard_cases.yaml), run with a clear status for every outcome.

ROS-free. A case changes the default problem by scene, start pose, target and
knot spacing; `run_case` plans it and returns one JSON-serialisable record,
with `status` 'invalid_request' (and the reason) when the case cannot be posed,
never an exception.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from cito_ros.config import SceneConfig, load_parameters
from cito_ros.paths import config_path
from cito_ros.planner import PlanResult, SolverOptions, plan_push


@dataclass(frozen=True)
class Case:
    name: str
    scene: str = "default"
    beta: float | None = 6.0
    start_q: tuple[float, ...] | None = None
    push: tuple[float, float, float] = (0.25, 0.0, 0.0)  # target relative to the cube's start: dx, dy (m), dyaw (rad)
    control_period_s: float | None = None


def load_cases(path: str | Path | None = None) -> dict[str, Case]:
    path = Path(path) if path is not None else config_path("hard_cases.yaml")
    with open(path, encoding="utf-8") as stream:
        document = yaml.safe_load(stream)
    base = document.get("base", {})
    cases = {}
    for name, spec in document.get("cases", {}).items():
        merged = {**base, **(spec or {})}
        unknown = set(merged) - {"scene", "beta", "start_q", "push", "control_period_s"}
        if unknown:
            raise ValueError(f"{path}: case {name}: unknown keys {sorted(unknown)}")
        cases[name] = Case(name=name, scene=merged.get("scene", "default"), beta=merged.get("beta"),
                           start_q=tuple(merged["start_q"]) if merged.get("start_q") else None,
                           push=tuple(merged.get("push", (0.25, 0.0, 0.0))),
                           control_period_s=merged.get("control_period_s"))
    return cases


def result_is_finite(result: PlanResult) -> bool:
    """No NaN or Inf in any array or metric of a plan."""
    arrays = [result.knot_torques_Nm, result.knot_contact_control, *result.knot_variables.values()]
    for trajectory in (result.trajectory, result.replay):
        arrays += [value for value in vars(trajectory).values() if isinstance(value, np.ndarray)]
    metrics = [v for v in vars(result.metrics).values() if isinstance(v, float)]
    return all(bool(np.all(np.isfinite(a))) for a in arrays) and all(math.isfinite(v) for v in metrics)


def run_case(case: Case, contact_model: str, parameters: Mapping[str, Any] | None = None,
             options: SolverOptions | None = None) -> tuple[dict[str, Any], PlanResult | None]:
    """Plan a case; return its record and the plan (None when the case cannot be posed)."""
    parameters = copy.deepcopy(dict(load_parameters() if parameters is None else parameters))
    if case.control_period_s is not None:
        parameters["control_period_s"] = case.control_period_s
    record: dict[str, Any] = {"case": case.name, "contact_model": contact_model}
    try:
        scene = SceneConfig.load(case.scene)
        x, y = scene.object.position_m
        result = plan_push(contact_model, case.beta, start_q=None if case.start_q is None else np.array(case.start_q),
                           target_position_m=[x + case.push[0], y + case.push[1]], target_yaw_rad=case.push[2],
                           scene=case.scene, options=options, parameters=parameters)
    except ValueError as error:
        record.update(status="invalid_request", success=False, message=str(error), finite=True,
                      position_error_m=None, orientation_error_rad=None, physical_inaccuracy_Ns=None,
                      replay_position_error_m=None, solve_time_s=0.0, iterations=0, warnings={})
        return record, None
    summary = result.summary()
    record.update({key: summary[key] for key in (
        "status", "success", "position_error_m", "orientation_error_rad", "physical_inaccuracy_Ns",
        "replay_position_error_m", "solve_time_s", "iterations", "warnings", "initial_distance_m")})
    record.update(message="", finite=result_is_finite(result))
    return record, result
