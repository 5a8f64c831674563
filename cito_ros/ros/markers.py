"""What a 3D panel draws of a plan: /joint_states and /cito/scene_markers, one message per state.

The markers are the scene's own geoms (the arm's links, the plate, the cube, the table) posed by
MuJoCo's forward kinematics at each state of the executed motion, and the robot-object contact:
a sphere at the contact point and an arrow along the contact force. Each geom keeps its marker
id from state to state, so a viewer replaces rather than accumulates them.
"""
from __future__ import annotations

import mujoco
import numpy as np
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Vector3
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from cito_ros.model.scene import ARM_JOINTS, Scene
from cito_ros.model.simulator import Trajectory
from cito_ros.ros.messages import point_msg, pose_msg, time_msg

FORCE_ARROW_M_PER_N = 0.02    # arrow length per newton of contact force
CONTACT_SPHERE_M = 0.015
CONTACT_NS = "contact"
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
SHAPES = {mujoco.mjtGeom.mjGEOM_BOX: Marker.CUBE, mujoco.mjtGeom.mjGEOM_CYLINDER: Marker.CYLINDER,
          mujoco.mjtGeom.mjGEOM_CAPSULE: Marker.CYLINDER, mujoco.mjtGeom.mjGEOM_ELLIPSOID: Marker.SPHERE,
          mujoco.mjtGeom.mjGEOM_SPHERE: Marker.SPHERE}


def joint_states(trajectory: Trajectory, stamps_ns: list[int], frame_id: str) -> list[JointState]:
    """The executed arm motion: positions, velocities and applied torques at every state."""
    steps = len(trajectory.torque_Nm)
    return [JointState(header=_header(stamps_ns[t], frame_id), name=list(ARM_JOINTS),
                       position=trajectory.q[t].tolist(), velocity=trajectory.qdot[t].tolist(),
                       effort=trajectory.torque_Nm[min(t, steps - 1)].tolist())
            for t in range(len(trajectory.q))]


def scene_markers(scene: Scene, trajectory: Trajectory, stamps_ns: list[int], frame_id: str) -> list[MarkerArray]:
    """One MarkerArray per state of `trajectory` (executed in `scene`)."""
    model, data = scene.model, mujoco.MjData(scene.model)
    geoms = [g for g in range(model.ngeom) if int(model.geom_type[g]) in SHAPES]
    out = []
    for t, stamp in enumerate(stamps_ns):
        data.qpos[scene.arm_qpos_adr] = trajectory.q[t]
        adr = scene.object_qpos_adr
        data.qpos[adr:adr + 3], data.qpos[adr + 3:adr + 7] = trajectory.object_position_m[t], \
            trajectory.object_quaternion[t]
        mujoco.mj_kinematics(model, data)
        header = _header(stamp, frame_id)
        markers = []
        for g in geoms:
            markers += _geom_markers(model, data, g, header)
        force = trajectory.contact_force_N[t] if t < len(trajectory.contact_count) and \
            trajectory.contact_count[t] > 0 else None
        markers += _contact_markers(trajectory.contact_point_m[min(t, len(trajectory.contact_point_m) - 1)],
                                    force, header)
        out.append(MarkerArray(markers=markers))
    return out


def _geom_markers(model: mujoco.MjModel, data: mujoco.MjData, g: int, header: Header) -> list[Marker]:
    kind, size = int(model.geom_type[g]), model.geom_size[g]
    quaternion = np.empty(4)
    mujoco.mju_mat2Quat(quaternion, data.geom_xmat[g])
    rgba = model.geom_rgba[g]
    color = ColorRGBA(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))
    name = model.geom(g).name or f"geom{g}"

    def marker(shape: int, index: int, position: np.ndarray, scale: tuple[float, float, float]) -> Marker:
        return Marker(header=header, ns=name, id=index, type=shape, action=Marker.ADD,
                      pose=pose_msg(position, quaternion), scale=Vector3(x=scale[0], y=scale[1], z=scale[2]),
                      color=color, lifetime=Duration(), frame_locked=False)

    position = data.geom_xpos[g]
    if kind == mujoco.mjtGeom.mjGEOM_BOX or kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        return [marker(SHAPES[kind], 0, position, tuple(2 * float(v) for v in size))]
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return [marker(Marker.SPHERE, 0, position, (2 * float(size[0]),) * 3)]
    radius, half = float(size[0]), float(size[1])
    shapes = [marker(Marker.CYLINDER, 0, position, (2 * radius, 2 * radius, 2 * half))]
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:  # a cylinder with a sphere at each end
        axis = data.geom_xmat[g].reshape(3, 3)[:, 2]
        shapes += [marker(Marker.SPHERE, i, position + sign * half * axis, (2 * radius,) * 3)
                   for i, sign in ((1, 1.0), (2, -1.0))]
    return shapes


def _contact_markers(point: np.ndarray, force: np.ndarray | None, header: Header) -> list[Marker]:
    if force is None:
        return [Marker(header=header, ns=CONTACT_NS, id=i, action=Marker.DELETE) for i in (0, 1)]
    yellow = ColorRGBA(r=1.0, g=0.85, b=0.0, a=1.0)
    sphere = Marker(header=header, ns=CONTACT_NS, id=0, type=Marker.SPHERE, action=Marker.ADD,
                    pose=pose_msg(point, IDENTITY),
                    scale=Vector3(x=CONTACT_SPHERE_M, y=CONTACT_SPHERE_M, z=CONTACT_SPHERE_M), color=yellow)
    tip = point + FORCE_ARROW_M_PER_N * force
    arrow = Marker(header=header, ns=CONTACT_NS, id=1, type=Marker.ARROW, action=Marker.ADD,
                   pose=pose_msg(np.zeros(3), IDENTITY),
                   points=[point_msg(point), point_msg(tip)], scale=Vector3(x=0.008, y=0.016, z=0.02), color=yellow)
    return [sphere, arrow]


def _header(stamp_ns: int, frame_id: str) -> Header:
    return Header(stamp=time_msg(stamp_ns), frame_id=frame_id)
