"""The push task: where the object should end, and the pose error of a final object pose.

ROS-free. Orientation errors are the Euler angles (roll, pitch, yaw) of the
object's rotation relative to the target rotation (a yaw about world z).

The object is a cube (every scene's: one edge, SceneConfig.object.half_size_m, uniform): turned by a quarter turn
about z it is the same object, to the camera and to the physics, so a goal yaw counts modulo QUARTER_TURN_RAD.
A task aims at the goal's equivalent nearest the object's start yaw (make_task), at most an eighth of a turn away.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from cito_ros.settings.typed_config import require_finite


def euler_angles(rotation: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (rad) of a rotation matrix, R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return np.array([
        math.atan2(rotation[2, 1], rotation[2, 2]),
        math.asin(max(-1.0, min(1.0, -rotation[2, 0]))),
        math.atan2(rotation[1, 0], rotation[0, 0]),
    ])


def yaw_of(quaternion: np.ndarray) -> float | np.ndarray:
    """The yaw (rad, about world z) of a unit quaternion (w, x, y, z), or of each of an (..., 4) array of them."""
    w, x, y, z = np.moveaxis(np.asarray(quaternion, dtype=float), -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def tilt_of(quaternion: np.ndarray) -> float | np.ndarray:
    """The angle (rad) between the cube's top (its body z) and world z, 0 upright, of a quaternion (w, x, y, z) or of
    each of an (..., 4) array of them."""
    q = np.asarray(quaternion, dtype=float)
    x, y = q[..., 1], q[..., 2]  # the rotation's zz entry, 1 - 2 (x^2 + y^2) of the unit quaternion
    return np.arccos(np.clip(1 - 2 * (x * x + y * y) / np.sum(q * q, axis=-1), -1.0, 1.0))


def turn_rad(from_yaw_rad: float, to_yaw_rad: float) -> float:
    """The turn (rad) from one yaw to another the shorter way round, in [-pi, pi]: counter-clockwise positive."""
    return math.remainder(to_yaw_rad - from_yaw_rad, 2 * math.pi)


QUARTER_TURN_RAD = math.pi / 2
# an equivalent yaw replaces the requested one only where it is nearer by more than this: a goal an eighth of a turn
# away (45 degrees, as asked to a few digits) is as near either way round, and is taken as asked
EQUIVALENT_TIE_RAD = 1e-3


def nearest_equivalent_yaw(target_yaw_rad: float, yaw_rad: float) -> float:
    """The yaw a quarter turn or several from target_yaw_rad (the same pose of the cube) nearest yaw_rad:
    target_yaw_rad itself, to the last bit, where none is nearer by more than EQUIVALENT_TIE_RAD."""
    nearest = target_yaw_rad - QUARTER_TURN_RAD * round((target_yaw_rad - yaw_rad) / QUARTER_TURN_RAD)
    nearer = abs(turn_rad(yaw_rad, target_yaw_rad)) - abs(turn_rad(yaw_rad, nearest)) > EQUIVALENT_TIE_RAD
    return nearest if nearer else target_yaw_rad


def cube_turn_rad(from_yaw_rad: float, to_yaw_rad: float) -> float:
    """The turn (rad) from the cube at one yaw to the same cube at another, to the nearest of its four equivalents
    (nearest_equivalent_yaw): within [-pi/4, pi/4] but for EQUIVALENT_TIE_RAD."""
    return turn_rad(from_yaw_rad, nearest_equivalent_yaw(to_yaw_rad, from_yaw_rad))


def push_turn_limit_rad(task_settings, distance_m: float) -> float:
    """The most one push over distance_m turns the object (task.turn_per_push_rad_per_m on top of the orientation
    tolerance): what a goal may ask of one push (builder.check_pushable)."""
    return task_settings.success_orientation_error_rad + task_settings.turn_per_push_rad_per_m * distance_m


def quarter_turns(requested_yaw_rad: float, taken_yaw_rad: float) -> int:
    """How many quarter turns (counter-clockwise positive) the yaw aimed at (make_task) lies from the one requested."""
    return round(turn_rad(requested_yaw_rad, taken_yaw_rad) / QUARTER_TURN_RAD)


def equivalent_yaw_note(requested_yaw_rad: float, taken_yaw_rad: float) -> str:
    """What an answer says where the yaw aimed at is not the one requested (make_task), else ""."""
    quarters = quarter_turns(requested_yaw_rad, taken_yaw_rad)
    return "" if quarters == 0 else (
        f"the goal yaw {requested_yaw_rad:.3f} rad was taken as {taken_yaw_rad:.3f} rad, {abs(quarters)} quarter "
        f"turn(s) {'counter-clockwise' if quarters > 0 else 'clockwise'} from it: the same pose of the cube, nearer "
        f"its start")


def yaw_rotation(yaw_rad: float) -> np.ndarray:
    """The rotation matrix of a yaw about world z."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quaternion_matrix(quaternion: np.ndarray) -> np.ndarray:
    rotation = np.empty(9)
    mujoco.mju_quat2Mat(rotation, quaternion / np.linalg.norm(quaternion))
    return rotation.reshape(3, 3)


@dataclass(frozen=True)
class PushTask:
    """Where the object should end: position (m, world) and yaw (rad) about world z; and where the pushes aim
    (the terminal cost, the scripts): the target, or a point past it along the push (`aim_position_m`, make_task)
    where the turn needs a longer push than the target is away. A plan is judged at the target (pose_error)."""

    target_position_m: np.ndarray
    target_yaw_rad: float = 0.0
    aim_position_m: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "target_position_m", _position("target", self.target_position_m))
        if self.aim_position_m is not None:
            object.__setattr__(self, "aim_position_m", _position("aim", self.aim_position_m))
        object.__setattr__(self, "target_yaw_rad", require_finite("target yaw", self.target_yaw_rad))

    @property
    def aim_m(self) -> np.ndarray:
        """Where the pushes aim: aim_position_m, or the target."""
        return self.target_position_m if self.aim_position_m is None else self.aim_position_m

    @property
    def target_rotation(self) -> np.ndarray:
        return yaw_rotation(self.target_yaw_rad)

    def angle_error(self, quaternion: np.ndarray) -> np.ndarray:
        """Euler angles (rad) of an object orientation (w, x, y, z) relative to the target."""
        return euler_angles(self.target_rotation.T @ quaternion_matrix(quaternion))

    def final_errors(self, trajectory) -> tuple[float, float]:
        """Position (m) and orientation (rad) error norms of a Trajectory's last object pose."""
        position_error, angle_error = self.pose_error(
            np.concatenate([trajectory.object_position_m[-1], trajectory.object_quaternion[-1]]))
        return float(np.linalg.norm(position_error)), float(np.linalg.norm(angle_error))

    def pose_error(self, object_qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position error vector (m) and Euler-angle error (rad) of an object pose (x y z qw qx qy qz)."""
        return object_qpos[:3] - self.target_position_m, self.angle_error(object_qpos[3:7])

    def aim_error(self, object_qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """pose_error against the aim (aim_m): what the pushes minimize."""
        return object_qpos[:3] - self.aim_m, self.angle_error(object_qpos[3:7])


def _position(name: str, value) -> np.ndarray:
    position = np.asarray(value, dtype=float)
    if position.shape != (3,):
        raise ValueError(f"{name} position must have 3 coordinates, got shape {position.shape}")
    if not np.all(np.isfinite(position)):
        raise ValueError(f"{name} position contains NaN or Inf")
    return position


def aim_past_m(target_position_m, aim_position_m) -> float:
    """How far past the goal the pushes aimed (PushTask.aim_position_m; None: 0)."""
    return 0.0 if aim_position_m is None else \
        float(np.linalg.norm(np.asarray(aim_position_m)[:2] - np.asarray(target_position_m)[:2]))


def aim_note(target_position_m, aim_position_m) -> str:
    """What an answer says where the pushes aimed past the goal (PushTask.aim_position_m), else ""."""
    if aim_position_m is None:
        return ""
    return (f"the push aimed {100 * aim_past_m(target_position_m, aim_position_m):.1f} cm past the goal along the "
            f"push: a push turns the cube only as it moves it, and the goal's turn needs a push that long (judged at "
            f"the goal)")
