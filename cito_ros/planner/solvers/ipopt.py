"""IPOPT (cyipopt) behind the solver seam: the limited-memory interior-point solver of the paper.

IPOPT sees scaled variables x = z / scale (solver.scale_variables), the cost
and its gradient, the constraints and their dense Jacobian. Its options come
from `solver.ipopt` in the settings; the shared stopping rules (cancellation,
time limit, stall) run in its intermediate callback.

Curvature: `limited_memory` is the paper's (IPOPT's quasi-Newton model, the
`hessian_approximation` of the options); `gauss_newton` gives IPOPT the
Hessian 2 J^T J of the cost r . r from the residual Jacobian J (forward
sensitivities through the same per-step linearization as the gradient) and
leaves out the constraints' curvature: CCCM's constraints act on knot means of
the signed distance, whose second derivatives the linearizations do not give.
"""
from __future__ import annotations

import cyipopt
import numpy as np

from cito_ros.planner.results import Status
from cito_ros.planner.solvers.base import IterationMonitor, NlpPoint, NlpProblem, StageOutcome, violation
from cito_ros.settings import IPOPT_CURVATURES, SolverSettings

# IPOPT return codes (IpReturnCodes.h)
_IPOPT_STATUS = {0: Status.CONVERGED, 1: Status.ACCEPTABLE, -1: Status.ITERATION_LIMIT,
                 -4: Status.TIME_LIMIT, -13: Status.NUMERICAL_ERROR}


class _Callbacks:
    """cyipopt's problem object over scaled variables."""

    def __init__(self, problem: NlpProblem, scale: np.ndarray, monitor: IterationMonitor):
        self.problem, self.scale, self.monitor = problem, scale, monitor
        self.lower_bounds, self.upper_bounds = problem.constraint_bounds()
        self.last: NlpPoint | None = None
        self.stop_reason: Status | None = None
        self.lower_triangle = np.tril_indices(problem.size)

    def _evaluate(self, x) -> NlpPoint:
        self.last = self.problem.evaluate(x * self.scale)
        return self.last

    def objective(self, x):
        point = self._evaluate(x)
        return point.cost if point.finite else 1e20

    def gradient(self, x):
        try:
            return self.problem.gradient(x * self.scale) * self.scale
        except FloatingPointError:
            return np.zeros_like(x)

    def constraints(self, x):
        point = self._evaluate(x)
        return point.constraints if point.finite else np.full(self.problem.n_constraints, 1e20)

    def jacobian(self, x):
        if not self.problem.n_constraints:
            return np.zeros(0)
        try:
            return (self.problem.jacobian(x * self.scale) * self.scale[None, :]).ravel()
        except FloatingPointError:
            return np.zeros(self.problem.n_constraints * self.problem.size)

    def jacobianstructure(self):
        rows, columns = np.indices((self.problem.n_constraints, self.problem.size))
        return rows.ravel(), columns.ravel()

    def hessian(self, x, lagrange, obj_factor):
        """The Gauss-Newton Hessian of the cost (lower triangle), none of the constraints'."""
        try:
            jacobian = self.problem.residual_jacobian(x * self.scale) * self.scale[None, :]
        except FloatingPointError:
            return np.zeros(len(self.lower_triangle[0]))
        return (2.0 * obj_factor) * (jacobian.T @ jacobian)[self.lower_triangle]

    def hessianstructure(self):
        return self.lower_triangle

    def intermediate(self, alg_mod, iter_count, obj_value, inf_pr, inf_du, mu, d_norm, regularization_size,
                     alpha_du, alpha_pr, ls_trials):
        last_violation = violation(self.last, self.lower_bounds, self.upper_bounds) if self.last else 0.0
        self.stop_reason = self.monitor.record(int(iter_count), float(obj_value), float(inf_pr), self.last,
                                               last_violation)
        return self.stop_reason is None


class IpoptSolver:
    """Solves one stage with IPOPT (the settings' `solver` section)."""

    def __init__(self, settings: SolverSettings, curvature: str = "limited_memory"):
        if curvature not in IPOPT_CURVATURES:
            raise ValueError(f"IPOPT's curvature must be one of {list(IPOPT_CURVATURES)}, got {curvature!r}")
        self.settings = settings
        self.options = settings.ipopt_options
        if curvature == "gauss_newton":
            self.options["hessian_approximation"] = "exact"

    @property
    def violation_tolerance(self) -> float:
        return float(self.options.get("constr_viol_tol", 1e-4))

    def solve(self, problem: NlpProblem, start: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              monitor: IterationMonitor) -> StageOutcome:
        scale = problem.scale if self.settings.scale_variables else np.ones(problem.size)
        callbacks = _Callbacks(problem, scale, monitor)
        nlp = cyipopt.Problem(n=problem.size, m=problem.n_constraints, problem_obj=callbacks,
                              lb=lower / scale, ub=upper / scale, cl=callbacks.lower_bounds, cu=callbacks.upper_bounds)
        nlp.add_option("max_iter", self.settings.max_iter)
        nlp.add_option("print_level", 0)
        nlp.add_option("sb", "yes")
        for key, value in self.options.items():
            nlp.add_option(key, value)
        x, info = nlp.solve(np.clip(start, lower, upper) / scale)
        status = callbacks.stop_reason or _IPOPT_STATUS.get(int(info["status"]), Status.SOLVER_FAILED)
        z = np.clip(x * scale, lower, upper)
        final = problem.evaluate(z)
        return monitor.outcome(z, status, final, violation(final, callbacks.lower_bounds, callbacks.upper_bounds))
