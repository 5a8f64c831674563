"""The decision layout of a push problem and its bounds: what each entry of z is.

Decision vector z, knot-major: at each of the N knots, the 7 joint torques u_l, then the contact
model's knot variables (VSCM: k_l; CCCM: gamma_l, s_l; SCM: none). A stage without the virtual
force has the torques alone and the contact control held at 0. `DecisionLayout` is the part of
`PushProblem` that maps z to actuator controls and back; it relies on the attributes
`PushProblem.__init__` sets (n_knots, n_joints, width, size, variables, cost, scene, contact_model,
initial_guess, slack_eliminated).
"""
from __future__ import annotations

import numpy as np


class DecisionLayout:
    """z <-> knot torques, contact variables and actuator controls; the constraints' bounds."""

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

    def _control_column(self) -> int | None:
        """The knot variable that is the contact control, if the decisions include it."""
        return self.contact_model.control_variable if self.variables else None

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
