"""Single-shooting rollouts of piecewise-constant joint torques at N control knots.

ROS-free. A rollout starts from a full physics state (arm at rest at q0, object
at its scene pose), holds each knot's controls for `steps_per_knot` simulation
steps, and runs entirely inside MuJoCo (`mujoco.rollout`): the bias
compensation and the virtual contact force are computed by the native engine
plugins, so batched multi-threaded rollouts and `mjd_transitionFD` see exactly
the same dynamics.
"""
from __future__ import annotations

import functools
import weakref
from dataclasses import dataclass, field

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from cito_ros.model import _native
from cito_ros.model.scene import ARM_JOINTS, Scene
from cito_ros.model.timing import PhaseClock
from cito_ros.settings.typed_config import require_finite

FULL_PHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS
# per scene, its worlds' scenes by (friction, mass) scale (Simulator.in_world), as long as the scene lives
_WORLD_SCENES: weakref.WeakKeyDictionary[Scene, dict[tuple[float, float], Scene]] = weakref.WeakKeyDictionary()


@dataclass(frozen=True)
class Trajectory:
    """A simulated motion. Arrays over states have n_steps + 1 rows (t = 0 ... T);
    arrays over steps have n_steps rows, row t being what acted during step t,
    evaluated at state t."""

    time_s: np.ndarray                 # (T+1,)
    q: np.ndarray                      # (T+1, 7) joint positions (rad)
    qdot: np.ndarray                   # (T+1, 7) joint velocities (rad/s)
    object_position_m: np.ndarray      # (T+1, 3) world
    object_quaternion: np.ndarray      # (T+1, 4) world, (w, x, y, z)
    torque_Nm: np.ndarray              # (T, 7) applied tau = u + C^ - J_c^T lambda_c
    control_torque_Nm: np.ndarray      # (T, 7) u
    contact_control: np.ndarray        # (T,) contact actuator control (k or gamma, by model)
    stiffness_N: np.ndarray | None     # (T,) k, None for a model without stiffness (CCCM)
    gamma_N: np.ndarray                # (T,) virtual normal force
    virtual_force_N: np.ndarray        # (T, 3) the virtual force on the object, world (gamma n)
    signed_distance_m: np.ndarray      # (T,) phi between the candidates
    contact_force_N: np.ndarray        # (T, 3) actual robot-on-object contact force (MuJoCo), world
    contact_torque_Nm: np.ndarray      # (T, 3) its torque about contact_point_m, world
    contact_point_m: np.ndarray        # (T, 3) force-weighted contact centroid, world
    contact_count: np.ndarray          # (T,) number of robot-object contacts
    ee_velocity_m_s: np.ndarray        # (T, 3) plate-centre velocity, world
    warnings: dict[str, int] = field(default_factory=dict)  # MuJoCo warnings raised during the rollout
    final_state: np.ndarray | None = None  # the full physics state at t = T, to simulate on from (tracking.held_motion)

    @property
    def finite(self) -> bool:
        arrays = [self.q, self.qdot, self.object_position_m, self.object_quaternion, self.torque_Nm,
                  self.gamma_N, self.signed_distance_m, self.contact_force_N, self.ee_velocity_m_s]
        return all(bool(np.all(np.isfinite(a))) for a in arrays)

    def followed_by(self, continuation: "Trajectory | None") -> "Trajectory":
        """This motion, then `continuation` (a rollout from this one's final state, as tracking.held_motion):
        one Trajectory over both, the continuation's first state (this one's last) once."""
        if continuation is None:
            return self
        n_states = len(self.time_s)
        joined = {}
        for name, value in vars(self).items():
            other = getattr(continuation, name)
            if name == "warnings":
                joined[name] = {key: value.get(key, 0) + other.get(key, 0) for key in {**value, **other}}
            elif name == "final_state" or value is None:
                joined[name] = other
            else:  # arrays over states repeat the joint; arrays over steps do not
                joined[name] = np.concatenate([value, other[1:] if len(value) == n_states else other])
        return Trajectory(**joined)


class Simulator:
    """Rolls out knot controls in one scene (one contact model)."""

    def __init__(self, scene: Scene, horizon_s: float = 1.0, control_period_s: float = 0.05, nthread: int = 2):
        horizon_s = require_finite("horizon_s", horizon_s, positive=True)
        control_period_s = require_finite("control_period_s", control_period_s, positive=True)
        n_knots = horizon_s / control_period_s
        if abs(n_knots - round(n_knots)) > 1e-9 or round(n_knots) < 1:
            raise ValueError(f"horizon_s {horizon_s} must be a positive whole number of control periods {control_period_s}")
        timestep = scene.model.opt.timestep
        steps = control_period_s / timestep
        if abs(steps - round(steps)) > 1e-9 or round(steps) < 1:
            raise ValueError(f"control_period_s {control_period_s} must be a whole number of timesteps {timestep}")
        if not isinstance(nthread, int) or nthread < 1:
            raise ValueError(f"nthread must be a positive integer, got {nthread!r}")
        self.scene = scene
        self.model = scene.model
        self.horizon_s = horizon_s
        self.control_period_s = control_period_s
        self.n_knots = int(round(n_knots))
        self.steps_per_knot = int(round(steps))
        self.n_steps = self.n_knots * self.steps_per_knot
        self.timestep_s = timestep
        self.nthread = nthread
        self.nstate = mujoco.mj_stateSize(self.model, FULL_PHYSICS)
        self._serial = mj_rollout.Rollout(nthread=0)
        self.clock = PhaseClock()  # the time of the rollouts and linearizations on this simulator
        self._worlds: dict[tuple[float, float], Simulator] = {}

    @functools.cached_property
    def _pool(self) -> mj_rollout.Rollout:
        return mj_rollout.Rollout(nthread=self.nthread) if self.nthread > 1 else self._serial

    @functools.cached_property
    def _data(self) -> list[mujoco.MjData]:
        # made on the first rollout here: the simulators of the worlds a plan is tracked in never roll out (the
        # tracking has its own), and making their mjData was 3 of a replan's 100 ms
        return [mujoco.MjData(self.model) for _ in range(self.nthread)]

    def in_world(self, friction_scale: float, mass_scale: float) -> Simulator:
        """This simulator where the object's friction and mass are these times the model's (one thread; built
        once per pair): the same state layout, another world."""
        key = (float(friction_scale), float(mass_scale))
        if key not in self._worlds:
            # the world's scene compiled once per scene: the executor's replans build a simulator per push length,
            # and compiling their four worlds each time was 7 % of a replan
            scenes = _WORLD_SCENES.setdefault(self.scene, {})
            if key not in scenes:
                scenes[key] = Scene(self.scene.contact_model, self.scene.config.with_object_scaled(*key),
                                    native=self.scene.native)
            self._worlds[key] = Simulator(scenes[key], self.horizon_s, self.control_period_s, nthread=1)
        return self._worlds[key]

    # ------------------------------------------------------------------ inputs

    def knot_controls(self, torques_Nm: np.ndarray, contact_control: np.ndarray | None = None) -> np.ndarray:
        """Validated (n_knots, nu) controls: 7 torques u per knot, then the contact control."""
        torques = np.asarray(torques_Nm, dtype=float)
        if torques.shape != (self.n_knots, len(ARM_JOINTS)):
            raise ValueError(f"torques must have shape ({self.n_knots}, 7) (knots x joints), got {torques.shape}")
        if not np.all(np.isfinite(torques)):
            raise ValueError("torques contain NaN or Inf")
        limit = self.scene.torque_limit
        over = np.abs(torques) > limit + 1e-12
        if np.any(over):
            knot, joint = np.argwhere(over)[0]
            raise ValueError(f"torque {torques[knot, joint]} N m at knot {knot} exceeds the {ARM_JOINTS[joint]} "
                             f"motor limit {limit[joint]} N m")
        model = self.scene.contact_model
        if contact_control is None:
            contact = np.full(self.n_knots, model.default_control())
        else:
            contact = np.asarray(contact_control, dtype=float)
            if contact.shape != (self.n_knots,):
                raise ValueError(f"contact_control must have shape ({self.n_knots},) (one per knot), got {contact.shape}")
            contact = model.validate_control(contact)
        controls = np.zeros((self.n_knots, self.model.nu))
        controls[:, self.scene.motor_ids] = torques
        controls[:, self.scene.contact_actuator_id] = contact
        return controls

    def step_controls(self, knot_controls: np.ndarray) -> np.ndarray:
        """(n_steps, nu) per-step controls: each knot held for steps_per_knot steps."""
        return np.repeat(knot_controls, self.steps_per_knot, axis=0)

    def validate_state(self, state: np.ndarray) -> np.ndarray:
        state = np.asarray(state, dtype=float)
        if state.shape != (self.nstate,):
            raise ValueError(f"initial state must have shape ({self.nstate},) (mjSTATE_FULLPHYSICS), got {state.shape}")
        if not np.all(np.isfinite(state)):
            raise ValueError("initial state contains NaN or Inf")
        return state

    # ------------------------------------------------------------------ rollouts

    def rollout(self, initial_state: np.ndarray, torques_Nm: np.ndarray,
                contact_control: np.ndarray | None = None, *, virtual_force: bool = True) -> Trajectory:
        """Simulate the horizon from `initial_state` under the knot controls.

        With virtual_force=False the contact actuator's control is zeroed (gamma = 0 for
        every contact model): the torques and the bias compensation act alone.
        """
        initial_state = self.validate_state(initial_state)
        knot_controls = self.knot_controls(torques_Nm, contact_control)
        if not virtual_force:
            knot_controls[:, self.scene.contact_actuator_id] = 0.0
        controls = self.step_controls(knot_controls)
        states, sensordata, warnings = self.rollout_batch(initial_state[None], controls[None])
        return self.trajectory(initial_state, states[0], sensordata[0], controls, warnings)

    def rollout_batch(self, initial_states: np.ndarray, step_controls: np.ndarray,
                      nstep: int | None = None) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
        """Many rollouts on the thread pool, a single one on the calling thread
        (inputs are trusted: no validation).

        initial_states (B, nstate), step_controls (B, nstep, nu). Returns the states
        (B, nstep, nstate), the sensordata (B, nstep, nsensordata) and the MuJoCo
        warnings summed over the batch.
        """
        with self.clock.measure("rollout"):
            return self._rollout_batch(initial_states, step_controls, nstep)

    def _rollout_batch(self, initial_states: np.ndarray, step_controls: np.ndarray,
                       nstep: int | None) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
        for data in self._data:
            _clear_warnings(data)
        batch = initial_states.shape[0]
        # A fixed (zero) warmstart makes every rollout independent of what ran before on its
        # thread's mjData: the same inputs give the same bits on any number of threads.
        nstep = step_controls.shape[1] if nstep is None else nstep
        runner, datas = (self._serial, self._data[:1]) if batch == 1 else (self._pool, self._data)
        states = np.empty((batch, nstep, self.nstate))
        sensordata = np.empty((batch, nstep, self.model.nsensordata))
        runner.rollout([self.model] * batch, datas, np.ascontiguousarray(initial_states),
                       np.ascontiguousarray(step_controls), skip_checks=True, nstep=nstep,
                       initial_warmstart=np.zeros((batch, self.model.nv)), state=states, sensordata=sensordata)
        return states, sensordata, _warnings(datas)

    def feedback_rollouts(self, initial_state: np.ndarray, knot_states: np.ndarray, decisions: np.ndarray,
                          k: np.ndarray, K: np.ndarray, step_lengths: np.ndarray, lower: np.ndarray,
                          upper: np.ndarray, actuators: np.ndarray
                          ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, int]]]:
        """iLQR's forward pass, natively and side by side on up to nthread threads: one rollout per step
        length alpha, whose knot decisions (N, w) are chosen knot by knot from the state x_l reached:
        c_l = clip(decisions_l + alpha k_l + K_l (x_l - knot_states_l), lower_l, upper_l), decision i
        driving actuator actuators[i] (-1: none; other controls zero). The open-loop rollout of the
        chosen decisions is the same motion bit for bit (the constraint solver's warmstart carried across
        knots as rollout_batch carries it). Returns, per step length, the decisions chosen (N, w), the
        states (n_steps, nstate), the sensordata and the MuJoCo warnings."""
        N, w = decisions.shape
        nx = 2 * self.model.nv
        if knot_states.shape != (N, self.nstate) or k.shape != (N, w) or K.shape != (N, w, nx) or \
                lower.shape != (N, w) or upper.shape != (N, w) or actuators.shape != (w,) or N != self.n_knots:
            raise ValueError(f"feedback rollouts need {self.n_knots} knots: knot_states (N, {self.nstate}), "
                             f"decisions, k, lower, upper (N, w), K (N, w, {nx}) and actuators (w,)")
        step_lengths = np.ascontiguousarray(step_lengths, dtype=float)
        n = len(step_lengths)
        trials = np.empty((n, N, w))
        states = np.empty((n, self.n_steps, self.nstate))
        sensordata = np.empty((n, self.n_steps, self.model.nsensordata))
        warnings = np.zeros((n, mujoco.mjtWarning.mjNWARNING.value), dtype=np.int32)
        contiguous = [np.ascontiguousarray(a, dtype=float) for a in (initial_state, knot_states, decisions, k, K)]
        with self.clock.measure("rollout"):
            _native.feedback_rollouts(self.model._address, tuple(d._address for d in self._data), n, N,
                                      self.steps_per_knot, w, *contiguous, step_lengths,
                                      np.ascontiguousarray(lower, dtype=float), np.ascontiguousarray(upper, dtype=float),
                                      np.ascontiguousarray(actuators, dtype=np.int32), trials, states, sensordata,
                                      warnings)
        return [(trials[i], states[i], sensordata[i], warning_counts(warnings[i])) for i in range(n)]

    # ------------------------------------------------------------------ outputs

    def trajectory(self, initial_state: np.ndarray, states: np.ndarray, sensordata: np.ndarray,
                   controls: np.ndarray, warnings: dict[str, int]) -> Trajectory:
        """Decode one rollout's states and sensor values into a Trajectory."""
        scene, sensors = self.scene, self.scene.sensors
        all_states = np.vstack([initial_state[None], states])
        qpos = all_states[:, scene.state_qpos_adr:scene.state_qpos_adr + self.model.nq]
        qvel = all_states[:, scene.state_qvel_adr:scene.state_qvel_adr + self.model.nv]
        contact_control = controls[:, scene.contact_actuator_id].copy()
        obj = scene.object_qpos_adr
        return Trajectory(
            time_s=all_states[:, 0].copy(),
            q=qpos[:, scene.arm_qpos_adr].copy(),
            qdot=qvel[:, scene.arm_dof_adr].copy(),
            object_position_m=qpos[:, obj:obj + 3].copy(),
            object_quaternion=qpos[:, obj + 3:obj + 7].copy(),
            torque_Nm=sensordata[:, sensors.torque].copy(),
            control_torque_Nm=controls[:, scene.motor_ids].copy(),
            contact_control=contact_control,
            stiffness_N=scene.contact_model.stiffness(contact_control),
            gamma_N=sensordata[:, sensors.gamma][:, 0].copy(),
            virtual_force_N=sensordata[:, sensors.gamma] * scene.inward_normals(qpos[:-1, obj + 3:obj + 7]),
            signed_distance_m=scene.signed_distance_from_local(sensordata[:, sensors.robot_candidate_in_object]),
            contact_force_N=sensordata[:, sensors.contact_force].copy(),
            contact_torque_Nm=sensordata[:, sensors.contact_torque].copy(),
            contact_point_m=sensordata[:, sensors.contact_position].copy(),
            contact_count=sensordata[:, sensors.contact_found][:, 0].copy(),
            ee_velocity_m_s=sensordata[:, sensors.ee_velocity].copy(),
            warnings=warnings,
            final_state=all_states[-1].copy(),
        )


def _clear_warnings(data: mujoco.MjData) -> None:
    for warning in data.warning:
        warning.number = 0


def _warnings(datas: list[mujoco.MjData]) -> dict[str, int]:
    return warning_counts(np.sum([[w.number for w in data.warning] for data in datas], axis=0))


def warning_counts(numbers: np.ndarray) -> dict[str, int]:
    """{warning name: count} of the warnings raised (numbers indexed by mjtWarning)."""
    return {mujoco.mjtWarning(index).name: int(number) for index, number in enumerate(numbers) if number}
