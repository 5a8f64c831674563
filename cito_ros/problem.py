"""The single-shooting push problem of the paper (section II.C), and the stage costs beyond it.

ROS-free. Decision vector z, knot-major: at each of the N knots, the 7 joint
torques u_l, then the contact model's knot variables (VSCM: k_l; CCCM: gamma_l,
s_l; SCM: none). A stage without the virtual force (`StageCost.virtual_force`
False) has the torques alone and the contact control held at 0: the dynamics
the plan is executed with. The paper's cost, eqs. (8)-(9) (+ w5 sum s^2 for
CCCM):

    c_f = w1 ||(p_T - p*) / max(||p_0 - p*||, d_min)||^2 + w2 ||theta_T||^2
    c_i = (t_c / N) sum_l (w3 <||xdot||^2>_l + w4 <gamma^2>_l)

with theta_T the Euler angles (roll, pitch, yaw) of the object's rotation
relative to the target, and <.>_l the mean over knot l's simulation steps of the
end-effector (plate centre) speed squared and the virtual force squared.
Constraints, when the contact model has any (CCCM), act on the knot means of the
signed distance phi. Beyond the paper, a stage may add (each zero by default
weight, see `StageCost`): penalties on joint speeds and positions beyond a
margin of their limits, on the object's final velocity, and a contact term
that draws the plate onto the object's face at chosen steps.

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
from cito_ros.simulator import Simulator, Trajectory
from cito_ros.task import PushTask

CACHED_EVALUATIONS = 6


@dataclass(frozen=True)
class StageCost:
    """What one stage minimizes: the paper's weighted terms, and the terms beyond the paper.

    joint_speed: weight of (1/T) sum_t,j max(0, |qdot_tj| / limit_j - margin)^2
    joint_position: weight of (1/T) sum_t,j (distance beyond [low + margin, high - margin] in rad)^2
    object_velocity: weight of |v_T|^2 + (h |w_T|)^2 (the object's final linear and angular
      velocity, h its half size): a plan that ends with the object at rest
    contact: weight of sum_t profile_t max(gap_t, 0)^2, gap_t the distance between the plate and the
      object (the plate drawn onto the object at the steps the profile weights)
    complementarity: CCCM with its slack eliminated: weight of sum_l <(phi gamma)^2>_l (the mean over
      knot l's steps) in place of the slack s_l, its cost w5 sum s_l^2 and the constraints. At the
      paper's optimum s_l = phi_l gamma_l; what is left is box-bounded (a least-squares problem), and
      the simulator's contacts keep phi from going far below 0. 0: the model's own variables
    """

    weights: Weights
    virtual_force: bool
    joint_speed: float
    joint_speed_margin: float
    joint_position: float
    joint_position_margin_rad: float
    object_velocity: float
    contact: float
    contact_profile: np.ndarray | None  # (T,) step weights of the contact term
    complementarity: float = 0.0

    @classmethod
    def paper(cls, weights: Weights) -> "StageCost":
        return cls(weights, True, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, None)


@dataclass(frozen=True)
class KnotExpansion:
    """z expanded knot by knot (N knots, nx = 2 nv tangent states, w decisions per knot): knot_states
    (N+1, nstate) at each knot start, dynamics F_x (N, nx, nx) and F_c (N, nx, w) from a knot's start
    to the next, the Gauss-Newton expansion of each knot's running cost (l_x, l_c, l_xx, l_cc, l_cx)
    and of the terminal cost (v_x, v_xx)."""

    knot_states: np.ndarray
    fx: np.ndarray
    fc: np.ndarray
    lx: np.ndarray
    lc: np.ndarray
    lxx: np.ndarray
    lcc: np.ndarray
    lcx: np.ndarray
    vx: np.ndarray
    vxx: np.ndarray
    derivative_info: dict[str, int]


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
    residuals: np.ndarray         # r: the cost is r . r
    position_error_m: float       # final object position error
    gradient: np.ndarray | None = None
    jacobian: np.ndarray | None = None
    residual_jacobian: np.ndarray | None = None
    linearization: derivatives.Linearization | None = None  # shared by the gradient and the residual Jacobian
    derivative_info: dict[str, int] = field(default_factory=dict)


class PushProblem:
    """Cost, constraints and derivatives of pushing the object to `task` from `initial_state`."""

    def __init__(self, simulator: Simulator, initial_state: np.ndarray, task: PushTask, cost: StageCost,
                 derivative_settings: DerivativeSettings, position_error_scale_min_m: float):
        self.simulator = simulator
        self.scene = simulator.scene
        self.contact_model = self.scene.contact_model
        self.initial_state = simulator.validate_state(initial_state)
        self.task = task
        self.cost = cost
        self.weights = cost.weights
        self.derivative_settings = derivative_settings
        model = self.scene.model
        self.n_knots, self.steps_per_knot, self.n_steps = simulator.n_knots, simulator.steps_per_knot, simulator.n_steps
        self.n_joints = len(ARM_JOINTS)
        # CCCM's slack eliminated: gamma is its only knot variable, and it has no constraints
        self.slack_eliminated = cost.virtual_force and cost.complementarity > 0
        slack = self.contact_model.slack_variable
        if self.slack_eliminated and slack is None:
            raise ValueError(f"{self.contact_model.name} has no complementarity constraints to eliminate a slack "
                             f"of; the complementarity weight is CCCM's")
        knot_variables = self.contact_model.knot_variables if cost.virtual_force else ()
        self.variables = tuple(v for i, v in enumerate(knot_variables) if not (self.slack_eliminated and i == slack))
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
        self.position_scale_min_m = position_error_scale_min_m
        self.position_scale = max(self.initial_position_error_m, position_error_scale_min_m)

        sensors = self.scene.sensors
        self.ee_rows = np.arange(sensors.ee_velocity.start, sensors.ee_velocity.stop)
        self.gamma_row = sensors.gamma.start
        self.local_rows = np.arange(sensors.robot_candidate_in_object.start, sensors.robot_candidate_in_object.stop)
        self.q_rows = np.arange(sensors.joint_position.start, sensors.joint_position.stop)
        self.qdot_rows = np.arange(sensors.joint_velocity.start, sensors.joint_velocity.stop)
        self.gap_row = sensors.plate_gap.start
        self.used_rows = np.concatenate([self.ee_rows, [self.gamma_row], self.local_rows, self.q_rows, self.qdot_rows,
                                         [self.gap_row]])
        # running-cost factor: (t_c / N) per knot, averaged over the knot's steps
        self.running_factor = simulator.control_period_s / self.n_knots / self.steps_per_knot
        self.n_constraints_per_knot = len(self.constraint_bounds()[0]) // self.n_knots
        self.n_constraints = self.n_knots * self.n_constraints_per_knot
        low, high = self.scene.joint_range.T
        self.soft_joint_range = (low + cost.joint_position_margin_rad, high - cost.joint_position_margin_rad)
        self._cache: list[Evaluation] = []  # the latest evaluations (a solver's point and its trial)
        # one mjData per linearization thread, owned here (the native code keeps none)
        self._linearization_data = tuple(mujoco.MjData(model) for _ in range(derivative_settings.threads))

    # ------------------------------------------------------------------ layout

    def split(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        knots = np.asarray(z, dtype=float).reshape(self.n_knots, self.width)
        return knots[:, :self.n_joints], knots[:, self.n_joints:]

    def contact_control(self, variables: np.ndarray) -> np.ndarray:
        """The contact actuator's control per knot (0 without the virtual force)."""
        if not self.cost.virtual_force:
            return np.zeros(self.n_knots)
        return self.contact_model.contact_control(variables)

    def knot_controls(self, z: np.ndarray) -> np.ndarray:
        torques, variables = self.split(z)
        controls = np.zeros((self.n_knots, self.scene.model.nu))
        controls[:, self.scene.motor_ids] = torques
        controls[:, self.scene.contact_actuator_id] = self.contact_control(variables)
        return controls

    def with_torques(self, torques: np.ndarray, variables: np.ndarray | None = None) -> np.ndarray:
        """The decision vector of (N, 7) torques and (N, n_var) knot variables (default: their start)."""
        knots = self.initial_guess.reshape(self.n_knots, self.width).copy()
        knots[:, :self.n_joints] = torques
        if variables is not None and self.variables:
            knots[:, self.n_joints:] = variables
        return knots.reshape(-1)

    def _knot_constraints(self, phi: np.ndarray, variables: np.ndarray):
        if not self.cost.virtual_force or self.slack_eliminated:
            return None
        return self.contact_model.knot_constraints(phi, variables)

    def constraint_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        constraints = self._knot_constraints(np.zeros(self.n_knots), self.split(self.initial_guess)[1])
        if constraints is None:
            return np.zeros(0), np.zeros(0)
        return np.tile(constraints.lower, self.n_knots), np.tile(constraints.upper, self.n_knots)

    def variable_column(self, name: str) -> int:
        """Column of knot variable `name` within a knot's block of `width` decisions."""
        names = [v.name for v in self.variables]
        if name not in names:
            raise ValueError(f"{name!r} is not one of {self.contact_model.name}'s knot variables {names}")
        return self.n_joints + names.index(name)

    # ------------------------------------------------------------------ residuals

    def _terminal_residuals(self, final_state: np.ndarray,
                            derivatives: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Residuals of the final state, and (with `derivatives`, else None) their derivatives with respect to
        it (tangent space): position (3) and Euler angles (3) against the target, then the object's velocity
        (6), then the joint speeds beyond their margin (7: the running term sees the steps' start states only)."""
        w, c, nv = self.weights, self.cost, self.scene.model.nv
        dof = self.scene.object_dof_adr
        object_qpos = self.scene.object_qpos(final_state)
        position_error, angle_error = self.task.pose_error(object_qpos)
        position_root, angle_root = math.sqrt(w.w1) / self.position_scale, math.sqrt(w.w2)
        rows = 6 + (6 if c.object_velocity else 0) + (7 if c.joint_speed else 0)
        residuals = np.zeros(rows)
        # an evaluation's cost needs the residuals alone; the Jacobian (six Euler-angle evaluations among the
        # rest) is for the expansions
        jacobian = np.zeros((rows, 2 * nv)) if derivatives else None
        residuals[:3], residuals[3:6] = position_root * position_error, angle_root * angle_error
        if derivatives:
            jacobian[:3, dof:dof + 3] = position_root * np.eye(3)
            h = 1e-6  # Euler angles by central differences in the object's local rotation
            for axis in range(3):
                turned = []
                for sign in (1.0, -1.0):
                    quaternion = object_qpos[3:7].copy()
                    mujoco.mju_quatIntegrate(quaternion, np.eye(3)[axis], sign * h)
                    turned.append(self.task.angle_error(quaternion))
                jacobian[3:6, dof + 3 + axis] = angle_root * (turned[0] - turned[1]) / (2 * h)
        row = 6
        if c.object_velocity:
            root = math.sqrt(c.object_velocity)
            scale = np.array([1.0, 1.0, 1.0, *[float(self.scene.object_half_size[0])] * 3])
            residuals[row:row + 6] = root * scale * self.scene.object_qvel(final_state)
            if derivatives:
                jacobian[row:row + 6, nv + dof:nv + dof + 6] = np.diag(root * scale)
            row += 6
        if c.joint_speed:
            excess, slope = self._speed_excess(self.scene.arm_qvel(final_state)[None])
            residuals[row:row + 7] = excess[0]
            if derivatives:
                jacobian[row:row + 7, nv + self.scene.arm_dof_adr] = np.diag(slope[0])
        return residuals, jacobian

    def _speed_excess(self, qdot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The joint speed residuals of (k, 7) velocities, as one step of the running term, and their
        derivatives (diagonal, (k, 7))."""
        c = self.cost
        root = math.sqrt(c.joint_speed / self.n_steps)
        excess = np.maximum(np.abs(qdot) / self.scene.velocity_limit - c.joint_speed_margin, 0.0)
        return root * excess, root * (excess > 0) * np.sign(qdot) / self.scene.velocity_limit

    def _running_residuals(self, sensordata: np.ndarray,
                           derivatives: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Residuals of every step, (T, k), and (with `derivatives`, else None) their derivatives with respect
        to the step's used sensor rows, (T, k, rows): end-effector velocity (3), the virtual force (1, with it),
        joint speeds (7) and positions (7) beyond their margins, the contact term (1: the plate-object gap),
        and CCCM's complementarity with the slack eliminated (1: phi gamma)."""
        w, c, T = self.weights, self.cost, self.n_steps
        used = {name: slice(start, start + size) for name, start, size in (
            ("ee", 0, 3), ("gamma", 3, 1), ("local", 4, 3), ("q", 7, 7), ("qdot", 14, 7), ("gap", 21, 1))}
        blocks: list[tuple[np.ndarray, np.ndarray]] = []  # (residuals (T, k), jacobian (T, k, rows))

        def block(values: np.ndarray, rows: slice, diagonal: np.ndarray | None = None,
                  derivative: np.ndarray | None = None) -> None:
            """Residuals (T, k) on sensor `rows`, and their derivative (T, k, len(rows)) or, for one residual per
            row, its diagonal (T, k): the (T, k, k) blocks are built only with the derivatives."""
            if not derivatives:
                blocks.append((values, None))
                return
            jacobian = np.zeros((T, values.shape[1], len(self.used_rows)))
            jacobian[:, :, rows] = diagonal[:, :, None] * np.eye(values.shape[1]) if derivative is None else derivative
            blocks.append((values, jacobian))

        root = math.sqrt(self.running_factor * w.w3)
        block(root * sensordata[:, self.ee_rows], used["ee"], np.full((T, 3), root))
        if self.cost.virtual_force:
            root = math.sqrt(self.running_factor * w.w4)
            block(root * sensordata[:, [self.gamma_row]], used["gamma"], np.full((T, 1), root))
        if c.joint_speed:
            excess, slope = self._speed_excess(sensordata[:, self.qdot_rows])
            block(excess, used["qdot"], slope)
        if c.joint_position:
            root = math.sqrt(c.joint_position / T)
            q = sensordata[:, self.q_rows]
            low, high = self.soft_joint_range
            excess = np.maximum(q - high, 0.0) + np.minimum(q - low, 0.0)
            block(root * excess, used["q"], root * (excess != 0))
        if c.contact:
            gap = sensordata[:, self.gap_row]
            root = np.sqrt(c.contact * c.contact_profile) * (gap > 0)
            block((root * gap)[:, None], used["gap"], root[:, None])
        if self.slack_eliminated:
            root = math.sqrt(c.complementarity / self.steps_per_knot)
            phi, d_phi = self._signed_distance_derivative(sensordata)
            gamma = sensordata[:, self.gamma_row]
            derivative = np.concatenate([root * phi[:, None], root * gamma[:, None] * d_phi], axis=1)
            block((root * phi * gamma)[:, None], slice(used["gamma"].start, used["local"].stop),
                  derivative=derivative[:, None, :])
        residuals = np.concatenate([b[0] for b in blocks], axis=1)
        return residuals, np.concatenate([b[1] for b in blocks], axis=1) if derivatives else None

    def _variable_residuals(self, variables: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The contact model's residuals on its knot variables alone (none with CCCM's slack eliminated)."""
        if not self.variables or self.slack_eliminated:
            return np.zeros(0), np.zeros((0, *variables.shape))
        return self.contact_model.variable_residuals(variables, self.weights)

    def _signed_distance_derivative(self, sensordata: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """phi per step and its derivative with respect to the robot candidate in the object frame."""
        offset = sensordata[:, self.local_rows] - self.scene.object_candidate_in_geom
        distance = np.linalg.norm(offset, axis=1, keepdims=True)
        phi = self.signed_distance(sensordata)
        return phi, np.sign(phi)[:, None] * offset / np.maximum(distance, 1e-12)

    def signed_distance(self, sensordata: np.ndarray) -> np.ndarray:
        return self.scene.signed_distance_from_local(sensordata[..., self.local_rows])

    def terminal_cost(self, object_qpos: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """The paper's final cost c_f, the position error vector (m) and the Euler-angle error (rad)."""
        position_error, angle_error = self.task.pose_error(object_qpos)
        cost = (self.weights.w1 * float(np.sum((position_error / self.position_scale) ** 2))
                + self.weights.w2 * float(np.sum(angle_error ** 2)))
        return cost, position_error, angle_error

    # ------------------------------------------------------------------ evaluation

    def _outputs(self, states: np.ndarray, sensordata: np.ndarray, variables: np.ndarray):
        """Residual blocks (terminal, running, variables), constraints and knot mean signed distances."""
        terminal, _ = self._terminal_residuals(states[-1], derivatives=False)
        running, _ = self._running_residuals(sensordata, derivatives=False)
        extra = self._variable_residuals(variables)[0]
        phi = self.signed_distance(sensordata).reshape(self.n_knots, self.steps_per_knot).mean(axis=1)
        constraints = self._knot_constraints(phi, variables)
        values = np.zeros(0) if constraints is None else constraints.values.reshape(-1)
        return (terminal, running, extra), values, phi

    def trajectory(self, z: np.ndarray) -> Trajectory:
        """The rollout of z (usually cached), decoded."""
        evaluation = self.evaluate(z)
        return self.simulator.trajectory(self.initial_state, evaluation.states, evaluation.sensordata,
                                         self.simulator.step_controls(evaluation.knot_controls), evaluation.warnings)

    def evaluate(self, z: np.ndarray) -> Evaluation:
        z = np.asarray(z, dtype=float)
        for cached in self._cache:
            if np.array_equal(cached.z, z):
                return cached
        step_controls = self.simulator.step_controls(self.knot_controls(z))
        states, sensordata, warnings = self.simulator.rollout_batch(self.initial_state[None], step_controls[None])
        return self.remember(z, states[0], sensordata[0], warnings)

    def remember(self, z: np.ndarray, states: np.ndarray, sensordata: np.ndarray,
                 warnings: dict[str, int]) -> Evaluation:
        """The evaluation of z from its rollout (states after and sensors before each step), cached: for a
        solver that has simulated z itself."""
        z = np.asarray(z, dtype=float)
        _, variables = self.split(z)
        finite = bool(np.all(np.isfinite(states)) and np.all(np.isfinite(sensordata)))
        if finite:
            (terminal, running, extra), constraints, phi = self._outputs(states, sensordata, variables)
            residuals = np.concatenate([terminal, running.ravel(), extra])
            terms = {"terminal": float(terminal @ terminal), "running": float(np.sum(running ** 2)),
                     "variables": float(extra @ extra)}
            cost = float(residuals @ residuals)
            finite = math.isfinite(cost) and bool(np.all(np.isfinite(constraints)))
        else:
            terms, cost, residuals = {}, math.inf, np.zeros(0)
            constraints, phi = np.full(self.n_constraints, math.nan), np.full(self.n_knots, math.nan)
        position_error = float(np.linalg.norm(self.task.pose_error(self.scene.object_qpos(states[-1]))[0])) \
            if finite else math.nan
        evaluation = Evaluation(z.copy(), self.knot_controls(z), states, sensordata, warnings, cost, terms,
                                constraints, phi, finite, residuals, position_error)
        self._cache = [evaluation, *self._cache[:CACHED_EVALUATIONS - 1]]
        return evaluation

    # ------------------------------------------------------------------ derivatives

    def gradient(self, z: np.ndarray) -> np.ndarray:
        return self.derivatives(z).gradient

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        return self.derivatives(z).jacobian

    def residuals(self, z: np.ndarray) -> np.ndarray:
        """The residual vector r (the cost is r . r)."""
        return self.evaluate(z).residuals

    def derivatives(self, z: np.ndarray, *, cached: bool = True) -> Evaluation:
        """Evaluation with the cost gradient (size,) and constraint Jacobian (n_constraints, size);
        cached=False computes them, and the linearization they come from, again."""
        evaluation = self._finite(z)
        if cached and evaluation.gradient is not None:
            return evaluation
        if not cached:
            evaluation.linearization = None
        if self.derivative_settings.method == "forward_differences":
            info = {"restarted_knots": self.n_knots}
            d_dynamics, d_phi = self._restart_differences(evaluation, self.n_knots)
        else:
            d_dynamics, d_phi, info = self._adjoint(evaluation)
        gradient = d_dynamics
        if self.variables:
            _, variables = self.split(evaluation.z)
            values, derivative = self._variable_residuals(variables)
            gradient = gradient + self._knot_layout(2 * np.einsum("k,kln->ln", values, derivative))
        evaluation.gradient, evaluation.jacobian = gradient, self._constraint_jacobian(evaluation, d_phi)
        evaluation.derivative_info = info
        return evaluation

    def residual_jacobian(self, z: np.ndarray) -> np.ndarray:
        """dr/dz (len(r), size): forward sensitivities through the per-step linearizations, with
        knot-restart differences for the knots up to a step whose linearization is unreliable."""
        evaluation = self._finite(z)
        if evaluation.residual_jacobian is not None:
            return evaluation.residual_jacobian
        if self.derivative_settings.method == "forward_differences":
            jacobian = np.zeros((len(evaluation.residuals), self.size))
            dynamic = self._restart_differences(evaluation, self.n_knots, residuals=True)[1]
            jacobian[:len(dynamic)] = dynamic
            if self.variables:
                _, variables = self.split(evaluation.z)
                _, derivative = self._variable_residuals(variables)
                if len(derivative):
                    jacobian[len(dynamic):] = np.stack([self._knot_layout(d) for d in derivative])
            evaluation.residual_jacobian, evaluation.derivative_info = jacobian, {"restarted_knots": self.n_knots}
            return jacobian
        linearization = self.linearize(z)
        S, N, nu = self.steps_per_knot, self.n_knots, self.scene.model.nu
        d_sensors, d_final = derivatives.forward_sensitivities(
            linearization.A, linearization.B, linearization.C[:, self.used_rows, :],
            linearization.D[:, self.used_rows, :], S)
        _, terminal_jacobian = self._terminal_residuals(evaluation.states[-1])
        _, running_jacobian = self._running_residuals(evaluation.sensordata)
        by_controls = np.concatenate([terminal_jacobian @ d_final,
                                      np.einsum("tkr,trc->tkc", running_jacobian, d_sensors).reshape(-1, N * nu)])
        jacobian = np.zeros((len(evaluation.residuals), self.size))
        rows = by_controls.shape[0]
        jacobian[:rows] = self._to_decisions(by_controls.reshape(rows, N, nu))
        if self.variables:
            _, variables = self.split(evaluation.z)
            _, derivative = self._variable_residuals(variables)
            if len(derivative):
                jacobian[rows:] = np.stack([self._knot_layout(d) for d in derivative])
        info = {**linearization.info(), "restarted_knots": 0}
        unresolved = linearization.unresolved_steps
        if unresolved.size:
            knots = int(unresolved.max() // S) + 1
            info["restarted_knots"] = knots
            columns = slice(0, knots * self.width)
            jacobian[:rows, columns] = self._restart_differences(evaluation, knots, residuals=True)[1][:rows, columns]
        evaluation.residual_jacobian, evaluation.derivative_info = jacobian, info
        return jacobian

    def _finite(self, z: np.ndarray) -> Evaluation:
        evaluation = self.evaluate(z)
        if not evaluation.finite:
            raise FloatingPointError("the rollout is not finite; no derivatives")
        return evaluation

    def states_before(self, evaluation: Evaluation) -> np.ndarray:
        """(T, nstate): the state each step of an evaluation starts from."""
        return np.vstack([self.initial_state[None], evaluation.states[:-1]])

    def linearize(self, z: np.ndarray) -> derivatives.Linearization:
        """The per-step linearization of the rollout of z.

        Without the virtual force, nothing the controls do reaches the object before the arm first
        touches it (the dynamics are block-diagonal there), and nothing that reaches the object
        then acts back on the arm: the object's columns of those steps are left out (zero), which
        changes no derivative of the cost with respect to the decisions."""
        evaluation = self.evaluate(z)
        if evaluation.linearization is not None:
            return evaluation.linearization
        states_before = self.states_before(evaluation)
        untouched = 0
        if not self.cost.virtual_force:
            touching = np.flatnonzero(evaluation.sensordata[:, self.scene.sensors.contact_found.start] > 0)
            untouched = int(touching[0]) if touching.size else self.n_steps
        with self.simulator.clock.measure("linearization"):
            evaluation.linearization = derivatives.linearize(
                self.scene.model, self._linearization_data, states_before,
                self.simulator.step_controls(evaluation.knot_controls), self.derivative_settings.epsilon,
                self.scene.object_dofs, untouched)
        return evaluation.linearization

    def _adjoint(self, evaluation: Evaluation):
        """d(dynamic cost terms)/dz and d(knot mean phi)/dz through the dynamics, by the adjoint pass."""
        linearization = self.linearize(evaluation.z)
        T, S, N = self.n_steps, self.steps_per_knot, self.n_knots
        m = self.n_constraints_per_knot
        n_out = 1 + (N if m else 0)  # the cost, then the knot mean signed distances
        # d(cost)/d(sensors) = 2 G_t^T rho_t per step; d(knot mean phi)/d(sensors) for the constraints
        running, running_jacobian = self._running_residuals(evaluation.sensordata)
        weights = np.zeros((T, len(self.used_rows), n_out))
        weights[:, :, 0] = 2 * np.einsum("tk,tkr->tr", running, running_jacobian)
        if m:
            _, d_phi_d_local = self._signed_distance_derivative(evaluation.sensordata)
            weights[np.arange(T), 4:7, 1 + np.arange(T) // S] = d_phi_d_local / S
        terminal, terminal_jacobian = self._terminal_residuals(evaluation.states[-1])
        seed = np.zeros((2 * self.scene.model.nv, n_out))
        seed[:, 0] = 2 * terminal_jacobian.T @ terminal
        d_controls = derivatives.adjoint(linearization.A, linearization.B, linearization.C[:, self.used_rows, :],
                                         linearization.D[:, self.used_rows, :], weights, seed, S)

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

    def _control_column(self) -> int | None:
        """The knot variable that is the contact control, if the decisions include it."""
        return self.contact_model.control_variable if self.variables else None

    def _to_decisions(self, d_knot_controls: np.ndarray) -> np.ndarray:
        """Map d/d(knot controls) (..., N, nu) to d/dz (..., size) (through the dynamics only)."""
        lead = d_knot_controls.shape[:-2]
        gradient = np.zeros((*lead, self.n_knots, self.width))
        gradient[..., :self.n_joints] = d_knot_controls[..., self.scene.motor_ids]
        index = self._control_column()
        if index is not None:
            gradient[..., self.n_joints + index] = d_knot_controls[..., self.scene.contact_actuator_id]
        return gradient.reshape(*lead, self.size)

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
        constraints = self._knot_constraints(evaluation.knot_signed_distance, variables)
        for l in range(self.n_knots):
            for c in range(m):
                row = l * m + c
                jacobian[row] = constraints.d_phi[l, c] * d_phi[l]
                start = l * self.width + self.n_joints
                jacobian[row, start:start + len(self.variables)] += constraints.d_variables[l, c]
        return jacobian

    def _restart_differences(self, evaluation: Evaluation, knots: int, residuals: bool = False):
        """Knot-restart forward differences (cito_ros.derivatives.restart_differences) for the first
        `knots` knots: d(dynamic cost)/dz and d(knot mean phi)/dz, or with residuals=True the
        dynamic cost's derivative and d(terminal and running residuals)/dz."""
        _, variables = self.split(evaluation.z)
        control = self._control_column()
        acting = [c for c in range(self.width) if c < self.n_joints or c - self.n_joints == control]
        columns = [np.array([knot * self.width + c for c in acting]) for knot in range(knots)]
        steps = self.derivative_settings.restart_step * self.scale
        steps = np.where(evaluation.z + steps > self.upper, -steps, steps)

        def outputs(states, sensordata):
            (terminal, running, _), _, phi = self._outputs(states, sensordata, variables)
            dynamic = float(terminal @ terminal) + float(np.sum(running ** 2))
            if residuals:
                return dynamic, np.concatenate([terminal, running.ravel()])
            return dynamic, phi if self.n_constraints_per_knot else None

        states_before = self.states_before(evaluation)
        with self.simulator.clock.measure("linearization"):
            return derivatives.restart_differences(
                self.simulator, states_before, evaluation.states, evaluation.sensordata, evaluation.z, columns,
                steps, lambda z: self.simulator.step_controls(self.knot_controls(z)), outputs)

    # ------------------------------------------------------------------ knot-wise model (iLQR)

    def decision_actuators(self) -> np.ndarray:
        """(width,) int32: the actuator each decision of a knot drives, -1 for none (a contact variable)."""
        actuators = np.full(self.width, -1, dtype=np.int32)
        actuators[:self.n_joints] = self.scene.motor_ids
        index = self._control_column()
        if index is not None:
            actuators[self.n_joints + index] = self.scene.contact_actuator_id
        return actuators

    def decision_map(self) -> np.ndarray:
        """(nu, width): the actuator controls of one knot as a linear map of its decisions."""
        P = np.zeros((self.scene.model.nu, self.width))
        actuators = self.decision_actuators()
        driving = np.flatnonzero(actuators >= 0)
        P[actuators[driving], driving] = 1.0
        return P

    def knot_expansion(self, z: np.ndarray) -> KnotExpansion:
        """The cost and dynamics of z expanded knot by knot to second (Gauss-Newton) and first order:
        the state at each knot start, the knot-to-knot Jacobians, and the derivatives of each knot's
        running cost and of the terminal cost with respect to the knot's start state and decisions."""
        evaluation = self._finite(z)
        linearization = self.linearize(z)
        S, N, w = self.steps_per_knot, self.n_knots, self.width
        nx = 2 * self.scene.model.nv
        running, G = self._running_residuals(evaluation.sensordata)
        # the actuators no decision drives left out: without the virtual force, the contact law's
        # derivative at zero control is infinite wherever the plate's centre is inside the object
        # (k exp(-(c/k) phi) for phi < 0), and 0 * inf would make the whole knot's expansion NaN
        P = self.decision_map()
        driven = np.flatnonzero(P.any(axis=1))
        P, B = P[driven], linearization.B[:, :, driven]
        C, D = linearization.C[:, self.used_rows, :], linearization.D[:, self.used_rows][:, :, driven]
        X = np.repeat(np.eye(nx)[None], N, axis=0)   # d x_t / d x_l, all knots at once
        U = np.zeros((N, nx, w))                       # d x_t / d c_l
        Jx, Jc, r = [], [], []  # each knot's running residuals and their Jacobians, step by step
        for j in range(S):
            steps = np.arange(N) * S + j
            Jx.append(G[steps] @ (C[steps] @ X))
            Jc.append(G[steps] @ (C[steps] @ U + D[steps] @ P))
            r.append(running[steps][..., None])
            X = linearization.A[steps] @ X
            U = linearization.A[steps] @ U + B[steps] @ P
        # stacked over the knot's steps, the sums over steps are batched products
        Jx, Jc, r = np.concatenate(Jx, axis=1), np.concatenate(Jc, axis=1), np.concatenate(r, axis=1)
        lx, lc = 2 * (Jx.mT @ r)[..., 0], 2 * (Jc.mT @ r)[..., 0]
        lxx, lcc, lcx = 2 * (Jx.mT @ Jx), 2 * (Jc.mT @ Jc), 2 * (Jc.mT @ Jx)
        if self.variables:
            _, variables = self.split(z)
            values, derivative = self._variable_residuals(variables)
            for value, d in zip(values, derivative):  # each residual acts on one knot's variables
                knot = int(np.argmax(np.abs(d).sum(axis=1)))
                g = np.zeros(w)
                g[self.n_joints:] = d[knot]
                lc[knot] += 2 * value * g
                lcc[knot] += 2 * np.outer(g, g)
        terminal, JT = self._terminal_residuals(evaluation.states[-1])
        knot_states = np.vstack([self.initial_state[None], evaluation.states[S - 1::S]])
        return KnotExpansion(knot_states, X, U, lx, lc, lxx, lcc, lcx, 2 * JT.T @ terminal, 2 * JT.T @ JT,
                             {**linearization.info(), "restarted_knots": 0})
