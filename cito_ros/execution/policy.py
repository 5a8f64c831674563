"""A plan as a controller runs it: feed-forward torques, the states they should lead through, and feedback.

A `Policy` starts at `start_s` on the robot's clock. At time t it gives the joint torques

    u(t) = clamp(u_ref(t) + K(t) (x - x_ref(t)), -limit, limit)

with u_ref the plan's knot torque, x_ref the planner model's state along the plan at that simulation step,
x the estimated state, the difference taken in MuJoCo's tangent space (positions by mj_differentiatePos,
then velocities: the arm's joints and the cube's free joint), and K the knot's feedback gain (cito_ros.planner
.solvers.ilqr: the gains of the backward pass, on the whole state, arm and cube), interpolated linearly from
one knot's to the next. These are the torques u of the planner's model, in which the motors add the arm's
bias forces (gravity, Coriolis): a robot that adds none gets u plus those, computed from the model.

`Retreat` is the other path the executor has the arm follow: a slow minimum-jerk joint path between poses, or,
after a side push, back the way the push came.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from cito_ros.model.scene import Scene
from cito_ros.model.speed_guard import path_slowdown, within_speed_limits

SPEED_GUARD = 0.95  # of each joint's velocity limit: the executor keeps every joint within it


@dataclass(frozen=True)
class Policy:
    start_s: float               # on the robot's clock: where the plan's time 0 is
    control_period_s: float      # a knot
    timestep_s: float            # a simulation step
    torques_Nm: np.ndarray       # (N, 7) u_ref per knot
    gains: np.ndarray            # (N, 7, nx) K per knot, nx = 2 nv
    reference: np.ndarray        # (T + 1, nstate) x_ref at every step of the planner's model, T = N * steps
    sturdy: bool = False         # planned to reach the goal in the model and in the executor's worlds (PlanResult.
                                 # sturdy, as the planner's search judged it; a replan's is not asked: only pushes count)
    worst_world: float = math.inf  # the largest tolerance ratio at rest in the executor's worlds, the reference
                                 # tracked by its servo from its start (PushModel.worst_world)
    object_scales: tuple[float, float] = (1.0, 1.0)  # the cube's friction and mass in the model it was planned in
    target: tuple[tuple[float, float], float] | None = None  # ((x, y), yaw) it was planned to: a waypoint, or None
                                 # for the goal; its replans are held to the same
    face: int = 0                # the cube's face it pushes (side_faces.face_towards: 0 the near face, 1 and 3 the
                                 # side faces, which the arm reaches around the cube)

    @property
    def end_s(self) -> float:
        return self.start_s + len(self.torques_Nm) * self.control_period_s

    @property
    def final_state(self) -> np.ndarray:
        return self.reference[-1]

    def torques_at(self, times_s: np.ndarray) -> np.ndarray:
        """u_ref at the given robot times (the last knot's after the end, the first's before the start)."""
        knots = np.floor((np.asarray(times_s) - self.start_s) / self.control_period_s + 1e-9).astype(int)
        return self.torques_Nm[np.clip(knots, 0, len(self.torques_Nm) - 1)]

    def command(self, time_s: float, state: np.ndarray, scene: Scene) -> np.ndarray:
        """u(time_s) for the estimated state (mjSTATE_FULLPHYSICS of `scene`'s model)."""
        steps = len(self.reference) - 1
        step = int(np.clip(np.floor((time_s - self.start_s) / self.timestep_s + 1e-9), 0, steps))
        per_knot = steps // len(self.torques_Nm)
        knot = min(step // per_knot, len(self.torques_Nm) - 1)
        fraction = (step - knot * per_knot) / per_knot
        gain = self.gains[knot] if knot + 1 >= len(self.gains) else \
            (1.0 - fraction) * self.gains[knot] + fraction * self.gains[knot + 1]
        deviation = state_difference(scene, state, self.reference[step])
        return np.clip(self.torques_Nm[knot] + gain @ deviation, -scene.torque_limit, scene.torque_limit)


def state_difference(scene: Scene, state: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """state - reference in the tangent space (2 nv): position differences by mj_differentiatePos, then the
    velocity differences."""
    model = scene.model
    nq, nv = model.nq, model.nv
    q, r = scene.state_qpos_adr, scene.state_qvel_adr
    difference = np.empty(2 * nv)
    mujoco.mj_differentiatePos(model, difference[:nv], 1.0, reference[q:q + nq], state[q:q + nq])
    difference[nv:] = state[r:r + nv] - reference[r:r + nv]
    return difference


def hold_torques(scene: Scene, data: mujoco.MjData, kp: np.ndarray, kd: np.ndarray, hold_q: np.ndarray,
                 q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
    """A joint servo holding hold_q at rest, plus the arm's bias forces: the total torques of a robot's hold."""
    return kp * (hold_q - q) - kd * qdot + bias_torques(scene, data, q, qdot)


def robot_torques(scene: Scene, data: mujoco.MjData, u: np.ndarray, q: np.ndarray, qdot: np.ndarray,
                  speed_horizon_s: float) -> np.ndarray:
    """The total joint torques the executor sends for its servo's u at (q, qdot): u within the speed guard
    (SPEED_GUARD of the velocity limits, speed_horizon_s ahead: a robot's limiter faults past them) and, the arm's
    bias forces added, within the motors' limits. The checks of its plans step the same law (tracking with
    speed_guard: the inertia and bias forces of each step's state)."""
    bias = bias_torques(scene, data, q, qdot)
    return within_speed_limits(scene, data, u, qdot, bias, SPEED_GUARD * scene.velocity_limit, speed_horizon_s) + bias


def bias_torques(scene: Scene, data: mujoco.MjData, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
    """The arm's bias forces (gravity, Coriolis, centrifugal) at (q, qdot) in `scene`'s model: what its motors
    add to u, and what a robot that adds none must be sent on top of it."""
    data.qpos[scene.arm_qpos_adr], data.qvel[scene.arm_dof_adr] = q, qdot
    mujoco.mj_fwdPosition(scene.model, data)
    mujoco.mj_fwdVelocity(scene.model, data)
    return data.qfrc_bias[scene.arm_dof_adr].copy()


@dataclass(frozen=True)
class Retreat:
    """A joint path from one pose to another, on the robot's clock: minimum jerk, or along given poses."""

    start_s: float
    end_s: float
    from_q: np.ndarray
    to_q: np.ndarray
    path_q: np.ndarray | None = None  # (k, 7) joint poses, evenly in time from from_q to to_q (None: minimum jerk)

    @classmethod
    def between(cls, start_s: float, from_q: np.ndarray, to_q: np.ndarray, velocity_limit: np.ndarray,
                settings) -> Retreat:
        """Slow enough that no joint passes settings.retreat_speed_fraction of its limit (a minimum-jerk path's
        peak speed is 1.875 times its mean), and at least settings.retreat_min_s long."""
        fastest = float(np.max(1.875 * np.abs(to_q - from_q) / (settings.retreat_speed_fraction * velocity_limit)))
        return cls(start_s, start_s + max(settings.retreat_min_s, fastest), from_q.copy(), to_q.copy())

    @classmethod
    def back_along(cls, start_s: float, path_q: np.ndarray, timestep_s: float, velocity_limit: np.ndarray,
                   settings) -> Retreat:
        """Along path_q (joint poses timestep_s apart, the way a push came, reversed), slowed where a joint would
        pass settings.retreat_speed_fraction of its limit, and at least settings.retreat_min_s long: the straight
        way back from a side push crosses the cube the arm reached around."""
        slowdown = path_slowdown(path_q, timestep_s, settings.retreat_speed_fraction, velocity_limit)
        duration = max(settings.retreat_min_s, (len(path_q) - 1) * timestep_s * slowdown)
        return cls(start_s, start_s + duration, path_q[0].copy(), path_q[-1].copy(), path_q.copy())

    def at(self, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The joint positions and velocities at time_s."""
        duration = self.end_s - self.start_s
        s = min(max((time_s - self.start_s) / duration, 0.0), 1.0)
        if self.path_q is not None:
            where = s * (len(self.path_q) - 1)
            k = min(int(where), len(self.path_q) - 2)
            step = self.path_q[k + 1] - self.path_q[k]
            return self.path_q[k] + (where - k) * step, (s < 1.0) * (len(self.path_q) - 1) / duration * step
        step = self.to_q - self.from_q
        return self.from_q + (10 * s**3 - 15 * s**4 + 6 * s**5) * step, \
            (30 * s**2 - 60 * s**3 + 30 * s**4) / duration * step
