"""Pushes on the object's side faces, for goals beside it: the scripted start of a push no push on the near face
(the face towards the arm) can make. ROS-free.

A push on the near face moves the object away from the arm, within the friction cone of that face's normal; a
goal more than 45 degrees off that normal needs the face whose inward normal is nearest the push (`face_needed`).
Face-on to a side face the plate is beyond the joints' reach for a cube 0.99 m out (by 3 cm: docs/experiments.md),
but turned by one of `tilts_rad` away from the arm it reaches the face anywhere along it, and its curved rim (the
plate is an ellipsoid) presses along the face's normal. An arm moving straight there would go through the object, so the
path is a joint-space transit past a point in front of the near face and beside the side face to `standoff_m` off
the face, then the plate onto the face and through the push. The contact point's offset along the face turns the
object as it moves (`turn_per_offset`); the physical stages refine the tracked path's torques as they refine the
near face's scripts (cito_ros.planner.scripted).
"""
from __future__ import annotations

import math

import mujoco
import numpy as np
from mujoco import minimize

from cito_ros.model.scene import pushed_face
from cito_ros.model.simulator import FULL_PHYSICS
from cito_ros.planner.scripted import _at_start, _cross, _minimum_jerk
from cito_ros.planner.task import cube_turn_rad, turn_rad, yaw_of
from cito_ros.planner.tracking import JointPath
from cito_ros.settings import ScriptedSettings, SideFaceSettings

NEAR, FAR = 0, 2           # face_towards' quarter turns from the near face (1 and 3: the side faces)
POSTURE_WEIGHT_M = 0.05    # the inverse kinematics' first pull towards its start posture (m/rad)
TABLE_WEIGHT = 10.0        # the arm's clearance above the table against the plate's place, in the push's steps


def face_towards(near_normal_rad: float, direction_rad: float) -> int:
    """The face whose inward normal is nearest a push in direction_rad, in quarter turns (counter-clockwise) from the
    near face, whose inward normal points at near_normal_rad (both world yaws)."""
    return round(turn_rad(near_normal_rad, direction_rad) / (math.pi / 2)) % 4


def near_normal_rad(object_xy, object_yaw_rad: float) -> float:
    """The world yaw of the inward normal of a cube's near face, the one towards the arm base (scene.pushed_face,
    where the object candidate sits), the cube at object_xy with object_yaw_rad."""
    return object_yaw_rad + pushed_face(object_xy, object_yaw_rad) * math.pi / 2


def face_for(object_xy, object_yaw_rad: float, target_xy) -> int:
    """face_towards for a push from a cube at object_xy with object_yaw_rad towards target_xy (near_normal_rad)."""
    push = np.asarray(target_xy, dtype=float)[:2] - np.asarray(object_xy, dtype=float)[:2]
    if np.linalg.norm(push) < 1e-9:
        return NEAR
    return face_towards(near_normal_rad(object_xy, object_yaw_rad), math.atan2(push[1], push[0]))


def across_first(object_xy, object_yaw_rad: float, target_xy, target_yaw_rad: float
                 ) -> tuple[tuple[float, float], float, float, float]:
    """A push from a cube at object_xy with object_yaw_rad towards target_xy split into its parts across and along
    the near face's inward normal: the waypoint the part across leads to, with the turn to target_yaw_rad (the cube's
    turn to it, cube_turn_rad) shared in proportion to the two parts' lengths, and the parts' lengths (m; across
    positive to the normal's left)."""
    (x, y), normal_rad = object_xy, near_normal_rad(object_xy, object_yaw_rad)
    normal = np.array([math.cos(normal_rad), math.sin(normal_rad)])
    push = np.asarray(target_xy, dtype=float)[:2] - (x, y)
    across_m, along_m = float(push @ (-normal[1], normal[0])), float(push @ normal)
    share = abs(across_m) / max(abs(across_m) + abs(along_m), 1e-12)
    return ((x - across_m * normal[1], y + across_m * normal[0]),
            object_yaw_rad + share * cube_turn_rad(object_yaw_rad, target_yaw_rad), across_m, along_m)


def face_needed(object_xy, object_yaw_rad: float, target_xy, settings) -> int:
    """face_for where stages.scripted.side_faces is enabled and the goal is further from the object than the success
    tolerance; else NEAR (the near face's pushes, which also hold an object at its goal)."""
    distance_m = np.linalg.norm(np.asarray(target_xy, dtype=float)[:2] - np.asarray(object_xy, dtype=float)[:2])
    if not settings.stages.scripted.side_faces.enabled or distance_m <= settings.task.success_position_error_m:
        return NEAR
    return face_for(object_xy, object_yaw_rad, target_xy)


class SideGeometry:
    """Where the plate stands on a side face: the face's inward normal, the tilted plate normal, the plate centre
    at the contact point and off the face, and the transit's via point, all in the world frame."""

    def __init__(self, scene, initial_state: np.ndarray, target_m: np.ndarray, target_yaw_rad: float,
                 face: int, side: SideFaceSettings, tilt_rad: float, offset_scale: float = 1.0):
        qpos = scene.object_qpos(initial_state)
        centre, half = qpos[:3], float(scene.object_half_size[0])
        away = scene.inward_normals(qpos[None, 3:7])[0]          # the near face's: away from the arm
        quarter = face * math.pi / 2
        inward = np.array([math.cos(quarter) * away[0] - math.sin(quarter) * away[1],
                           math.sin(quarter) * away[0] + math.cos(quarter) * away[1], 0.0])
        self.normal = math.cos(tilt_rad) * inward + math.sin(tilt_rad) * away
        self.push = np.asarray(target_m, dtype=float) - centre
        distance = float(np.linalg.norm(self.push[:2]))
        # the offset along the face (towards `away`) that turns the object by the goal's turn over this push:
        # a contact nearer the arm than the face centre turns it the way inward x away points
        handed = float(np.cross(inward, away)[2])
        turn = turn_rad(yaw_of(qpos[3:7]), target_yaw_rad)
        offset = 0.0 if distance < 1e-9 else -turn / (handed * side.turn_per_offset * distance)
        self.offset_m = offset_scale * float(np.clip(offset, -side.max_offset_m, side.max_offset_m))
        radius, half_thickness = scene.plate_radius_m, scene.plate_half_thickness_m
        along = float(inward @ self.normal)
        extent = math.sqrt(radius ** 2 * (1 - along ** 2) + half_thickness ** 2 * along ** 2)
        touch = (radius ** 2 * inward + (half_thickness ** 2 - radius ** 2) * along * self.normal) / extent
        lift = np.array([0.0, 0.0, side.contact_height_m])
        self.contact = centre - half * inward + self.offset_m * away - touch + lift
        self.off_face = self.contact - side.standoff_m * inward
        self.via = centre - (half + side.via_front_m) * away - (half + side.via_aside_m) * inward + lift


def _low_points(scene, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lowest point (world) of each of the arm's capsules, with its body and its height above the table top
    (inf where it is not over the table), in a kinematics-computed mjData: what of the arm comes nearest the table
    as the plate reaches low and tilted beside the object. Arrays over the capsules: bodies, (n, 3), (n,)."""
    model = scene.model
    low, high, table_z = scene.table_top()
    geoms = scene.arm_capsule_ids
    axes = data.geom_xmat[geoms, 2::3] * model.geom_size[geoms, 1:2]  # the capsules' z axes, half-length long
    points = data.geom_xpos[geoms] - axes * np.sign(axes[:, 2:3])
    points[:, 2] -= model.geom_size[geoms, 0]
    over = np.all((points[:, :2] >= low) & (points[:, :2] <= high), axis=1)
    return model.geom_bodyid[geoms], points, np.where(over, points[:, 2] - table_z, math.inf)


def _table_rows(scene, data: mujoco.MjData, clearance_m: float, dofs) -> tuple[np.ndarray, np.ndarray]:
    """For each arm capsule lower than clearance_m above the table top: how far below it is (m) and the Jacobian
    row of its lowest point's height over the arm's joints (none: (0,) and (0, n))."""
    errors, rows = [], []
    jacp = np.zeros((3, scene.model.nv))
    for body, point, height in zip(*_low_points(scene, data), strict=True):
        if height < clearance_m:
            mujoco.mj_jac(scene.model, data, jacp, None, point, body)
            errors.append(clearance_m - height)
            rows.append(jacp[2, dofs].copy())
    return np.array(errors), np.array(rows).reshape(len(rows), len(dofs))


def _plate_pose_q(scene, data: mujoco.MjData, position: np.ndarray, normal: np.ndarray, start_q: np.ndarray,
                  margin_rad: float, normal_weight: float, clearance_m: float) -> tuple[np.ndarray, float]:
    """Joint angles that put the plate centre at `position` with its normal along `normal`, from start_q, every
    joint margin_rad inside its range and the arm's capsules clearance_m above the table top
    (mujoco.minimize.least_squares), and the plate's distance from `position`."""
    low, high = scene.joint_range[:, 0] + margin_rad, scene.joint_range[:, 1] - margin_rad
    site, qadr = scene.robot_site_id, scene.arm_qpos_adr

    def residual(x: np.ndarray, posture: float) -> np.ndarray:
        columns = []
        for q in x.T:
            data.qpos[qadr] = q
            mujoco.mj_kinematics(scene.model, data)
            heights = _low_points(scene, data)[2]
            columns.append(np.r_[data.site_xpos[site] - position,
                                 normal_weight * (data.site_xmat[site].reshape(3, 3)[:, 2] - normal),
                                 np.minimum(heights - clearance_m, 0.0), posture * (q - start_q)])
        return np.array(columns).T

    # first near start_q, then exactly there: unpulled, the least squares lands on far-away wrist postures the
    # transit cannot reach within the joint speed limits
    q = np.clip(start_q, low, high)
    for posture in (POSTURE_WEIGHT_M, 0.0):
        q, _ = minimize.least_squares(q, lambda x, pull=posture: residual(x, pull), bounds=(low, high), verbose=0)
    return q, float(np.linalg.norm(residual(q[:, None], 0.0)[:3, 0]))


def plate_tilt(scene, initial_state: np.ndarray, task, face: int, side: SideFaceSettings,
               margin_rad: float) -> tuple[float, float]:
    """The first of side.tilts_rad at which the plate reaches the side face's contact at the push's start and at its
    end (by inverse kinematics alone), and how far it falls short there (at the last tilt where none reaches): a
    steeper tilt reaches further out along the face, and turns the object more as it pushes."""
    data = mujoco.MjData(scene.model)
    mujoco.mj_setState(scene.model, data, initial_state, FULL_PHYSICS)
    q0 = data.qpos[scene.arm_qpos_adr].copy()
    for tilt in side.tilts_rad:
        geometry = SideGeometry(scene, initial_state, task.aim_m, task.target_yaw_rad, face, side, tilt)
        q, short_start = _plate_pose_q(scene, data, geometry.contact, geometry.normal, q0, margin_rad,
                                       side.normal_weight, side.table_clearance_m)
        _, short_end = _plate_pose_q(scene, data, geometry.contact + geometry.push, geometry.normal, q, margin_rad,
                                     side.normal_weight, side.table_clearance_m)
        if max(short_start, short_end) <= side.reach_tolerance_m:
            break
    return tilt, max(short_start, short_end)


def side_joint_path(problem, script: ScriptedSettings, face: int, tilt_rad: float,
                    offset_scale: float = 1.0) -> JointPath:
    """The side push in joint space over the problem's horizon, the plate tilted by tilt_rad (plate_tilt's), its
    contact offset_scale times SideGeometry's offset along the face: to side.transit_fraction
    (longer, up to max_transit_fraction, where the joints would exceed script.speed_fraction of their limits) a
    transit through the via point (a cubic Hermite spline in the joint angles, not stopping there) to the plate
    standoff_m off the face; then, by damped least squares on the plate's position and normal, each step within
    script.speed_fraction of the joint speed limits, onto the face by contact_fraction and along the push, the plate
    following the object's centre from its start to the target by push_end_fraction."""
    side = script.side_faces
    scene = problem.simulator.scene
    model, site, qadr, dofs = scene.model, scene.robot_site_id, scene.arm_qpos_adr, scene.arm_dof_adr
    geometry = SideGeometry(scene, problem.initial_state, problem.task.aim_m, problem.task.target_yaw_rad,
                            face, side, tilt_rad, offset_scale)
    data = _at_start(problem)
    q0 = data.qpos[qadr].copy()
    q_via, _ = _plate_pose_q(scene, data, geometry.via, geometry.normal, q0, script.joint_margin_rad,
                             side.normal_weight, side.table_clearance_m)
    dt, T = model.opt.timestep, problem.simulator.n_steps

    def spline(steps):  # a cubic from rest to rest at the via point, over the first half of the transit
        s = np.linspace(0.0, 1.0, steps // 2 + 1)[:, None]
        return q0 + (3 * s ** 2 - 2 * s ** 3) * (q_via - q0)

    # transit_fraction of the horizon, or longer (up to max_transit_fraction) where the joints would move faster
    # than script.speed_fraction of their limits: in joint space to the via point, then the plate straight along
    # the side face to standoff_m off it (in joint space the arm went through the object's corner)
    n_transit = max(2, int(side.transit_fraction * T))
    transit = spline(n_transit)
    speed = np.max(np.abs(np.diff(transit, axis=0)) / (scene.velocity_limit * dt))
    if speed > script.speed_fraction:
        n_transit = min(int(math.ceil(n_transit * speed / script.speed_fraction)), int(side.max_transit_fraction * T))
        transit = spline(n_transit)
    low = scene.joint_range[:, 0] + script.joint_margin_rad
    high = scene.joint_range[:, 1] - script.joint_margin_rad
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    weight = script.orientation_weight
    step_max = script.speed_fraction * scene.velocity_limit * dt  # per step, as the near face's script
    q = [transit[-1]]
    data.qpos[qadr] = transit[-1]
    approach, pushing = n_transit - (len(transit) - 1), T - n_transit
    for k in range(1, approach + pushing + 1):
        s = max(k - approach, 0) / pushing
        onto = _minimum_jerk(s / side.contact_fraction)
        along = _minimum_jerk((s - side.contact_fraction) / (side.push_end_fraction - side.contact_fraction))
        aside = _minimum_jerk(k / approach)
        target = geometry.via + (geometry.off_face - geometry.via) * aside + \
            (geometry.contact - geometry.off_face) * onto + geometry.push * along
        for _ in range(script.ik_iterations):
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            mujoco.mj_jacSite(model, data, jacp, jacr, site)
            table_errors, table_rows = _table_rows(scene, data, side.table_clearance_m, dofs)
            # the last joint turns the plate about its normal, which nothing asks of it: held, or it wanders
            error = np.concatenate((target - data.site_xpos[site],
                                    weight * _cross(data.site_xmat[site][2::3], geometry.normal),
                                    TABLE_WEIGHT * table_errors, [0.0]))
            J = np.vstack([jacp[:, dofs], weight * jacr[:, dofs], TABLE_WEIGHT * table_rows, np.eye(len(dofs))[-1]])
            step = np.clip(J.T @ np.linalg.solve(J @ J.T + script.damping * np.eye(len(error)), error), -step_max,
                           step_max)
            data.qpos[qadr] = np.clip(q[-1] + np.clip(data.qpos[qadr] + step - q[-1], -step_max, step_max), low, high)
        q.append(data.qpos[qadr].copy())
    path = np.vstack([transit, np.array(q[1:])])
    return JointPath(path, np.gradient(path, dt, axis=0))
