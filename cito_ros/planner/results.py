"""What a solve returns: the status enum, the per-iteration log, the metrics and the plan.

ROS-free. `Metrics` is the one declaration of the metric fields: the JSON
summary, the CSV and Markdown writers and the ROS message conversion (the
`cito_msgs/PlanMetrics` message has the same fields, lower-cased) all iterate
over it, so a new metric is one field here and one line in PlanMetrics.msg.
"""
from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cito_ros.model.scene import Scene
from cito_ros.model.simulator import Trajectory
from cito_ros.settings import TaskSettings


class Status(enum.Enum):
    """How a solve ended."""

    CONVERGED = "converged"              # the solver met its tolerance
    ACCEPTABLE = "acceptable"            # the solver met its acceptable-level tolerance
    STALLED = "stalled"                  # the cost stopped improving (stall_iterations, stall_tolerance)
    GOAL_REACHED = "goal_reached"        # the stage's plan, executed, is at the goal with margin: done early
    ITERATION_LIMIT = "iteration_limit"  # best iterate after max_iter iterations
    TIME_LIMIT = "time_limit"            # best iterate when the time limit ran out
    BUDGET_SPENT = "budget_spent"        # best iterate when the solve's iteration budget ran out
    CANCELLED = "cancelled"              # best iterate when cancel was set
    SOLVER_FAILED = "solver_failed"      # the solver gave up (restoration failure, ...)
    NUMERICAL_ERROR = "numerical_error"  # NaN/Inf or MuJoCo warnings in the planned motion

    @property
    def finished(self) -> bool:
        """Whether the solver stopped on its own convergence test."""
        return self in (Status.CONVERGED, Status.ACCEPTABLE, Status.STALLED, Status.GOAL_REACHED)

    @property
    def interrupted(self) -> bool:
        """Whether the solve was stopped from outside (no further stage may run)."""
        return self in (Status.CANCELLED, Status.TIME_LIMIT, Status.BUDGET_SPENT)


@dataclass(frozen=True)
class IterationLog:
    iteration: int               # counted over the stages of one start
    cost: float
    constraint_violation: float
    elapsed_s: float             # since the solve began
    stage: str                   # e.g. "start 1: discovery", "start 1: physical 2"
    position_error_m: float      # the last evaluated point's object position error: where the object comes to
                                 # rest in a stage without the virtual force, at the horizon's end with it (NaN if none)
    virtual_force: bool          # whether that error is with the virtual force (the contact model's plan)
                                 # or executed without it


@dataclass(frozen=True)
class StageRecord:
    """One stage of a solve: where the time and the iterations went."""

    name: str
    status: Status
    iterations: int
    seconds: float               # the stage's wall clock: the four phases below
    cost: float                  # the stage's own cost at its end
    position_error_m: float      # the stage's plan executed without the virtual force, at rest
    rollout_s: float             # simulating the solver's decisions and trials
    linearization_s: float       # the per-step linearizations (and knot-restart differences)
    solver_s: float              # the rest of the solve: backward passes, QPs, IPOPT, residuals
    evaluation_s: float          # executing the stage's plan without the virtual force, to rank it

    def as_dict(self) -> dict[str, Any]:
        return {**{f.name: getattr(self, f.name) for f in dataclasses.fields(self)}, "status": self.status.value}


def metric(description: str) -> Any:
    return field(metadata={"description": description})


@dataclass(frozen=True)
class Metrics:
    """The figures of a plan. Every field is a column of every report and a field of PlanMetrics.msg."""

    position_error_m: float = metric("the returned torques executed without the virtual force (on the robot): "
                                     "object position vs goal where it comes to rest, the arm holding its last "
                                     "position for tracking.hold_s after the horizon")
    orientation_error_rad: float = metric("executed: norm of the Euler-angle deviation from the goal, at rest")
    tracked_position_error_m: float = metric("the returned joint trajectory executed by a PD joint trajectory "
                                             "controller: position error at rest (after the same hold)")
    tracked_orientation_error_rad: float = metric("tracked: orientation error at rest")
    planned_position_error_m: float = metric("the contact model's plan, with the virtual force (the paper's)")
    planned_orientation_error_rad: float = metric("planned: final orientation error")
    physical_inaccuracy_Ns: float = metric("the planned virtual force's integral, sum of gamma dt (Table I)")
    max_joint_speed_ratio: float = metric("executed: largest |qdot_j| / velocity limit_j over the horizon and the "
                                          "hold after it")
    joint_range_excess_rad: float = metric("executed: farthest any joint goes beyond its position range over the "
                                           "horizon and the hold (0 inside)")
    final_object_speed_m_s: float = metric("executed: the object's speed at the end of the horizon, before the hold")
    rest_object_speed_m_s: float = metric("executed: the fastest any point of the object moves after the hold "
                                          "(Scene.object_speed_m_s), where it is judged at rest")
    steady_reach_margin_m: float = metric("the steady push reach (cito_ros.planner.push_limits.steady_reach_m) "
                                          "minus the goal's distance from the arm base: inside it (>= 0) a steady "
                                          "push gets the object there; beyond it (< 0) only a strike at the joint "
                                          "speed limits does, whose outcome is sensitive: best effort")
    solve_time_s: float = metric("wall clock of the whole solve")
    setup_time_s: float = metric("posing the problems (scene, simulator, touch-down profile), summed over starts")
    rollout_time_s: float = metric("simulating the solvers' decisions and trials, summed over stages")
    linearization_time_s: float = metric("per-step linearizations and knot-restart differences, summed over stages")
    solver_time_s: float = metric("the solvers' own work (backward passes, QPs, IPOPT, residuals), summed")
    evaluation_time_s: float = metric("executing each stage's plan without the virtual force to rank it, summed; "
                                      "with starts side by side the five phases sum to more than the solve time")
    iterations: int = metric("solver iterations over all stages and starts")
    status: Status = metric("how the solve ended")
    success: bool = metric("executed, at rest (task.rest_speed_m_s), within task.success_position_error_m and "
                           "success_orientation_error_rad, every joint within its velocity limit and its range over "
                           "the horizon and the hold (succeeds)")
    planned_success: bool = metric("planned error below task.planned_success_position_error_m (the paper's)")

    def as_dict(self) -> dict[str, Any]:
        """JSON-serialisable values by field name (the status by its value)."""
        return {name: value.value if isinstance(value, Status) else value for name, value in self.items()}

    def items(self):
        return ((f.name, getattr(self, f.name)) for f in dataclasses.fields(self))


METRIC_NAMES = tuple(f.name for f in dataclasses.fields(Metrics))


def within_limits(max_joint_speed_ratio: float, joint_range_excess_rad: float) -> bool:
    """Every joint within its velocity limit (a ratio of at most 1.0: a robot faults or clamps beyond it) and
    within its range."""
    return max_joint_speed_ratio <= 1.0 and joint_range_excess_rad == 0.0


def tolerance_ratio(position_m: float, orientation_rad: float, task: TaskSettings) -> float:
    """The larger of the errors as fractions of their success tolerances (below 1: at the goal; inf: NaN)."""
    if not (math.isfinite(position_m) and math.isfinite(orientation_rad)):
        return math.inf
    return max(position_m / task.success_position_error_m, orientation_rad / task.success_orientation_error_rad)


def world_ratio(errors, task: TaskSettings, max_tilt_rad: float) -> float:
    """tolerance_ratio of a world's (position, orientation, tilt) errors (tracking.WorldErrors), or the tilt as a
    fraction of max_tilt_rad where that is larger (max_tilt_rad 0: the tilt not judged)."""
    position_m, orientation_rad, tilt_rad = errors
    ratio = tolerance_ratio(position_m, orientation_rad, task)
    return max(ratio, tilt_rad / max_tilt_rad) if max_tilt_rad > 0 and math.isfinite(ratio) else ratio


def at_goal(position_error_m: float, orientation_error_rad: float, rest_object_speed_m_s: float, task: TaskSettings,
            fraction: float = 1.0) -> bool:
    """The object at rest (task.rest_speed_m_s) within `fraction` of the success tolerances of the goal. NaN
    anywhere is no."""
    return (position_error_m < fraction * task.success_position_error_m
            and orientation_error_rad < fraction * task.success_orientation_error_rad
            and rest_object_speed_m_s < task.rest_speed_m_s)


def succeeds(metrics: Metrics, task: TaskSettings) -> bool:
    """The success verdict of a plan's figures: finite and free of MuJoCo warnings, at the goal at rest, within
    the arm's limits."""
    return (metrics.status is not Status.NUMERICAL_ERROR
            and at_goal(metrics.position_error_m, metrics.orientation_error_rad, metrics.rest_object_speed_m_s, task)
            and within_limits(metrics.max_joint_speed_ratio, metrics.joint_range_excess_rad))


def shortfalls(metrics: Metrics, task: TaskSettings) -> list[str]:
    """What keeps a plan from success, one phrase per gate it fails."""
    out = []
    if metrics.status is Status.NUMERICAL_ERROR:
        out.append("the motion is not finite or raised MuJoCo warnings")
    if not metrics.position_error_m < task.success_position_error_m:
        out.append(f"position {100 * metrics.position_error_m:.2f} cm (needs < {100 * task.success_position_error_m:g})")
    if not metrics.orientation_error_rad < task.success_orientation_error_rad:
        out.append(f"orientation {metrics.orientation_error_rad:.3f} rad (needs < {task.success_orientation_error_rad:g})")
    if not metrics.rest_object_speed_m_s < task.rest_speed_m_s:
        out.append(f"the object still moving at {1e3 * metrics.rest_object_speed_m_s:.1f} mm/s after the hold "
                   f"(needs < {1e3 * task.rest_speed_m_s:g})")
    if not metrics.max_joint_speed_ratio <= 1.0:
        out.append(f"joint speeds {metrics.max_joint_speed_ratio:.3f} of their limits (needs <= 1)")
    if not metrics.joint_range_excess_rad == 0.0:
        out.append(f"a joint {metrics.joint_range_excess_rad:.4f} rad beyond its range")
    return out
ZONES = ("steady", "strike")  # goals inside the steady push reach, and beyond it (reached only by a strike)


def zone(steady_reach_margin_m: float) -> str:
    """The reach zone of a goal with this steady_reach_margin_m."""
    return "steady" if steady_reach_margin_m >= 0.0 else "strike"


def zone_note(steady_reach_margin_m: float) -> str:
    """What an answer says of its goal's zone: nothing inside the steady push reach; beyond it, that the plan
    is a strike and best effort."""
    if zone(steady_reach_margin_m) == "steady":
        return ""
    return (f"the goal is {-100 * steady_reach_margin_m:.1f} cm beyond the steady push reach: the plan relies on "
            f"a strike at the joint speed limits, and its outcome is sensitive to small changes (best effort)")
PHASE_METRICS = ("setup_time_s", "rollout_time_s", "linearization_time_s", "solver_time_s", "evaluation_time_s")


def phase_table(groups: dict[str, list[dict[str, Any]]]) -> str:
    """Markdown: per group of plan summaries, the median time of each phase and of the solve, and the
    median share of the solve each phase took (the phases of side-by-side starts add up to more)."""
    header = " | ".join(name.removesuffix("_time_s") for name in PHASE_METRICS)
    lines = [f"| plans | solve (s) | {header} (median s) | {header} (median share of the solve) |",
             "|---|---|" + "---|" * 2 * len(PHASE_METRICS)]
    for label, rows in groups.items():
        rows = [r for r in rows if all(name in r for name in PHASE_METRICS)]
        if not rows:
            continue
        times = [f"{float(np.median([r[name] for r in rows])):.2f}" for name in PHASE_METRICS]
        shares = [f"{float(np.median([r[name] / r['solve_time_s'] for r in rows])):.0%}" for name in PHASE_METRICS]
        lines.append(f"| {label} ({len(rows)}) | {float(np.median([r['solve_time_s'] for r in rows])):.2f} | "
                     + " | ".join(times) + " | " + " | ".join(shares) + " |")
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class PlanResult:
    contact_model: str
    beta: float | None
    initial_distance_m: float
    target_position_m: np.ndarray
    target_yaw_rad: float
    knot_time_s: np.ndarray          # (N+1,) knot boundaries
    knot_torques_Nm: np.ndarray      # (N, 7) u per knot: the returned plan
    knot_contact_control: np.ndarray  # (N,) k (SCM/VSCM) or gamma (CCCM) of the contact model's plan
    knot_variables: dict[str, np.ndarray]  # the contact model's knot variables by name, in its plan
    trajectory: Trajectory           # the returned plan executed without the virtual force (the robot's motion)
    planned: Trajectory              # the contact model's plan, with the virtual force
    tracked: Trajectory              # trajectory's joint motion executed by a PD joint trajectory controller
    rest: Trajectory | None          # trajectory continued with the arm held at its last position for
                                     # tracking.hold_s: where the metrics judge it (None: it ended non-finite)
    tracked_rest: Trajectory | None  # the same hold after `tracked`
    metrics: Metrics
    iteration_log: tuple[IterationLog, ...]
    stages: tuple[StageRecord, ...]
    derivative_info: dict[str, int]
    scene: Scene                     # where it was planned: the object's start pose, the geometry to draw
    worst_world: float = math.inf    # the largest tolerance ratio at rest in the model and in every world of
                                     # tracking.world_*_scales, as the search judged it (Executed.worst_world; inf:
                                     # other worlds not asked)
    note: str = ""                   # what the search could not try, which an answer that misses says
    aim_position_m: np.ndarray | None = None  # where the pushes aimed past the goal (PushTask.aim_position_m)
    legs: tuple["PlanResult", ...] = ()  # a sequence's pushes (cito_ros.planner.sequence), each planned from where
                                     # the one before leaves the object; its knots and `planned` are the last's
                                     # (empty: one push, this one)

    @property
    def executed_motion(self) -> Trajectory:
        """What the robot does: the returned plan executed, then the arm held (`rest`), where the object
        ends; the recorded and published motion."""
        return self.trajectory.followed_by(self.rest)

    @property
    def status(self) -> Status:
        return self.metrics.status

    @property
    def sturdy(self) -> bool:
        """Tracked to within the task's tolerances in the model and in every world it was checked in."""
        return self.worst_world < 1.0

    @property
    def knot_q(self) -> np.ndarray:
        """(N+1, 7) joint positions at the knot boundaries (a sequence's: its last push's, as planned)."""
        if self.legs:
            return self.legs[-1].knot_q
        steps = (len(self.trajectory.time_s) - 1) // len(self.knot_torques_Nm)
        return self.trajectory.q[::steps]

    def summary(self) -> dict[str, Any]:
        """The identifiers and metrics as a JSON-serialisable dict."""
        motion = self.executed_motion
        return {
            "contact_model": self.contact_model,
            "beta": self.beta,
            "initial_distance_m": self.initial_distance_m,
            "target_position_m": self.target_position_m.tolist(),
            "target_yaw_rad": self.target_yaw_rad,
            "aim_position_m": None if self.aim_position_m is None else self.aim_position_m.tolist(),
            "object_start_position_m": self.trajectory.object_position_m[0].tolist(),
            "object_start_yaw_rad": self.scene.config.object.yaw_rad,
            **self.metrics.as_dict(),
            "final_object_position_m": motion.object_position_m[-1].tolist(),  # at rest
            "planned_object_position_m": self.planned.object_position_m[-1].tolist(),
            "tracked_object_position_m": (self.tracked if self.tracked_rest is None else
                                          self.tracked_rest).object_position_m[-1].tolist(),  # at rest
            "warnings": motion.warnings,
            "derivatives": self.derivative_info,
            "stages": [record.as_dict() for record in self.stages],
            "note": self.note,
            "pushes": max(len(self.legs), 1),
        }

    def finite(self) -> bool:
        """No NaN or Inf in any array or metric of the plan."""
        arrays = [self.knot_torques_Nm, self.knot_contact_control, *self.knot_variables.values()]
        for trajectory in (self.trajectory, self.planned, self.tracked, self.rest, self.tracked_rest):
            if trajectory is None:
                continue
            arrays += [value for value in vars(trajectory).values() if isinstance(value, np.ndarray)]
        numbers = [v for _, v in self.metrics.items() if isinstance(v, float)]
        return all(bool(np.all(np.isfinite(a))) for a in arrays) and bool(np.all(np.isfinite(numbers)))
