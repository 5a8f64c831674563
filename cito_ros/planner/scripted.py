"""The scripted push: the physical pipeline's first start, a guess at the torques of a push that
touches the object by construction. ROS-free.

Discovery from zero torques is the hard part of a solve: each discovery is a lottery ticket that costs
tens of iterations, and a push pays for one or more (docs/planner.md: The physical pipeline). A push that
touches is easy to script, though: the plate goes behind the
object, its face turned along the push, and moves through to where the object's face ends at the goal.
Here that path is a minimum-jerk Cartesian motion of the plate centre (robot_candidate), turned into
joint positions by damped least-squares inverse kinematics, each step within a fraction of the joint
speed limits and inside the joint ranges, and executed by the same PD joint trajectory controller
that cito-bench tracks plans with (cito_ros.planner.tracking), object contact and all. The controller's
torques, averaged over each knot, are the start's torques: the physical stages refine them without
the virtual force, as they refine a discovery.

What the script does not know is left to those stages: the object's yaw, its sliding after the
plate stops, and pushes beyond what a quasi-static push reaches (the paper's 25 cm pushes end near
the arm's reach, where the optimizer shoves and lets the cube slide: docs/planner.md). A scripted start that
does not succeed costs its stages, and the discovery starts follow as before.
"""
from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from cito_ros.model.simulator import FULL_PHYSICS
from cito_ros.planner import push_limits, tracking
from cito_ros.planner.task import turn_rad, yaw_of
from cito_ros.planner.tracking import JointPath
from cito_ros.settings import ScriptedSettings, TrackingSettings


def _minimum_jerk(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s ** 3 * (10.0 - 15.0 * s + 6.0 * s * s)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.cross of two 3-vectors: the same products and differences, without the general case's axis handling
    (a third of a script's time). joint_path builds its other arrays as it did: J comes out of np.vstack in
    Fortran order, the matrix products sum in an order that follows the layout, and a C-ordered J gave joint
    paths differing in the 14th digit, which near the reach moves a plan."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _at_start(problem) -> mujoco.MjData:
    """An mjData at the problem's initial state (the object where the request put it), its kinematics done."""
    data = mujoco.MjData(problem.scene.model)
    mujoco.mj_setState(problem.scene.model, data, problem.initial_state, FULL_PHYSICS)
    mujoco.mj_kinematics(problem.scene.model, data)
    return data


def plate_path(problem, script: ScriptedSettings) -> tuple[np.ndarray, np.ndarray]:
    """(n_steps + 1, 3) plate-centre positions, world frame, and (n_steps + 1, 3) unit plate normals: from where
    the plate starts to standoff_m behind the object's face along the push, then through to where that
    face ends with the object at the target, both at contact_height_m above the object's centre. The normal
    turns along the push during the approach and keeps it; with script.follow_face, for a target at least
    follow_face_margin_m inside the steady push reach, it is the pushed face's instead, turning with the object's
    yaw from the start's to the target's (a flat plate pressed on a face lines the face up with it: a plate along
    the push turns the cube to the push's direction, whatever the target yaw). Nearer that reach's edge, and beyond
    it, the plate stays along the push: a strike throws the object along the plate's normal, and at the edge the arm
    holds a turned plate only slowly (docs/results.md: The scripts follow the face)."""
    scene, simulator = problem.simulator.scene, problem.simulator
    data = _at_start(problem)
    plate = data.site_xpos[scene.robot_site_id].copy()
    object_qpos = scene.object_qpos(problem.initial_state)
    start = object_qpos[:3]
    push = problem.task.aim_m[:2] - start[:2]
    # a target on the object's start (a turn in place): the plate comes up to the face along its normal
    direction = push if np.linalg.norm(push) > 1e-9 else data.site_xmat[scene.robot_site_id].reshape(3, 3)[:2, 2]
    along = np.r_[direction / np.linalg.norm(direction), 0.0]
    face0, turn = 0.0, 0.0
    follow_face = script.follow_face and push_limits.steady_reach_margin_m(
        scene, problem.initial_state, problem.task.aim_m) >= script.follow_face_margin_m
    if follow_face:
        yaw0 = yaw_of(object_qpos[3:7])
        quarter = round(turn_rad(yaw0, math.atan2(direction[1], direction[0])) / (math.pi / 2))
        face0 = yaw0 + quarter * math.pi / 2  # the pushed face's inward normal
        turn = turn_rad(yaw0, problem.task.target_yaw_rad)
        along = _along(face0)
    behind = scene.object_half_size[0] + scene.plate_half_thickness_m
    lift = np.array([0.0, 0.0, script.contact_height_m])
    before = start - (behind + script.standoff_m) * along + lift
    after = problem.task.aim_m - behind * along + lift
    T = simulator.n_steps
    path, normals = np.empty((T + 1, 3)), np.tile(along, (T + 1, 1))
    for t in range(T + 1):
        s = t / T
        if s < script.approach_fraction:
            path[t] = plate + (before - plate) * _minimum_jerk(s / script.approach_fraction)
            continue
        sigma = _minimum_jerk((s - script.approach_fraction) / (script.push_end_fraction - script.approach_fraction))
        if follow_face:  # the object's centre and yaw from the start's to the target's, the plate behind
            normals[t] = _along(face0 + sigma * turn)
            path[t] = start + sigma * (problem.task.aim_m - start) + lift - \
                (behind + (1.0 - sigma) * script.standoff_m) * normals[t]
        else:
            path[t] = before + (after - before) * sigma
    return path, normals


def _along(angle_rad: float) -> np.ndarray:
    return np.array([math.cos(angle_rad), math.sin(angle_rad), 0.0])


def joint_path(problem, script: ScriptedSettings) -> JointPath:
    """The plate path (plate_path) in joint space: damped least squares on the plate centre's position
    and on its normal turning from where it starts to along the push during the approach, the joints'
    start posture in the null space; each step within speed_fraction of the velocity limits and
    joint_margin_rad inside the ranges. Where the path is out of reach the joints lag behind it."""
    scene = problem.simulator.scene
    model = scene.model
    path, normals = plate_path(problem, script)
    data = _at_start(problem)
    site, dofs, qadr = scene.robot_site_id, scene.arm_dof_adr, scene.arm_qpos_adr
    normal0 = data.site_xmat[site].reshape(3, 3)[:, 2].copy()
    dt = model.opt.timestep
    step_max = script.speed_fraction * scene.velocity_limit * dt
    low, high = scene.joint_range[:, 0] + script.joint_margin_rad, scene.joint_range[:, 1] - script.joint_margin_rad
    inverse_weights = 1.0 / np.asarray(script.joint_weights)
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    damping, identity = script.damping * np.eye(6), np.eye(len(dofs))
    weight = script.orientation_weight
    T = len(path) - 1
    q = np.empty((T + 1, len(qadr)))
    q[0] = data.qpos[qadr]
    for t in range(1, T + 1):
        turned = min(1.0, t / T / script.approach_fraction)
        normal = (1.0 - turned) * normal0 + turned * normals[t]
        normal /= np.linalg.norm(normal)
        for _ in range(script.ik_iterations):
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            mujoco.mj_jacSite(model, data, jacp, jacr, site)
            # [2::3]: the plate normal, the site frame's z column
            error = np.concatenate((path[t] - data.site_xpos[site], weight * _cross(data.site_xmat[site][2::3], normal)))
            J = np.vstack([jacp[:, dofs], weight * jacr[:, dofs]])
            JW = J * inverse_weights
            system = JW @ J.T + damping
            step = JW.T @ np.linalg.solve(system, error)
            null_space = identity - JW.T @ np.linalg.solve(system, J)
            step += null_space @ (script.posture_gain * (q[0] - data.qpos[qadr]))
            data.qpos[qadr] = np.clip(np.clip(data.qpos[qadr] + step, q[t - 1] - step_max, q[t - 1] + step_max),
                                      low, high)
        q[t] = data.qpos[qadr]
    return JointPath(q, np.gradient(q, dt, axis=0))


def scripted_torques(problem, script: ScriptedSettings, gains: TrackingSettings,
                     path: JointPath | None = None) -> np.ndarray:
    """(N, 7) knot torques: the PD controller's (gains, kp and kd times script.gain_scale) torques tracking
    `path` (default joint_path: the near face's push), object contact included, averaged over each knot."""
    simulator = problem.simulator
    gains = dataclasses.replace(gains, kp=tuple(script.gain_scale * k for k in gains.kp),
                                kd=tuple(script.gain_scale * k for k in gains.kd))
    path = joint_path(problem, script) if path is None else path
    executed = tracking.track(simulator, problem.initial_state, path, gains)
    return executed.control_torque_Nm.reshape(simulator.n_knots, simulator.steps_per_knot, -1).mean(axis=1)
