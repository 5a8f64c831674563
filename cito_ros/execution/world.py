"""A simulated robot in a world that is not the planner's model.

`SimulatedWorld` is the scene's MuJoCo world with a `Mismatch` applied: the cube's friction and mass scaled and
the cube off from where the planner is told it is. The arm takes total joint torques, as an effort controller
does (no gravity compensation: whoever commands it compensates), clamped to the motor limits, and the world is
stepped one timestep at a time. It reports what a robot's drivers and a camera would: the joint state every
step, and the cube's pose at the camera's rate, with noise and latency. Its truth (where the cube really is)
is there for judging, never for the executor.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import mujoco
import numpy as np

from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import Scene
from cito_ros.settings import SceneConfig, Settings


@dataclass(frozen=True)
class Mismatch:
    """How a world differs from the planner's model, and how its camera sees the cube."""

    name: str = "nominal"
    friction_scale: float = 1.0          # of every contact pair with the cube
    mass_scale: float = 1.0              # of the cube
    offset_m: tuple[float, float] = (0.0, 0.0)  # the cube's true position minus where the planner is told (x, y)
    offset_yaw_rad: float = 0.0          # its true yaw minus the told one
    pose_noise_m: float = 0.0            # standard deviation of the camera's position error, per axis
    yaw_noise_rad: float = 0.0           # and of its yaw error
    latency_s: float = 0.0               # a camera pose arrives this long after the instant it shows
    camera_rate_hz: float = 30.0

    def __post_init__(self):
        for name in ("friction_scale", "mass_scale", "camera_rate_hz"):
            if not math.isfinite(getattr(self, name)) or getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("pose_noise_m", "yaw_noise_rad", "latency_s"):
            if not math.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                raise ValueError(f"{name} must be zero or more, got {getattr(self, name)}")

    def world_config(self, told: SceneConfig) -> SceneConfig:
        """The world's scene: `told` (the planner's) with the cube's friction, mass and pose changed."""
        scaled = told.with_object_scaled(self.friction_scale, self.mass_scale)
        x, y = told.object.position_m
        return dataclasses.replace(scaled, object=dataclasses.replace(
            scaled.object, position_m=(x + self.offset_m[0], y + self.offset_m[1]),
            yaw_rad=told.object.yaw_rad + self.offset_yaw_rad))


@dataclass(frozen=True)
class JointReading:
    stamp_s: float
    q: np.ndarray
    qdot: np.ndarray
    effort: np.ndarray        # the torques applied over the last step


@dataclass(frozen=True)
class PoseReading:
    stamp_s: float            # the instant the pose shows (it arrived latency_s later)
    position_m: np.ndarray    # (3,)
    quaternion: np.ndarray    # (4,) w, x, y, z


class SimulatedWorld:
    """The robot and the cube in a mismatched world (see the module docstring)."""

    def __init__(self, settings: Settings, mismatch: Mismatch, start_q: np.ndarray, told: SceneConfig | None = None,
                 seed: int = 0):
        self.mismatch = mismatch
        self.scene = Scene(contact_model("scm", settings.contact_models),
                           mismatch.world_config(settings.scene if told is None else told), native=False)
        self.model = self.scene.model
        self.data = mujoco.MjData(self.model)
        mujoco.mj_setState(self.model, self.data, self.scene.initial_state(start_q), mujoco.mjtState.mjSTATE_FULLPHYSICS)
        mujoco.mj_forward(self.model, self.data)
        self.timestep_s = self.model.opt.timestep
        self._rng = np.random.default_rng(seed)
        self._effort = np.zeros(len(self.scene.motor_ids))
        self._camera_period_s = 1.0 / mismatch.camera_rate_hz
        self._next_capture_s = 0.0
        self._captured: list[PoseReading] = []   # taken, not yet delivered (the latency)

    @property
    def time_s(self) -> float:
        return float(self.data.time)

    def step(self, torques_Nm: np.ndarray) -> None:
        """One timestep with these total joint torques (clamped to the motor limits)."""
        limit = self.scene.torque_limit
        self._effort = np.clip(np.asarray(torques_Nm, dtype=float), -limit, limit)
        self.data.ctrl[:] = 0.0
        self.data.ctrl[self.scene.motor_ids] = self._effort
        mujoco.mj_step(self.model, self.data)
        self._capture()

    def joints(self) -> JointReading:
        scene = self.scene
        return JointReading(self.time_s, self.data.qpos[scene.arm_qpos_adr].copy(),
                            self.data.qvel[scene.arm_dof_adr].copy(), self._effort.copy())

    def camera(self) -> list[PoseReading]:
        """The cube poses that have arrived by now (taken at least latency_s ago), oldest first; each once."""
        arrived = [p for p in self._captured if p.stamp_s + self.mismatch.latency_s <= self.time_s + 1e-9]
        self._captured = self._captured[len(arrived):]
        return arrived

    def _capture(self) -> None:
        if self.time_s + 1e-9 < self._next_capture_s:
            return
        self._next_capture_s += self._camera_period_s
        position, quaternion = self.true_object_pose()
        noise = self._rng.normal(0.0, self.mismatch.pose_noise_m, 3) if self.mismatch.pose_noise_m else np.zeros(3)
        turn = self._rng.normal(0.0, self.mismatch.yaw_noise_rad) if self.mismatch.yaw_noise_rad else 0.0
        seen = np.empty(4)
        mujoco.mju_mulQuat(seen, np.array([math.cos(turn / 2), 0.0, 0.0, math.sin(turn / 2)]), quaternion)
        self._captured.append(PoseReading(self.time_s, position + noise, seen))

    def true_object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        adr = self.scene.object_qpos_adr
        return self.data.qpos[adr:adr + 3].copy(), self.data.qpos[adr + 3:adr + 7].copy()

    def object_speed_m_s(self) -> float:
        state = np.empty(mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
        mujoco.mj_getState(self.model, self.data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        return self.scene.object_speed_m_s(state)

    def joint_speed_ratio(self) -> float:
        return float(np.max(np.abs(self.data.qvel[self.scene.arm_dof_adr]) / self.scene.velocity_limit))

    def joint_range_excess(self) -> float:
        return self.scene.joint_range_excess(self.data.qpos[self.scene.arm_qpos_adr])
