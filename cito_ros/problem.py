"""The single-shooting push problem of the paper (section II.C): layout, cost, constraints.

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

A `PushProblem` is what a solver sees (cito_ros.solver.NlpProblem): size,
bounds, scales, `evaluate` (cost and constraints, cached), `gradient` and
`jacobian` (exact, from cito_ros.derivatives: an adjoint pass over the per-step
linearizations, with knot-restart differences where a contact switch makes a
step's linearization unreliable).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from cito_ros import derivatives
from cito_ros.scene import ARM_JOINTS
from cito_ros.settings import DerivativeSettings, Weights
from cito_ros.simulator import Simulator
from cito_ros.task import PushTask


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


class PushProblem:
    """Cost, constraints and derivatives of pushing the object to `task` from `initial_state`."""

    def __init__(self, simulator: Simulator, initial_state: np.ndarray, task: PushTask, weights: Weights,
                 derivative_settings: DerivativeSettings, position_error_scale_min_m: float):
        self.simulator = simulator
        self.scene = simulator.scene
        self.contact_model = self.scene.contact_model
        self.initial_state = simulator.validate_state(initial_state)
        self.task = task
        self.weights = weights
        self.derivative_settings = derivative_settings
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

        self.initial_object_position = self.scene.object_qpos(self.initial_state)[:3].copy()
        self.initial_position_error_m = float(np.linalg.norm(self.initial_object_position - task.target_position_m))
        self.position_scale = max(self.initial_position_error_m, position_error_scale_min_m)

        sensors = self.scene.sensors
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
        self._linearization_data = tuple(mujoco.MjData(model) for _ in range(derivative_settings.threads))

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

    def variable_column(self, name: str) -> int:
        """Column of knot variable `name` within a knot's block of `width` decisions."""
        names = [v.name for v in self.variables]
        if name not in names:
            raise ValueError(f"{name!r} is not one of {self.contact_model.name}'s knot variables {names}")
        return self.n_joints + names.index(name)

    # ------------------------------------------------------------------ cost pieces

    def terminal_cost(self, object_qpos: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """Final cost c_f, position error vector (m) and Euler-angle error (rad)."""
        position_error, angle_error = self.task.pose_error(object_qpos)
        cost = (self.weights.w1 * float(np.sum((position_error / self.position_scale) ** 2))
                + self.weights.w2 * float(np.sum(angle_error ** 2)))
        return cost, position_error, angle_error

    def terminal_gradient(self, object_qpos: np.ndarray) -> np.ndarray:
        """d c_f / d(object pose) in MuJoCo's tangent space (world translation, local rotation)."""
        gradient = 2 * self.weights.w1 * (object_qpos[:3] - self.task.target_position_m) / self.position_scale ** 2
        rotation_gradient = np.zeros(3)
        h = 1e-6
        for axis in range(3):
            values = []
            for sign in (1.0, -1.0):
                quaternion = object_qpos[3:7].copy()
                mujoco.mju_quatIntegrate(quaternion, np.eye(3)[axis], sign * h)
                values.append(self.weights.w2 * float(np.sum(self.task.angle_error(quaternion) ** 2)))
            rotation_gradient[axis] = (values[0] - values[1]) / (2 * h)
        return np.concatenate([gradient, rotation_gradient])

    def signed_distance(self, sensordata: np.ndarray) -> np.ndarray:
        return self.scene.signed_distance_from_local(sensordata[..., self.local_rows])

    # ------------------------------------------------------------------ evaluation

    def _outputs(self, states: np.ndarray, sensordata: np.ndarray, variables: np.ndarray):
        """Cost terms, constraints and knot mean signed distances of one rollout."""
        w = self.weights
        terminal, _, _ = self.terminal_cost(self.scene.object_qpos(states[-1]))
        speed2 = np.sum(sensordata[:, self.ee_rows] ** 2, axis=1)
        gamma = sensordata[:, self.gamma_row]
        velocity_term = self.running_factor * w.w3 * float(np.sum(speed2))
        force_term = self.running_factor * w.w4 * float(np.sum(gamma ** 2))
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

    def gradient(self, z: np.ndarray) -> np.ndarray:
        return self.derivatives(z).gradient

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        return self.derivatives(z).jacobian

    def derivatives(self, z: np.ndarray, *, cached: bool = True) -> Evaluation:
        """Evaluation with the cost gradient (size,) and constraint Jacobian (n_constraints, size)."""
        evaluation = self.evaluate(z)
        if cached and evaluation.gradient is not None:
            return evaluation
        if not evaluation.finite:
            raise FloatingPointError("the rollout is not finite; no derivatives")
        if self.derivative_settings.method == "forward_differences":
            info = {"restarted_knots": self.n_knots}
            d_dynamics, d_phi = self._restart_differences(evaluation, self.n_knots)
        else:
            d_dynamics, d_phi, info = self._adjoint(evaluation)
        _, variables = self.split(evaluation.z)
        gradient = d_dynamics + self._knot_layout(self.contact_model.variable_cost(variables, self.weights)[1])
        evaluation.gradient, evaluation.jacobian = gradient, self._constraint_jacobian(evaluation, d_phi)
        evaluation.derivative_info = info
        return evaluation

    def linearize(self, z: np.ndarray) -> derivatives.Linearization:
        """The per-step linearization of the rollout of z."""
        evaluation = self.evaluate(z)
        states_before = np.vstack([self.initial_state[None], evaluation.states[:-1]])
        return derivatives.linearize(self.scene.model, self._linearization_data, states_before,
                                     self.simulator.step_controls(evaluation.knot_controls),
                                     self.derivative_settings.epsilon)

    def _adjoint(self, evaluation: Evaluation):
        """d(dynamic cost terms)/dz and d(knot mean phi)/dz through the dynamics, by the adjoint pass."""
        linearization = self.linearize(evaluation.z)
        T, S, N = self.n_steps, self.steps_per_knot, self.n_knots
        nx = 2 * self.scene.model.nv
        sensordata = evaluation.sensordata
        m = self.n_constraints_per_knot
        n_out = 1 + (N if m else 0)  # the cost, then the knot mean signed distances

        # d(outputs)/d(used sensor rows) per step: rows = [ee velocity (3), gamma, robot-in-object (3)]
        weights = np.zeros((T, len(self.used_rows), n_out))
        weights[:, 0:3, 0] = 2 * self.running_factor * self.weights.w3 * sensordata[:, self.ee_rows]
        weights[:, 3, 0] = 2 * self.running_factor * self.weights.w4 * sensordata[:, self.gamma_row]
        if m:
            local = sensordata[:, self.local_rows]
            offset = local - self.scene.object_candidate_in_geom
            distance = np.linalg.norm(offset, axis=1, keepdims=True)
            sign = np.sign(self.signed_distance(sensordata))[:, None]
            d_phi_d_local = sign * offset / np.maximum(distance, 1e-12) / S
            knot_of_step = np.arange(T) // S
            weights[np.arange(T), 4:7, 1 + knot_of_step] = d_phi_d_local
        terminal = np.zeros((nx, n_out))
        dof = self.scene.object_dof_adr
        terminal[dof:dof + 6, 0] = self.terminal_gradient(self.scene.object_qpos(evaluation.states[-1]))
        d_controls = derivatives.adjoint(linearization.A, linearization.B, linearization.C[:, self.used_rows, :],
                                         linearization.D[:, self.used_rows, :], weights, terminal, S)

        gradient, d_phi = self._to_decisions(d_controls[:, :, 0]), None
        info = {**linearization.info(), "restarted_knots": 0}
        if m:
            d_phi = np.stack([self._to_decisions(d_controls[:, :, 1 + l]) for l in range(N)])
        unresolved = linearization.unresolved_steps
        if unresolved.size:
            knots = int(unresolved.max() // S) + 1
            info["restarted_knots"] = knots
            fd_gradient, fd_d_phi = self._restart_differences(evaluation, knots)
            columns = slice(0, knots * self.width)
            gradient[columns] = fd_gradient[columns]
            if m:
                d_phi[:, columns] = fd_d_phi[:, columns]
        return gradient, d_phi, info

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

    def _restart_differences(self, evaluation: Evaluation, knots: int):
        """d(dynamic cost terms)/dz and d(knot mean phi)/dz for the first `knots` knots by knot-restart
        forward differences (cito_ros.derivatives.restart_differences)."""
        _, variables = self.split(evaluation.z)
        acting = [c for c in range(self.width) if c < self.n_joints
                  or c - self.n_joints == self.contact_model.control_variable]
        columns = [np.array([knot * self.width + c for c in acting]) for knot in range(knots)]
        steps = self.derivative_settings.restart_step * self.scale
        steps = np.where(evaluation.z + steps > self.upper, -steps, steps)

        def outputs(states, sensordata):
            terms, _, phi = self._outputs(states, sensordata, variables)
            return terms["terminal"] + terms["velocity"] + terms["force"], phi if self.n_constraints_per_knot else None

        states_before = np.vstack([self.initial_state[None], evaluation.states[:-1]])
        return derivatives.restart_differences(
            self.simulator, states_before, evaluation.states, evaluation.sensordata, evaluation.z, columns, steps,
            lambda z: self.simulator.step_controls(self.knot_controls(z)), outputs)
