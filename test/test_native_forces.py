"""The native engine plugins against the pure-Python oracle (cito_ros.model.oracle)."""
import dataclasses

import mujoco
import numpy as np
import pytest

from cito_ros.execution.mpc import servo_tracking
from cito_ros.execution.policy import robot_torques
from cito_ros.execution.world import Mismatch, SimulatedWorld
from cito_ros.model import oracle
from cito_ros.model.scene import start_configuration
from cito_ros.planner import tracking
from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.planner.scripted import joint_path

from conftest import approach_torques


def random_states(scene, count, seed=0):
    """Forward-computed mjData at random arm configurations and velocities near the cube."""
    rng = np.random.default_rng(seed)
    datas = []
    for beta in np.linspace(5, 7, count):
        data = mujoco.MjData(scene.model)
        q0 = np.array([-np.pi / 12, -np.pi / beta, 0, 3 * np.pi / beta, -np.pi / 6, -2 * np.pi / beta, 0])
        data.qpos[scene.arm_qpos_adr] = q0 + rng.normal(0, 0.05, 7)
        data.qvel[scene.arm_dof_adr] = rng.normal(0, 0.5, 7)
        data.qvel[scene.object_dof_adr:scene.object_dof_adr + 6] = rng.normal(0, 0.1, 6)
        data.ctrl[scene.motor_ids] = rng.uniform(-1, 1, 7) * scene.torque_limit * 0.5
        datas.append(data)
    return datas


@pytest.mark.parametrize("name, control", [("vscm", 100.0), ("vscm", 7.5), ("scm", 100.0), ("cccm", 2.5)])
def test_native_forces_equal_the_oracle(scenes, name, control):
    scene = scenes[name]
    for data in random_states(scene, 8):
        data.ctrl[scene.contact_actuator_id] = control
        mujoco.mj_forward(scene.model, data)
        expected = oracle.forces(scene, data, control)
        assert data.actuator_force[scene.contact_actuator_id] == pytest.approx(expected.gamma_N, rel=1e-9, abs=0)
        np.testing.assert_allclose(data.actuator_force[scene.motor_ids],
                                   data.ctrl[scene.motor_ids] + expected.bias_Nm, rtol=1e-9)
        # generalized forces of all actuators: motors (u + C^) plus the virtual contact force
        total = expected.generalized_force.copy()
        total[scene.arm_dof_adr] += data.ctrl[scene.motor_ids] + expected.bias_Nm
        np.testing.assert_allclose(data.qfrc_actuator, total, rtol=1e-9, atol=1e-9 * np.abs(total).max())
        assert expected.gamma_N > 0


def test_virtual_forces_are_equal_and_opposite(scenes):
    scene = scenes["vscm"]
    model = scene.model
    for data in random_states(scene, 6, seed=4):
        data.ctrl[scene.motor_ids] = 0
        data.ctrl[scene.contact_actuator_id] = 100.0
        mujoco.mj_forward(model, data)
        gamma = data.actuator_force[scene.contact_actuator_id]
        # on the object: the free joint's translational dofs carry the world-frame force
        dofs = scene.object_dof_adr
        object_force = data.qfrc_actuator[dofs:dofs + 3]
        np.testing.assert_allclose(object_force, gamma * scene.inward_normal(data), rtol=1e-12)
        # on the robot: recover the Cartesian force at its candidate from the joint torques
        robot_torques = data.qfrc_actuator[scene.arm_dof_adr] - data.actuator_force[scene.motor_ids]
        jacobian = np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jacobian, None, scene.robot_site_id)
        robot_force, *_ = np.linalg.lstsq(jacobian[:, scene.arm_dof_adr].T, robot_torques, rcond=None)
        np.testing.assert_allclose(robot_force, -object_force, rtol=1e-9, atol=1e-12)
        # the force acts through the object candidate: no torque about it
        torque_dofs = data.qfrc_actuator[dofs + 3:dofs + 6]
        lever = data.site_xpos[scene.object_site_id] - data.xpos[scene.object_body_id]
        expected_torque = data.xmat[scene.object_body_id].reshape(3, 3).T @ np.cross(lever, object_force)
        np.testing.assert_allclose(torque_dofs, expected_torque, atol=1e-12)


@pytest.mark.parametrize("name", ["cccm", "scm", "vscm"])
def test_native_rollout_equals_the_oracle_rollout(simulators, oracle_scenes, start_states, name):
    simulator = simulators[name]
    torques = approach_torques(simulator, seed=2)
    control = np.linspace(0, 3, 20) if name == "cccm" else None
    native = simulator.rollout(start_states[7], torques, control)
    python = oracle.rollout(simulator, oracle_scenes[name], start_states[7], torques, control)
    for field in ("q", "qdot", "object_position_m", "torque_Nm", "gamma_N", "signed_distance_m"):
        a, b = getattr(native, field), getattr(python, field)
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * max(1.0, np.abs(a).max()), err_msg=field)


def test_oracle_rollout_needs_the_oracle_scene(simulators, scenes, start_states):
    with pytest.raises(ValueError, match="needs the oracle scene"):
        oracle.rollout(simulators["vscm"], scenes["vscm"], start_states[5], np.zeros((20, 7)))


def test_trajectory_virtual_force_is_gamma_along_the_inward_normal(simulators, start_states):
    simulator = simulators["cccm"]
    trajectory = simulator.rollout(start_states[6], np.zeros((20, 7)), np.full(20, 3.0))
    scene = simulator.scene
    for t in (0, 77, 199):
        data = mujoco.MjData(scene.model)
        data.qpos[scene.object_qpos_adr:scene.object_qpos_adr + 3] = trajectory.object_position_m[t]
        data.qpos[scene.object_qpos_adr + 3:scene.object_qpos_adr + 7] = trajectory.object_quaternion[t]
        mujoco.mj_kinematics(scene.model, data)
        np.testing.assert_allclose(trajectory.virtual_force_N[t], trajectory.gamma_N[t] * scene.inward_normal(data),
                                   atol=1e-12)


def test_native_tracking_equals_the_oracle_bit_for_bit(settings):
    """The joint trajectory controller (tracking.pd_motion, natively) steps as its Python oracle does: a
    scripted push through contact, the torques saturating on a reference far off, a feed-forward added, and the
    hold after it."""
    problem = build_problem(settings, PushRequest("vscm", 7)).problem
    simulator, gains = problem.simulator, settings.tracking
    path = joint_path(problem, settings.stages.scripted)
    steps = simulator.n_steps
    far_off = path.q[:steps] + np.linspace(0.0, 0.5, steps)[:, None]  # beyond the motor limits' reach
    # a feed-forward of up to 0.3 of the motor limits, rising and falling (an executor's servo runs a plan so)
    effort = 0.3 * problem.scene.torque_limit * np.sin(np.linspace(0.0, 3.0, steps))[:, None]
    for q_ref, qdot_ref, feed_forward in ((path.q[:steps], path.qdot[:steps], None),
                                          (far_off, path.qdot[:steps], None),
                                          (path.q[:steps], path.qdot[:steps], effort)):
        native = tracking.pd_motion(simulator, problem.initial_state, q_ref, qdot_ref, gains, feed_forward)
        python = oracle.pd_motion(simulator, problem.initial_state, q_ref, qdot_ref, gains, feed_forward)
        assert native.warnings == python.warnings
        for name, value in vars(native).items():
            if isinstance(value, np.ndarray):
                np.testing.assert_array_equal(value, getattr(python, name), err_msg=name)
    pd_alone = tracking.pd_motion(simulator, problem.initial_state, path.q[:steps], path.qdot[:steps], gains)
    assert np.abs(native.q - pd_alone.q).max() > 1e-3  # the last motion's feed-forward moved the arm
    pushed = tracking.track(simulator, problem.initial_state, path, gains)
    assert pushed.contact_count.max() > 0  # the push touches the cube
    assert np.any(np.abs(tracking.pd_motion(simulator, problem.initial_state, far_off, path.qdot[:steps],
                                            gains).control_torque_Nm) == problem.scene.torque_limit)
    held = tracking.held_motion(simulator, pushed.final_state, gains)
    steps = round(gains.hold_s / simulator.timestep_s)
    q_held = np.tile(pushed.q[-1], (steps, 1))
    reference = oracle.pd_motion(simulator, pushed.final_state, q_held, np.zeros_like(q_held), gains)
    np.testing.assert_array_equal(held.final_state, reference.final_state)
    np.testing.assert_array_equal(held.object_position_m, reference.object_position_m)


def test_native_tracking_with_the_speed_guard_equals_the_oracle_and_keeps_the_joints_within_it(settings):
    """With tracking.speed_guard (the executor's plans are checked so), a soft servo driven by full torques on every
    joint through the scripted push: natively as in the oracle, bit for bit, every joint within the guard's 0.95 of
    its limit plus what one step adds, where without the guard they pass their limits."""
    problem = build_problem(settings, PushRequest("vscm", 7)).problem
    simulator, scene = problem.simulator, problem.scene
    path, steps = joint_path(problem, settings.stages.scripted), simulator.n_steps
    flat_out = np.tile(np.array([1, -1, 1, -1, 1, 1, 1]) * scene.torque_limit, (steps, 1))
    servo = dataclasses.replace(settings.tracking, kp=tuple(0.1 * np.array(settings.tracking.kp)),
                                kd=tuple(0.1 * np.array(settings.tracking.kd)), feed_forward=True)
    guarded = dataclasses.replace(servo, speed_guard=0.95)
    native = tracking.pd_motion(simulator, problem.initial_state, path.q[:steps], path.qdot[:steps], guarded, flat_out)
    python = oracle.pd_motion(simulator, problem.initial_state, path.q[:steps], path.qdot[:steps], guarded, flat_out)
    for name, value in vars(native).items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(value, getattr(python, name), err_msg=name)
    raw = tracking.pd_motion(simulator, problem.initial_state, path.q[:steps], path.qdot[:steps], servo, flat_out)
    assert np.max(np.abs(raw.qdot) / scene.velocity_limit) > 1.2
    assert np.max(np.abs(native.qdot) / scene.velocity_limit) <= 0.95 + 0.01


def test_the_check_of_the_executors_plans_tracks_the_push_its_torques_make_on_the_benchs_world(settings):
    """The executor's torques (its servo's u within the speed guard, plus the bias forces it sends: policy.
    robot_torques) on cito-bench closed-loop's world (plain motors that add nothing, the oracle scene) move the arm
    and the cube as the check of its plans (tracking with the executor's servo, mpc.servo_tracking) has them move in
    the planner's model, whose motors add the bias forces: full torques on every joint through the scripted push,
    where the guard and the motors' limits act. (At 2e77a79 the check held u alone within the limits, at the last
    step's inertia, and the two parted by 0.013 rad and 3 cm of the cube.)"""
    problem = build_problem(settings, PushRequest("vscm", 7)).problem
    simulator, scene = problem.simulator, problem.scene
    path, steps = joint_path(problem, settings.stages.scripted), simulator.n_steps
    flat_out = np.tile(np.array([1, -1, 1, -1, 1, 1, 1]) * scene.torque_limit, (steps, 1))
    servo = servo_tracking(settings)
    checked = tracking.pd_motion(simulator, problem.initial_state, path.q[:steps], path.qdot[:steps], servo, flat_out)
    world = SimulatedWorld(settings, Mismatch(), start_configuration(7))
    mujoco.mj_setState(world.model, world.data, problem.initial_state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    scratch, kp, kd = mujoco.MjData(scene.model), np.array(servo.kp), np.array(servo.kd)
    for t in range(steps):
        joints = world.joints()
        u = np.clip(flat_out[t] + kp * (path.q[t] - joints.q) + kd * (path.qdot[t] - joints.qdot), -scene.torque_limit,
                    scene.torque_limit)
        world.step(robot_torques(scene, scratch, u, joints.q, joints.qdot, settings.executor.speed_horizon_s))
    assert np.max(np.abs(checked.qdot) / scene.velocity_limit) > 0.9  # the guard acted
    np.testing.assert_allclose(world.joints().q, checked.q[-1], atol=1e-6)
    position, _ = world.true_object_pose()
    np.testing.assert_allclose(position, checked.object_position_m[-1], atol=1e-6)
