"""The physical pipeline's stages: the scripted starts, the discovery, the stages without the virtual force."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from cito_ros.settings.typed_config import setting


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
    gain_scale: tuple[float, ...] = setting("the variant's gain_scale", positive=True)

    def check(self, path: str) -> None:
        if len({len(getattr(self, f.name)) for f in dataclasses.fields(self)}) != 1:
            raise ValueError(f"{path} must give every variant one entry in each of "
                             f"{[f.name for f in dataclasses.fields(self)]}")

    def __iter__(self):
        return iter(zip(self.contact_height_m, self.push_end_fraction, self.horizon_scale, self.gain_scale))


@dataclass(frozen=True)
class SideFaceSettings:
    """Scripted pushes on the object's side faces, for goals more than 45 degrees off the near face's normal
    (cito_ros.planner.side_faces)."""

    enabled: bool = setting("plan goals beside the object by a push on a side face (false: refused)")
    horizon_scale: float = setting("the side push's horizon, in horizon_s: the transit around the object's corner "
                                   "takes most of horizon_s within the joint speed limits", positive=True)
    control_period_s: float = setting("the side push's knot period (s): the transit's torques, replayed open loop at "
                                      "horizon_s's period, swing the arm off its path", positive=True)
    gradient_stride: int = setting("the side push's solves linearize every this many simulation steps, and every "
                                   "step where the plate's contact begins or ends (gradient.stride for them)",
                                   minimum=1)
    faces: tuple[int, ...] = setting("the side faces planned, in quarter turns counter-clockwise from the near face "
                                     "(1, 3); a goal needing another is refused")
    offset_scales: tuple[float, ...] = setting("one scripted start per entry: the contact's offset along the face "
                                               "(the one that turns the object by the goal's turn) times this")
    tilts_rad: tuple[float, ...] = setting("the plate normal turned from the side face's inward normal away from the "
                                           "arm (rad): the first at which the plate reaches the contact")
    contact_height_m: float = setting("height of the plate centre above the object's centre (m)")
    standoff_m: float = setting("the transit ends with the plate this far off the face (m)", positive=True)
    via_front_m: float = setting("the transit's via point: this far in front of the near face (m)")
    via_aside_m: float = setting("and this far out beside the side face (m)")
    transit_fraction: float = setting("fraction of the horizon the transit takes", positive=True)
    max_transit_fraction: float = setting("and at most, where the joints would exceed the script's speed_fraction of "
                                          "their limits", positive=True)
    contact_fraction: float = setting("fraction of the rest where the plate is on the face", positive=True)
    push_end_fraction: float = setting("fraction of the rest where the push ends", positive=True)
    turn_per_offset: float = setting("the object's turn per metre pushed per metre of contact offset (rad/m^2, "
                                     "measured)", positive=True)
    max_offset_m: float = setting("the contact offset from the face centre at most (m)", minimum=0.0)
    normal_weight: float = setting("weight of the plate normal against its position in the inverse kinematics (m)",
                                   positive=True)
    table_clearance_m: float = setting("the arm's links kept this far above the table top by the path's inverse "
                                       "kinematics (m)", minimum=0.0)
    reach_tolerance_m: float = setting("where the plate falls short of the side contact by more than this, at the "
                                       "push's start or end, only the near face's starts run (m)", positive=True)

    def check(self, path: str) -> None:
        transit_ok = 0.0 < self.transit_fraction <= self.max_transit_fraction < 1.0
        if not transit_ok or not 0.0 < self.contact_fraction < self.push_end_fraction <= 1.0:
            raise ValueError(f"{path}: 0 < transit_fraction <= max_transit_fraction < 1 and 0 < contact_fraction < "
                             f"push_end_fraction <= 1 are needed, got {self.transit_fraction}, "
                             f"{self.max_transit_fraction}, {self.contact_fraction}, {self.push_end_fraction}")
        if not self.offset_scales or not self.tilts_rad:
            raise ValueError(f"{path}.offset_scales and tilts_rad must list at least one entry each")
        if not set(self.faces) <= {1, 3}:
            raise ValueError(f"{path}.faces must list side faces, 1 or 3 (quarter turns from the near face), "
                             f"got {list(self.faces)}")


@dataclass(frozen=True)
class SequenceSettings:
    """Two pushes for a goal well off the near face's normal (cito_ros.planner.sequence)."""

    across_first_rad: float = setting("a goal ahead of the near face more than this off its inward normal, and "
                                      "further than the position tolerance both across and along it, is reached by "
                                      "two pushes: across it on the side face, then along it (0: one push)",
                                      minimum=0.0)
    first_time_fraction: float = setting("the first push's share of solver.time_limit_s; the second has what is "
                                         "left", positive=True)
    transit_speed_fraction: float = setting("between the pushes the arm goes back the way the first came, no joint "
                                            "faster than this fraction of its speed limit", positive=True)

    def check(self, path: str) -> None:
        if self.first_time_fraction >= 1.0 or self.transit_speed_fraction > 1.0:
            raise ValueError(f"{path}: first_time_fraction must be in (0, 1) and transit_speed_fraction in (0, 1], "
                             f"got {self.first_time_fraction} and {self.transit_speed_fraction}")


@dataclass(frozen=True)
class ScriptedSettings:
    """The scripted push, the physical pipeline's first start (cito_ros.planner.scripted), and its variants."""

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
    gain_scale: float = setting("the path is followed by the tracking controller with tracking.kp, kd times this",
                                positive=True)
    follow_face: bool = setting("for a target at least follow_face_margin_m inside the steady push reach, the "
                                "plate normal is the pushed face's, turning from the object's yaw to the target's "
                                "during the push (false, or nearer that reach's edge: along the push, which turns "
                                "the object to the push's direction)")
    follow_face_margin_m: float = setting("the face is followed only for targets at least this far inside the "
                                          "steady push reach (m)")
    variants: ScriptVariants = setting("further scripted starts where the first misses")
    side_faces: SideFaceSettings = setting("pushes on the object's side faces")

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
    sequence: SequenceSettings = setting("two pushes for a goal well off the near face's normal")
    touch_force_N: float = setting("a virtual force above this marks the discovery's touch-down", positive=True)
    goal_margin: float = setting("a start's stages end once its executed plan is within this fraction of the success "
                                 "tolerances (at most 1)", positive=True)
    orientation_balance: float = setting(
        "the final orientation's weight at least this times the position's, each error in units of its success "
        "tolerance (w2 >= this w1 (tolerance_m / tolerance_rad / position scale)^2; 0: the paper's w2 alone, which "
        "near the goal, at the position scale's floor, weighs a turn off by its tolerance 7 times less than a "
        "position off by its own)", minimum=0.0)

    def check(self, path: str) -> None:
        if any(start >= 1.0 for start in self.starts) or not (self.starts or self.scripted.enabled or
                                                             self.scripted.side_faces.enabled):
            raise ValueError(f"{path}.starts must be fractions of the horizon in [0, 1), at least one where the scripts "
                             f"and the side faces are off, got {list(self.starts)}")
        if not self.horizon_scales:
            raise ValueError(f"{path}.horizon_scales must list at least one scale of horizon_s")
        if self.goal_margin > 1.0:
            raise ValueError(f"{path}.goal_margin must be a fraction of the success tolerances in (0, 1], "
                             f"got {self.goal_margin}")
