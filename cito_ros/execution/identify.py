"""What the pushes so far say about the cube: the friction the next push is planned for.

Every push is recorded as it happened (`Observed`): the arm's measured joint positions and velocities from the push's
start until the cube was judged at rest, and the camera's poses of the cube meanwhile. `identify` drives a simulated
arm stiffly along the measured joint path, in worlds whose cube's friction is a scale of the model's, and
compares the simulated cube with the poses seen: the arm's motion is what it was (the servo, its speed guard and its
delays are in it), and only the cube's response is left to the world. The cubes that fit about as well as the best
are the possible ones, and the next push is planned for their middle, sturdy in their corners (planning.compute):
where the first push had to hold for every cube the lab might have, the next holds for those the pushes left.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from cito_ros.execution.mpc import PushModel
from cito_ros.planner.task import yaw_of
from cito_ros.planner.tracking import JointPath, track
from cito_ros.settings import TrackingSettings


@dataclass(frozen=True)
class Observed:
    start_state: np.ndarray     # the model's state where the push began (the cube where it was measured)
    joints: np.ndarray          # (n, 15): stamp (s), q (7), qdot (7) of every joint state from then
    poses: np.ndarray           # (m, 4): stamp (s), x, y, yaw (unwrapped) of every camera pose from then


@dataclass(frozen=True)
class Identified:
    friction_scale: float                     # the friction the next push is planned for (of the model's)
    low: float                                # the least and the most of the possible frictions, relative to it
    high: float
    misfit: dict[float, float]                # per friction scale: its mean squared error

    def worlds(self, friction_scales: Sequence[float]) -> list[float]:
        """World friction scales (tracking.world_friction_scales) around the identified friction: those below 1
        at its least possible, those above at its most."""
        return [self.low if f < 1.0 else self.high if f > 1.0 else 1.0 for f in friction_scales]


def identify(model: PushModel, seen: Sequence[Observed], stiff: TrackingSettings, friction_scales: Sequence[float],
             spread: float, tolerance: float) -> Identified:
    """The cube's frictions the pushes seen leave possible (see the module docstring). Its mass is left out: with
    the arm driven along its measured path, a cube's slide does not depend on it (its friction force and inertia
    scale alike), and the arm's own motion, which does, is taken as it was.

    A friction scale is judged by the mean, over every camera pose of every push, of the squared position and yaw
    errors of its simulated cube (the arm tracked along the measured path with `stiff`, PD without feed-forward),
    each over its task tolerance; possible are those within `tolerance` of the best. The planner takes the middle
    of their range, and worlds at its ends, at least spread and 1 / spread times that middle."""
    if not seen:
        raise ValueError("identify needs at least one observed push")
    task = model.settings.task
    misfit = {}
    for friction in friction_scales:
        errors = []
        for observed in seen:
            errors += _errors(model, observed, stiff, float(friction), task)
        misfit[float(friction)] = float(np.mean(errors)) if errors else math.inf
    best = min(misfit.values())
    if not math.isfinite(best):
        raise ValueError("no world reproduced the pushes seen (MuJoCo warned or the records are empty)")
    possible = [friction for friction, value in misfit.items() if value <= best + tolerance]
    centre = math.sqrt(min(possible) * max(possible))
    return Identified(centre, min(min(possible) / centre, 1.0 / spread), max(max(possible) / centre, spread), misfit)


def _errors(model: PushModel, observed: Observed, stiff: TrackingSettings, friction: float, task) -> list[float]:
    """The squared, tolerance-scaled errors of the simulated cube at each camera pose of one push."""
    scene, joints, poses = model.scene, observed.joints, observed.poses
    start_s = joints[0, 0]
    knots = max(1, math.ceil((joints[-1, 0] - start_s) / model.control_period_s - 1e-9))
    simulator = model.simulator(knots).in_world(friction, 1.0)
    times = start_s + np.arange(simulator.n_steps + 1) * simulator.timestep_s
    q = np.stack([np.interp(times, joints[:, 0], joints[:, 1 + j]) for j in range(7)], axis=1)
    qdot = np.stack([np.interp(times, joints[:, 0], joints[:, 8 + j]) for j in range(7)], axis=1)
    state = observed.start_state.copy()
    state[scene.state_qpos_adr + scene.arm_qpos_adr] = joints[0, 1:8]
    state[scene.state_qvel_adr + scene.arm_dof_adr] = joints[0, 8:15]
    motion = track(simulator, state, JointPath(q, qdot), stiff)
    if motion.warnings:
        return [math.inf]
    steps = np.clip(np.round((poses[:, 0] - start_s) / simulator.timestep_s).astype(int), 0, simulator.n_steps)
    position = motion.object_position_m[steps, :2]
    yaw = yaw_of(motion.object_quaternion[steps])
    turn = np.abs(np.remainder(yaw - poses[:, 3] + np.pi, 2 * np.pi) - np.pi)
    return list((np.hypot(*(position - poses[:, 1:3]).T) / task.success_position_error_m) ** 2 +
                (turn / task.success_orientation_error_rad) ** 2)
