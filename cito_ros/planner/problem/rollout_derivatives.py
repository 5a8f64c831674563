"""Derivatives of a rollout: per-step linearizations, the adjoint pass, knot-restart differences.

ROS-free. Every simulation step t is linearized natively (`_native.linearize`:
finite differences that skip the pipeline stages a perturbation cannot change,
spread over threads, a position perturbation that makes or breaks a contact
retried on the other side):

    x_{t+1} = f(x_t, u_t):  A_t = df/dx, B_t = df/du;    s_t = h(x_t, u_t):  C_t = dh/dx, D_t = dh/du

`adjoint` is the pure reverse pass that turns them, with the derivatives of the
outputs with respect to the sensors and the final state, into the derivatives
of those outputs with respect to every knot's controls. `restart_differences`
is the fallback for steps whose linearization is unreliable (contacts switch on
both sides of a perturbation): forward differences of whole rollouts, each
restarted from the saved state at its knot and batched through mujoco.rollout.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cito_ros.model import _native


@dataclass(frozen=True)
class Linearization:
    """Per-step Jacobians of one rollout (T steps; tangent-space states, nx = 2 nv)."""

    A: np.ndarray      # (T, nx, nx)
    B: np.ndarray      # (T, nx, nu)
    C: np.ndarray      # (T, ns, nx)
    D: np.ndarray      # (T, ns, nu)
    flags: np.ndarray  # (T, 3): one-sided columns, unresolved columns, MuJoCo warnings

    @property
    def unresolved_steps(self) -> np.ndarray:
        return np.nonzero(self.flags[:, 1])[0]

    def spread(self, steps: np.ndarray, count: int) -> Linearization:
        """This linearization of the steps `steps` (increasing, from 0) of a rollout of `count` steps spread over
        them all: each step between takes the Jacobians of the linearized one before it, and no flags (they
        count what was computed)."""
        source = np.searchsorted(steps, np.arange(count), side="right") - 1
        flags = np.zeros((count, 3), dtype=self.flags.dtype)
        flags[steps] = self.flags
        return Linearization(self.A[source], self.B[source], self.C[source], self.D[source], flags)

    def info(self) -> dict[str, int]:
        return {"one_sided_columns": int(self.flags[:, 0].sum()), "unresolved_columns": int(self.flags[:, 1].sum()),
                "linearization_warnings": int(self.flags[:, 2].sum())}


def linearize(model: mujoco.MjModel, datas: tuple[mujoco.MjData, ...], states_before: np.ndarray,
              step_controls: np.ndarray, epsilon: float, skip_dofs: np.ndarray | None = None,
              skip_steps: int = 0) -> Linearization:
    """Linearize every step t from states_before[t] (T, nstate) under step_controls[t] (T, nu), on one
    thread per mjData in `datas` (overwritten). The position and velocity columns of A and C of the
    dofs `skip_dofs` (indices) are zero, not computed, in the steps t < skip_steps."""
    T = len(states_before)
    nx, nu, ns = 2 * model.nv, model.nu, model.nsensordata
    A, B = np.empty((T, nx, nx)), np.empty((T, nx, nu))
    C, D = np.empty((T, ns, nx)), np.empty((T, ns, nu))
    flags = np.zeros((T, 3), dtype=np.int32)
    skip = np.zeros(model.nv, dtype=np.int32)
    if skip_dofs is not None:
        skip[skip_dofs] = 1
    _native.linearize(model._address, tuple(d._address for d in datas), T, np.ascontiguousarray(states_before),
                      np.ascontiguousarray(step_controls), epsilon, skip, skip_steps, A, B, C, D, flags)
    return Linearization(A, B, C, D, flags)


def adjoint(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, sensor_weights: np.ndarray,
            terminal: np.ndarray, steps_per_knot: int) -> np.ndarray:
    """Derivatives of n_out outputs with respect to each knot's controls, (N, nu, n_out).

    The outputs are y = sum_t w_t . s_t + g(x_T) over the sensors s_t that matter: C (T, ns, nx) and
    D (T, ns, nu) restricted to them, sensor_weights (T, ns, n_out) = dy/ds_t, terminal (nx, n_out) =
    dy/dx_T. The backward recursion lambda_t = A_t^T lambda_{t+1} + C_t^T w_t is the only sequential
    part; dy/du_t = B_t^T lambda_{t+1} + D_t^T w_t, summed over each knot's steps_per_knot steps.
    """
    T, nx = A.shape[0], A.shape[1]
    sensor_terms = np.einsum("tsi,tso->tio", C, sensor_weights)
    adjoints = np.empty((T + 1, nx, terminal.shape[1]))
    adjoints[T] = terminal
    A_transposed = A.transpose(0, 2, 1)
    for t in range(T - 1, -1, -1):
        adjoints[t] = A_transposed[t] @ adjoints[t + 1] + sensor_terms[t]
    per_step = np.einsum("tiu,tio->tuo", B, adjoints[1:]) + np.einsum("tsu,tso->tuo", D, sensor_weights)
    return per_step.reshape(T // steps_per_knot, steps_per_knot, B.shape[2], terminal.shape[1]).sum(axis=1)


def restart_differences(simulator, states_before: np.ndarray, states: np.ndarray, sensordata: np.ndarray,
                        z: np.ndarray, columns: list[np.ndarray], steps: np.ndarray, step_controls, outputs):
    """Forward differences of a rollout's outputs for the decision columns of the first knots.

    columns[l] are knot l's columns (those that act on the dynamics), steps the signed difference step
    of every column, step_controls(z) the (T, nu) controls of a decision vector and outputs(states,
    sensordata) -> (value, vector or None) the outputs. Each perturbation is rolled out from the
    saved state states_before[l * S] at the start of its knot; the steps before it are reused.
    Returns d(value)/dz (size,) and d(vector)/dz (len(vector), size) or None.
    """
    S = simulator.steps_per_knot
    base_value, base_vector = outputs(states, sensordata)
    d_value = np.zeros(len(z))
    d_vector = None if base_vector is None else np.zeros((len(base_vector), len(z)))
    for knot, knot_columns in enumerate(columns):
        batch = np.zeros((len(knot_columns), len(states) - knot * S, simulator.model.nu))
        for row, column in enumerate(knot_columns):
            perturbed = z.copy()
            perturbed[column] += steps[column]
            batch[row] = step_controls(perturbed)[knot * S:]
        start = np.repeat(states_before[knot * S][None], len(knot_columns), axis=0)
        knot_states, knot_sensors, _ = simulator.rollout_batch(start, batch)
        for row, column in enumerate(knot_columns):
            value, vector = outputs(np.vstack([states[:knot * S], knot_states[row]]),
                                    np.vstack([sensordata[:knot * S], knot_sensors[row]]))
            d_value[column] = (value - base_value) / steps[column]
            if d_vector is not None:
                d_vector[:, column] = (vector - base_vector) / steps[column]
    return d_value, d_vector


def forward_sensitivities(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray,
                          steps_per_knot: int) -> tuple[np.ndarray, np.ndarray]:
    """Sensitivities of the sensors and the final state to every knot's controls.

    With X_t = dx_t/dc and U_t = du_t/dc (knot l's controls held over its steps), the recursion
    X_{t+1} = A_t X_t + B_t U_t gives dS_t/dc = C_t X_t + D_t U_t for the sensor rows of C and D
    (T, ns, nx) and (T, ns, nu). Returns dS (T, ns, N nu) and X_T (nx, N nu), columns knot-major.
    Columns of knots after step t are zero at t (causality), so each step multiplies only the
    columns of the knots so far.
    """
    T, nx, nu = A.shape[0], A.shape[1], B.shape[2]
    N = T // steps_per_knot
    X = np.zeros((nx, N * nu))
    dS = np.zeros((T, C.shape[1], N * nu))
    for t in range(T):
        knot = t // steps_per_knot
        past, own = slice(0, knot * nu), slice(knot * nu, (knot + 1) * nu)
        dS[t, :, past] = C[t] @ X[:, past]
        dS[t, :, own] = C[t] @ X[:, own] + D[t]
        X[:, past] = A[t] @ X[:, past]
        X[:, own] = A[t] @ X[:, own] + B[t]
    return dS, X
