"""The planner model's state from what a robot measures.

The arm's joints are taken as read. The cube is seen by a camera, late and noisy: its position (x, y) and yaw
come from the latest pose, its velocity from a least-squares line through the last few poses (the pose's own
time stamps, so the camera's rate and latency need not be known), and both are carried forward from the
pose's stamp to now at that velocity. The cube is taken to lie flat at its resting height in the model (a push
does not lift it), so the camera's noise in height, roll and pitch cannot put it into or above the table.
"""
from __future__ import annotations

import math
from collections import deque

import mujoco
import numpy as np

from cito_ros.execution.world import JointReading, PoseReading
from cito_ros.model.scene import Scene
from cito_ros.planner.task import tilt_of, yaw_of

FULL_PHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS


def tipping_tilt_rad(scene: Scene) -> float:
    """The tilt past which the cube's centre of mass is beyond the edge it stands on, so that it falls onto its
    side: the box's diagonal angle, 45 degrees for a cube."""
    half = scene.object_half_size
    return math.atan2(float(half[0]), float(half[2]))


def tipped_over(scene: Scene, tilt_rad: float) -> bool:
    """Whether a cube tilted by tilt_rad (tilt_of) is past tipping_tilt_rad: fallen, or falling, onto its side."""
    return tilt_rad >= tipping_tilt_rad(scene)


class StateEstimator:
    """The state estimate (see the module docstring) in `scene`'s model; `resting_state` gives the cube's
    resting height and everything the measurements do not (the table, the time, the actuators)."""

    def __init__(self, scene: Scene, resting_state: np.ndarray, window: int = 4, rest_window: int = 10):
        self.scene = scene
        self._template = np.array(resting_state, dtype=float)
        self._template[0] = 0.0
        self._resting_z = float(scene.object_qpos(resting_state)[2])
        # stamp, x, y, unwrapped yaw: the last `window` for the velocity in the state, the last `rest_window` to
        # tell rest (a longer line averages the camera's noise down: at rest no faster than that noise allows)
        self._poses: deque[tuple[float, float, float, float]] = deque(maxlen=max(window, rest_window))
        self._window = window
        self.tilt_rad = 0.0  # of the latest pose

    def add_pose(self, reading: PoseReading) -> None:
        self.tilt_rad = tilt_of(reading.quaternion)
        yaw = yaw_of(reading.quaternion)
        if self._poses:  # unwrapped, so that the line through the yaws has no 2 pi jumps
            yaw = self._poses[-1][3] + math.remainder(yaw - self._poses[-1][3], 2 * math.pi)
        self._poses.append((reading.stamp_s, float(reading.position_m[0]), float(reading.position_m[1]), yaw))

    @property
    def has_pose(self) -> bool:
        return bool(self._poses)

    @property
    def last_pose(self) -> tuple[float, float, float, float]:
        """The latest pose as measured: stamp, x, y and (unwrapped) yaw."""
        return self._poses[-1]

    def object_motion(self, window: int | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """The last pose (stamp, x, y, yaw) and the velocity (vx, vy, yaw rate) fitted through the last `window`
        poses (default: the state's window)."""
        poses = np.array(self._poses)[-(window or self._window):]
        last = poses[-1]
        if len(poses) < 2:
            return last, np.zeros(3), last[0]
        t = poses[:, 0] - poses[:, 0].mean()
        velocity = (t @ (poses[:, 1:] - poses[:, 1:].mean(axis=0))) / max(float(t @ t), 1e-12)
        return last, velocity, last[0]

    def object_speed_m_s(self) -> float:
        """The estimated speed of the cube's fastest point (as Scene.object_speed_m_s), over the rest window."""
        _, velocity, _ = self.object_motion(self._poses.maxlen)
        return float(np.hypot(velocity[0], velocity[1]) + abs(velocity[2]) * np.linalg.norm(self.scene.object_half_size))

    def object_pose(self, now_s: float) -> tuple[np.ndarray, float]:
        """(x, y) and yaw of the cube carried forward to now_s."""
        last, velocity, stamp = self.object_motion()
        ahead = max(now_s - stamp, 0.0)
        return last[1:3] + velocity[:2] * ahead, float(last[3] + velocity[2] * ahead)

    def resting_pose(self) -> tuple[np.ndarray, float]:
        """(x, y) and yaw of a cube at rest: the mean over the rest window's poses, the camera's noise averaged
        down (a single pose carried forward by a velocity fitted through noise is off by millimetres)."""
        poses = np.array(self._poses)
        return poses[:, 1:3].mean(axis=0), float(poses[:, 3].mean())

    def state(self, joints: JointReading, now_s: float, at_rest: bool = False) -> np.ndarray:
        """The mjSTATE_FULLPHYSICS state of the scene's model at now_s (its time field 0); with at_rest, the cube
        still at its resting_pose (fitted through the camera's noise, 1 mm and 0.01 rad, the last poses of a cube at
        rest turn it at a median 0.09 rad/s, p90 0.23 rad/s, and the replans' states carried that turn)."""
        scene = self.scene
        state = self._template.copy()
        q, v = scene.state_qpos_adr, scene.state_qvel_adr
        state[q + scene.arm_qpos_adr] = joints.q
        state[v + scene.arm_dof_adr] = joints.qdot
        if at_rest:
            (x, y), yaw = self.resting_pose()
            velocity = np.zeros(3)
        else:
            (x, y), yaw = self.object_pose(now_s)
            _, velocity, _ = self.object_motion()
        pose = scene.object_qpos(state)
        pose[:] = [x, y, self._resting_z, math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        motion = scene.object_qvel(state)
        motion[:] = [velocity[0], velocity[1], 0.0, 0.0, 0.0, velocity[2]]  # linear (world), angular (local: z up)
        return state
