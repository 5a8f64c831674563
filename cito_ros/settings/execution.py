"""How a plan is executed and judged: the arm's limits and the joint trajectory controller."""
from __future__ import annotations

from dataclasses import dataclass

from cito_ros.settings.solver import SWITCHES
from cito_ros.settings.typed_config import setting


@dataclass(frozen=True)
class LimitSettings:
    joint_speed_weight: float = setting("the discovery's weight of (|qdot| / limit - margin)^2 beyond the margin",
                                        minimum=0.0)
    joint_speed_margin: float = setting("fraction of the velocity limit where the speed term starts", positive=True)
    joint_position_weight: float = setting("the discovery's weight of the joint positions beyond their margin",
                                           minimum=0.0)
    joint_position_margin_rad: float = setting("margin inside each joint's range (rad)", minimum=0.0)
    object_velocity_weight: float = setting("weight of the object's final velocity", minimum=0.0)


@dataclass(frozen=True)
class TrackingSettings:
    kp: tuple[float, ...] = setting("PD position gains of the joint trajectory controller (N m/rad)", minimum=0.0)
    kd: tuple[float, ...] = setting("PD velocity gains (N m s/rad)", minimum=0.0)
    feed_forward: bool = setting("the controller adds the plan's torques to its PD (a joint trajectory controller "
                                 "with effort feed-forward, as the executor's servo runs a plan); false: the PD alone")
    max_error_increase_m: float = setting(
        "physical pipeline: a start's plan at the goal ends the search only if the PD controller's execution "
        "ends within this of its executed error; otherwise the next starts run (m)", minimum=0.0)
    reference_offsets: int = setting(
        "physical pipeline: seeded smooth offsets of the tracked reference; a start's plan at the goal ends the "
        "search only if the PD controller brings the object within the success tolerance under every one and "
        "without them (where no start's does, the best plan is one it follows without them); 0: the nominal "
        "tracking alone, within max_error_increase_m", minimum=0)
    reference_offset_rad: float = setting("the largest offset of any joint (rad)", minimum=0.0)
    world_friction_scales: tuple[float, ...] = setting(
        "physical pipeline: worlds whose object's friction is this times the model's (paired by position with "
        "world_mass_scales; the pair 1, 1 is the model itself); a start's plan at the goal ends the search only if "
        "the PD controller also brings the object within the success tolerances in each", positive=True)
    world_mass_scales: tuple[float, ...] = setting("and whose object's mass is this times the model's",
                                                   positive=True)
    world_max_tilt_rad: float = setting(
        "and only if in each of those worlds the object never tilts further than this from upright on the way "
        "(rad; 0: its tilt not judged)", minimum=0.0)
    hold_s: float = setting(
        "after a plan's last point the controller holds it at rest this long, as a joint trajectory controller "
        "does; every execution is judged where the object is then, not at the end of the horizon (s)", minimum=0.0)
    speed_guard: float = setting("the controller keeps every joint within this fraction of its velocity limit "
                                 "speed_horizon_s ahead, as the executor's speed guard does (0: no guard)",
                                 minimum=0.0)
    speed_horizon_s: float = setting("how far ahead (s)", positive=True)

    def check(self, path: str) -> None:
        if len(self.kp) != 7 or len(self.kd) != 7:
            raise ValueError(f"{path}.kp and {path}.kd must have one gain per arm joint (7)")
        if len(self.world_friction_scales) != len(self.world_mass_scales):
            raise ValueError(f"{path}.world_friction_scales and {path}.world_mass_scales must pair up (the same "
                             f"length), got {len(self.world_friction_scales)} and {len(self.world_mass_scales)}")


@dataclass(frozen=True)
class ExecutorSettings:
    """The closed-loop executor (cito_ros.execution.executor): feedback, replanning, and when it stops."""

    replan: bool = setting("replan the push from the measured state while it runs (MPC); off, the push runs its "
                           "plan's policy and a new push is planned from where the cube comes to rest")
    replan_side_pushes: bool = setting("with replan, a push on a side face (side_first_rad) is replanned too; off, "
                                       "it runs its plan's policy (its replans, over the 0.04 s knots of a 4 s push, "
                                       "ran at 7-14 Hz and left as many cubes at the goal: docs/results.md)")
    replan_budget_s: float = setting("a replan stops after the iteration that passes this much time (s)",
                                     positive=True)
    replan_iterations: int = setting("iLQR iterations of a replan at most", minimum=1)
    replan_mu: float = setting("the regularization a replan's iLQR starts from", positive=True)
    replan_regularizations: int = setting("a replan raises iLQR's mu at most this often before it gives up on a "
                                          "step (a forward pass each)", minimum=0)
    replan_stride: int = setting("a replan linearizes every this many simulation steps, the steps between taking "
                                 "the Jacobians of the one before (gradient.stride)", minimum=1)
    replan_switches: str = setting("the contact's switches a replan also linearizes (gradient.switches)",
                                   choices=SWITCHES)
    min_replan_knots: int = setting("no replan with fewer knots of the push left", minimum=1)
    feedback_regularization: float = setting("mu of the backward pass a plan's feedback gains come from, where "
                                             "no iLQR step gave them", positive=True)
    stale_after_s: float = setting("measurements older than this stop the execution, the arm held (s)",
                                   positive=True)
    rest_speed_m_s: float = setting("the cube's estimated speed below which it counts as at rest (m/s)",
                                    positive=True)
    done_fraction: float = setting("a push is judged at the goal when the camera sees the cube at rest within this "
                                   "fraction of the task's tolerances (the larger of position and yaw): the camera's "
                                   "resting pose is off the truth by millimetres and hundredths of a radian",
                                   positive=True)
    polish_orientation_rad: float = setting(
        "a cube at rest within done_fraction of the task's tolerances but turned by more than done_fraction of this "
        "from the goal is pushed again, a push planned with this as the yaw tolerance and made only where it is "
        "sturdy to it; where there is none the execution ends a success (0: never; rad)", minimum=0.0)
    settle_s: float = setting("after a push the arm holds at least this long before the push is judged (s)",
                              minimum=0.0)
    max_pushes: int = setting("pushes per execution: the first, and new ones from where the cube rests", minimum=1)
    side_first_rad: float = setting(
        "a push towards a goal more than this off the near face's inward normal (outside its friction cone), with "
        "pushes left after it, is first made on the side face towards the goal's offset across that normal, to the "
        "waypoint that leaves the rest of the way along it, where that plan is sturdy (0: never)", minimum=0.0)
    side_when_stuck: bool = setting(
        "after a push, where no push on the near face would bring the cube closer (the executor would end there), a "
        "push to the goal on the side face it needs is planned, and made where it is sturdy and brings it closer")
    nominal_when_stuck: bool = setting(
        "after a push, where neither the near face's push sturdy in the worlds nor side_when_stuck's brings the cube "
        "closer, the near face's push planned in the identified cube's world alone (the mass taken as the model's) "
        "is made where it brings it closer there: the push sturdy in the worlds is the one that never touches it")
    waypoint_world_ratio: float = setting(
        "side_first_rad's push to its waypoint is made where its worst world ends within this many times the "
        "tolerances of the waypoint (1: sturdy to it): the pushes after it correct the rest", minimum=1.0)
    max_world_ratio: float = setting(
        "a near-face push that is not sturdy is made only where its worst check world ends the cube within this many "
        "times the tolerances of its target; where neither plan of a push is, the execution ends with the arm held "
        "(beyond, some world throws the cube)", minimum=1.0)
    waypoint_fraction: float = setting("a push whose plan to the goal is not sturdy (PlanResult.sturdy), with pushes "
                                       "left after it, is planned again to this fraction of the way there, and that "
                                       "plan taken if it is sturdy (0: never)", minimum=0.0)
    waypoint_first_after_miss: bool = setting(
        "once a push has gone to a waypoint (its plan to the goal not sturdy), each next push with pushes left after "
        "it is planned to the waypoint first, and to the goal only where that plan is not made")
    direct_iterations: int = setting("the planner's iterations for that plan to the goal, where a waypoint may "
                                     "follow (with none, plan_iterations)", minimum=1)
    off_path_m: float = setting("a push is cut short, the arm held where it is, once the measured cube is this far "
                                "from where the push's reference has it at that instant: the rest of it would push "
                                "the cube on astray; the next push starts from where it comes to rest (m)",
                                positive=True)
    object_gain_scale: float = setting("the plan's feedback gains on the cube's state: this times the backward pass's "
                                       "(0: the arm's servo alone; docs/experiments.md has what the full gains did)",
                                       minimum=0.0)
    retreat_speed_fraction: float = setting("after a push that missed, the arm goes back to where the execution "
                                            "started, no joint faster than this fraction of its velocity limit",
                                            positive=True)
    retreat_min_s: float = setting("and taking at least this long (s)", positive=True)
    start_clearance_m: float = setting("an execution begun with the arm nearer the cube than this first draws it back "
                                       "to the start pose of beta, where its pushes then start (m)", positive=True)
    speed_horizon_s: float = setting("the executor keeps every joint within SPEED_GUARD of its velocity limit this "
                                     "far ahead: the arm's accelerations are clipped to those that cannot pass it "
                                     "by then (s; at least the loop's delay)", positive=True)
    servo_gain_scale: float = setting("the executor's joint servo gains: this times tracking.kp and kd (a servo behind "
                                      "a measurement and command delay of milliseconds needs far lower gains than "
                                      "the planner's zero-delay controller)", positive=True)
    world_friction_scales: tuple[float, ...] = setting(
        "the executor's plans: tracking.world_friction_scales for them (a plan at the goal ends the search only if "
        "the executor's own servo also brings the cube there in each such world)", positive=True)
    world_mass_scales: tuple[float, ...] = setting("and tracking.world_mass_scales for them", positive=True)
    moved_fraction: float = setting("a push planned during the retreat is planned again from where the cube is if "
                                    "it has moved since by more than this fraction of the task's tolerances (the "
                                    "larger of position and yaw)", positive=True)
    predicted_moved_fraction: float = setting(
        "a next push the model predicts moves the cube by no more than this fraction of the task's tolerances is "
        "not made: lower than moved_fraction, the retreat's, which is judged on the camera's noisy poses",
        positive=True)
    identify_friction_scales: tuple[float, ...] = setting(
        "after a push, the cube's frictions among these scales of the model's whose simulation, the arm driven "
        "along its measured path, moves the cube about as the camera saw it (every push so far) are the possible "
        "ones; the next push is planned for the middle of their range, sturdy at its ends (empty: never)",
        positive=True)
    identify_tolerance: float = setting("possible: a mean squared error (of position and yaw, each over its task "
                                        "tolerance) within this of the best's", minimum=0.0)
    identified_spread: float = setting("those ends at least this and 1 / this times the middle", minimum=1.0)
    orientation_balance: float = setting("stages.orientation_balance for the executor's plans and replans: the "
                                         "corrections near the goal turn the cube as they move it", minimum=0.0)
    horizon_s: float = setting("the horizon of the executor's pushes (s; horizon_s for them): a slower push's cube "
                               "goes where the model has it in more worlds", positive=True)
    plan_iterations: int = setting("the planner's iterations for one push (solver.iteration_budget: the best plan "
                                   "by then is taken, the same however loaded the machine is)", minimum=1)
    plan_time_limit_s: float = setting("and the wall clock of all of a push's plans together at most, a safety net (s)",
                                       positive=True)
    time_limit_s: float = setting("an execution's wall-clock limit where the goal gives none (s)", positive=True)

    def replans(self, face: int) -> bool:
        """Whether a push on `face` (side_faces: 0 the near face) is replanned while it runs."""
        return self.replan and (self.replan_side_pushes or face == 0)

    def check(self, path: str) -> None:
        if not self.done_fraction <= 1.0:
            raise ValueError(f"{path}.done_fraction must be at most 1 (a cube judged at the goal outside the task's "
                             f"tolerances is not there), got {self.done_fraction}")
        if not self.waypoint_fraction < 1.0:
            raise ValueError(f"{path}.waypoint_fraction must be below 1 (a fraction of the way to the goal; 0: no "
                             f"waypoints), got {self.waypoint_fraction}")
