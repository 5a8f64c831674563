"""Conversions between the ROS interfaces and the ROS-free planner.

Requests become validated `PlanInputs` (or a ValueError that says what is
wrong); a `PlanResult` becomes the response, the topic messages and the bag
messages. Nothing here talks to the ROS graph.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Duration, Time
from cito_msgs.msg import (
    ContactForce,
    PlanMetrics,
    PlanRequest,
    PlanResult as PlanResultMsg,
    SolverProgress,
    StageTiming,
)
from cito_msgs.srv import PlanPush
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from cito_ros.model.contact_models import CONTACT_MODELS
from cito_ros.model.scene import ARM_JOINTS, TABLE_TOP_Z_M
from cito_ros.planner.results import IterationLog, Metrics, PlanResult, StageRecord, Status, shortfalls, zone_note
from cito_ros.planner.sequence import sequence_note
from cito_ros.planner.task import aim_note, equivalent_yaw_note, yaw_of
from cito_ros.settings import SceneConfig, Settings

Response = PlanPush.Response
QUATERNION_MIN_NORM = 1e-6
TILT_TOLERANCE_RAD = 1e-3  # largest roll/pitch accepted in a target orientation


@dataclass(frozen=True)
class PlanInputs:
    """A validated request with its defaults resolved."""

    contact_model: str
    start_q: np.ndarray | None       # None: q0 of the configured beta
    target_position_m: np.ndarray
    target_yaw_rad: float
    target_orientation: np.ndarray   # normalised quaternion (x, y, z, w)
    time_limit_s: float
    object_pose: tuple[np.ndarray, float] | None  # (position (3,), yaw); None: the scene's own pose
    scene: str | None                # None: the configured scene


def flat_pose(pose: Pose, name: str, *, unset_allowed: bool = False) -> tuple[np.ndarray, float, np.ndarray] | None:
    """(position, yaw, normalised quaternion x y z w) of a pose that may only turn about z. ValueError
    naming `name` for NaN, a zero quaternion or a tilt beyond 1 mrad; a non-unit quaternion is
    normalised. With unset_allowed, a pose at the origin (the arm's base, where no object can be:
    a default-constructed Pose) is unset: None."""
    p, o = pose.position, pose.orientation
    position = np.array([p.x, p.y, p.z])
    quaternion = np.array([o.x, o.y, o.z, o.w])
    if unset_allowed and not np.any(position):
        return None
    norm = float(np.linalg.norm(quaternion)) if np.all(np.isfinite(quaternion)) else math.nan
    if not np.all(np.isfinite(position)):
        raise ValueError(f"{name}.position contains NaN or Inf: {position.tolist()}")
    if not np.all(np.isfinite(quaternion)):
        raise ValueError(f"{name}.orientation contains NaN or Inf: {quaternion.tolist()}")
    if norm < QUATERNION_MIN_NORM:
        raise ValueError(f"{name}.orientation is a zero quaternion; give a unit quaternion (w = 1 for no rotation)")
    x, y, z, w = quaternion / norm
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    if abs(roll) > TILT_TOLERANCE_RAD or abs(pitch) > TILT_TOLERANCE_RAD:
        raise ValueError(f"{name}.orientation must be a rotation about z (the object rests flat on the table); "
                         f"it has roll {roll:.4f} rad and pitch {pitch:.4f} rad")
    return position, math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)), np.array([x, y, z, w])


def parse_request(request, default_contact_model: str, default_time_limit_s: float) -> PlanInputs:
    """Validate a PlanPush service request or action goal (the same fields). Raises ValueError with a
    message for the caller."""
    position, yaw, orientation = flat_pose(request.target_pose, "target_pose")
    model = request.contact_model.strip().lower() or default_contact_model
    if model not in CONTACT_MODELS:
        raise ValueError(f"unknown contact model {request.contact_model!r}; choose one of {sorted(CONTACT_MODELS)} "
                         "(or empty for the default)")
    time_limit = request.time_limit_s
    if not math.isfinite(time_limit) or time_limit < 0:
        raise ValueError(f"time_limit_s must be a non-negative number (0: the default), got {time_limit}")
    object_pose = flat_pose(request.object_pose, "object_pose", unset_allowed=True)
    scene = request.scene.strip() or None
    if scene is not None and ("/" in scene or scene.endswith((".yaml", ".yml"))):
        raise ValueError(f"scene must be the name of a scene in config/scenes, got {request.scene!r}")
    return PlanInputs(model, parse_start_state(request.start_state), position, yaw, orientation,
                      time_limit or default_time_limit_s, None if object_pose is None else object_pose[:2], scene)


def parse_start_state(state: JointState) -> np.ndarray | None:
    """Arm start configuration from a JointState (joints by name, any order), None if empty."""
    if not state.name and not len(state.position):
        return None
    names = list(state.name)
    if len(state.position) != len(names):
        raise ValueError(f"start_state has {len(names)} names but {len(state.position)} positions")
    if sorted(names) != sorted(ARM_JOINTS):
        raise ValueError(f"start_state must name the joints {list(ARM_JOINTS)} exactly once each, got {names}")
    positions = dict(zip(names, state.position))
    q = np.array([positions[name] for name in ARM_JOINTS], dtype=float)
    if not np.all(np.isfinite(q)):
        raise ValueError("start_state.position contains NaN or Inf")
    if len(state.velocity):
        velocity = np.asarray(state.velocity, dtype=float)
        if len(velocity) != len(names):
            raise ValueError(f"start_state has {len(names)} names but {len(velocity)} velocities")
        if not np.all(np.isfinite(velocity)) or np.any(np.abs(velocity) > 1e-6):
            raise ValueError("start_state.velocity must be zero (or empty): the planner starts from rest")
    return q


def response_status(result: PlanResult, settings: Settings, requested_yaw_rad: float) -> tuple[int, str]:
    """The service status and a message for a finished plan of a goal with requested_yaw_rad."""
    status = result.status
    if status is Status.CANCELLED:
        return Response.STATUS_CANCELLED, "the solve was cancelled; the best iterate is returned"
    if status is Status.NUMERICAL_ERROR:
        return Response.STATUS_NUMERICAL_ERROR, f"the planned motion is not finite or raised MuJoCo warnings " \
                                                f"{result.executed_motion.warnings}"
    if status is Status.SOLVER_FAILED:
        return Response.STATUS_SOLVER_FAILED, "IPOPT failed; the best iterate is returned"
    m = result.metrics
    ends = (f"executed without the virtual force, the object ends {100 * m.position_error_m:.2f} cm and "
            f"{m.orientation_error_rad:.3f} rad from the goal (solver {status.value})")
    notes = (zone_note(m.steady_reach_margin_m), equivalent_yaw_note(requested_yaw_rad, result.target_yaw_rad),
             aim_note(result.target_position_m, result.aim_position_m), sequence_note(result))
    if m.success:
        return Response.STATUS_SUCCEEDED, ends + "".join(f"; {n}" for n in notes if n)
    return Response.STATUS_TASK_NOT_ACHIEVED, (
        f"task not achieved: {ends}; short of success by: {', '.join(shortfalls(m, settings.task))}"
        + "".join(f"; {n}" for n in (*notes, result.note) if n))


def metrics_msg(metrics: Metrics) -> PlanMetrics:
    """The PlanMetrics message: every Metrics field under its lower-cased name."""
    return PlanMetrics(**{name.lower(): value for name, value in metrics.as_dict().items()})


def stage_msgs(stages: tuple[StageRecord, ...]) -> list[StageTiming]:
    """One StageTiming message per stage: every StageRecord field under its name."""
    return [StageTiming(**record.as_dict()) for record in stages]


def time_msg(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def duration_msg(seconds: float) -> Duration:
    ns = int(round(seconds * 1e9))
    return Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def point_msg(p: np.ndarray) -> Point:
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def pose_msg(position: np.ndarray, quaternion_wxyz: np.ndarray) -> Pose:
    w, x, y, z = (float(v) for v in quaternion_wxyz)
    return Pose(position=point_msg(position),
                orientation=Quaternion(x=x, y=y, z=z, w=w))


def fill_xyz(message, values: list[float]) -> None:
    """A Vector3's or Point's fields, in place."""
    message.x, message.y, message.z = values


def request_msg(inputs: PlanInputs, start_q: np.ndarray, scene: SceneConfig, request_id: int, stamp_ns: int,
                frame_id: str) -> PlanRequest:
    """The request as it is planned: defaults resolved, the object where `scene` puts it."""
    x, y, z, w = inputs.target_orientation
    yaw = scene.object.yaw_rad
    object_position = np.array([*scene.object.position_m, TABLE_TOP_Z_M + scene.object.half_size_m])
    return PlanRequest(
        header=Header(stamp=time_msg(stamp_ns), frame_id=frame_id), request_id=request_id,
        target_pose=pose_msg(inputs.target_position_m, np.array([w, x, y, z])),
        contact_model=inputs.contact_model,
        start_state=JointState(header=Header(stamp=time_msg(stamp_ns), frame_id=frame_id), name=list(ARM_JOINTS),
                               position=[float(v) for v in start_q]),
        time_limit_s=float(inputs.time_limit_s),
        object_pose=pose_msg(object_position, np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])),
        scene=scene.name)


def progress_msg(entry: IterationLog, request_id: int, contact_model: str, stamp_ns: int, frame_id: str) -> SolverProgress:
    return SolverProgress(header=Header(stamp=time_msg(stamp_ns), frame_id=frame_id), request_id=request_id,
                          contact_model=contact_model, stage=entry.stage, iteration=entry.iteration, cost=entry.cost,
                          constraint_violation=entry.constraint_violation, elapsed_s=entry.elapsed_s,
                          position_error_m=entry.position_error_m, virtual_force=entry.virtual_force)


@dataclass(frozen=True)
class PlanMessages:
    """What a finished plan answers with; stamped at the start of its horizon, the per-step ones along the horizon
    and the hold after it."""

    trajectory: JointTrajectory
    contact_forces: list[ContactForce]
    result: PlanResultMsg
    step_stamps_ns: list[int]   # the stamp of each contact force
    state_stamps_ns: list[int]  # the stamp of each state (one more than the steps)


def plan_messages(result: PlanResult, request_id: int, stamp_ns: int, frame_id: str, bag_path: str,
                  target_orientation: np.ndarray, settings: Settings) -> PlanMessages:
    """The answer's messages of a plan whose horizon starts at stamp_ns: the joint trajectory over the horizon
    (what a robot's controller is sent), the contact forces over the whole motion (result.executed_motion: the
    horizon, then the arm held where the object comes to rest) and the result."""
    trajectory = result.trajectory
    header = Header(stamp=time_msg(stamp_ns), frame_id=frame_id)
    steps = len(trajectory.gamma_N)
    dt = float(trajectory.time_s[1] - trajectory.time_s[0])
    joint_trajectory = JointTrajectory(header=header, joint_names=list(ARM_JOINTS))
    # a message's constructor builds every nested default, even those passed in: the answer's ~5000 messages
    # are filled in place instead (half the time; they go out before the recording starts)
    q, qdot, torque = trajectory.q.tolist(), trajectory.qdot.tolist(), trajectory.torque_Nm.tolist()
    for t in range(steps + 1):
        point = JointTrajectoryPoint(positions=q[t], velocities=qdot[t], effort=torque[min(t, steps - 1)])
        point.time_from_start.sec, point.time_from_start.nanosec = divmod(round(t * dt * 1e9), 1_000_000_000)
        joint_trajectory.points.append(point)
    motion = result.executed_motion
    steps = len(motion.gamma_N)
    stamps = [stamp_ns + int(round(t * dt * 1e9)) for t in range(steps + 1)]
    has_stiffness = motion.stiffness_N is not None
    columns = zip(stamps, motion.gamma_N.tolist(), motion.stiffness_N.tolist() if has_stiffness else [0.0] * steps,
                  motion.signed_distance_m.tolist(), motion.virtual_force_N.tolist(), motion.contact_count.tolist(),
                  motion.contact_force_N.tolist(), motion.contact_torque_Nm.tolist(), motion.contact_point_m.tolist())
    forces = []
    for stamp, gamma, stiffness, distance, virtual, count, force, torque, point in columns:
        message = ContactForce(gamma_n=gamma, has_stiffness=has_stiffness, stiffness_n=stiffness,
                               signed_distance_m=distance, contact_count=int(count))
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        message.header.frame_id = frame_id
        fill_xyz(message.virtual_force, virtual)
        fill_xyz(message.contact_wrench.force, force)
        fill_xyz(message.contact_wrench.torque, torque)
        fill_xyz(message.contact_point, point)
        forces.append(message)
    x, y, z, w = target_orientation
    status, message = response_status(result, settings, float(yaw_of(np.array([w, x, y, z]))))
    result_msg = PlanResultMsg(
        header=header, request_id=request_id, status=status, message=message, contact_model=result.contact_model,
        target_pose=pose_msg(result.target_position_m, np.array([w, x, y, z])),
        final_object_pose=pose_msg(motion.object_position_m[-1], motion.object_quaternion[-1]),
        planned_object_pose=pose_msg(result.planned.object_position_m[-1], result.planned.object_quaternion[-1]),
        metrics=metrics_msg(result.metrics), stages=stage_msgs(result.stages), bag_path=bag_path)
    return PlanMessages(joint_trajectory, forces, result_msg, stamps[:steps], stamps)


def object_poses(result: PlanResult, stamps_ns: list[int], frame_id: str) -> list[PoseStamped]:
    """The object's pose at every state of the executed motion (the horizon, then the hold): the last is where
    the executed error is measured."""
    motion = result.executed_motion
    return [PoseStamped(header=Header(stamp=time_msg(stamp), frame_id=frame_id),
                        pose=pose_msg(motion.object_position_m[t], motion.object_quaternion[t]))
            for t, stamp in enumerate(stamps_ns)]


def fill_response(response, messages: PlanMessages):
    """Fill a PlanPush service response or action result (the same fields) from a finished plan."""
    result = messages.result
    response.success, response.status, response.message = result.metrics.success, result.status, result.message
    response.metrics, response.stages, response.bag_path = result.metrics, result.stages, result.bag_path
    response.trajectory = messages.trajectory
    response.contact_forces = messages.contact_forces
    return response
