"""How far the arm can push the object steadily, and how little releasing it at speed adds: the
kinematic bound behind the near-reach lottery (docs/planner.md: Reach zones). ROS-free.

The push reach (Scene.push_reach_m) counts the plate's rim at full stretch. A steady push keeps the
plate's face on the object's face, and a push can also end in a release, the object sliding on after
the plate stops. At each plate position along a radial push line, at a fixed height, this module
finds the fastest plate speed along the push that the joint velocity limits allow while the plate
holds its height (and, for the face, its orientation): a linear program in the joint velocities,
solved exactly by enumerating the vertices of its feasible polytope (7 variables, at most 4
equalities: 35 bases, 2^3 signs each). The object released at that speed comes to rest one MuJoCo
slide further on. The largest rest distance over the positions is an upper bound on where a push
whose plate holds its height can leave the object: the joint torques, the object tipping under a
hard push, and the time to speed up only lower it. Beyond it the object must be struck.

`steady_reach_m` is that bound as every answer uses it (the reach zones): at each height where the plate
lies wholly on the object's face, the farthest plate position with its face along the push is found
directly (a penalty least squares that pulls the plate outwards), and the object released there at the
fastest speed the joint limits allow comes to rest one MuJoCo slide further on.

`pull_reach_m` bounds the other way: how far out the plate can still press the object's far face, the one a pull
towards the arm needs, with the rest of the arm clear of the object (it reaches over the object to get there).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from mujoco import minimize

from cito_ros.model import reach_cache, scene as scene_module
from cito_ros.model.scene import PLATE_GEOM, TABLE_TOP_Z_M, Scene, stretched_starts
from cito_ros.model.simulator import FULL_PHYSICS

CONTACTS = ("face", "rim")  # the plate's face along the push; any orientation, the rim leading
MARGIN_RAD = 0.05            # the inverse kinematics keeps every joint this far inside its range
POSITION_TOLERANCE_M = 1e-3  # an inverse-kinematics solution counts when the plate is this close to its goal
NORMAL_TOLERANCE = 1e-2      # and (for the face) its normal this close to the push direction
SOURCES = (Path(__file__), Path(scene_module.__file__))  # the code a reach here hangs on (reach_cache)


@dataclass(frozen=True)
class PushLimit:
    """One plate position on the push line, for one kind of contact."""

    contact: str                 # "face" or "rim"
    plate_height_m: float        # plate centre above the world origin
    plate_distance_m: float      # plate centre from the arm base, along the (radial) push
    object_distance_m: float     # object centre from the arm base with the plate on its face
    release_speed_m_s: float     # fastest plate speed along the push within the joint velocity limits
    slide_m: float               # how far the object slides on when released at that speed (MuJoCo)

    @property
    def rest_distance_m(self) -> float:
        return self.object_distance_m + self.slide_m


def fastest_push_m_s(jacp: np.ndarray, jacr: np.ndarray, along: np.ndarray, velocity_limit: np.ndarray,
                     hold_orientation: bool) -> float:
    """The largest plate-centre speed along `along` (unit, horizontal) with |qdot_j| <= velocity_limit_j,
    the plate's sideways and vertical velocity zero and, with hold_orientation, its normal (the site's z
    axis, here `along`) not turning. jacp, jacr: (3, 7) the site's Jacobians in the arm's joints."""
    side = np.array([-along[1], along[0], 0.0])
    rows = [side @ jacp, jacp[2]]
    if hold_orientation:  # the normal turns only by rotations about the two axes normal to it
        rows += [side @ jacr, jacr[2]]
    equalities = np.array(rows)
    objective = along @ jacp
    n, k = len(velocity_limit), len(rows)
    best = 0.0
    for basic in itertools.combinations(range(n), k):
        square = equalities[:, basic]
        if abs(np.linalg.det(square)) < 1e-12:
            continue
        bound = [j for j in range(n) if j not in basic]
        for signs in itertools.product((-1.0, 1.0), repeat=n - k):
            qdot = np.zeros(n)
            qdot[bound] = np.array(signs) * velocity_limit[bound]
            qdot[list(basic)] = np.linalg.solve(square, -equalities[:, bound] @ qdot[bound])
            if np.all(np.abs(qdot) <= velocity_limit * (1.0 + 1e-9)):
                best = max(best, float(objective @ qdot))
    return best


def slide_m(scene: Scene, speed_m_s: float, initial_state: np.ndarray, seconds: float = 2.0) -> float:
    """How far the object, at rest in initial_state with the arm clear of it, slides along world +x on the
    table when set moving at speed_m_s (MuJoCo, the scene's friction), by the end of `seconds`."""
    model, data = scene.model, mujoco.MjData(scene.model)
    mujoco.mj_setState(model, data, initial_state, FULL_PHYSICS)
    start = data.qpos[scene.object_qpos_adr]
    data.qvel[scene.object_dof_adr] = speed_m_s
    for _ in range(int(round(seconds / model.opt.timestep))):
        mujoco.mj_step(model, data)
    return float(data.qpos[scene.object_qpos_adr] - start)


def face_heights_m(scene: Scene) -> tuple[float, ...]:
    """Plate-centre heights where the plate lies wholly on the object's face: its bottom and top edges and
    the face's middle (the middle alone for a face lower than the plate)."""
    half, radius = float(scene.object_half_size[2]), scene.plate_radius_m
    middle = TABLE_TOP_Z_M + half
    if half <= radius:
        return (middle,)
    return (middle - half + radius, middle, middle + half - radius)


def _joint_bounds(scene: Scene, margin_rad: float) -> tuple[np.ndarray, np.ndarray]:
    return scene.joint_range[:, 0] + margin_rad, scene.joint_range[:, 1] - margin_rad


def push_limits(scene: Scene, initial_state: np.ndarray, plate_heights_m: tuple[float, ...],
                start_m: float = 0.95, step_m: float = 0.005, margin_rad: float = MARGIN_RAD) -> list[PushLimit]:
    """Every kind of contact at every plate height, along the world +x push line through the arm base,
    the object's slides simulated from initial_state (the object at rest, the arm clear of it),
    from start_m outwards in step_m until the plate cannot reach (inverse kinematics by
    mujoco.minimize.least_squares within the joint ranges less margin_rad, from the last solution and
    stretched starts; positions within 1 mm, the face's normal within 1e-2)."""
    if step_m <= 0.0 or not plate_heights_m:
        raise ValueError(f"a scan needs a positive step and at least one height, got {step_m} and {plate_heights_m}")
    model, data = scene.model, mujoco.MjData(scene.model)
    low, high = _joint_bounds(scene, margin_rad)
    site, qadr, dofs = scene.robot_site_id, scene.arm_qpos_adr, scene.arm_dof_adr
    along = np.array([1.0, 0.0, 0.0])
    half = float(scene.object_half_size[0])
    stretched = stretched_starts(low, high)
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    slides: dict[float, float] = {}
    limits = []
    for contact in CONTACTS:
        face = contact == "face"
        for height in plate_heights_m:
            previous: list[np.ndarray] = []
            distance = start_m
            while True:
                goal = np.array([distance, 0.0, height])

                def residual(x: np.ndarray) -> np.ndarray:
                    out = np.empty((6 if face else 3, x.shape[1]))
                    for column, q in enumerate(x.T):
                        data.qpos[qadr] = q
                        mujoco.mj_kinematics(model, data)
                        error = 10.0 * (data.site_xpos[site] - goal)
                        out[:, column] = np.r_[error, data.site_xmat[site][2::3] - along] if face else error
                    return out

                speeds = []
                solutions = []
                for start in previous + stretched:
                    q, _ = minimize.least_squares(start, residual, (low, high), verbose=0, max_iter=100)
                    data.qpos[qadr] = q
                    mujoco.mj_kinematics(model, data)
                    mujoco.mj_comPos(model, data)
                    if np.linalg.norm(data.site_xpos[site] - goal) > POSITION_TOLERANCE_M or \
                            (face and np.linalg.norm(data.site_xmat[site][2::3] - along) > NORMAL_TOLERANCE):
                        continue
                    mujoco.mj_jacSite(model, data, jacp, jacr, site)
                    speeds.append(fastest_push_m_s(jacp[:, dofs], jacr[:, dofs], along, scene.velocity_limit, face))
                    solutions.append(q)
                if not speeds:
                    break
                previous = [solutions[int(np.argmax(speeds))]]
                speed = round(max(speeds), 3)  # the slide is simulated once per speed, to the millimetre per second
                if speed not in slides:
                    slides[speed] = slide_m(scene, speed, initial_state)
                ahead = scene.plate_half_thickness_m if face else scene.plate_radius_m
                limits.append(PushLimit(contact, height, distance, distance + ahead + half, max(speeds), slides[speed]))
                distance = round(distance + step_m, 9)
    return limits


def farthest(limits: list[PushLimit], contact: str) -> PushLimit:
    """The position of `contact` that leaves the object farthest."""
    rows = [row for row in limits if row.contact == contact]
    if not rows:
        raise ValueError(f"no reachable position for the {contact} contact")
    return max(rows, key=lambda row: row.rest_distance_m)


def steady_reach_margin_m(scene: Scene, initial_state: np.ndarray, target_position_m) -> float:
    """The steady push reach less the target's horizontal distance from the arm base: positive inside it."""
    return steady_reach_m(scene, initial_state) - float(np.hypot(*np.asarray(target_position_m)[:2]))


def steady_reach_m(scene: Scene, initial_state: np.ndarray) -> float:
    """The farthest from the arm base (horizontally) a push whose plate holds its height and its face
    along the push can leave the object's centre: the largest, over face_heights_m, of the farthest such
    plate position plus the plate's half thickness and the object's half size, plus the slide of the
    object released there at fastest_push_m_s (simulated from initial_state, the object at rest and the
    arm clear of it). Cached (reach_cache)."""
    def compute() -> float:
        model, data = scene.model, mujoco.MjData(scene.model)
        low, high = _joint_bounds(scene, MARGIN_RAD)
        site, qadr, dofs = scene.robot_site_id, scene.arm_qpos_adr, scene.arm_dof_adr
        along = np.array([1.0, 0.0, 0.0])
        jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        reach = 0.0
        for height in face_heights_m(scene):
            def residual(x: np.ndarray) -> np.ndarray:
                # outwards along +x as far as the plate can hold its line, height and normal (weighted 100)
                out = np.empty((6, x.shape[1]))
                for column, q in enumerate(x.T):
                    data.qpos[qadr] = q
                    mujoco.mj_kinematics(model, data)
                    plate = data.site_xpos[site]
                    out[:, column] = np.r_[2.0 - plate[0], 100.0 * plate[1], 100.0 * (plate[2] - height),
                                           10.0 * (data.site_xmat[site][2::3] - along)]
                return out

            for start in stretched_starts(low, high):
                q, _ = minimize.least_squares(start, residual, (low, high), verbose=0, max_iter=200)
                data.qpos[qadr] = q
                mujoco.mj_kinematics(model, data)
                mujoco.mj_comPos(model, data)
                plate = data.site_xpos[site]
                if abs(plate[1]) > POSITION_TOLERANCE_M or abs(plate[2] - height) > POSITION_TOLERANCE_M or \
                        np.linalg.norm(data.site_xmat[site][2::3] - along) > NORMAL_TOLERANCE:
                    continue
                mujoco.mj_jacSite(model, data, jacp, jacr, site)
                speed = fastest_push_m_s(jacp[:, dofs], jacr[:, dofs], along, scene.velocity_limit, True)
                rest = float(plate[0]) + scene.plate_half_thickness_m + float(scene.object_half_size[0]) + \
                    slide_m(scene, speed, initial_state)
                reach = max(reach, rest)
        if reach == 0.0:
            raise ValueError(f"scene {scene.config.name}: the plate cannot hold the object's face at any height")
        return reach

    return reach_cache.cached("steady", scene, compute, *SOURCES)


def pull_reach_m(scene: Scene) -> float:
    """The farthest from the arm base (horizontally, along +x) the object's centre can stand with the plate against
    the middle of its far face (the face away from the arm, which a pull presses) and no other part of the arm in
    the object: at each of face_heights_m, the plate's point nearest the arm is pulled outwards along +x (a penalty
    least squares from stretched starts, as steady_reach_m), the object's far face put there, and every other arm
    geom's signed distance from the object (mujoco.mj_geomDistance) held at zero or more; 0.0 where nothing reaches.
    Cached (reach_cache)."""
    def compute() -> float:
        model, data = scene.model, mujoco.MjData(scene.model)
        low, high = _joint_bounds(scene, MARGIN_RAD)
        site, qadr, oadr = scene.robot_site_id, scene.arm_qpos_adr, scene.object_qpos_adr
        plate, target = model.geom(PLATE_GEOM).id, scene.object_geom_id
        arm = [int(g) for g in scene.arm_geom_ids if g != plate]
        half = float(scene.object_half_size[0])
        axes = np.diag([scene.plate_radius_m, scene.plate_radius_m, scene.plate_half_thickness_m])
        towards_arm = np.array([-1.0, 0.0, 0.0])
        reach = 0.0
        for height in face_heights_m(scene):
            def residual(x: np.ndarray, height: float = height) -> np.ndarray:
                out = np.empty((3 + len(arm), x.shape[1]))
                for column, q in enumerate(x.T):
                    data.qpos[qadr] = q
                    mujoco.mj_kinematics(model, data)
                    rotation = data.site_xmat[site].reshape(3, 3)
                    stretched = axes @ rotation.T @ towards_arm  # the plate ellipsoid's support point towards the arm
                    touch = data.site_xpos[site] + rotation @ (axes @ stretched) / np.linalg.norm(stretched)
                    data.qpos[oadr:oadr + 7] = (touch[0] - half, touch[1], TABLE_TOP_Z_M + half, 1.0, 0.0, 0.0, 0.0)
                    mujoco.mj_kinematics(model, data)
                    inside = [min(mujoco.mj_geomDistance(model, data, g, target, 0.05, None), 0.0) for g in arm]
                    out[:, column] = np.r_[2.0 - touch[0], 100.0 * touch[1], 100.0 * (touch[2] - height),
                                           100.0 * np.array(inside)]
                return out

            for start in stretched_starts(low, high):
                q, _ = minimize.least_squares(start, residual, (low, high), verbose=0, max_iter=200)
                out = residual(q[:, None])[:, 0]
                if np.all(np.abs(out[1:3]) <= 100.0 * POSITION_TOLERANCE_M) and \
                        np.all(out[3:] >= -100.0 * POSITION_TOLERANCE_M):
                    reach = max(reach, 2.0 - float(out[0]) - half)
        return reach

    return reach_cache.cached("pull", scene, compute, *SOURCES)
