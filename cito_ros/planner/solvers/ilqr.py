"""Box-constrained iterative LQR behind the solver seam: Gauss-Newton over the knots' decisions with
a feedback-stabilized forward pass.

The decisions stay the paper's: piecewise-constant knot controls rolled out open loop. What iLQR
adds is how a step is found. The backward pass takes the knot-wise Gauss-Newton expansion of the
cost (cito_ros.planner.problem.PushProblem.knot_expansion: the residuals' exact Jacobians through the
per-step linearizations) and solves, knot by knot from the end, a box-constrained quadratic
program (mju_boxQP) for a feedforward change k_l and a feedback gain K_l on the deviation of the
knot's start state. The forward pass then rolls out c_l = c_l + a k_l + K_l (x_l - x_l) for several
step lengths a, natively and side by side on the simulator's threads (Simulator.feedback_rollouts),
and keeps the best: the feedback keeps
each trial near the trajectory the expansion was taken about, where contact events make open-loop
steps leave the model's region of validity after a few hundredths of a newton metre (the failure
of a plain Gauss-Newton step here).
The controls a trial applies are its new decisions, so its open-loop rollout is the same motion.

Regularization: mu (Levenberg-Marquardt on the scaled decisions) falls after an iteration whose
full step was kept and rises after a failed one. The shared stopping rules run in IterationMonitor.
"""
from __future__ import annotations

import math

import mujoco
import numpy as np

from cito_ros.planner.results import Status
from cito_ros.planner.solvers.base import IterationMonitor, StageOutcome
from cito_ros.settings import SolverSettings


class IlqrSolver:
    """Solves one box-bounded stage of a PushProblem by iLQR (settings `solver.ilqr`)."""

    violation_tolerance = 0.0

    def __init__(self, settings: SolverSettings):
        self.settings = settings
        options = settings.ilqr_options
        self.mu, self.mu_min, self.mu_max = options["mu_initial"], options["mu_min"], options["mu_max"]
        self.mu_factor = options["mu_factor"]
        self.step_lengths = np.asarray(options["step_lengths"], dtype=float)
        self.accept_ratio = options["accept_ratio"]
        self.tolerance = options["tolerance"]
        self.gains: np.ndarray | None = None  # (N, w, nx) of the last backward pass whose step was kept

    def solve(self, problem, start: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              monitor: IterationMonitor) -> StageOutcome:
        if problem.n_constraints:
            raise ValueError("iLQR takes box-bounded problems only (no CCCM constraints)")
        N, w = problem.n_knots, problem.width
        scale = problem.scale.reshape(N, w)
        lower, upper = lower.reshape(N, w), upper.reshape(N, w)
        z = np.clip(start, lower.reshape(-1), upper.reshape(-1))
        point = problem.evaluate(z)
        if not point.finite:
            return monitor.outcome(z, Status.NUMERICAL_ERROR, point, 0.0)
        mu, status, iteration = self.mu, Status.ITERATION_LIMIT, 0
        stop = monitor.record(0, point.cost, 0.0, point, 0.0)
        while stop is None and iteration < self.settings.max_iter:
            iteration += 1
            expansion = problem.knot_expansion(z)
            accepted = False
            while not accepted and mu <= self.mu_max:
                gains = _backward(expansion, z.reshape(N, w), lower, upper, scale, mu)
                if gains is None:
                    mu = max(mu * self.mu_factor, self.mu_min)
                    continue
                k, K, expected = gains
                if -expected <= self.tolerance * max(1.0, point.cost):
                    status, stop = Status.CONVERGED, Status.CONVERGED
                    break
                # every step length tried, the best kept: contact makes the cost along the step anything
                # but the model's parabola, and a short step can win where a long one fails
                trials = _forward(problem, expansion, z.reshape(N, w), k, K, self.step_lengths, lower, upper)
                best = min(range(len(trials)), key=lambda i: trials[i].cost if trials[i].finite else math.inf)
                trial, alpha = trials[best], self.step_lengths[best]
                if trial.finite and trial.cost < point.cost and \
                        (point.cost - trial.cost) / (-expected * alpha) >= self.accept_ratio:
                    z, point, accepted, self.gains = trial.z, trial, True, K
                if accepted:
                    mu = self._after_step(mu, alpha)
                else:
                    mu = max(mu * self.mu_factor, self.mu_min)
            if stop is not None:
                break
            if not accepted:
                status = Status.STALLED
                break
            stop = monitor.record(iteration, point.cost, 0.0, point, 0.0)
        if stop is not None and stop is not Status.CONVERGED:
            status = stop
        return monitor.outcome(z, status, point, 0.0)

    def _after_step(self, mu: float, alpha: float) -> float:
        """mu after a step of length alpha was accepted: lower only after a full-length step. The step
        length the line search kept says how far the Gauss-Newton model held; lowering mu after every
        success, as plain Levenberg-Marquardt does, made every other iteration pay for a failed trial
        (four rollouts), because contact leaves the model's region of validity after a tenth of the
        step in most iterations (docs/experiments.md)."""
        if alpha >= self.step_lengths.max():
            return mu / self.mu_factor if mu / self.mu_factor >= self.mu_min else 0.0
        return mu


def feedback_gains(problem, z: np.ndarray, mu: float) -> np.ndarray:
    """The gains K (N, w, nx) of one backward pass at z (regularized by mu on the scaled decisions): the
    time-varying feedback on the knot-start state deviation that keeps a rollout near z's; zero for a decision
    at its bound. For a plan that was not reached by a kept iLQR step."""
    N, w = problem.n_knots, problem.width
    expansion = problem.knot_expansion(z)
    while mu <= 1e12:
        gains = _backward(expansion, np.asarray(z).reshape(N, w), problem.lower.reshape(N, w),
                          problem.upper.reshape(N, w), problem.scale.reshape(N, w), mu)
        if gains is not None:
            return gains[1]
        mu = max(10.0 * mu, 1e-6)
    return np.zeros((N, w, 2 * problem.scene.model.nv))


def _backward(expansion, decisions: np.ndarray, lower: np.ndarray, upper: np.ndarray, scale: np.ndarray,
              mu: float):
    """Feedforward changes k (N, w), gains K (N, w, nx) and the expected cost change of a full step,
    or None when a knot's quadratic program is not positive definite."""
    N, w = decisions.shape
    nx = expansion.vx.shape[0]
    vx, vxx = expansion.vx.copy(), expansion.vxx.copy()
    k, K = np.zeros((N, w)), np.zeros((N, w, nx))
    expected = 0.0
    scratch = np.zeros((w, w + 7))
    for l in range(N - 1, -1, -1):
        fx, fc = expansion.fx[l], expansion.fc[l]
        qx = expansion.lx[l] + fx.T @ vx
        qc = expansion.lc[l] + fc.T @ vx
        qxx = expansion.lxx[l] + fx.T @ vxx @ fx
        qcc = expansion.lcc[l] + fc.T @ vxx @ fc
        qcx = expansion.lcx[l] + fc.T @ vxx @ fx
        d = scale[l]  # the quadratic program in scaled decisions, regularized there
        hessian = np.ascontiguousarray(d[:, None] * qcc * d[None, :] + mu * np.eye(w))
        gradient = (d * qc)[:, None]
        step = np.zeros((w, 1))
        free = mujoco.mju_boxQP(step, scratch, None, hessian, gradient,
                                ((lower[l] - decisions[l]) / d)[:, None], ((upper[l] - decisions[l]) / d)[:, None])
        if free < 0:
            return None
        step = step[:, 0]
        clamped = (step <= (lower[l] - decisions[l]) / d + 1e-12) | (step >= (upper[l] - decisions[l]) / d - 1e-12)
        gain = np.zeros((w, nx))
        if not clamped.all():
            f = ~clamped
            try:
                gain[f] = -np.linalg.solve(hessian[np.ix_(f, f)], (d[:, None] * qcx)[f])
            except np.linalg.LinAlgError:
                return None
        k[l], K[l] = d * step, d[:, None] * gain
        expected += float(k[l] @ qc + 0.5 * k[l] @ qcc @ k[l])
        vx = qx + K[l].T @ qcc @ k[l] + K[l].T @ qc + qcx.T @ k[l]
        vxx = qxx + K[l].T @ qcc @ K[l] + K[l].T @ qcx + qcx.T @ K[l]
        vxx = 0.5 * (vxx + vxx.T)
    if not math.isfinite(expected):
        return None
    return k, K, expected


def _forward(problem, expansion, decisions: np.ndarray, k: np.ndarray, K: np.ndarray, step_lengths: np.ndarray,
             lower: np.ndarray, upper: np.ndarray) -> list:
    """The evaluations of the decisions closed-loop rollouts choose knot by knot, from each knot's start
    state, one per step length alpha: c_l = c_l + alpha k_l + K_l (x_l - x_l). Open loop, they
    reproduce the same motions."""
    rollouts = problem.simulator.feedback_rollouts(problem.initial_state, expansion.knot_states[:-1], decisions, k, K,
                                                   step_lengths, lower, upper, problem.decision_actuators())
    return [problem.remember(trial.reshape(-1), states, sensordata, warnings)
            for trial, states, sensordata, warnings in rollouts]
