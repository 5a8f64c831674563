"""The single-shooting push problem of the paper (section II.C) and its exact derivatives.

ROS-free. Decision vector z, knot-major: at each of the N knots, the 7 joint
torques u_l, then the contact model's knot variables (VSCM: k_l; CCCM: gamma_l,
s_l; SCM: none). Cost, eqs. (8)-(9) (+ w5 sum s^2 for CCCM):

    c_f = w1 ||(p_T - p*) / max(||p_0 - p*||, d_min)||^2 + w2 ||theta_T||^2
    c_i = (t_c / N) sum_l (w3 <||xdot||^2>_l + w4 <gamma^2>_l)

with theta_T the Euler angles (roll, pitch, yaw) of the object's rotation
relative to the target, and <.>_l the mean over knot l's simulation steps of the
end-effector (plate centre) speed squared and the virtual force squared.
Constraints, when the contact model has any (CCCM), act on the knot means of the
signed distance phi.

Derivatives: every simulation step is linearized natively (`_native.linearize`:
finite differences that skip unchanged pipeline stages, run on several threads
and retry a perturbation on the other side when it makes or breaks a contact);
an adjoint (reverse) pass over the steps then gives the gradient of the cost and
the Jacobian of every constraint in one sweep. Where a perturbation switches
contacts on both sides the linearization of that step is unreliable; the knots
up to it are then differentiated by forward differences that restart from the
saved state at each knot, batched through mujoco.rollout.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import mujoco
import numpy as np

from cito_ros import _native
from cito_ros.config import require_finite
from cito_ros.scene import ARM_JOINTS
from cito_ros.simulator import Simulator

GRADIENT_METHODS = ("adjoint", "forward_differences")
WEIGHT_NAMES = ("w1", "w2", "w3", "w4")


@dataclass(frozen=True)
class PushTask:
    """Where the object should end: position (m, world) and yaw (rad) about world z."""

    target_position_m: np.ndarray
    target_yaw_rad: float = 0.0

    def __post_init__(self):
        position = np.asarray(self.target_position_m, dtype=float)
        if position.shape != (3,):
            raise ValueError(f"target position must have 3 coordinates, got shape {position.shape}")
        if not np.all(np.isfinite(position)):
            raise ValueError("target position contains NaN or Inf")
        object.__setattr__(self, "target_position_m", position)
        object.__setattr__(self, "target_yaw_rad", require_finite("target yaw", self.target_yaw_rad))

    @property
    def target_rotation(self) -> np.ndarray:
        c, s = math.cos(self.target_yaw_rad), math.sin(self.target_yaw_rad)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class ProblemSettings:
    """Cost weights and derivative settings (from config/planner.yaml)."""

    weights: Mapping[str, float]
    position_error_scale_min_m: float = 0.05
    gradient_method: str = "adjoint"
    epsilon: float = 1e-6
    threads: int = 2
    restart_step: float = 1e-4  # forward-difference step of the knot-restart method, relative to scale

    @classmethod
    def from_parameters(cls, parameters: Mapping[str, Any], contact_model_name: str) -> "ProblemSettings":
        weights = parameters.get("weights", {}).get(contact_model_name)
        if not isinstance(weights, Mapping):
            raise ValueError(f"config has no weights.{contact_model_name} section")
        gradient = parameters.get("gradient", {})
        return cls(
            weights={k: require_finite(f"weights.{contact_model_name}.{k}", v, nonnegative=True)
                     for k, v in weights.items()},
            position_error_scale_min_m=require_finite(
                "task.position_error_scale_min_m",
                parameters.get("task", {}).get("position_error_scale_min_m", 0.05), positive=True),
            gradient_method=str(gradient.get("method", "adjoint")),
            epsilon=require_finite("gradient.epsilon", gradient.get("epsilon", 1e-6), positive=True),
            threads=int(gradient.get("threads", 2)),
            restart_step=require_finite("gradient.restart_step", gradient.get("restart_step", 1e-4), positive=True),
        )

    def __post_init__(self):
        missing = [w for w in WEIGHT_NAMES if w not in self.weights]
        if missing:
            raise ValueError(f"missing cost weights {missing}")
        if self.gradient_method not in GRADIENT_METHODS:
            raise ValueError(f"gradient method must be one of {GRADIENT_METHODS}, got {self.gradient_method!r}")
        if self.threads < 1:
            raise ValueError(f"gradient threads must be at least 1, got {self.threads}")


@dataclass
class Evaluation:
    """A rollout of one decision vector and everything computed from it."""

    z: np.ndarray
    knot_controls: np.ndarray     # (N, nu)
    states: np.ndarray            # (T, nstate): states after each step
    sensordata: np.ndarray        # (T, ns): sensors at the state before each step
    warnings: dict[str, int]
    cost: float
    cost_terms: dict[str, float]
    constraints: np.ndarray       # (N * m,)
    knot_signed_distance: np.ndarray  # (N,)
    finite: bool
    gradient: np.ndarray | None = None
    jacobian: np.ndarray | None = None
    derivative_info: dict[str, int] = field(default_factory=dict)


def euler_angles(rotation: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (rad) of a rotation matrix, R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return np.array([
        math.atan2(rotation[2, 1], rotation[2, 2]),
        math.asin(max(-1.0, min(1.0, -rotation[2, 0]))),
        math.atan2(rotation[1, 0], rotation[0, 0]),
    ])


def quaternion_matrix(quaternion: np.ndarray) -> np.ndarray:
    rotation = np.empty(9)
    mujoco.mju_quat2Mat(rotation, quaternion / np.linalg.norm(quaternion))
    return rotation.reshape(3, 3)


class PushProblem:
    """Cost, constraints and derivatives of pushing the object to `task` from `initial_state`."""

    def __init__(self, simulator: Simulator, initial_state: np.ndarray, task: PushTask, settings: ProblemSettings):
        self.simulator = simulator
        self.scene = simulator.scene
        self.contact_model = self.scene.contact_model
        self.initial_state = simulator.validate_state(initial_state)
        self.task = task
        self.settings = settings
        self.weights = dict(settings.weights)
        model = self.scene.model
        self.n_knots, self.steps_per_knot, self.n_steps = simulator.n_knots, simulator.steps_per_knot, simulator.n_steps
        self.n_joints = len(ARM_JOINTS)
        self.variables = self.contact_model.knot_variables
        self.width = self.n_joints + len(self.variables)
        self.size = self.n_knots * self.width

        limit = self.scene.torque_limit
        per_knot = lambda torque, extra: np.tile(np.concatenate([torque, extra]), self.n_knots)  # noqa: E731
        self.lower = per_knot(-limit, [v.lower for v in self.variables])
        self.upper = per_knot(limit, [v.upper for v in self.variables])
        self.scale = per_knot(limit, [v.scale for v in self.variables])
        self.initial_guess = per_knot(np.zeros(self.n_joints), [v.initial for v in self.variables])

        data = mujoco.MjData(model)
        mujoco.mj_setState(model, data, self.initial_state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        mujoco.mj_forward(model, data)
        self.initial_object_position, _ = self.scene.object_pose(data)
        self.initial_position_error_m = float(np.linalg.norm(self.initial_object_position - task.target_position_m))
        self.position_scale = max(self.initial_position_error_m, settings.position_error_scale_min_m)

        sensors = self.scene.sensors
        self.qpos_offset = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_TIME)
        self.object_qpos = self.qpos_offset + self.scene.object_qpos_adr
        self.object_dof = self.scene.object_dof_adr
        self.ee_rows = np.arange(sensors.ee_velocity.start, sensors.ee_velocity.stop)
        self.gamma_row = sensors.gamma.start
        self.local_rows = np.arange(sensors.robot_candidate_in_object.start, sensors.robot_candidate_in_object.stop)
        self.used_rows = np.concatenate([self.ee_rows, [self.gamma_row], self.local_rows])
        # running-cost factor: (t_c / N) per knot, averaged over the knot's steps
        self.running_factor = simulator.control_period_s / self.n_knots / self.steps_per_knot
        self.n_constraints_per_knot = len(self.contact_model.knot_constraints(
            np.zeros(self.n_knots), self.initial_guess.reshape(self.n_knots, self.width)[:, self.n_joints:]).lower)
        self.n_constraints = self.n_knots * self.n_constraints_per_knot
        self._cache: Evaluation | None = None
        # one mjData per linearization thread, owned here (the native code keeps none)
        self._linearization_data = tuple(mujoco.MjData(model) for _ in range(settings.threads))

    # ------------------------------------------------------------------ layout

    def split(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        knots = np.asarray(z, dtype=float).reshape(self.n_knots, self.width)
        return knots[:, :self.n_joints], knots[:, self.n_joints:]

    def knot_controls(self, z: np.ndarray) -> np.ndarray:
        torques, variables = self.split(z)
        controls = np.zeros((self.n_knots, self.scene.model.nu))
        controls[:, self.scene.motor_ids] = torques
        controls[:, self.scene.contact_actuator_id] = self.contact_model.contact_control(variables)
        return controls

    def constraint_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        constraints = self.contact_model.knot_constraints(
            np.zeros(self.n_knots), self.split(self.initial_guess)[1])
        return np.tile(constraints.lower, self.n_knots), np.tile(constraints.upper, self.n_knots)

    # ------------------------------------------------------------------ cost pieces

    def terminal_cost(self, object_qpos: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """Final cost c_f, position error vector (m) and Euler-angle error (rad)."""
        position_error = object_qpos[:3] - self.task.target_position_m
        relative = self.task.target_rotation.T @ quaternion_matrix(object_qpos[3:7])
        angle_error = euler_angles(relative)
        cost = (self.weights["w1"] * float(np.sum((position_error / self.position_scale) ** 2))
                + self.weights["w2"] * float(np.sum(angle_error ** 2)))
        return cost, position_error, angle_error

    def terminal_gradient(self, object_qpos: np.ndarray) -> np.ndarray:
        """d c_f / d(object pose) in MuJoCo's tangent space (world translation, local rotation)."""
        gradient = 2 * self.weights["w1"] * (object_qpos[:3] - self.task.target_position_m) / self.position_scale ** 2
        rotation_gradient = np.zeros(3)
        h = 1e-6
        for axis in range(3):
            values = []
            for sign in (1.0, -1.0):
                quaternion = object_qpos[3:7].copy()
                mujoco.mju_quatIntegrate(quaternion, np.eye(3)[axis], sign * h)
                relative = self.task.target_rotation.T @ quaternion_matrix(quaternion)
                values.append(self.weights["w2"] * float(np.sum(euler_angles(relative) ** 2)))
            rotation_gradient[axis] = (values[0] - values[1]) / (2 * h)
        return np.concatenate([gradient, rotation_gradient])

    def signed_distance(self, sensordata: np.ndarray) -> np.ndarray:
        return self.scene.signed_distance_from_local(sensordata[..., self.local_rows])

    # ------------------------------------------------------------------ evaluation

    def _outputs(self, states: np.ndarray, sensordata: np.ndarray, variables: np.ndarray):
        """Cost terms, constraints and knot mean signed distances of one rollout."""
        w = self.weights
        final_qpos = states[-1, self.object_qpos:self.object_qpos + 7]
        terminal, _, _ = self.terminal_cost(final_qpos)
        speed2 = np.sum(sensordata[:, self.ee_rows] ** 2, axis=1)
        gamma = sensordata[:, self.gamma_row]
        velocity_term = self.running_factor * w["w3"] * float(np.sum(speed2))
        force_term = self.running_factor * w["w4"] * float(np.sum(gamma ** 2))
        variable_term, _ = self.contact_model.variable_cost(variables, w)
        phi = self.signed_distance(sensordata).reshape(self.n_knots, self.steps_per_knot).mean(axis=1)
        constraints = self.contact_model.knot_constraints(phi, variables)
        terms = {"terminal": terminal, "velocity": velocity_term, "force": force_term, "variables": variable_term}
        return terms, constraints.values.reshape(-1), phi

    def evaluate(self, z: np.ndarray) -> Evaluation:
        z = np.asarray(z, dtype=float)
        if self._cache is not None and np.array_equal(self._cache.z, z):
            return self._cache
        _, variables = self.split(z)
        knot_controls = self.knot_controls(z)
        step_controls = self.simulator.step_controls(knot_controls)
        states, sensordata, warnings = self.simulator.rollout_batch(self.initial_state[None], step_controls[None])
        states, sensordata = states[0], sensordata[0]
        finite = bool(np.all(np.isfinite(states)) and np.all(np.isfinite(sensordata)))
        if finite:
            terms, constraints, phi = self._outputs(states, sensordata, variables)
            cost = float(sum(terms.values()))
            finite = math.isfinite(cost) and bool(np.all(np.isfinite(constraints)))
        else:
            terms, cost = {}, math.inf
            constraints, phi = np.full(self.n_constraints, math.nan), np.full(self.n_knots, math.nan)
        self._cache = Evaluation(z.copy(), knot_controls, states, sensordata, warnings, cost, terms,
                                 constraints, phi, finite)
        return self._cache

    # ------------------------------------------------------------------ derivatives

    def derivatives(self, z: np.ndarray) -> Evaluation:
        """Evaluation with the cost gradient (size,) and constraint Jacobian (n_constraints, size)."""
        evaluation = self.evaluate(z)
        if evaluation.gradient is not None:
            return evaluation
        if not evaluation.finite:
            raise FloatingPointError("the rollout is not finite; no derivatives")
        if self.settings.gradient_method == "forward_differences":
            knots = self.n_knots
            info = {"restarted_knots": knots}
            gradient, jacobian = self._restart_differences(evaluation, knots)
        else:
            gradient, jacobian, info = self._adjoint(evaluation)
        evaluation.gradient, evaluation.jacobian, evaluation.derivative_info = gradient, jacobian, info
        return evaluation

    def _linearize(self, evaluation: Evaluation):
        model, T = self.scene.model, self.n_steps
        nx, nu, ns = 2 * model.nv, model.nu, model.nsensordata
        inputs = np.ascontiguousarray(np.vstack([self.initial_state[None], evaluation.states[:-1]]))
        controls = np.ascontiguousarray(self.simulator.step_controls(evaluation.knot_controls))
        A, B = np.empty((T, nx, nx)), np.empty((T, nx, nu))
        C, D = np.empty((T, ns, nx)), np.empty((T, ns, nu))
        flags = np.zeros((T, 3), dtype=np.int32)
        _native.linearize(model._address, tuple(d._address for d in self._linearization_data), T, inputs, controls,
                          self.settings.epsilon, A, B, C, D, flags)
        return A, B, C, D, flags

    def _adjoint(self, evaluation: Evaluation):
        A, B, C, D, flags = self._linearize(evaluation)
        T, S, N = self.n_steps, self.steps_per_knot, self.n_knots
        model = self.scene.model
        nx = 2 * model.nv
        sensordata = evaluation.sensordata
        _, variables = self.split(evaluation.z)
        m = self.n_constraints_per_knot
        n_out = 1 + (N if m else 0)  # the cost, then the knot mean signed distances

        # d(outputs)/d(used sensor rows) per step: rows = [ee velocity (3), gamma, robot-in-object (3)]
        weights = np.zeros((T, len(self.used_rows), n_out))
        weights[:, 0:3, 0] = 2 * self.running_factor * self.weights["w3"] * sensordata[:, self.ee_rows]
        weights[:, 3, 0] = 2 * self.running_factor * self.weights["w4"] * sensordata[:, self.gamma_row]
        if m:
            local = sensordata[:, self.local_rows]
            offset = local - self.scene.object_candidate_in_geom
            distance = np.linalg.norm(offset, axis=1, keepdims=True)
            sign = np.sign(self.signed_distance(sensordata))[:, None]
            d_phi_d_local = sign * offset / np.maximum(distance, 1e-12) / S
            knot_of_step = np.arange(T) // S
            weights[np.arange(T), 4:7, 1 + knot_of_step] = d_phi_d_local

        # backward pass: lambda_t = A_t^T lambda_{t+1} + C_t^T w_t; only that recursion is sequential
        sensor_terms = np.einsum("tsi,tso->tio", C[:, self.used_rows, :], weights)
        adjoints = np.empty((T + 1, nx, n_out))
        adjoints[T] = 0.0
        final = evaluation.states[-1, self.object_qpos:self.object_qpos + 7]
        adjoints[T, self.object_dof:self.object_dof + 6, 0] = self.terminal_gradient(final)
        A_transposed = A.transpose(0, 2, 1)
        for t in range(T - 1, -1, -1):
            adjoints[t] = A_transposed[t] @ adjoints[t + 1] + sensor_terms[t]
        # d(outputs)/d(controls) per step: B_t^T lambda_{t+1} + D_t^T w_t, summed over each knot
        per_step = (np.einsum("tiu,tio->tuo", B, adjoints[1:])
                    + np.einsum("tsu,tso->tuo", D[:, self.used_rows, :], weights))
        d_controls = per_step.reshape(N, S, model.nu, n_out).sum(axis=1)

        gradient, d_phi = self._to_decisions(d_controls[:, :, 0]), None
        info = {"one_sided_columns": int(flags[:, 0].sum()), "unresolved_columns": int(flags[:, 1].sum()),
                "linearization_warnings": int(flags[:, 2].sum()), "restarted_knots": 0}
        if m:
            d_phi = np.stack([self._to_decisions(d_controls[:, :, 1 + l]) for l in range(N)])
        unresolved_steps = np.nonzero(flags[:, 1])[0]
        if unresolved_steps.size:
            knots = int(unresolved_steps.max() // S) + 1
            info["restarted_knots"] = knots
            fd_gradient, fd_d_phi = self._restart_differences(evaluation, knots, raw=True)
            columns = slice(0, knots * self.width)
            gradient[columns] = fd_gradient[columns]
            if m:
                d_phi[:, columns] = fd_d_phi[:, columns]
        variable_cost_gradient = self.contact_model.variable_cost(variables, self.weights)[1]
        gradient += self._knot_layout(variable_cost_gradient)
        return gradient, self._constraint_jacobian(evaluation, d_phi), info

    def _to_decisions(self, d_knot_controls: np.ndarray) -> np.ndarray:
        """Map d/d(knot controls) (N, nu) to d/dz (through the dynamics only)."""
        gradient = np.zeros((self.n_knots, self.width))
        gradient[:, :self.n_joints] = d_knot_controls[:, self.scene.motor_ids]
        index = self.contact_model.control_variable
        if index is not None:
            gradient[:, self.n_joints + index] = d_knot_controls[:, self.scene.contact_actuator_id]
        return gradient.reshape(-1)

    def _knot_layout(self, variable_array: np.ndarray) -> np.ndarray:
        full = np.zeros((self.n_knots, self.width))
        full[:, self.n_joints:] = variable_array
        return full.reshape(-1)

    def _constraint_jacobian(self, evaluation: Evaluation, d_phi: np.ndarray | None) -> np.ndarray:
        m = self.n_constraints_per_knot
        jacobian = np.zeros((self.n_constraints, self.size))
        if not m:
            return jacobian
        _, variables = self.split(evaluation.z)
        constraints = self.contact_model.knot_constraints(evaluation.knot_signed_distance, variables)
        for l in range(self.n_knots):
            for c in range(m):
                row = l * m + c
                jacobian[row] = constraints.d_phi[l, c] * d_phi[l]
                start = l * self.width + self.n_joints
                jacobian[row, start:start + len(self.variables)] += constraints.d_variables[l, c]
        return jacobian

    def _restart_differences(self, evaluation: Evaluation, knots: int, raw: bool = False):
        """Forward differences of the outputs for the decisions of the first `knots` knots, each
        perturbation rolled out from the saved state at the start of its knot.

        Returns (cost gradient, d(knot mean phi)/dz) with raw=True (dynamics only), else
        (gradient incl. variable costs, constraint Jacobian).
        """
        S, N, width = self.steps_per_knot, self.n_knots, self.width
        z = evaluation.z
        states_before = np.vstack([self.initial_state[None], evaluation.states[:-1]])
        gradient = np.zeros(self.size)
        m = self.n_constraints_per_knot
        d_phi = np.zeros((N, self.size)) if m else None
        _, base_variables = self.split(z)
        base_terms, _, base_phi = self._outputs(evaluation.states, evaluation.sensordata, base_variables)
        base_dynamic = base_terms["terminal"] + base_terms["velocity"] + base_terms["force"]
        for knot in range(knots):
            columns = np.arange(knot * width, (knot + 1) * width)
            columns = columns[[self._affects_dynamics(c) for c in columns]]
            steps = np.zeros((len(columns), (N - knot) * S, self.scene.model.nu))
            perturbed = []
            for row, column in enumerate(columns):
                zp = z.copy()
                h = self.settings.restart_step * self.scale[column]
                if zp[column] + h > self.upper[column]:
                    h = -h
                zp[column] += h
                perturbed.append(h)
                steps[row] = self.simulator.step_controls(self.knot_controls(zp))[knot * S:]
            start = np.repeat(states_before[knot * S][None], len(columns), axis=0)
            states, sensordata, _ = self.simulator.rollout_batch(start, steps)
            for row, column in enumerate(columns):
                full_states = np.vstack([evaluation.states[:knot * S], states[row]])
                full_sensors = np.vstack([evaluation.sensordata[:knot * S], sensordata[row]])
                terms, _, phi = self._outputs(full_states, full_sensors, base_variables)
                dynamic = terms["terminal"] + terms["velocity"] + terms["force"]
                gradient[column] = (dynamic - base_dynamic) / perturbed[row]
                if m:
                    d_phi[:, column] = (phi - base_phi) / perturbed[row]
        if raw:
            return gradient, d_phi
        gradient += self._knot_layout(self.contact_model.variable_cost(base_variables, self.weights)[1])
        return gradient, self._constraint_jacobian(evaluation, d_phi)

    def _affects_dynamics(self, column: int) -> bool:
        offset = column % self.width
        return offset < self.n_joints or offset - self.n_joints == self.contact_model.control_variable
