"""Every planner setting, read once into typed, frozen, validated dataclasses.

`load_settings()` reads `config/planner.yaml` (the ROS params-file the node
loads too); `Settings.from_mapping` takes the same tree from anywhere else (the
node's parameters). Every value comes from that file: the dataclasses have no
defaults of their own, a missing or unknown parameter is an error, and every
bad value is reported with its dotted name before anything is solved. Below
these entry points nothing reads a raw parameter dict.

Each field's metadata carries its description and admissible range, which the
validation here and the ROS parameter descriptors share.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import yaml

from cito_ros.paths import config_path
from cito_ros.typed_config import parse, setting, unparse

PLANNER_FILE = "planner.yaml"
DEFAULT_SCENE = "default"
CONTACT_MODEL_NAMES = ("cccm", "scm", "vscm")


# ------------------------------------------------------------------------------------- scenes

@dataclass(frozen=True)
class ObjectConfig:
    half_size_m: float = setting("cube half edge (m)", positive=True)
    mass_kg: float = setting("cube mass (kg)", positive=True)
    position_m: tuple[float, ...] = setting("cube centre x, y (m, world); z follows from the table top")
    yaw_rad: float = setting("cube yaw about world z (rad)")
    friction: float = setting("sliding friction of every pair involving the cube", minimum=0.0)

    def check(self, path: str) -> None:
        if len(self.position_m) != 2:
            raise ValueError(f"{path}.position_m must be [x, y], got {list(self.position_m)}")


@dataclass(frozen=True)
class SceneConfig:
    """A push scene: the model file and what is applied on top of it.

    `config/scenes/default.yaml` gives every field; any other scene file gives only what it
    changes, applied over the default scene, so every scene default lives in that one file.
    """

    description: str = setting("what the scene is")
    model: str = setting("model file in models/")
    timestep_s: float = setting("simulation timestep (s)", positive=True)
    object: ObjectConfig = setting("the object to push")
    collisions: str = setting("minimal: the model's pair list (or `pairs`); all: every geom pair",
                              choices=("minimal", "all"))
    pairs: tuple[tuple[str, ...], ...] | None = setting("the collision pairs instead of the model's, as "
                                                        "[geom, geom] names (collisions: minimal only)")
    source: str = field(default="", compare=False, metadata={"internal": True})  # the name or path loaded

    def check(self, path: str) -> None:
        if self.pairs is not None and (self.collisions != "minimal" or any(len(p) != 2 for p in self.pairs)):
            raise ValueError("pairs must be a list of [geom, geom] names, with collisions: minimal")

    @property
    def name(self) -> str:
        return Path(self.source).stem

    @classmethod
    def load(cls, name_or_path: str | Path = DEFAULT_SCENE) -> "SceneConfig":
        """Load `config/scenes/<name>.yaml`, or a YAML file given by path."""
        path = Path(name_or_path)
        if path.suffix not in (".yaml", ".yml"):
            path = config_path("scenes") / f"{name_or_path}.yaml"
        if not path.is_file():
            raise ValueError(f"unknown scene {str(name_or_path)!r}: {path} does not exist")
        with open(path, encoding="utf-8") as stream:
            raw = yaml.safe_load(stream) or {}
        return cls.from_mapping(path.stem, raw, source=str(name_or_path))

    @classmethod
    def from_mapping(cls, name: str, raw: Mapping[str, Any], source: str | None = None) -> "SceneConfig":
        """A scene from its description, applied over the default scene's."""
        tree = raw
        if name != DEFAULT_SCENE:
            with open(config_path("scenes") / f"{DEFAULT_SCENE}.yaml", encoding="utf-8") as stream:
                tree = _merged(yaml.safe_load(stream), raw)
        try:
            scene = parse(cls, tree, "")
        except ValueError as error:
            raise ValueError(f"scene {name}: {error}") from None
        return dataclasses.replace(scene, source=name if source is None else source)


def _merged(base: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    tree = dict(base)
    for key, value in changes.items():
        tree[key] = _merged(base[key], value) if isinstance(value, Mapping) and isinstance(base.get(key), Mapping) \
            else value
    return tree


def _options(value: Any, name: str) -> tuple[tuple[str, Any], ...]:
    if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
        raise ValueError(f"{name} must be a section of option names and values, got {value!r}")
    return tuple(value.items())


def _scene(value: Any, name: str) -> SceneConfig:
    if isinstance(value, SceneConfig):
        return value
    if not isinstance(value, str) or not value:
        raise ValueError(f"{name} must be a scene name in config/scenes, got {value!r}")
    return SceneConfig.load(value)


# ---------------------------------------------------------------------------------- planner

@dataclass(frozen=True)
class NodeSettings:
    default_contact_model: str = setting("contact model for requests with an empty contact_model",
                                         choices=CONTACT_MODEL_NAMES)
    bag_directory: str = setting("one rosbag2 (MCAP) bag per plan; relative to the working directory")
    frame_id: str = setting("frame of every stamped message")


@dataclass(frozen=True)
class ScmSettings:
    stiffness: float = setting("k (N), fixed", positive=True)
    curvature: float = setting("c (N/m); alpha = c / k", positive=True)


@dataclass(frozen=True)
class VscmSettings:
    stiffness_max: float = setting("upper bound of k per knot (N)", positive=True)
    stiffness_initial: float = setting("k per knot at the optimizer's start (N)", minimum=0.0)
    curvature: float = setting("c (N/m)", positive=True)

    def check(self, path: str) -> None:
        if self.stiffness_initial > self.stiffness_max:
            raise ValueError(f"{path}.stiffness_initial {self.stiffness_initial} exceeds "
                             f"{path}.stiffness_max {self.stiffness_max}")


@dataclass(frozen=True)
class CccmSettings:
    force_max: float = setting("upper bound of gamma per knot (N)", positive=True)
    slack_max: float = setting("upper bound of the complementarity slack s per knot (N m)", positive=True)


@dataclass(frozen=True)
class ContactModelsSettings:
    cccm: CccmSettings = setting("relaxed complementarity constraints, force per knot")
    scm: ScmSettings = setting("smooth contact model, gamma = k exp(-(c/k) phi), k fixed")
    vscm: VscmSettings = setting("variable smooth contact model, k per knot in [0, stiffness_max]")


@dataclass(frozen=True)
class TaskSettings:
    push_distance_m: float = setting("default target: this far along world +x from the object's start")
    success_position_error_m: float = setting("success: the executed plan ends this close to the goal (m)",
                                              positive=True)
    success_orientation_error_rad: float = setting("success: and this close in orientation (rad)", positive=True)
    planned_success_position_error_m: float = setting("the paper's criterion on the planned error (m)",
                                                      positive=True)
    position_error_scale_min_m: float = setting("floor of the position-cost normaliser ||p_0 - p*|| (m)",
                                                positive=True)
    target_height_tolerance_m: float = setting("a target's z must be the object's resting height within this (m)",
                                               positive=True)


@dataclass(frozen=True)
class Weights:
    """Cost weights of eqs. (8)-(10); w5 (the CCCM slack) only where the model has slack."""

    w1: float = setting("final position", minimum=0.0)
    w2: float = setting("final orientation", minimum=0.0)
    w3: float = setting("end-effector speed squared", minimum=0.0)
    w4: float = setting("virtual force squared", minimum=0.0)
    w5: float | None = setting("complementarity slack squared (CCCM)", minimum=0.0)


@dataclass(frozen=True)
class WeightsSettings:
    cccm: Weights = setting("CCCM cost weights")
    scm: Weights = setting("SCM cost weights")
    vscm: Weights = setting("VSCM cost weights")

    def check(self, path: str) -> None:
        if self.cccm.w5 is None:
            raise ValueError(f"{path}.cccm.w5: missing (CCCM's slack weight)")


@dataclass(frozen=True)
class DerivativeSettings:
    method: str = setting("adjoint (per-step linearization) or forward_differences (knot restarts)",
                          choices=("adjoint", "forward_differences"))
    epsilon: float = setting("finite-difference step of the per-step linearization", positive=True)
    restart_step: float = setting("knot-restart difference step, relative to the variable scale", positive=True)
    threads: int = setting("linearization threads, one mjData each", minimum=1)


@dataclass(frozen=True)
class HorizonSettings:
    horizon_s: float = setting("planned horizon (s)", positive=True)
    control_period_s: float = setting("t_c: one knot per control period (s)", positive=True)


@dataclass(frozen=True)
class DiscoverySettings:
    reach_weight: float = setting("weight of the plate-object gap, squared, from the start's fraction of the "
                                  "horizon on", minimum=0.0)
    max_iter: int = setting("solver iterations of the discovery", minimum=1)
    cccm: str = setting("CCCM's discovery: slack_eliminated (s = phi gamma: box-bounded, solved by stages.solver) "
                        "or constraints (the paper's slack and constraints, by IPOPT)",
                        choices=("slack_eliminated", "constraints"))


@dataclass(frozen=True)
class PhysicalStage:
    """One stage without the virtual force (see PhysicalStages)."""

    contact_weight: float
    joint_speed_weight: float
    joint_position_weight: float
    max_iter: int
    only_if_beyond_limits: bool


@dataclass(frozen=True)
class PhysicalStages:
    """The stages without the virtual force, one entry of each list per stage, in order."""

    contact_weight: tuple[float, ...] = setting("weight of the plate-object gap, squared, from the touch-down on",
                                                minimum=0.0)
    joint_speed_weight: tuple[float, ...] = setting("weight of the joint speeds beyond their margin", minimum=0.0)
    joint_position_weight: tuple[float, ...] = setting("weight of the joint positions beyond their margin",
                                                       minimum=0.0)
    max_iter: tuple[int, ...] = setting("solver iterations of the stage", minimum=1)
    only_if_beyond_limits: tuple[bool, ...] = setting("run only while the best plan so far is beyond the arm's "
                                                      "limits (joint speeds or ranges)")

    def check(self, path: str) -> None:
        lengths = {len(getattr(self, f.name)) for f in dataclasses.fields(self)}
        if len(lengths) != 1 or 0 in lengths:
            raise ValueError(f"{path} must list at least one stage, with one entry per stage in each of "
                             f"{[f.name for f in dataclasses.fields(self)]}")
        if self.only_if_beyond_limits[0]:
            raise ValueError(f"{path}.only_if_beyond_limits[0] must be false: the first stage refines every start")

    def __iter__(self):
        return (PhysicalStage(*values) for values in zip(self.contact_weight, self.joint_speed_weight,
                                                           self.joint_position_weight, self.max_iter,
                                                           self.only_if_beyond_limits))


@dataclass(frozen=True)
class ScriptVariants:
    """Further scripted starts, one entry of each list per start, in order: the scripted push again with
    these values, after the first script and before the discoveries."""

    contact_height_m: tuple[float, ...] = setting("the variant's contact_height_m (m)")
    push_end_fraction: tuple[float, ...] = setting("the variant's push_end_fraction", positive=True)
    horizon_scale: tuple[float, ...] = setting("the variant's horizon, in horizon_s", positive=True)

    def check(self, path: str) -> None:
        if len({len(getattr(self, f.name)) for f in dataclasses.fields(self)}) != 1:
            raise ValueError(f"{path} must give every variant one entry in each of "
                             f"{[f.name for f in dataclasses.fields(self)]}")

    def __iter__(self):
        return iter(zip(self.contact_height_m, self.push_end_fraction, self.horizon_scale))


@dataclass(frozen=True)
class ScriptedSettings:
    """The scripted push, the physical pipeline's first start (cito_ros.scripted), and its variants."""

    enabled: bool = setting("try the scripted push before the discoveries")
    approach_fraction: float = setting("fraction of the horizon the plate takes to get behind the object",
                                       positive=True)
    push_end_fraction: float = setting("fraction of the horizon where the push ends (then the plate holds)",
                                       positive=True)
    standoff_m: float = setting("gap between plate and object at the end of the approach (m)", minimum=0.0)
    contact_height_m: float = setting("height of the plate centre above the object's centre (m)")
    speed_fraction: float = setting("each joint's step within this fraction of its velocity limit", positive=True)
    joint_margin_rad: float = setting("joints kept this far inside their ranges (rad)", minimum=0.0)
    orientation_weight: float = setting("weight of the plate normal's direction against the plate position (m/rad)",
                                        minimum=0.0)
    posture_gain: float = setting("pull towards the start posture in the null space, per step", minimum=0.0)
    joint_weights: tuple[float, ...] = setting("cost of moving each joint in the least squares (7)", positive=True)
    damping: float = setting("damping of the least squares (m^2)", positive=True)
    ik_iterations: int = setting("least-squares iterations per simulation step", minimum=1)
    variants: ScriptVariants = setting("further scripted starts where the first misses")

    def check(self, path: str) -> None:
        for push_end in (self.push_end_fraction, *self.variants.push_end_fraction):
            if not self.approach_fraction < push_end <= 1.0:
                raise ValueError(f"{path}: approach_fraction < push_end_fraction <= 1 is needed, got "
                                 f"{self.approach_fraction} and {push_end}")
        if len(self.joint_weights) != 7:
            raise ValueError(f"{path}.joint_weights must have one entry per arm joint (7), got {len(self.joint_weights)}")


IPOPT_CURVATURES = ("limited_memory", "gauss_newton")


@dataclass(frozen=True)
class StagesSettings:
    solver: str = setting("solver of the box-bounded stages (SCM, VSCM, CCCM with its slack eliminated, physical)",
                          choices=("ilqr", "least_squares", "ipopt"))
    ipopt_curvature: str = setting("IPOPT's Hessian in the physical pipeline (CCCM's discovery, any stage with "
                                   "solver: ipopt): gauss_newton, from the linearizations, or limited_memory, the "
                                   "paper's", choices=IPOPT_CURVATURES)
    starts: tuple[float, ...] = setting("one discovery per entry, drawing the plate onto the object from this "
                                        "fraction of the horizon on", minimum=0.0)
    horizon_scales: tuple[float, ...] = setting("the starts are solved at horizon_s times each of these in "
                                                "turn", positive=True)
    parallel: bool = setting("solve the next start speculatively beside the current one (the same plan)")
    scripted: ScriptedSettings = setting("the scripted push, the first start")
    discovery: DiscoverySettings = setting("the contact model's stage")
    physical: PhysicalStages = setting("the stages without the virtual force")
    touch_force_N: float = setting("a virtual force above this marks the discovery's touch-down", positive=True)
    goal_margin: float = setting("a start's stages end once its executed plan is within this fraction of the success "
                                 "tolerances (at most 1)", positive=True)

    def check(self, path: str) -> None:
        if not self.starts or any(start >= 1.0 for start in self.starts):
            raise ValueError(f"{path}.starts must be one or more fractions of the horizon in [0, 1), "
                             f"got {list(self.starts)}")
        if not self.horizon_scales:
            raise ValueError(f"{path}.horizon_scales must list at least one scale of horizon_s")
        if self.goal_margin > 1.0:
            raise ValueError(f"{path}.goal_margin must be a fraction of the success tolerances in (0, 1], "
                             f"got {self.goal_margin}")


@dataclass(frozen=True)
class LimitSettings:
    joint_speed_weight: float = setting("the discovery's weight of (|qdot| / limit - margin)^2 beyond the margin",
                                        minimum=0.0)
    joint_speed_margin: float = setting("fraction of the velocity limit where the speed term starts", positive=True)
    max_joint_speed_ratio: float = setting("a plan faster than this fraction of a velocity limit is no success",
                                           positive=True)
    joint_position_weight: float = setting("the discovery's weight of the joint positions beyond their margin",
                                           minimum=0.0)
    joint_position_margin_rad: float = setting("margin inside each joint's range (rad)", minimum=0.0)
    object_velocity_weight: float = setting("weight of the object's final velocity", minimum=0.0)


@dataclass(frozen=True)
class TrackingSettings:
    kp: tuple[float, ...] = setting("PD position gains of the joint trajectory controller (N m/rad)", minimum=0.0)
    kd: tuple[float, ...] = setting("PD velocity gains (N m s/rad)", minimum=0.0)
    max_error_increase_m: float = setting(
        "physical pipeline: a start's plan at the goal ends the search only if the PD controller's execution "
        "ends within this of its executed error; otherwise the next starts run (m)", minimum=0.0)
    reference_offsets: int = setting(
        "physical pipeline: seeded smooth offsets of the tracked reference; a start's plan at the goal ends the "
        "search only if the PD controller brings the object within the success tolerance under every one and "
        "without them (where no start's does, the best plan is one it follows without them); 0: the nominal "
        "tracking alone, within max_error_increase_m", minimum=0)
    reference_offset_rad: float = setting("the largest offset of any joint (rad)", minimum=0.0)
    hold_s: float = setting(
        "after a plan's last point the controller holds it at rest this long, as a joint trajectory controller "
        "does; every execution is judged where the object is then, not at the end of the horizon (s)", minimum=0.0)

    def check(self, path: str) -> None:
        if len(self.kp) != 7 or len(self.kd) != 7:
            raise ValueError(f"{path}.kp and {path}.kd must have one gain per arm joint (7)")


@dataclass(frozen=True)
class SolverSettings:
    max_iter: int = setting("IPOPT iterations per stage", minimum=1)
    time_limit_s: float = setting("wall clock of the whole solve, checked every iteration (s)", positive=True)
    stall_iterations: int = setting("stop when the best cost improved by less than stall_tolerance over this "
                                    "many iterations", minimum=1)
    stall_tolerance: float = setting("relative cost improvement below which the solve has stalled", minimum=0.0)
    restarts: int = setting("re-solves from the best point when the first ends short of the task", minimum=0)
    scale_variables: bool = setting("IPOPT sees z / scale (torque limits, k_max, gamma_max, slack_max)")
    ipopt: tuple[tuple[str, Any], ...] = setting("options passed to IPOPT as they are", convert=_options,
                                                 unconvert=dict)
    least_squares: tuple[tuple[str, Any], ...] = setting("options passed to mujoco.minimize.least_squares as "
                                                         "they are", convert=_options, unconvert=dict)
    ilqr: tuple[tuple[str, Any], ...] = setting("iLQR: mu_initial, mu_min, mu_max, mu_factor, step_lengths, "
                                                "accept_ratio, tolerance", convert=_options, unconvert=dict)

    @property
    def ipopt_options(self) -> dict[str, Any]:
        return dict(self.ipopt)

    @property
    def least_squares_options(self) -> dict[str, Any]:
        return dict(self.least_squares)

    @property
    def ilqr_options(self) -> dict[str, Any]:
        return dict(self.ilqr)


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
    solver: SolverSettings = setting("solver")

    def check(self, path: str) -> None:
        for where, horizon in (("", self), ("paper.", self.paper)):
            knots = horizon.horizon_s / horizon.control_period_s
            if abs(knots - round(knots)) > 1e-9 or round(knots) < 1:
                raise ValueError(f"{where}horizon_s {horizon.horizon_s} must be a positive whole number of control "
                                 f"periods {where}control_period_s {horizon.control_period_s}")
            steps = horizon.control_period_s / self.scene.timestep_s
            if abs(steps - round(steps)) > 1e-9 or round(steps) < 1:
                raise ValueError(f"{where}control_period_s {horizon.control_period_s} must be a whole number of "
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
    with open(path, encoding="utf-8") as stream:
        document = yaml.safe_load(stream)
    if isinstance(document, Mapping):
        for entry in document.values():
            if isinstance(entry, Mapping) and isinstance(entry.get("ros__parameters"), Mapping):
                return dict(entry["ros__parameters"])
    raise ValueError(f"{path}: no '<node>: ros__parameters:' section found")


def load_settings(path: str | Path | None = None) -> Settings:
    """Settings from a params file (default config/planner.yaml)."""
    return Settings.from_mapping(load_parameters(path))


