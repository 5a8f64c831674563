"""What a stage minimizes, as residuals r with cost = r . r: the paper's eqs. (8)-(9) and the terms
beyond the paper (see `StageCost`).

    c_f = w1 ||(p_T - p*) / max(||p_0 - p*||, d_min)||^2 + w2 ||theta_T||^2
    c_i = (t_c / N) sum_l (w3 <||xdot||^2>_l + w4 <gamma^2>_l)

with theta_T the Euler angles (roll, pitch, yaw) of the object's rotation relative to the target,
and <.>_l the mean over knot l's simulation steps of the end-effector (plate centre) speed squared
and the virtual force squared (+ w5 sum s^2 for CCCM). `Residuals` is the part of `PushProblem`
that computes them from a rollout's final state and per-step sensors, with their derivatives with
respect to those when asked.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from cito_ros.settings import Weights


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
    orientation_equivalent_m_per_rad: the final orientation's weight at least w1 (this / position scale)^2: a turn
      weighs at least as much as this many metres per radian of position error (0: w2 alone)
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
    orientation_equivalent_m_per_rad: float = 0.0

    @classmethod
    def paper(cls, weights: Weights) -> "StageCost":
        return cls(weights, True, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, None)


class Residuals:
    """The terminal, running and knot-variable residuals of a rollout, and the knot constraints' values."""

    def _terminal_residuals(self, final_state: np.ndarray,
                            derivatives: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Residuals of the final state, and (with `derivatives`, else None) their derivatives with respect to
        it (tangent space): position (3) and Euler angles (3) against the aim (PushTask.aim_m), then the object's
        velocity (6), then the joint speeds beyond their margin (7: the running term sees the steps' start states
        only)."""
        w, c, nv = self.weights, self.cost, self.scene.model.nv
        dof = self.scene.object_dof_adr
        object_qpos = self.scene.object_qpos(final_state)
        position_error, angle_error = self.task.aim_error(object_qpos)
        position_root = math.sqrt(w.w1) / self.position_scale
        angle_root = max(math.sqrt(w.w2), position_root * c.orientation_equivalent_m_per_rad)
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

    def _outputs(self, states: np.ndarray, sensordata: np.ndarray, variables: np.ndarray):
        """Residual blocks (terminal, running, variables), constraints and knot mean signed distances."""
        terminal, _ = self._terminal_residuals(states[-1], derivatives=False)
        running, _ = self._running_residuals(sensordata, derivatives=False)
        extra = self._variable_residuals(variables)[0]
        phi = self.signed_distance(sensordata).reshape(self.n_knots, self.steps_per_knot).mean(axis=1)
        constraints = self._knot_constraints(phi, variables)
        values = np.zeros(0) if constraints is None else constraints.values.reshape(-1)
        return (terminal, running, extra), values, phi
