"""The planner's settings as a whole (config/planner.yaml, `ros__parameters`) and how they are loaded."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from cito_ros.settings.contact import CONTACT_MODEL_NAMES, ContactModelsSettings, WeightsSettings
from cito_ros.settings.execution import ExecutorSettings, LimitSettings, TrackingSettings
from cito_ros.settings.paths import config_path, read_yaml
from cito_ros.settings.scene import SceneConfig
from cito_ros.settings.solver import DerivativeSettings, SolverSettings
from cito_ros.settings.stages import StagesSettings
from cito_ros.settings.typed_config import parse, setting, unparse

PLANNER_FILE = "planner.yaml"


def _scene(value: Any, name: str) -> SceneConfig:
    if isinstance(value, SceneConfig):
        return value
    if not isinstance(value, str) or not value:
        raise ValueError(f"{name} must be a scene name in config/scenes, got {value!r}")
    return SceneConfig.load(value)


@dataclass(frozen=True)
class NodeSettings:
    default_contact_model: str = setting("contact model for requests with an empty contact_model",
                                         choices=CONTACT_MODEL_NAMES)
    bag_directory: str = setting("one rosbag2 (MCAP) bag per plan; relative to the working directory")
    frame_id: str = setting("frame of every stamped message")


@dataclass(frozen=True)
class TaskSettings:
    push_distance_m: float = setting("default target: this far along world +x from the object's start")
    success_position_error_m: float = setting("success: the executed plan ends this close to the goal (m)",
                                              positive=True)
    success_orientation_error_rad: float = setting("success: and this close in orientation (rad)", positive=True)
    rest_speed_m_s: float = setting("success: the object at rest after the hold, no point of it faster than this (m/s)",
                                    positive=True)
    planned_success_position_error_m: float = setting("the paper's criterion on the planned error (m)",
                                                      positive=True)
    position_error_scale_min_m: float = setting("floor of the position-cost normaliser ||p_0 - p*|| (m)",
                                                positive=True)
    target_height_tolerance_m: float = setting("a target's z must be the object's resting height within this (m)",
                                               positive=True)
    turn_per_push_rad_per_m: float = setting("one push on the pushed face turns the object by at most "
                                             "success_orientation_error_rad plus this much per metre its centre moves: "
                                             "a goal that needs more is refused at once (rad/m)", positive=True)
    aim_turn_rad_per_m: float = setting(
        "a goal whose turn beyond success_orientation_error_rad is more than this per metre of its distance from the "
        "object (a turn near or at the object's place) is aimed past, along the near face's push, as far as this "
        "needs (rad/m; below turn_per_push_rad_per_m: at that bound few pushes succeed)", positive=True)
    aim_past_max_m: float = setting("how far past the goal a push aims at most (m; within success_position_error_m: "
                                    "the plan is judged at the goal); 0: never", minimum=0.0)


@dataclass(frozen=True)
class HorizonSettings:
    horizon_s: float = setting("planned horizon (s)", positive=True)
    control_period_s: float = setting("t_c: one knot per control period (s)", positive=True)


@dataclass(frozen=True)
class Settings:
    """The planner's settings (config/planner.yaml, `ros__parameters`)."""

    node: NodeSettings = setting("cito_planner_node only")
    scene: SceneConfig = setting("scene in config/scenes", convert=_scene, unconvert=lambda scene: scene.source)
    beta: float = setting("start pose q0(beta) = [-pi/12, -pi/b, 0, 3pi/b, -pi/6, -2pi/b, 0]", positive=True)
    pipeline: str = setting("physical: plans refined without the virtual force; paper: the paper's problem",
                            choices=("physical", "paper"))
    horizon_s: float = setting("planned horizon of the physical pipeline (s)", positive=True)
    control_period_s: float = setting("t_c: one knot per control period (s)", positive=True)
    paper: HorizonSettings = setting("the paper's horizon and knots")
    contact_models: ContactModelsSettings = setting("contact model parameters")
    task: TaskSettings = setting("targets and success")
    weights: WeightsSettings = setting("cost weights per contact model")
    gradient: DerivativeSettings = setting("derivatives")
    stages: StagesSettings = setting("the physical pipeline's stages")
    limits: LimitSettings = setting("the arm's limits in the physical pipeline")
    tracking: TrackingSettings = setting("the joint trajectory controller a plan is also executed with")
    executor: ExecutorSettings = setting("the closed-loop executor")
    solver: SolverSettings = setting("solver")

    def check(self, path: str) -> None:
        executor = HorizonSettings(self.executor.horizon_s, self.control_period_s)
        for where, period, horizon in (("", "", self), ("paper.", "paper.", self.paper), ("executor.", "", executor)):
            knots = horizon.horizon_s / horizon.control_period_s
            if abs(knots - round(knots)) > 1e-9 or round(knots) < 1:
                raise ValueError(f"{where}horizon_s {horizon.horizon_s} must be a positive whole number of control "
                                 f"periods {period}control_period_s {horizon.control_period_s}")
            steps = horizon.control_period_s / self.scene.timestep_s
            if abs(steps - round(steps)) > 1e-9 or round(steps) < 1:
                raise ValueError(f"{period}control_period_s {horizon.control_period_s} must be a whole number of "
                                 f"timesteps {self.scene.timestep_s} (scene {self.scene.name})")

    @property
    def round_horizons_s(self) -> tuple[float, ...]:
        """The physical pipeline's horizon per stages.horizon_scales entry, in whole control periods."""
        return tuple(self.round_horizon_s(scale) for scale in self.stages.horizon_scales)

    def round_horizon_s(self, scale: float) -> float:
        """horizon_s times scale, in whole control periods."""
        return max(round(self.horizon_s * scale / self.control_period_s), 1) * self.control_period_s

    @property
    def horizon(self) -> tuple[float, float]:
        """(horizon_s, control_period_s) of the configured pipeline."""
        if self.pipeline == "paper":
            return self.paper.horizon_s, self.paper.control_period_s
        return self.horizon_s, self.control_period_s

    @classmethod
    def from_mapping(cls, parameters: Mapping[str, Any]) -> "Settings":
        """Settings from the nested `ros__parameters` tree; ValueError naming the first bad value."""
        return parse(cls, parameters, "")

    def to_mapping(self) -> dict[str, Any]:
        """The nested parameter tree these settings were read from."""
        return unparse(self)

    def with_overrides(self, overrides: Mapping[str, Any]) -> "Settings":
        """A copy with parameters replaced by dotted name ({"solver.max_iter": 10}), validated."""
        tree = self.to_mapping()
        for dotted, value in overrides.items():
            keys = dotted.split(".")
            node = tree
            for i, key in enumerate(keys[:-1]):
                child = node.get(key)
                if child is None:
                    child = node[key] = {}
                if not isinstance(child, dict):
                    raise ValueError(f"{'.'.join(keys[:i + 1])} is a value, not a section: cannot set {dotted}")
                node = child
            if value is None:
                node.pop(keys[-1], None)
            else:
                node[keys[-1]] = value
        return Settings.from_mapping(tree)

    def contact_model_settings(self, name: str):
        return getattr(self.contact_models, name)


def load_parameters(path: str | Path | None = None) -> dict[str, Any]:
    """The nested `ros__parameters` mapping of a params file (the node's or the wildcard entry)."""
    path = Path(path) if path is not None else config_path(PLANNER_FILE)
    document = read_yaml(path)
    if isinstance(document, Mapping):
        for entry in document.values():
            if isinstance(entry, Mapping) and isinstance(entry.get("ros__parameters"), Mapping):
                return dict(entry["ros__parameters"])
    raise ValueError(f"{path}: no '<node>: ros__parameters:' section found")


def load_settings(path: str | Path | None = None) -> Settings:
    """Settings from a params file (default config/planner.yaml)."""
    return Settings.from_mapping(load_parameters(path))
