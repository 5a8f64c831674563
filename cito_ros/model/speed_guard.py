"""The executor's speed guard: joint torques kept from taking the arm past its speed limits within a short horizon.

One law for the executor's commands (cito_ros.execution.executor) and for the checks of its plans (the tracking
controller with tracking.speed_guard, natively in cito_track, of which this is the oracle: MuJoCo's own operations in
cito_track's order, so that the two agree bit for bit); and how much slower a joint path must run to stay within a
fraction of the limits (`path_slowdown`: the executor's retreats, the planner's transits between pushes).
"""
from __future__ import annotations

import mujoco
import numpy as np

from cito_ros.model.scene import Scene


def within_speed_limits(scene: Scene, data: mujoco.MjData, u: np.ndarray, qdot: np.ndarray, bias: np.ndarray,
                        speed_limit: np.ndarray, horizon_s: float) -> np.ndarray:
    """u within the motors' torque limits, u + bias too (a robot's motors bound the total the executor sends, the
    planner's model's bound u and add the bias: within both, the two move alike), changed only where it would take
    an arm joint moving at qdot past speed_limit within horizon_s.

    The arm's accelerations from u are a = M^-1 u (M its inertia at data.qM, forwarded by the caller at the state
    whose bias forces it gives: motors that add the bias forces leave u to accelerate the arm); the allowed ones
    are (+-speed_limit - qdot) / horizon_s, so a joint already past its limit is braked back within horizon_s. The
    allowed a nearest u's is a_t; its torques M a_t can pass a motor's limit (the joints are coupled through M), so
    the torques are M (a_0 + s (a_t - a_0)), a_0 the allowed accelerations nearest rest, with the largest s in
    [0, 1] within the torque limits: the whole motion scaled back, as a trajectory scaler does. The cube's contact
    forces, which only hold the arm back, are left out. The checks of the executor's plans give the bias forces the
    model's motors add, as the executor gives those it sends on top of u: a push there is the push the executor
    makes (where the check took the limits on u alone and the last step's inertia, a push that the check ended
    0.7 cm short of the goal ended 2.5 cm past it in the same world: docs/results.md)."""
    limit = scene.torque_limit
    low_Nm, high_Nm = np.maximum(-limit, -limit - bias), np.minimum(limit, limit - bias)
    u = np.ascontiguousarray(np.clip(u, low_Nm, high_Nm))
    full = np.zeros((scene.model.nv, scene.model.nv))
    mujoco.mj_fullM(scene.model, data, full)
    inertia = np.ascontiguousarray(full[np.ix_(scene.arm_dof_adr, scene.arm_dof_adr)])
    factor, acceleration = inertia.copy(), np.zeros(len(u))
    mujoco.mju_cholFactor(factor, mujoco.mjMINVAL)
    mujoco.mju_cholSolve(acceleration, factor, u)
    low, high = (-speed_limit - qdot) / horizon_s, (speed_limit - qdot) / horizon_s
    if np.all(acceleration >= low) and np.all(acceleration <= high):
        return u
    rest_Nm, target_Nm = np.zeros(len(u)), np.zeros(len(u))
    mujoco.mju_mulMatVec(rest_Nm, inertia, np.clip(0.0, low, high))
    mujoco.mju_mulMatVec(target_Nm, inertia, np.clip(acceleration, low, high))
    step_Nm = target_Nm - rest_Nm
    up, down = step_Nm > 0, step_Nm < 0
    room = np.concatenate([(high_Nm - rest_Nm)[up] / step_Nm[up], (low_Nm - rest_Nm)[down] / step_Nm[down], [1.0]])
    return np.clip(rest_Nm + float(np.clip(np.min(room), 0.0, 1.0)) * step_Nm, low_Nm, high_Nm)


def path_slowdown(path_q: np.ndarray, timestep_s: float, fraction: float, speed_limit: np.ndarray) -> float:
    """How many times slower than one pose per timestep_s a joint path (poses in rows) must run for no joint to pass
    `fraction` of its speed_limit between its poses: at least 1 (a path already slow enough keeps its pace)."""
    return max(float(np.max(np.abs(np.diff(path_q, axis=0)) / (timestep_s * fraction * speed_limit), initial=0.0)),
               1.0)
