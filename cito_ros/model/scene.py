"""The push scene: MuJoCo model, start pose q0(beta), signed distance, object pose.

ROS-free. A `Scene` compiles `models/<scene.model>` with a scene description
from `config/scenes/` applied on top, and adds the contact actuator of one
contact model. With `native=False` it compiles the oracle variant, in which the
state-dependent forces are plain actuators whose controls the pure-Python
oracle (cito_ros.model.oracle) computes every step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from mujoco import minimize

from cito_ros.model import _native  # noqa: F401  (registers the cito.* engine plugins)
from cito_ros.model import reach_cache
from cito_ros.model.contact_models import ContactModel
from cito_ros.settings import SceneConfig
from cito_ros.settings.paths import model_path
from cito_ros.settings.typed_config import require_finite

ARM_JOINTS = ("j0", "j1", "j2", "j3", "j4", "j5", "j6")
ARM_MOTORS = ("m0", "m1", "m2", "m3", "m4", "m5", "m6")
CONTACT_ACTUATOR = "virtual_contact"
GAMMA_SENSOR = "gamma"
PLATE_GAP_SENSOR = "plate_object_gap"
ROBOT_CANDIDATE = "robot_candidate"
OBJECT_CANDIDATE = "object_candidate"
OBJECT_BODY = "object"
OBJECT_GEOM = "object_geom"
OBJECT_JOINT = "object_joint"
TABLE_GEOM = "table"
PLATE_GEOM = "plate"
TABLE_TOP_GEOM = "table_top"
TABLE_TOP_Z_M = 0.025
VELOCITY_LIMIT = "velocity_limit"  # <numeric> of the arm's joint velocity limits (rad/s)
SETTLE_TIME_S = 0.3  # time for the object to settle into its table contact (several contact time constants)


def pushed_face(position_m, yaw_rad: float) -> int:
    """The vertical face of a cube at (x, y) with yaw_rad towards the arm base (the origin): k, the face whose inward
    normal is the cube's +x turned by k quarter turns (0: its -x face, the model file's candidate). A push away from
    the arm lands on it; a cube turned by a quarter turn is the same cube, so the candidate goes there."""
    away_rad = math.atan2(position_m[1], position_m[0])
    return round(math.remainder(away_rad - yaw_rad, 2 * math.pi) / (math.pi / 2)) % 4


def start_configuration(beta: float) -> np.ndarray:
    """The paper's start pose q0(beta) = [-pi/12, -pi/b, 0, 3pi/b, -pi/6, -2pi/b, 0] (rad)."""
    beta = require_finite("beta", beta, positive=True)
    return np.array([-math.pi / 12, -math.pi / beta, 0.0, 3 * math.pi / beta, -math.pi / 6, -2 * math.pi / beta, 0.0])


@dataclass(frozen=True)
class SensorSlices:
    """Where each quantity sits in mjData.sensordata."""

    robot_candidate_in_object: slice  # robot candidate in the object box frame (m), 3
    ee_velocity: slice                # plate-centre linear velocity, world (m/s), 3
    torque: slice                     # applied joint torque tau of eq. (2) (N m), 7
    contact_found: slice              # number of robot-object contacts, 1
    contact_force: slice              # net robot-on-object contact force, world (N), 3
    contact_torque: slice             # its torque about contact_position, world (N m), 3
    contact_position: slice           # force-weighted contact centroid, world (m), 3
    gamma: slice                      # virtual normal force (N), 1
    joint_position: slice             # arm joint positions (rad), 7
    joint_velocity: slice             # arm joint velocities (rad/s), 7
    plate_gap: slice                  # distance between the plate and the object, negative in overlap (m), 1


class Scene:
    """A compiled push scene for one contact model."""

    def __init__(self, contact_model: ContactModel, config: SceneConfig | str = "default", *, native: bool = True):
        if not isinstance(contact_model, ContactModel):
            raise TypeError(f"contact_model must be a ContactModel, got {type(contact_model).__name__}")
        self.contact_model = contact_model
        self.config = config if isinstance(config, SceneConfig) else SceneConfig.load(config)
        self.native = native
        self.model = self._compile()
        m = self.model

        joints = [m.joint(name) for name in ARM_JOINTS]
        self.arm_qpos_adr = np.array([j.qposadr[0] for j in joints])
        self.arm_dof_adr = np.array([j.dofadr[0] for j in joints])
        self.joint_range = np.array([j.range for j in joints])
        self.velocity_limit = m.numeric(VELOCITY_LIMIT).data.copy()
        self.motor_ids = np.array([m.actuator(name).id for name in ARM_MOTORS])
        self.torque_limit = np.array([m.actuator(name).ctrlrange[1] for name in ARM_MOTORS])
        self.contact_actuator_id = m.actuator(CONTACT_ACTUATOR).id
        object_joint = m.joint(OBJECT_JOINT)
        self.object_qpos_adr = int(object_joint.qposadr[0])
        self.object_dof_adr = int(object_joint.dofadr[0])
        self.object_dofs = np.arange(self.object_dof_adr, self.object_dof_adr + 6)  # a free joint's
        # where the object's qpos and qvel sit in a mjSTATE_FULLPHYSICS state (time, qpos, qvel, ...)
        self.state_qpos_adr = mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_TIME)  # qpos, then qvel, in a state
        self._state_object_adr = self.state_qpos_adr + self.object_qpos_adr
        self.state_qvel_adr = self.state_qpos_adr + m.nq
        self._state_object_dof = self.state_qvel_adr + self.object_dof_adr
        self.robot_site_id = m.site(ROBOT_CANDIDATE).id
        self.object_site_id = m.site(OBJECT_CANDIDATE).id
        self.object_geom_id = m.geom(OBJECT_GEOM).id
        self.object_body_id = m.body(OBJECT_BODY).id
        self.arm_geom_ids = np.flatnonzero(~np.isin(m.geom_bodyid, (0, self.object_body_id)))  # not world's, object's
        self.arm_capsule_ids = self.arm_geom_ids[m.geom_type[self.arm_geom_ids] == mujoco.mjtGeom.mjGEOM_CAPSULE]
        self.object_half_size = m.geom_size[self.object_geom_id].copy()
        self.plate_radius_m, _, self.plate_half_thickness_m = map(float, m.geom_size[m.geom(PLATE_GEOM).id])  # normal: +z
        # The object candidate in the object box frame (constant: both sit on the object body).
        geom_to_body = self._geom_frame_in_body()
        self.object_candidate_in_geom = geom_to_body.T @ (m.site_pos[self.object_site_id] - m.geom_pos[self.object_geom_id])
        self.sensors = self._sensor_slices()

    # ------------------------------------------------------------------ model

    def _compile(self) -> mujoco.MjModel:
        config = self.config
        spec = mujoco.MjSpec.from_file(str(model_path(config.model)))
        spec.option.timestep = config.timestep_s

        obj = config.object
        h = obj.half_size_m
        spec.geom(OBJECT_GEOM).size = [h, h, h]
        spec.geom(OBJECT_GEOM).mass = obj.mass_kg
        site, turn = spec.site(OBJECT_CANDIDATE), pushed_face(obj.position_m, obj.yaw_rad) * math.pi / 2
        site.pos = [-h * math.cos(turn), -h * math.sin(turn), 0.0] if turn else [-h, 0.0, 0.0]
        if turn:  # another face than the model file's (its -x): the candidate turned about the cube's z with it
            site.quat = [math.cos((turn + math.pi) / 2), 0.0, 0.0, math.sin((turn + math.pi) / 2)]
        body = spec.body(OBJECT_BODY)
        body.pos = [obj.position_m[0], obj.position_m[1], TABLE_TOP_Z_M + h]
        body.quat = [math.cos(obj.yaw_rad / 2), 0.0, 0.0, math.sin(obj.yaw_rad / 2)]
        if config.collisions == "all":
            self._collide_everything(spec, obj.friction)
        else:
            if config.pairs is not None:
                self._replace_pairs(spec, config.pairs)
            for pair in spec.pairs:
                if OBJECT_GEOM in (pair.geomname1, pair.geomname2):
                    pair.friction[:2] = obj.friction

        # Contact actuator: force at the robot candidate along the object candidate's outward
        # normal (its +x), reaction at the object candidate (MuJoCo site transmission with refsite).
        _, high = self.contact_model.control_range()
        actuator = spec.add_actuator(name=CONTACT_ACTUATOR, trntype=mujoco.mjtTrn.mjTRN_SITE,
                                     target=ROBOT_CANDIDATE, refsite=OBJECT_CANDIDATE)
        actuator.gear = [1, 0, 0, 0, 0, 0]
        if self.native:
            actuator.ctrllimited = True
            actuator.ctrlrange = [0.0, high]
            self.contact_model.configure_actuator(spec, actuator)
        else:
            self._replace_plugin_motors(spec)
        spec.add_sensor(name=GAMMA_SENSOR, type=mujoco.mjtSensor.mjSENS_ACTUATORFRC,
                        objtype=mujoco.mjtObj.mjOBJ_ACTUATOR, objname=CONTACT_ACTUATOR)
        return spec.compile()

    @staticmethod
    def _replace_pairs(spec: mujoco.MjSpec, pairs: tuple[tuple[str, str], ...]) -> None:
        """Collide exactly the named geom pairs (sliding friction as in the model's first pair)."""
        friction = float(spec.pairs[0].friction[0])
        names = {geom.name for geom in spec.geoms}
        for pair in list(spec.pairs):
            spec.delete(pair)
        for a, b in pairs:
            unknown = [g for g in (a, b) if g not in names]
            if unknown:
                raise ValueError(f"collision pair [{a}, {b}]: no geom named {unknown[0]!r}; geoms: {sorted(names)}")
            spec.add_pair(name=f"{a}__{b}", geomname1=a, geomname2=b, condim=3,
                          friction=[friction, friction, 0.005, 0.0001, 0.0001])

    @staticmethod
    def _collide_everything(spec: mujoco.MjSpec, object_friction: float) -> None:
        """The reference scene for 'model only what the scene needs': every geom in the broad
        phase (full arm geometry, base, floor, table box), no pair list. The object's friction
        wins in its contacts (geom priority), the rest keep the pair list's 0.5."""
        pair_friction = float(spec.pairs[0].friction[0])
        for pair in list(spec.pairs):
            spec.delete(pair)
        spec.delete(spec.geom(TABLE_TOP_GEOM))  # the table box collides itself now
        for geom in spec.geoms:
            geom.contype, geom.conaffinity, geom.condim = 1, 1, 3
            geom.friction[0] = pair_friction
        obj = spec.geom(OBJECT_GEOM)
        obj.friction[0], obj.priority = object_friction, 1

    @staticmethod
    def _replace_plugin_motors(spec: mujoco.MjSpec) -> None:
        """Oracle variant: plain, unclamped torque motors; the oracle adds C^ and clamps u."""
        for name in ARM_MOTORS:
            motor = spec.actuator(name)
            motor.plugin.active = False
            motor.ctrllimited = False
        for plugin in list(spec.plugins):
            spec.delete(plugin)

    def _geom_frame_in_body(self) -> np.ndarray:
        rotation = np.empty(9)
        mujoco.mju_quat2Mat(rotation, self.model.geom_quat[self.object_geom_id])
        return rotation.reshape(3, 3)

    def _sensor_slices(self) -> SensorSlices:
        m = self.model

        def block(name: str, offset: int = 0, size: int | None = None) -> slice:
            sensor = m.sensor(name)
            start = int(sensor.adr[0]) + offset
            return slice(start, start + (int(sensor.dim[0]) if size is None else size))

        def joints(prefix: str) -> slice:
            start = int(m.sensor(f"{prefix}{ARM_JOINTS[0]}").adr[0])
            return slice(start, start + len(ARM_JOINTS))

        return SensorSlices(
            robot_candidate_in_object=block("robot_candidate_in_object"),
            ee_velocity=block("ee_velocity"),
            torque=joints("tau_"),
            contact_found=block("robot_object_contact", 0, 1),
            contact_force=block("robot_object_contact", 1, 3),
            contact_torque=block("robot_object_contact", 4, 3),
            contact_position=block("robot_object_contact", 7, 3),
            gamma=block(GAMMA_SENSOR),
            joint_position=joints("q_"),
            joint_velocity=joints("qdot_"),
            plate_gap=block(PLATE_GAP_SENSOR),
        )

    # ------------------------------------------------------------------ states

    def validate_arm_configuration(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != (len(ARM_JOINTS),):
            raise ValueError(f"arm configuration must have shape (7,), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ValueError("arm configuration contains NaN or Inf")
        low, high = self.joint_range.T
        outside = (q < low) | (q > high)
        if np.any(outside):
            j = int(np.argmax(outside))
            raise ValueError(f"joint {ARM_JOINTS[j]} = {q[j]:.4f} rad is outside its range [{low[j]}, {high[j]}]")
        return q

    def data_at(self, q: np.ndarray, qdot: np.ndarray | None = None) -> mujoco.MjData:
        """A fresh mjData at arm configuration q (object at its scene pose), forward-computed."""
        data = mujoco.MjData(self.model)
        data.qpos[self.arm_qpos_adr] = self.validate_arm_configuration(q)
        if qdot is not None:
            data.qvel[self.arm_dof_adr] = qdot
        mujoco.mj_forward(self.model, data)
        return data

    def initial_state(self, q: np.ndarray) -> np.ndarray:
        """mjSTATE_FULLPHYSICS state with the arm at rest at q and the object resting on the table.

        The object is placed touching the table and left to settle into its soft contact (the
        arm held at q) for SETTLE_TIME_S, then zeroed in velocity and time: a start exactly at
        zero penetration would sit on a contact switch, where linearizations are unreliable.
        """
        q = self.validate_arm_configuration(q)
        model, data = self.model, self.data_at(q)
        for _ in range(int(round(SETTLE_TIME_S / model.opt.timestep))):
            mujoco.mj_step(model, data)
            data.qpos[self.arm_qpos_adr] = q
            data.qvel[self.arm_dof_adr] = 0
        data.qvel[:] = 0
        data.time = 0
        mujoco.mj_forward(model, data)
        state = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
        mujoco.mj_getState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        return state

    # ------------------------------------------------------------------ geometry

    def signed_distance_from_local(self, robot_in_object: np.ndarray) -> np.ndarray:
        """Signed distance phi (m) from the robot candidate's position in the object box frame.

        phi is the distance between the two candidates, negative when the robot
        candidate is inside the object box (the native plugin's definition).
        Accepts (..., 3) arrays, e.g. the `robot_candidate_in_object` sensor over time.
        """
        local = np.asarray(robot_in_object, dtype=float)
        distance = np.linalg.norm(local - self.object_candidate_in_geom, axis=-1)
        inside = np.all(np.abs(local) < self.object_half_size, axis=-1)
        return np.where(inside, -distance, distance)

    def signed_distance(self, data: mujoco.MjData) -> float:
        """Signed distance phi (m) for a forward-computed mjData."""
        offset = data.site_xpos[self.robot_site_id] - data.geom_xpos[self.object_geom_id]
        local = data.geom_xmat[self.object_geom_id].reshape(3, 3).T @ offset
        return float(self.signed_distance_from_local(local))

    def object_qpos(self, state: np.ndarray) -> np.ndarray:
        """The object's pose (x, y, z, qw, qx, qy, qz) in a mjSTATE_FULLPHYSICS state, or in each of
        (..., nstate) states (a view)."""
        return state[..., self._state_object_adr:self._state_object_adr + 7]

    def object_qvel(self, state: np.ndarray) -> np.ndarray:
        """The object's velocity (linear world, angular local) in a state or (..., nstate) states (a view)."""
        return state[..., self._state_object_dof:self._state_object_dof + 6]

    def object_speed_m_s(self, state: np.ndarray) -> float:
        """The fastest any point of the object can be moving in a state: its centre's speed plus its angular
        speed times its half diagonal (m/s)."""
        velocity = self.object_qvel(state)
        return float(np.linalg.norm(velocity[:3]) + np.linalg.norm(velocity[3:]) * np.linalg.norm(self.object_half_size))

    def joint_range_excess(self, q: np.ndarray) -> float:
        """How far (rad) any of (..., 7) arm joint positions goes beyond its range; 0 inside."""
        low, high = self.joint_range.T
        return float(max(np.max(low - q, initial=0.0), np.max(q - high, initial=0.0)))

    def arm_qpos(self, state: np.ndarray) -> np.ndarray:
        """The arm's joint positions in a state or (..., nstate) states."""
        return state[..., self.state_qpos_adr + self.arm_qpos_adr]

    def arm_qvel(self, state: np.ndarray) -> np.ndarray:
        """The arm's joint velocities in a state or (..., nstate) states."""
        return state[..., self.state_qvel_adr + self.arm_dof_adr]

    def arm_clearance(self, data: mujoco.MjData, within_m: float) -> tuple[float, str]:
        """The smallest signed distance (m) from an arm geom to the object in a forward-computed mjData, and that
        geom's name; (within_m, "") when none is nearer."""
        nearest, name = within_m, ""
        for geom in map(int, self.arm_geom_ids):
            distance = mujoco.mj_geomDistance(self.model, data, geom, self.object_geom_id, within_m, None)
            if distance < nearest:
                nearest, name = distance, self.model.geom(geom).name
        return nearest, name

    def object_pose(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """Object position (m) and orientation quaternion (w, x, y, z), world frame."""
        qpos = data.qpos[self.object_qpos_adr:self.object_qpos_adr + 7]
        return qpos[:3].copy(), qpos[3:].copy()

    def initial_distance(self, beta: float) -> float:
        """Signed distance between the candidates at q0(beta) (the paper's phi_0)."""
        return self.signed_distance(self.data_at(start_configuration(beta)))

    def push_reach_m(self) -> float:
        """How far from the arm base (horizontally) the object's centre can be pushed: the farthest the
        plate centre reaches within the height of the object's faces (at their top, the nearest to the
        shoulder), plus the plate's radius and the object's half size (cached: reach_cache)."""
        return reach_cache.cached("push", self, lambda: _push_reach(self), Path(__file__))

    def table_top(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(x, y) lower and upper corners of the table top and its height (m), world frame."""
        table = self.model.geom(TABLE_GEOM)
        centre, half = table.pos[:2], table.size[:2]
        return centre - half, centre + half, float(table.pos[2] + table.size[2])

    def inward_normal(self, data: mujoco.MjData) -> np.ndarray:
        """Direction (world) in which the virtual force pushes the object: minus the
        object candidate's +x (its outward face normal)."""
        return -data.site_xmat[self.object_site_id].reshape(3, 3)[:, 0]

    def inward_normals(self, object_quaternions: np.ndarray) -> np.ndarray:
        """inward_normal for (n, 4) object orientations (w, x, y, z): (n, 3)."""
        site_x = np.empty(3)
        mujoco.mju_rotVecQuat(site_x, np.array([1.0, 0.0, 0.0]), self.model.site_quat[self.object_site_id])
        q = np.asarray(object_quaternions, dtype=float)
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        w, u = q[:, :1], q[:, 1:]
        # rotate site_x by each quaternion: v + 2 w (u x v) + 2 u x (u x v)
        uv = np.cross(u, site_x)
        return -(site_x + 2 * w * uv + 2 * np.cross(u, uv))


def stretched_starts(low: np.ndarray, high: np.ndarray, wrists_rad=(0.5, -0.5, 1.2)) -> list[np.ndarray]:
    """The arm stretched forward with the elbow and the wrist bent either way, within [low, high]: the starts of
    the reach searches' inverse kinematics."""
    return [np.clip(np.array([0.0, 0.3, 0.0, j3, 0.0, j5, 0.0]), low, high)
            for j3 in (0.0, 0.5, -0.5) for j5 in wrists_rad]


def _push_reach(scene: Scene) -> float:
    half_size = float(scene.object_half_size[0])
    model, data = scene.model, mujoco.MjData(scene.model)
    height = TABLE_TOP_Z_M + 2 * half_size
    low, high = scene.joint_range.T

    def residual(x: np.ndarray) -> np.ndarray:
        out = np.empty((3, x.shape[1]))
        for column, q in enumerate(x.T):
            data.qpos[scene.arm_qpos_adr] = q
            mujoco.mj_kinematics(model, data)
            plate = data.site_xpos[scene.robot_site_id]
            out[:, column] = [2.0 - plate[0], 10 * (plate[2] - height), 10 * plate[1]]
        return out

    reach = 0.0
    for start in stretched_starts(low, high, wrists_rad=(0.5, -0.5)):  # the farthest is among them
        q, _ = minimize.least_squares(start, residual, (low, high), verbose=0, max_iter=200)
        data.qpos[scene.arm_qpos_adr] = q
        mujoco.mj_kinematics(model, data)
        plate = data.site_xpos[scene.robot_site_id]
        if abs(plate[2] - height) < 5e-3:
            reach = max(reach, float(np.hypot(plate[0], plate[1])))
    return reach + scene.plate_radius_m + half_size
