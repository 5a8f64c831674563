"""The closed-loop executor: a push planned from the measured state, executed by its feedback policy, replanned from
the measured state while it runs, and pushed again from where the cube comes to rest if it is not there.

ROS-free and clock-agnostic: the caller feeds measurements (`on_joints`, `on_pose`) and asks for the joint torques
to send at every control step (`command`, never blocking). The planning (the first plan, the MPC replans, a new
push) comes as a `Job` (`job`), picklable, whose outcome `planning.compute` gives wherever there is the time: in
another process beside the control loop on a robot, in line in a simulation (`planning.work_in_line`). A plan
computed from the state at time t takes effect at t plus its compute time on the robot's clock, never earlier:
`accept` takes it with that time, and `command` swaps it in then.

Phases: `planning` (the arm held while a push is planned), `pushing` (the policy, replanned), `settling` (the arm
held at the push's end, or where it is once the cube is executor.off_path_m off the push's path, until the cube has
come to rest; then the push is judged by the camera: at the goal, done; else, while pushes and time are left,
`retreating`: the arm goes back along a minimum-jerk path to where the execution started (from a side push, the
way it came), and a new push is planned from there meanwhile, made once the arm is there and only if the model
predicts it brings the cube closer (both errors against their tolerances) and moves it by more than
executor.predicted_moved_fraction of them), `done`. A cube at rest within the tolerances but turned by more than
executor.polish_orientation_rad allows is pushed again where a push sturdy to that yaw is found (goal.polishing),
else it is done, a success. An execution begun with the arm against the cube (where the last ended or was cancelled)
begins `retreating` to the start pose of settings.beta. Stale measurements, a cancel, the time limit, a cube tipped
past its edge, or no push that can be planned or is safe to make (planning.compute) end it with the arm held.
"""
from __future__ import annotations

import dataclasses
import enum
import math
import threading
from dataclasses import dataclass

import mujoco
import numpy as np

from cito_ros.execution.estimator import StateEstimator, tipped_over
from cito_ros.execution.goal import ExecuteGoal, cube_in, moved_beyond, polishes, polishing, predict
from cito_ros.execution.identify import Observed
from cito_ros.execution.mpc import push_model
from cito_ros.execution.policy import Policy, Retreat, robot_torques
from cito_ros.execution.world import JointReading, PoseReading
from cito_ros.planner.results import tolerance_ratio
from cito_ros.settings import Settings


class Phase(str, enum.Enum):
    PLANNING = "planning"
    PUSHING = "pushing"
    SETTLING = "settling"
    RETREATING = "retreating"
    DONE = "done"


class Ending(enum.Enum):
    """How an execution ended (the ExecutePush result's status)."""

    SUCCEEDED = "succeeded"
    INVALID_REQUEST = "invalid_request"          # a push could not be planned from where things are
    TASK_NOT_ACHIEVED = "task_not_achieved"      # pushes spent, or no push found brings the cube closer or is safe
    CANCELLED = "cancelled"
    TIME_LIMIT = "time_limit"
    STALE_MEASUREMENTS = "stale_measurements"
    NUMERICAL_ERROR = "numerical_error"


@dataclass(frozen=True)
class Work:
    """A plan ready to take effect at `effective_s` on the robot's clock, and what it cost."""

    policy: Policy
    effective_s: float
    compute_s: float
    kind: str                               # "plan" or "replan"


class Executor:
    """See the module docstring."""

    def __init__(self, settings: Settings, goal: ExecuteGoal):
        self.settings, self.goal = settings, goal
        self.time_limit_s = goal.time_limit_s or settings.executor.time_limit_s
        self.model = push_model(settings, goal)  # the goal checked here (a ValueError for a bad one)
        scene = self.model.scene
        self.estimator = StateEstimator(scene, self.model.resting_state)
        self._data = mujoco.MjData(scene.model)
        self._lock = threading.Lock()
        self.phase = Phase.PLANNING
        self.ending: Ending | None = None
        self.message = ""
        self.policy: Policy | None = None
        self._pending: Work | None = None
        self._hold_q: np.ndarray | None = None
        self._home_q: np.ndarray | None = None    # the arm where the execution started: each push starts there
        self._retreat: Retreat | None = None
        self._push_end_s = self._settle_since_s = math.nan
        self._joints: JointReading | None = None
        self._pose_arrival_s = self._joints_arrival_s = -math.inf
        self.started_s: float | None = None
        self.pushes = 0
        self.pushes_cut = 0                    # pushes cut short with the cube off their path (executor.off_path_m)
        self.sturdy_pushes: list[bool] = []    # per push made: whether its plan was sturdy (Policy.sturdy)
        self.direct_missed = False             # a push made went to a waypoint (Job.direct_missed)
        self.stale_plans = 0                   # pushes planned ahead, dropped: the cube had moved before they began
        self.observed: list[Observed] = []     # every push made, as measured until the cube was judged at rest
        self._recording: tuple[np.ndarray, list, list] | None = None  # the push's: start state, joints, poses
        self.cause = ""                        # why it ended, finer than `ending` (set with it: _end)
        self.replan_seconds: list[float] = []  # every replan's compute time, taken or not
        self.replans_taken = 0                 # the replans that improved on the running plan and took its place
        self._planner_free_s = -math.inf

    # ------------------------------------------------------------------ measurements

    def on_joints(self, reading: JointReading, arrival_s: float | None = None) -> None:
        """A joint state, which arrived at arrival_s on the robot's clock (default: its stamp)."""
        self._joints = reading
        self._joints_arrival_s = reading.stamp_s if arrival_s is None else arrival_s
        if self.started_s is None:
            self.started_s = reading.stamp_s
        if self._hold_q is None:
            self._hold_q, self._home_q = reading.q.copy(), reading.q.copy()
        if self._recording is not None:
            self._recording[1].append(np.concatenate([[reading.stamp_s], reading.q, reading.qdot]))

    def on_pose(self, reading: PoseReading, arrival_s: float) -> None:
        self.estimator.add_pose(reading)
        self._pose_arrival_s = arrival_s
        if self._recording is not None:
            self._recording[2].append(self.estimator.last_pose)

    # ------------------------------------------------------------------ control

    def command(self, now_s: float) -> np.ndarray:
        """The total joint torques to send now (the policy's u plus the arm's bias forces, or a hold)."""
        joints = self._joints
        if joints is None:
            raise ValueError("no joint state yet")
        with self._lock:
            if self.phase is not Phase.DONE:
                self._advance(now_s)
            kp, kd = self.model.servo_gains
            if self.phase is Phase.PUSHING:
                state = self.estimator.state(joints, now_s)
                u = self.policy.command(now_s, state, self.model.scene)
            elif self.phase is Phase.RETREATING:
                q, qdot = self._retreat.at(now_s)
                u = kp * (q - joints.q) + kd * (qdot - joints.qdot)
            else:
                u = kp * (self._hold_q - joints.q) - kd * joints.qdot
            # _data: one thread at a time
            return robot_torques(self.model.scene, self._data, u, joints.q, joints.qdot,
                                 self.settings.executor.speed_horizon_s)

    def _advance(self, now_s: float) -> None:
        joints = self._joints
        stale = self.settings.executor.stale_after_s  # measurements that stopped arriving, whatever their stamps
        if now_s - self._joints_arrival_s > stale or now_s - self._pose_arrival_s > stale:
            what, age_s = max(("joint states", now_s - self._joints_arrival_s),
                              ("cube poses", now_s - self._pose_arrival_s), key=lambda item: item[1])
            return self._end(Ending.STALE_MEASUREMENTS, f"no {what} for {age_s:.2f} s (stale after {stale:g} s): "
                                                        f"the arm is held where it is", joints.q)
        if tipped_over(self.model.scene, self.estimator.tilt_rad):
            return self._end(Ending.TASK_NOT_ACHIEVED, f"the cube has tipped over (its top "
                                                       f"{math.degrees(self.estimator.tilt_rad):.0f} degrees from "
                                                       f"upright): the arm is held where it is", joints.q, "tipped")
        if now_s - self.started_s > self.time_limit_s:
            if self.cube_at_rest and self._succeeded(*self.errors(now_s), " when the time ran out", polish=False):
                return
            return self._end(Ending.TIME_LIMIT, f"the {self.time_limit_s:g} s time limit ran out", joints.q)
        if self.phase is Phase.RETREATING and now_s >= self._retreat.end_s:
            self.phase, self._hold_q = Phase.PLANNING, self._home_q.copy()
            # judged again with the arm away: the judgement after the push can disagree (docs/ros.md)
            if self.cube_at_rest and self._succeeded(*self.errors(now_s), ", once the arm drew back"):
                return
        # a push planned during the retreat waits for its end; if the cube has moved since it was planned (the
        # retreating arm brushed it), it is dropped, and the next job plans it again from where the cube is
        if self._pending is not None and now_s >= self._pending.effective_s and \
                (self._pending.kind == "replan" or self.phase is Phase.PLANNING):
            work, self._pending = self._pending, None
            if work.kind == "replan":
                self.policy = work.policy
            elif self._moved_since(work.policy):
                self.stale_plans += 1
            else:  # counted as made now: one planned ahead is dropped if the cube is found at the goal
                self.policy, self.phase, self._push_end_s = work.policy, Phase.PUSHING, work.policy.end_s
                self._recording = (work.policy.reference[0], [], [])
                self.pushes += 1
                self.sturdy_pushes.append(work.policy.sturdy)
                self.direct_missed |= work.policy.face == 0 and \
                    not np.array_equal(work.policy.target[0], self.goal.target_position_m)  # planning.compute
        if self.phase is Phase.PUSHING and self._off_path_m() > self.settings.executor.off_path_m:
            self.pushes_cut += 1
            self._push_end_s = now_s
        if self.phase is Phase.PUSHING and now_s >= self._push_end_s:  # held where it is: no jump to a reference
            self.phase, self._hold_q, self._settle_since_s = Phase.SETTLING, joints.q.copy(), now_s
        if self.phase is Phase.SETTLING and now_s - self._settle_since_s >= self.settings.executor.settle_s and \
                self.cube_at_rest:
            position, orientation = self.errors(now_s)  # at rest: the rest window's mean
            (start, arm, cube), self._recording = self._recording, None
            arm = np.array(arm)
            if len(arm) > 1 and cube:  # what the push showed of the cube (identify)
                self.observed.append(Observed(start, arm, np.array(cube)))
            if self._succeeded(position, orientation, "",
                               polish=self.pushes < self.settings.executor.max_pushes):
                return
            if self.pushes >= self.settings.executor.max_pushes:
                return self._end(Ending.TASK_NOT_ACHIEVED, f"after {self.pushes} push(es) the cube is "
                                                           f"{100 * position:.2f} cm and {orientation:.3f} rad from "
                                                           f"the goal", None, "pushes_spent")
            # another push, planned from the start pose (from beside the cube a push starts against it); from a side
            # push back the way the arm came, measured (the straight way crosses the cube it reached around)
            self.phase, limit = Phase.RETREATING, self.model.scene.velocity_limit
            self._retreat = Retreat.back_along(now_s, arm[::-1, 1:8], float(np.mean(np.diff(arm[:, 0]))), limit,
                                               self.settings.executor) if self.policy.face and len(arm) > 1 else \
                Retreat.between(now_s, joints.q, self._home_q, limit, self.settings.executor)

    def _moved_since(self, policy: Policy) -> bool:
        """Whether the cube has left where a push was planned for it (moved_beyond): the rest window's mean against
        the plan's start, which is one too."""
        return moved_beyond(self.settings, self.estimator.resting_pose(),
                            cube_in(self.model.scene, policy.reference[0]), self.settings.executor.moved_fraction)

    def _off_path_m(self) -> float:
        """How far the cube's last measured position is from where the running push's reference has it at that
        pose's instant (before the push: its start)."""
        stamp, x, y, _ = self.estimator.last_pose  # the pose itself: no line fitted through the last few
        reference = self.policy.reference
        step = int(np.clip(round((stamp - self.policy.start_s) / self.policy.timestep_s), 0, len(reference) - 1))
        planned = self.model.scene.object_qpos(reference[step])
        return math.hypot(x - planned[0], y - planned[1])

    def _succeeded(self, position_m: float, orientation_rad: float, after: str, polish: bool = True) -> bool:
        """Whether the camera sees the cube at rest within executor.done_fraction of the tolerances, and with
        `polish` of executor.polish_orientation_rad too (polishing): then it ends."""
        if tolerance_ratio(position_m, orientation_rad, self.settings.task) < self.settings.executor.done_fraction \
                and not (polish and polishes(self.settings, position_m, orientation_rad)):
            self._end(Ending.SUCCEEDED, f"the cube is {100 * position_m:.2f} cm and {orientation_rad:.3f} rad from "
                                        f"the goal after {self.pushes} push(es){after}", None)
            return True
        return False

    def _end(self, ending: Ending, message: str, hold_q: np.ndarray | None, cause: str | None = None) -> None:
        """The execution ends; `cause` says why where the ending alone does not (default: the ending's value)."""
        self.ending, self.message, self._pending = ending, message, None
        self.cause = cause or ending.value
        if hold_q is not None:
            self._hold_q = hold_q.copy()
        self.phase = Phase.DONE  # last: the node's action thread waits for it outside the lock, then reads the rest

    def cancel(self) -> None:
        with self._lock:
            if self.phase is not Phase.DONE:
                self._end(Ending.CANCELLED, "cancelled: the arm is held where it is",
                          None if self._joints is None else self._joints.q)

    def errors(self, now_s: float) -> tuple[float, float]:
        """The cube's position and yaw error against the goal, as the camera sees it now (at rest: averaged)."""
        return self.goal.errors(*self.object_pose(now_s))

    @property
    def cube_at_rest(self) -> bool:
        """Whether the camera sees the cube at rest: its estimated speed below executor.rest_speed_m_s."""
        return self.estimator.object_speed_m_s() < self.settings.executor.rest_speed_m_s

    def object_pose(self, now_s: float) -> tuple[np.ndarray, float]:
        """The cube's (x, y) and yaw as the camera sees it now: the rest window's mean when it is at rest."""
        return self.estimator.resting_pose() if self.cube_at_rest else self.estimator.object_pose(now_s)

    # ------------------------------------------------------------------ planning

    def job(self, now_s: float) -> Job | None:
        """What there is to plan now, from the state measured at now_s: a push, or a replan with knots of the push
        left (None: nothing)."""
        with self._lock:
            if self.phase is Phase.DONE or self._pending is not None or self._joints is None or \
                    not self.estimator.has_pose or now_s < self._planner_free_s:
                return None
            # as PushModel.replan counts the knots left: from the first knot after its budget (a replan that
            # would find too few is not a replan, and must not count as one computed in no time)
            executor = self.settings.executor
            if self.phase is Phase.PUSHING and now_s + executor.replan_budget_s + executor.min_replan_knots * \
                    self.model.control_period_s >= self._push_end_s:
                return None
            # the next push is planned while the arm retreats, from where the retreat ends, once the cube is at rest
            ahead = self.phase is Phase.RETREATING and self.cube_at_rest
            if self.phase is not Phase.PLANNING and not ahead and \
                    not (self.phase is Phase.PUSHING and executor.replans(self.policy.face)):
                return None
            # a push from rest is planned from where the camera's rest window has the cube, whatever its noise says of
            # the cube's speed (over ten poses it passes rest_speed_m_s now and then: through the nodes a plan then
            # started from one noisy pose carried forward, 5 mm off, and was dropped as stale when it became due)
            replan = self.phase is Phase.PUSHING
            state = self.estimator.state(self._joints, now_s, not replan or self.cube_at_rest)
            back_q = self.model.draw_back_q(state) if self.phase is Phase.PLANNING and not self._retreat else None
            if back_q is not None:  # the arm begins against the cube: drawn back first, its pushes start there
                self.phase, self._home_q = Phase.RETREATING, back_q
                self._retreat = Retreat.between(now_s, self._joints.q, back_q, self.model.scene.velocity_limit,
                                                executor)
                return None
            return Job("replan" if replan else "plan", now_s, state, (self._home_q if ahead else self._joints.q).copy(),
                       self.object_pose(now_s) if replan else self.estimator.resting_pose(),
                       self.time_limit_s - (now_s - self.started_s), self.policy, self._push_end_s,
                       executor.max_pushes - self.pushes - 1, tuple(self.observed), self.direct_missed)

    def accept(self, job: Job, outcome: Policy | Failure | None, elapsed_s: float) -> Work | None:
        """Take a job's outcome, computed in elapsed_s (on the robot's clock, from job.now_s): a plan that takes
        effect at job.now_s + elapsed_s, or the failure that ends the execution."""
        with self._lock:
            self._planner_free_s = job.now_s + elapsed_s  # the planner was busy with it until then
            if job.kind == "replan":
                self.replan_seconds.append(elapsed_s)
            expected = (Phase.PLANNING, Phase.RETREATING) if job.kind == "plan" else (Phase.PUSHING,)
            if self.phase not in expected:
                return None
            if isinstance(outcome, Failure):
                # a plan that is not finite ends as one, polishing or not
                if job.kind == "plan" and outcome.ending is not Ending.NUMERICAL_ERROR and \
                        self._polished(job, outcome.message):
                    return None
                ending, cause = outcome.ending, outcome.cause
                if ending is Ending.INVALID_REQUEST and self.pushes:  # the goal was posed; no next push reaches it
                    ending, cause = Ending.TASK_NOT_ACHIEVED, "no_push_from_here"
                self._end(ending, outcome.message, None if self._joints is None else self._joints.q, cause)
                return None
            if outcome is None:
                return None
            if job.kind == "plan" and self.pushes:
                # a push that would not bring the cube closer, nor hardly move it, is not made, nor left to run out
                # the time (Prediction)
                seen = predict(polishing(self.settings, *self.goal.errors(*job.object_pose)) or self.settings,
                               self.model.scene, self.goal, job.object_pose, outcome)
                if not seen.closer:
                    (off_m, off_rad), (moved_m, moved_rad) = seen.predicted, seen.moved
                    if self._polished(job, f"the best push found would leave it {100 * off_m:.2f} cm and "
                                           f"{off_rad:.3f} rad off"):
                        return None
                    position, orientation = self.goal.errors(*job.object_pose)
                    self._end(Ending.TASK_NOT_ACHIEVED, f"after {self.pushes} push(es) the cube is "
                                                        f"{100 * position:.2f} cm and {orientation:.3f} rad from the "
                                                        f"goal, and the best push found would leave it "
                                                        f"{100 * off_m:.2f} cm and {off_rad:.3f} rad off, moving it "
                                                        f"{100 * moved_m:.2f} cm and {moved_rad:.3f} rad",
                              None if self._joints is None else self._joints.q, "no_closer_push")
                    return None
            effective = max(job.now_s + elapsed_s, outcome.start_s)  # never before it is computed, nor its start
            if self.phase is Phase.RETREATING:
                effective = max(effective, self._retreat.end_s)
            if job.kind == "plan":  # a fresh push starts from rest when it is ready: its time 0 is then
                outcome = dataclasses.replace(outcome, start_s=effective)
            else:
                self.replans_taken += 1
            self._pending = Work(outcome, effective, elapsed_s, job.kind)
            return self._pending

    def _polished(self, job: Job, why: str) -> bool:
        """Where the job's push was to polish the cube's yaw (polishing) and none is made, the execution ends a
        success, the arm held where it is."""
        position, orientation = self.goal.errors(*job.object_pose)
        if not polishes(self.settings, position, orientation):
            return False
        self._end(Ending.SUCCEEDED, f"the cube is {100 * position:.2f} cm and {orientation:.3f} rad from the goal "
                                    f"after {self.pushes} push(es), no push turning it within "
                                    f"{self.settings.executor.polish_orientation_rad:g} rad ({why})",
                  None if self._joints is None else self._joints.q)
        return True

    @property
    def first_push_sturdy(self) -> bool | None:
        """Whether the first push's plan was sturdy (None: no push made)."""
        return self.sturdy_pushes[0] if self.sturdy_pushes else None

    @property
    def replans(self) -> int:
        return len(self.replan_seconds)

    @property
    def replan_rate_hz(self) -> float:
        """Replans a second while replanning back to back: 1 / the median compute time of one (NaN: none)."""
        return 1.0 / float(np.median(self.replan_seconds)) if self.replan_seconds else math.nan


@dataclass(frozen=True)
class Job:
    """What to plan (picklable: it may be computed in another process)."""

    kind: str                                # "plan" (a push from rest) or "replan"
    now_s: float                             # the robot's time of the state
    state: np.ndarray                        # the estimated model state then
    q: np.ndarray                            # the arm's joints then
    object_pose: tuple[np.ndarray, float]    # the cube's estimated (x, y) and yaw then
    time_left_s: float
    running: Policy | None                   # replan: the policy that runs (its torques warm-start the replan)
    push_end_s: float                        # replan: where the push ends
    pushes_left: int = 0                     # plan: the pushes the executor may make after this one
    observed: tuple[Observed, ...] = ()      # plan: the pushes so far, as measured (identify)
    direct_missed: bool = False              # plan: a push so far went to a waypoint, its plan to the goal not sturdy


@dataclass(frozen=True)
class Failure:
    ending: Ending
    message: str
    cause: str | None = None  # Executor.cause where the ending alone does not say why
