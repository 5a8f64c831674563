"""The exact derivatives of a push problem: the gradient and constraint Jacobian (an adjoint pass over
the per-step linearizations, cito_ros.planner.problem.rollout_derivatives), the residual Jacobian
(forward sensitivities) and the knot-wise Gauss-Newton expansion iLQR takes, with knot-restart
differences where a contact switch makes a step's linearization unreliable. `ProblemDerivatives` is
the part of `PushProblem` that computes them from its cached evaluations.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cito_ros.planner.problem import rollout_derivatives

if TYPE_CHECKING:  # the evaluation cache's record, which these derivatives are stored in
    from cito_ros.planner.problem.problem import Evaluation


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


class ProblemDerivatives:
    """Gradient, constraint Jacobian, residual Jacobian and knot-wise expansion of z, from its evaluation."""

    def gradient(self, z: np.ndarray) -> np.ndarray:
        return self.derivatives(z).gradient

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        return self.derivatives(z).jacobian

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
        d_sensors, d_final = rollout_derivatives.forward_sensitivities(
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

    def linearize(self, z: np.ndarray) -> rollout_derivatives.Linearization:
        """The per-step linearization of the rollout of z.

        Without the virtual force, nothing the controls do reaches the object before the arm first
        touches it (the dynamics are block-diagonal there), and nothing that reaches the object
        then acts back on the arm: the object's columns of those steps are left out (zero), which
        changes no derivative of the cost with respect to the decisions."""
        evaluation = self.evaluate(z)
        if evaluation.linearization is not None:
            return evaluation.linearization
        states = self.states_before(evaluation)
        controls = self.simulator.step_controls(evaluation.knot_controls)
        found = evaluation.sensordata[:, self.scene.sensors.contact_found.start] > 0
        untouched = 0
        if not self.cost.virtual_force:
            touching = np.flatnonzero(found)
            untouched = int(touching[0]) if touching.size else self.n_steps
        steps = self._linearized_steps(found)
        if steps is not None:  # only those steps: the rest take the one before's (spread below)
            states, controls, untouched = states[steps], controls[steps], int(np.searchsorted(steps, untouched))
        with self.simulator.clock.measure("linearization"):
            evaluation.linearization = rollout_derivatives.linearize(
                self.scene.model, self._linearization_data, states, controls, self.derivative_settings.epsilon,
                self.scene.object_dofs, untouched)
        if steps is not None:
            evaluation.linearization = evaluation.linearization.spread(steps, self.n_steps)
        return evaluation.linearization

    def _linearized_steps(self, found: np.ndarray) -> np.ndarray | None:
        """The steps linearized (None: every one): every gradient.stride-th, and where the plate's contact with the
        object (`found`, per step) begins or ends (an impact's Jacobians are like no step's around it: copied from
        the step before, they turned a strike's gradient around): at every such step, or with gradient.switches
        `ends` only at the first and the last (a plate chattering on the face switches at a third of the steps)."""
        stride, T = self.derivative_settings.stride, self.n_steps
        if stride == 1:
            return None
        switch = np.flatnonzero(found[1:] != found[:-1])
        if self.derivative_settings.switches == "ends":
            switch = switch[[0, -1]] if switch.size else switch
        return np.unique(np.concatenate([np.arange(0, T, stride), switch, switch + 1]))

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
        d_controls = rollout_derivatives.adjoint(linearization.A, linearization.B, linearization.C[:, self.used_rows, :],
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
        """Knot-restart forward differences (rollout_derivatives.restart_differences) for the first
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
            return rollout_derivatives.restart_differences(
                self.simulator, states_before, evaluation.states, evaluation.sensordata, evaluation.z, columns,
                steps, lambda z: self.simulator.step_controls(self.knot_controls(z)), outputs)

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
