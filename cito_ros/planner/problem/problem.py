"""The single-shooting push problem of the paper (section II.C): `PushProblem`, what a solver sees
(cito_ros.planner.solvers.base.NlpProblem): size, bounds, scales, `evaluate` (cost and constraints,
cached), `gradient` and `jacobian`.

It is put together from one part per concern: the decision layout and bounds (`layout`), the
residuals (`residuals`), the derivatives (`derivatives`); this module owns the construction and the
evaluation cache (the latest rollouts and everything computed from them).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from cito_ros.model.scene import ARM_JOINTS
from cito_ros.model.simulator import Simulator, Trajectory
from cito_ros.planner.problem import rollout_derivatives
from cito_ros.planner.problem.derivatives import ProblemDerivatives
from cito_ros.planner.problem.layout import DecisionLayout
from cito_ros.planner.problem.residuals import Residuals, StageCost
from cito_ros.planner.task import PushTask
from cito_ros.settings import DerivativeSettings

CACHED_EVALUATIONS = 6


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
    linearization: rollout_derivatives.Linearization | None = None  # shared by the gradient and the residual Jacobian
    derivative_info: dict[str, int] = field(default_factory=dict)


class PushProblem(DecisionLayout, Residuals, ProblemDerivatives):
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
        self.initial_position_error_m = float(np.linalg.norm(self.initial_object_position - task.aim_m))
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

    @functools.cached_property
    def _linearization_data(self) -> tuple[mujoco.MjData, ...]:
        # one mjData per linearization thread, owned here (the native code keeps none); made on the first
        # linearization: a problem that is only evaluated (the replans' touch profile) needs none
        return tuple(mujoco.MjData(self.scene.model) for _ in range(self.derivative_settings.threads))

    def residuals(self, z: np.ndarray) -> np.ndarray:
        """The residual vector r (the cost is r . r)."""
        return self.evaluate(z).residuals

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
