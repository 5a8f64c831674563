"""A plan executed the way a robot's joint trajectory controller would: PD tracking of the planned
joint positions and velocities with gravity (bias) compensation, no virtual force.

ROS-free. The controller runs every simulation step: tau = clamp(kp (q_ref - q) + kd (qdot_ref -
qdot)) + C^(q, qdot), where the clamp is the motor limit and C^ comes from the same compensated
motors the planner uses (cito.compensated_motor). The gains are the settings' `tracking` section.
"""
from __future__ import annotations

from typing import Protocol

import mujoco
import numpy as np

from cito_ros.settings import TrackingSettings
from cito_ros.simulator import FULL_PHYSICS, Simulator, Trajectory


class JointReference(Protocol):
    """What the controller tracks: joint positions and velocities (n_steps + 1, 7) at every state (a
    Trajectory, or the scripted start's cito_ros.scripted.JointPath)."""

    q: np.ndarray
    qdot: np.ndarray


def track(simulator: Simulator, initial_state: np.ndarray, reference: JointReference,
          gains: TrackingSettings) -> Trajectory:
    """Execute `reference` under PD control from initial_state."""
    scene, model = simulator.scene, simulator.model
    kp, kd = np.asarray(gains.kp), np.asarray(gains.kd)
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, initial_state, FULL_PHYSICS)
    steps = simulator.n_steps
    controls = np.zeros((steps, model.nu))
    states = np.empty((steps, simulator.nstate))
    sensordata = np.empty((steps, model.nsensordata))
    for warning in data.warning:
        warning.number = 0
    for t in range(steps):
        q, qdot = data.qpos[scene.arm_qpos_adr], data.qvel[scene.arm_dof_adr]
        command = kp * (reference.q[t] - q) + kd * (reference.qdot[t] - qdot)
        controls[t, scene.motor_ids] = np.clip(command, -scene.torque_limit, scene.torque_limit)
        data.ctrl[:] = controls[t]
        mujoco.mj_step(model, data)
        mujoco.mj_getState(model, data, states[t], FULL_PHYSICS)
        sensordata[t] = data.sensordata
    warnings = {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(data.warning) if w.number}
    return simulator.trajectory(initial_state, states, sensordata, controls, warnings)
