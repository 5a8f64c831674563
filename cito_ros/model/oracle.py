"""Pure-Python implementation of the state-dependent forces of eq. (2): the test
oracle of the native engine plugins, and the baseline of `cito-bench rollout`;
and of the PD joint trajectory controller (`pd_motion`), the oracle of the
native tracking.

    tau = u + C^(q, qdot) - J_c^T lambda_c,   lambda_c = gamma n on the object,
                                               -gamma n on the robot.

Every step the oracle evaluates the position and velocity stages (mj_step1),
computes u + C^ and gamma in Python, writes them as the controls of the oracle
scene's plain actuators (Scene(native=False)), and completes the step
(mj_step2). `virtual_generalized_force` maps gamma to joint space with MuJoCo's
Jacobians directly, independent of the actuator transmission used in the step.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cito_ros.model.scene import Scene
from cito_ros.model.simulator import Simulator, Trajectory, warning_counts
from cito_ros.model.speed_guard import within_speed_limits
from cito_ros.settings import TrackingSettings


@dataclass(frozen=True)
class OracleForces:
    bias_Nm: np.ndarray            # C^(q, qdot) on the arm joints
    signed_distance_m: float
    gamma_N: float
    object_force_N: np.ndarray     # virtual force on the object, world (= gamma n)
    robot_force_N: np.ndarray      # virtual force on the robot, world (= -gamma n)
    generalized_force: np.ndarray  # (nv,) J_obj^T (gamma n) + J_rob^T (-gamma n)


def forces(scene: Scene, data: mujoco.MjData, contact_control: float) -> OracleForces:
    """The oracle forces at a state whose position and velocity stages are computed."""
    model = scene.model
    phi = scene.signed_distance(data)
    gamma = float(scene.contact_model.gamma(np.array(phi), np.array(contact_control)))
    object_force = gamma * scene.inward_normal(data)
    jac_object = np.zeros((3, model.nv))
    jac_robot = np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jac_object, None, scene.object_site_id)
    mujoco.mj_jacSite(model, data, jac_robot, None, scene.robot_site_id)
    return OracleForces(
        bias_Nm=data.qfrc_bias[scene.arm_dof_adr].copy(),
        signed_distance_m=phi,
        gamma_N=gamma,
        object_force_N=object_force,
        robot_force_N=-object_force,
        generalized_force=jac_object.T @ object_force - jac_robot.T @ object_force,
    )


def rollout(simulator: Simulator, oracle_scene: Scene, initial_state: np.ndarray, torques_Nm: np.ndarray,
            contact_control: np.ndarray | None = None) -> Trajectory:
    """The rollout of `simulator.rollout`, with the forces computed in Python every step.

    `oracle_scene` is Scene(same contact model and config, native=False).
    """
    if oracle_scene.native:
        raise ValueError("the oracle rollout needs the oracle scene, Scene(..., native=False)")
    model = oracle_scene.model
    initial_state = simulator.validate_state(initial_state)
    controls = simulator.step_controls(simulator.knot_controls(torques_Nm, contact_control))
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, initial_state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    states = np.empty((simulator.n_steps, simulator.nstate))
    sensordata = np.empty((simulator.n_steps, model.nsensordata))
    motors, contact = oracle_scene.motor_ids, oracle_scene.contact_actuator_id
    for step, control in enumerate(controls):
        mujoco.mj_step1(model, data)
        oracle = forces(oracle_scene, data, control[contact])
        data.ctrl[motors] = control[motors] + oracle.bias_Nm
        data.ctrl[contact] = oracle.gamma_N
        mujoco.mj_step2(model, data)
        sensordata[step] = data.sensordata
        mujoco.mj_getState(model, data, states[step], mujoco.mjtState.mjSTATE_FULLPHYSICS)
    warnings = {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(data.warning) if w.number}
    return simulator.trajectory(initial_state, states, sensordata, controls, warnings)


def pd_motion(simulator: Simulator, initial_state: np.ndarray, q_ref: np.ndarray, qdot_ref: np.ndarray,
              gains: TrackingSettings, feed_forward: np.ndarray | None = None) -> Trajectory:
    """tracking.pd_motion (the joint trajectory controller, natively cito_track) in Python, step by step."""
    scene, model = simulator.scene, simulator.model
    kp, kd = np.asarray(gains.kp), np.asarray(gains.kd)
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, initial_state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    steps = len(q_ref)
    controls = np.zeros((steps, model.nu))
    states = np.empty((steps, simulator.nstate))
    sensordata = np.empty((steps, model.nsensordata))
    for t in range(steps):
        command = kp * (q_ref[t] - data.qpos[scene.arm_qpos_adr]) + kd * (qdot_ref[t] - data.qvel[scene.arm_dof_adr])
        if feed_forward is not None:
            command = feed_forward[t] + command
        controls[t, scene.motor_ids] = np.clip(command, -scene.torque_limit, scene.torque_limit)
        if gains.speed_guard > 0:  # mj_step1: this state's inertia and bias forces, as the executor takes them
            mujoco.mj_step1(model, data)
            controls[t, scene.motor_ids] = within_speed_limits(
                scene, data, controls[t, scene.motor_ids], data.qvel[scene.arm_dof_adr],
                data.qfrc_bias[scene.arm_dof_adr], gains.speed_guard * scene.velocity_limit, gains.speed_horizon_s)
        data.ctrl[:] = controls[t]
        if gains.speed_guard > 0:
            mujoco.mj_step2(model, data)
        else:
            mujoco.mj_step(model, data)
        mujoco.mj_getState(model, data, states[t], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        sensordata[t] = data.sensordata
    warnings = warning_counts(np.array([warning.number for warning in data.warning]))
    return simulator.trajectory(initial_state, states, sensordata, controls, warnings)

