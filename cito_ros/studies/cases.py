"""Named planning cases (config/hard_cases.yaml), run with a clear status for every outcome.

ROS-free. A case changes the default problem by scene, start pose, target and
knot spacing; `run_case` plans it and returns one JSON-serialisable record,
with `status` 'invalid_request' (and the reason) when the case cannot be posed,
never an exception.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cito_ros.planner.plan import plan_push
from cito_ros.planner.results import METRIC_NAMES, PlanResult
from cito_ros.settings import SceneConfig, Settings, load_settings
from cito_ros.settings.paths import config_path, read_yaml


@dataclass(frozen=True)
class Case:
    name: str
    scene: str = "default"
    beta: float | None = 6.0
    start_q: tuple[float, ...] | None = None
    push: tuple[float, float, float] = (0.25, 0.0, 0.0)  # target relative to the cube's start: dx, dy (m), dyaw (rad)
    knots: int | None = None  # N over the pipeline's horizon, instead of the configured control period


def load_cases(path: str | Path | None = None) -> dict[str, Case]:
    path = Path(path) if path is not None else config_path("hard_cases.yaml")
    document = read_yaml(path)
    base = document.get("base", {})
    cases = {}
    for name, spec in document.get("cases", {}).items():
        merged = {**base, **(spec or {})}
        unknown = set(merged) - {"scene", "beta", "start_q", "push", "knots"}
        if unknown:
            raise ValueError(f"{path}: case {name}: unknown keys {sorted(unknown)}")
        cases[name] = Case(name=name, scene=merged.get("scene", "default"), beta=merged.get("beta"),
                           start_q=tuple(merged["start_q"]) if merged.get("start_q") else None,
                           push=tuple(merged.get("push", (0.25, 0.0, 0.0))),
                           knots=merged.get("knots"))
    return cases


def run_case(case: Case, contact_model: str, settings: Settings | None = None) -> tuple[dict[str, Any], PlanResult | None]:
    """Plan a case; return its record (the metrics by name, with the case) and the plan (None when the
    case cannot be posed: then status 'invalid_request' and the reason)."""
    settings = load_settings() if settings is None else settings
    record: dict[str, Any] = {"case": case.name, "contact_model": contact_model}
    try:
        if case.knots is not None:
            horizon_s, _ = settings.horizon
            key = "paper.control_period_s" if settings.pipeline == "paper" else "control_period_s"
            settings = settings.with_overrides({key: horizon_s / case.knots})
        scene = SceneConfig.load(case.scene)
        x, y = scene.object.position_m
        result = plan_push(contact_model, case.beta, start_q=None if case.start_q is None else np.array(case.start_q),
                           target_position_m=[x + case.push[0], y + case.push[1]], target_yaw_rad=case.push[2],
                           scene=case.scene, settings=settings)
    except ValueError as error:
        record.update({name: None for name in METRIC_NAMES})
        record.update(status="invalid_request", success=False, message=str(error), finite=True, solve_time_s=0.0,
                      iterations=0, warnings={}, initial_distance_m=None)
        return record, None
    summary = result.summary()
    record.update({key: summary[key] for key in (*METRIC_NAMES, "warnings", "initial_distance_m")})
    record.update(message="", finite=result.finite())
    return record, result
