"""A plan executed the way a robot's joint trajectory controller would: PD tracking of the planned
joint positions and velocities with gravity (bias) compensation, no virtual force.

ROS-free. The controller runs every simulation step: tau = clamp(kp (q_ref - q) + kd (qdot_ref -
qdot)) + C^(q, qdot), where the clamp is the motor limit and C^ comes from the same compensated
motors the planner uses (cito.compensated_motor). The gains are the settings' `tracking` section.

After the last point the controller holds it at rest (`held_motion`), and a push is judged where the
object is then (`rest_errors`): a plan may end with the object still sliding, and what the robot delivers is
where it stops.
"""
from __future__ import annotations

import concurrent.futures
import math
import os
import threading
import weakref
from dataclasses import dataclass
from typing import Callable, NamedTuple, Protocol

import mujoco
import numpy as np

from cito_ros.model import _native
from cito_ros.model.simulator import Simulator, Trajectory, warning_counts
from cito_ros.planner.task import tilt_of
from cito_ros.settings import TrackingSettings


class JointReference(Protocol):
    """What the controller tracks: joint positions and velocities (n_steps + 1, 7) at every state, and the
    torques (n_steps, 7) it adds as feed-forward with gains.feed_forward (a Trajectory, or a JointPath)."""

    q: np.ndarray
    qdot: np.ndarray
    control_torque_Nm: np.ndarray | None


@dataclass(frozen=True)
class JointPath:
    """Joint positions and velocities (n_steps + 1, 7) over the states of a horizon: the scripted start's
    path (cito_ros.planner.scripted, no torques), or a plan's reference moved by an offset (its torques)."""

    q: np.ndarray
    qdot: np.ndarray
    control_torque_Nm: np.ndarray | None = None


def smooth_offset(rng: np.random.Generator, n_knots: int, n_states: int,
                  timestep_s: float) -> tuple[np.ndarray, np.ndarray]:
    """A seeded random joint offset (n_states, 7), within [-1, 1] for every joint, drawn at the horizon's
    n_knots + 1 knot times and linear between them (a servo's steady error, smooth enough for the
    controller to follow), and its rate (per second)."""
    corners = rng.uniform(-1.0, 1.0, (n_knots + 1, 7))
    times = np.linspace(0.0, n_knots, n_states)
    offset = np.stack([np.interp(times, np.arange(n_knots + 1), corners[:, j]) for j in range(7)], axis=1)
    return offset, np.gradient(offset, timestep_s, axis=0)


def offset_references(reference: JointReference, n_knots: int, timestep_s: float, count: int, amplitude_rad: float,
                      seed: int) -> list[JointPath]:
    """`reference` moved by `count` smooth offsets (smooth_offset) of up to amplitude_rad, drawn from `seed`."""
    rng = np.random.default_rng(seed)
    moved = []
    for _ in range(count):
        offset, rate = smooth_offset(rng, n_knots, len(reference.q), timestep_s)
        moved.append(JointPath(reference.q + amplitude_rad * offset, reference.qdot + amplitude_rad * rate,
                               reference.control_torque_Nm))
    return moved


def offset_position_errors_m(simulator: Simulator, initial_state: np.ndarray, reference: JointReference,
                             gains: TrackingSettings, task, count: int, amplitude_rad: float, seed: int) -> list[float]:
    """The task's position errors at rest (tracked_rest_error_m) of `reference` tracked with each of its
    offset_references."""
    return [tracked_rest_error_m(simulator, initial_state, moved, task, gains)
            for moved in offset_references(reference, simulator.n_knots, simulator.timestep_s, count, amplitude_rad,
                                           seed)]


def held_motion(simulator: Simulator, state: np.ndarray, gains: TrackingSettings) -> Trajectory | None:
    """The execution continued from `state` (where it ends) with the controller holding the arm's joint
    positions of `state` at rest for gains.hold_s (a joint trajectory controller past its last point), no
    virtual force; None when `state` is not finite. Its warnings are MuJoCo's on the way."""
    if not np.all(np.isfinite(state)):
        return None
    scene = simulator.scene
    steps = round(gains.hold_s / simulator.timestep_s)
    held = state[scene.state_qpos_adr + scene.arm_qpos_adr]
    return pd_motion(simulator, state, np.tile(held, (steps, 1)), np.zeros((steps, len(held))), gains)


class WorldErrors(NamedTuple):
    """A reference tracked (and held) in one world: the task's errors where the cube comes to rest, and how far it
    tilted from upright on the way."""

    position_m: float
    orientation_rad: float
    tilt_rad: float


def world_errors(simulator: Simulator, initial_state: np.ndarray, reference: JointReference,
                 gains: TrackingSettings, task, nominal: WorldErrors,
                 stop: Callable[[WorldErrors], bool] | None = None) -> list[WorldErrors]:
    """The WorldErrors of `reference` tracked (and held) in each world of gains.world_friction_scales and
    world_mass_scales other than the model's own (1, 1), and first `nominal`, its tracking in the model, where there
    are any: held to the tolerances in the other worlds, a plan is held to them in its own too (a plan the executor's
    servo tracked to 0.24 rad off in the model was taken). With `stop`, the worlds after the first whose errors it
    holds for are not tracked (a caller that rejects the plan there needs no more)."""
    worlds = [simulator.in_world(friction, mass) for friction, mass in zip(gains.world_friction_scales,
                                                                           gains.world_mass_scales)
              if not (friction == 1.0 and mass == 1.0)]

    def errors_in(world: Simulator) -> WorldErrors:
        tracked = track(world, initial_state, reference, gains)
        return motion_errors(tracked, held_motion(world, tracked.final_state, gains), task)

    # as many worlds at a time as the pool has threads (the native tracking runs without the GIL): the same
    # errors as one after the other, a world after the first that `stop` holds for tracked and left out
    pool, threads = _world_pool()
    errors = []
    for first in range(0, len(worlds), threads):
        for error in pool.map(errors_in, worlds[first:first + threads]):
            errors.append(error)
            if stop is not None and stop(error):
                return [nominal, *errors]
    return [nominal, *errors] if errors else []


def motion_errors(tracked: Trajectory, held: Trajectory | None, task) -> WorldErrors:
    """The WorldErrors of a tracked motion and its held_motion: errors_at_rest, and the cube's largest tilt over
    both (NaN where MuJoCo warned, as the errors)."""
    position_m, orientation_rad = errors_at_rest(held, task)
    if not math.isfinite(position_m):
        return WorldErrors(position_m, orientation_rad, math.nan)
    return WorldErrors(position_m, orientation_rad, max(float(tilt_of(motion.object_quaternion).max())
                                                        for motion in (tracked, held)))


_WORLD_POOLS: dict[int, concurrent.futures.ThreadPoolExecutor] = {}


def _world_pool() -> tuple[concurrent.futures.ThreadPoolExecutor, int]:
    """This process's threads for world_errors, one per core, and how many (a forked process gets its own: its
    parent's threads are not in it)."""
    pid, threads = os.getpid(), os.cpu_count() or 1
    if pid not in _WORLD_POOLS:
        _WORLD_POOLS[pid] = concurrent.futures.ThreadPoolExecutor(threads, thread_name_prefix="cito_world")
    return _WORLD_POOLS[pid], threads


_SCRATCH = threading.local()


def _scratch_data(scene) -> mujoco.MjData:
    """This thread's mjData for the scene's model: cito_track resets it as it begins (as good as a fresh one), and
    starts and worlds run side by side, one thread each (a fresh one per motion was 3 of a replan's 100 ms)."""
    datas = _SCRATCH.__dict__.setdefault("datas", weakref.WeakKeyDictionary())
    if scene not in datas:
        datas[scene] = mujoco.MjData(scene.model)
    return datas[scene]


def errors_at_rest(held: Trajectory | None, task) -> tuple[float, float]:
    """Position (m) and orientation (rad) error norms of the object against `task` at the end of a
    held_motion: where the object ends. NaN without one, or when MuJoCo warned on the way (its automatic
    reset is no rest pose)."""
    if held is None or held.warnings:
        return math.nan, math.nan
    return task.final_errors(held)


def rest_errors(simulator: Simulator, state: np.ndarray, task, gains: TrackingSettings) -> tuple[float, float]:
    """errors_at_rest of the execution that ends at `state`, continued by held_motion."""
    return errors_at_rest(held_motion(simulator, state, gains), task)


def tracked_rest_error_m(simulator: Simulator, initial_state: np.ndarray, reference: JointReference, task,
                         gains: TrackingSettings) -> float:
    """The position error at rest (rest_errors) of `reference` tracked from initial_state (track)."""
    return rest_errors(simulator, track(simulator, initial_state, reference, gains).final_state, task, gains)[0]


def track(simulator: Simulator, initial_state: np.ndarray, reference: JointReference,
          gains: TrackingSettings) -> Trajectory:
    """Execute `reference` under PD control from initial_state, with its torques as feed-forward where
    gains.feed_forward (as the executor's servo runs a plan) and it has them."""
    steps = simulator.n_steps
    torques = reference.control_torque_Nm if gains.feed_forward else None
    return pd_motion(simulator, initial_state, reference.q[:steps], reference.qdot[:steps], gains,
                     None if torques is None else torques[:steps])


def pd_motion(simulator: Simulator, initial_state: np.ndarray, q_ref: np.ndarray, qdot_ref: np.ndarray,
              gains: TrackingSettings, feed_forward: np.ndarray | None = None) -> Trajectory:
    """len(q_ref) steps from initial_state, the controller's motor torques before step t
    clamp(feed_forward[t] + kp (q_ref[t] - q) + kd (qdot_ref[t] - qdot)) to the motor limits (no feed_forward:
    the PD alone), through the executor's speed guard where gains.speed_guard > 0, every other control zero;
    natively (cito_track; cito_ros.model.oracle.pd_motion is the same in Python)."""
    scene, model = simulator.scene, simulator.model
    steps = len(q_ref)
    states = np.empty((steps, simulator.nstate))
    sensordata = np.empty((steps, model.nsensordata))
    controls = np.empty((steps, model.nu))
    warnings = np.zeros(mujoco.mjtWarning.mjNWARNING.value, dtype=np.int32)
    indices = (np.asarray(a, dtype=np.int32) for a in (scene.arm_qpos_adr, scene.arm_dof_adr, scene.motor_ids))
    floats = (np.ascontiguousarray(a, dtype=float) for a in (initial_state, q_ref, qdot_ref, gains.kp, gains.kd,
                                                            scene.torque_limit))
    data = _scratch_data(scene)
    _native.track(model._address, data._address, steps, len(scene.motor_ids), *floats, *indices, states, sensordata,
                  controls, warnings, None if feed_forward is None else np.ascontiguousarray(feed_forward, dtype=float),
                  gains.speed_guard * scene.velocity_limit if gains.speed_guard > 0 else None, gains.speed_horizon_s)
    return simulator.trajectory(initial_state, states, sensordata, controls, warning_counts(warnings))
