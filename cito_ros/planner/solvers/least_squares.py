"""Box-bounded Levenberg-Marquardt behind the solver seam: mujoco.minimize.least_squares on the
problem's residuals, with the Gauss-Newton model from their exact Jacobian.

The cost of a stage is r . r (cito_ros.planner.problem); the Jacobian dr/dz comes from
forward sensitivities through the per-step linearizations, so every iteration
costs one linearization and converges like Gauss-Newton near a solution. The
variables are scaled by the problem's scales (x_scale), the options come from
`solver.least_squares`, and the shared stopping rules (cancellation, time
limit, stall) run in the iteration callback. Only problems without general
constraints qualify (SCM, VSCM and the stages without the virtual force).
"""
from __future__ import annotations

import io

import numpy as np
from mujoco import minimize

from cito_ros.planner.results import Status
from cito_ros.planner.solvers.base import IterationMonitor, NlpProblem, StageOutcome
from cito_ros.settings import SolverSettings

# mujoco.minimize reports how it ended only in its final message
_ENDINGS = {minimize._STATUS_MESSAGE[status]: ours for status, ours in (
    (minimize.Status.DX_TOL, Status.CONVERGED), (minimize.Status.G_TOL, Status.CONVERGED),
    (minimize.Status.NO_IMPROVEMENT, Status.STALLED), (minimize.Status.MAX_ITER, Status.ITERATION_LIMIT),
    (minimize.Status.FACTORIZATION_FAILED, Status.SOLVER_FAILED))}


class _Stop(Exception):
    def __init__(self, status: Status):
        super().__init__(status.value)
        self.status = status


class LeastSquaresSolver:
    """Solves one box-bounded stage by Levenberg-Marquardt (the settings' `solver` section)."""

    violation_tolerance = 0.0

    def __init__(self, settings: SolverSettings):
        self.settings = settings
        self.options = settings.least_squares_options

    def solve(self, problem: NlpProblem, start: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              monitor: IterationMonitor) -> StageOutcome:
        if problem.n_constraints:
            raise ValueError("the least-squares solver takes box-bounded problems only (no CCCM constraints)")

        def callback(trace: list[minimize.IterLog]) -> None:
            point = problem.evaluate(trace[-1].candidate.reshape(-1))
            stop = monitor.record(len(trace) - 1, point.cost, 0.0, point, 0.0)
            if stop is not None:
                raise _Stop(stop)

        messages = io.StringIO()
        scale = problem.scale if self.settings.scale_variables else None
        try:
            x, _ = minimize.least_squares(
                np.clip(start, lower, upper), lambda x: problem.residuals(x.reshape(-1))[:, None],
                bounds=(lower, upper), jacobian=lambda x, r: problem.residual_jacobian(x.reshape(-1)),
                max_iter=self.settings.max_iter, verbose=minimize.Verbosity.FINAL, output=messages,
                iter_callback=callback, x_scale=scale, **self.options)
            status = next((ours for text, ours in _ENDINGS.items() if text in messages.getvalue()),
                          Status.SOLVER_FAILED)
        except _Stop as stop:
            x, status = monitor.best[2] if monitor.best is not None else start, stop.status
        except FloatingPointError:  # a Jacobian at a non-finite rollout
            x, status = monitor.best[2] if monitor.best is not None else start, Status.NUMERICAL_ERROR
        final = problem.evaluate(x)
        return monitor.outcome(x, status, final, 0.0)
