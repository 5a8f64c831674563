"""What a 3D panel draws of a plan: /joint_states and /cito/scene_markers, one message per state.

The markers are the scene's own geoms (the arm's links, the plate, the cube, the table) posed by
MuJoCo's forward kinematics at each state of the executed motion, and the robot-object contact:
a sphere at the contact point and an arrow along the contact force, transparent while there is none.
Each geom keeps its marker id from state to state, so a viewer replaces rather than accumulates them.

A motion has hundreds of states and each array some thirty markers, so the arrays are not built as
message objects state by state: one template array is serialized once by rclpy's typesupport, with
sentinel values where the stamp, the poses, the contact's points and its opacity go; every state's
array is that template with the values written in place by numpy (`SceneMarkers.serialize`).
"""
from __future__ import annotations

import mujoco
import numpy as np
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from cito_ros.model.scene import ARM_JOINTS, Scene
from cito_ros.model.simulator import Trajectory
from cito_ros.ros.messages import time_msg

FORCE_ARROW_M_PER_N = 0.02    # arrow length per newton of contact force
CONTACT_SPHERE_M = 0.015
CONTACT_NS = "contact"
CONTACT_RGB = (1.0, 0.85, 0.0)
SHAPES = {mujoco.mjtGeom.mjGEOM_BOX: Marker.CUBE, mujoco.mjtGeom.mjGEOM_CYLINDER: Marker.CYLINDER,
          mujoco.mjtGeom.mjGEOM_CAPSULE: Marker.CYLINDER, mujoco.mjtGeom.mjGEOM_ELLIPSOID: Marker.SPHERE,
          mujoco.mjtGeom.mjGEOM_SPHERE: Marker.SPHERE}
# sentinels: values no real field of the template takes, found by their bytes
STAMP_SEC, STAMP_NANOSEC = 0x5EC0DE01, 0x2ABCDEF1


def _sentinel(index: int) -> float:
    return 7.0e5 + index / 8.0  # exact in binary (in float32 too), far from any pose in metres


def joint_states(trajectory: Trajectory, stamps_ns: list[int], frame_id: str) -> list[JointState]:
    """The executed arm motion: positions, velocities and applied torques at every state."""
    steps = len(trajectory.torque_Nm)
    return [JointState(header=Header(stamp=time_msg(stamps_ns[t]), frame_id=frame_id), name=list(ARM_JOINTS),
                       position=trajectory.q[t].tolist(), velocity=trajectory.qdot[t].tolist(),
                       effort=trajectory.torque_Nm[min(t, steps - 1)].tolist())
            for t in range(len(trajectory.q))]


class SceneMarkers:
    """The /cito/scene_markers arrays of the motions of one scene, as CDR bytes."""

    def __init__(self, scene: Scene, frame_id: str):
        self.scene = scene
        model = scene.model
        self.geoms = [g for g in range(model.ngeom) if int(model.geom_type[g]) in SHAPES]
        # the template: every geom's marker(s), then the contact sphere and arrow, each value to fill a sentinel
        header = Header(stamp=time_msg(STAMP_SEC * 10**9 + STAMP_NANOSEC), frame_id=frame_id)
        markers, self._slots = [], []  # per marker: (geom or -1, capsule end -1/0/+1)
        count = 0

        def pose_sentinel() -> Pose:
            nonlocal count
            values = [_sentinel(count + i) for i in range(7)]
            count += 7
            return Pose(position=Point(x=values[0], y=values[1], z=values[2]),
                        orientation=Quaternion(x=values[4], y=values[5], z=values[6], w=values[3]))

        for g in self.geoms:
            kind, size = int(model.geom_type[g]), model.geom_size[g]
            rgba = model.geom_rgba[g]
            color = ColorRGBA(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))
            name = model.geom(g).name or f"geom{g}"

            def marker(shape: int, index: int, scale: tuple[float, float, float]) -> Marker:
                return Marker(header=header, ns=name, id=index, type=shape, action=Marker.ADD, pose=pose_sentinel(),
                              scale=Vector3(x=scale[0], y=scale[1], z=scale[2]), color=color, lifetime=Duration(),
                              frame_locked=False)

            if kind in (mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_ELLIPSOID):
                markers.append(marker(SHAPES[kind], 0, tuple(2 * float(v) for v in size)))
                self._slots.append((g, 0))
            elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
                markers.append(marker(Marker.SPHERE, 0, (2 * float(size[0]),) * 3))
                self._slots.append((g, 0))
            else:
                radius, half = float(size[0]), float(size[1])
                markers.append(marker(Marker.CYLINDER, 0, (2 * radius, 2 * radius, 2 * half)))
                self._slots.append((g, 0))
                if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:  # a cylinder with a sphere at each end
                    for index, end in ((1, 1), (2, -1)):
                        markers.append(marker(Marker.SPHERE, index, (2 * radius,) * 3))
                        self._slots.append((g, end))
        alpha = _sentinel(count)
        hidden = ColorRGBA(r=CONTACT_RGB[0], g=CONTACT_RGB[1], b=CONTACT_RGB[2], a=alpha)
        at = [_sentinel(count + 1 + i) for i in range(9)]  # the sphere's centre, then the arrow's tail and tip
        count += 10
        markers.append(Marker(header=header, ns=CONTACT_NS, id=0, type=Marker.SPHERE, action=Marker.ADD,
                              pose=Pose(position=Point(x=at[0], y=at[1], z=at[2]), orientation=Quaternion(w=1.0)),
                              scale=Vector3(x=CONTACT_SPHERE_M, y=CONTACT_SPHERE_M, z=CONTACT_SPHERE_M), color=hidden))
        markers.append(Marker(header=header, ns=CONTACT_NS, id=1, type=Marker.ARROW, action=Marker.ADD,
                              pose=Pose(orientation=Quaternion(w=1.0)),
                              points=[Point(x=at[3], y=at[4], z=at[5]), Point(x=at[6], y=at[7], z=at[8])],
                              scale=Vector3(x=0.008, y=0.016, z=0.02), color=hidden))
        self.template = np.frombuffer(serialize_message(MarkerArray(markers=markers)), dtype=np.uint8).copy()
        raw = self.template.tobytes()
        self._poses = np.array([_find(raw, np.float64(_sentinel(k)).tobytes()) for k in range(7 * len(self._slots))])
        self._alpha = _find_all(raw, np.float32(alpha).tobytes(), 2)
        self._contact = np.array([_find(raw, np.float64(value).tobytes()) for value in at])
        self._sec = _find_all(raw, np.int32(STAMP_SEC).tobytes(), len(markers))
        self._nanosec = _find_all(raw, np.uint32(STAMP_NANOSEC).tobytes(), len(markers))
        self._data = mujoco.MjData(model)

    def serialize(self, trajectory: Trajectory, stamps_ns: list[int]) -> list[bytes]:
        """One serialized MarkerArray per state of `trajectory` (executed in this scene), stamped stamps_ns."""
        scene, model, data = self.scene, self.scene.model, self._data
        n = len(stamps_ns)
        values = np.zeros((n, len(self._slots), 7))
        adr = scene.object_qpos_adr
        quaternion = np.empty(4)
        for t in range(n):
            data.qpos[scene.arm_qpos_adr] = trajectory.q[t]
            data.qpos[adr:adr + 3], data.qpos[adr + 3:adr + 7] = trajectory.object_position_m[t], \
                trajectory.object_quaternion[t]
            mujoco.mj_kinematics(model, data)
            for k, (g, end) in enumerate(self._slots):
                mujoco.mju_mat2Quat(quaternion, data.geom_xmat[g])
                position = data.geom_xpos[g]
                if end:
                    position = position + end * float(model.geom_size[g][1]) * data.geom_xmat[g].reshape(3, 3)[:, 2]
                values[t, k, :3], values[t, k, 3:] = position, quaternion
        frames = np.repeat(self.template[None], n, axis=0)
        _put(frames, self._poses, values.reshape(n, -1))
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        _put(frames, self._sec, np.repeat((stamps // 10**9).astype(np.int32)[:, None], len(self._sec), axis=1))
        _put(frames, self._nanosec, np.repeat((stamps % 10**9).astype(np.uint32)[:, None], len(self._nanosec), axis=1))
        steps = len(trajectory.contact_count)
        touching = np.zeros(n, dtype=bool)
        touching[:steps] = trajectory.contact_count[:n] > 0
        points = trajectory.contact_point_m[np.minimum(np.arange(n), len(trajectory.contact_point_m) - 1)]
        forces = np.zeros((n, 3))
        forces[:steps] = trajectory.contact_force_N[:n]
        _put(frames, self._contact, np.concatenate([points, points, points + FORCE_ARROW_M_PER_N * forces], axis=1))
        alpha = np.where(touching, 1.0, 0.0).astype(np.float32)
        _put(frames, self._alpha, np.repeat(alpha[:, None], 2, axis=1))
        return [frame.tobytes() for frame in frames]


def _put(frames: np.ndarray, offsets: np.ndarray, values: np.ndarray) -> None:
    """Write values (n, k) of one dtype at byte offsets (k,) of every frame (n, bytes)."""
    width = values.dtype.itemsize
    raw = np.ascontiguousarray(values).view(np.uint8).reshape(len(frames), len(offsets), width)
    columns = offsets[:, None] + np.arange(width)
    frames[:, columns] = raw


def _find(raw: bytes, pattern: bytes) -> int:
    return _find_all(raw, pattern, 1)[0]


def _find_all(raw: bytes, pattern: bytes, expected: int) -> np.ndarray:
    found, start = [], raw.find(pattern)
    while start >= 0:
        found.append(start)
        start = raw.find(pattern, start + 1)
    if len(found) != expected:
        raise RuntimeError(f"the marker template holds a sentinel {len(found)} times, not {expected}")
    return np.array(found)

